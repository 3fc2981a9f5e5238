"""pdestream.surrogate: torch models and the training loop (never imports JAX).

    MODELS, build_model(name, ndim, in_channels, out_channels, n_params, **cfg)   models.py (fno.py, unet.py)
    stack_frames, predict, pairs, rollout, relative_errors                       predict.py: the network's side
    train.train(model, loader, Stop(steps= | seconds=), out_dir)                 train.py: the one training loop
    save/load_checkpoint, train_state, atomic_write                              checkpoint.py: a run's files
    rel_l2, nrmse; rollout_errors, test_errors                                   metrics.py, evaluate.py
    MODE_SPECS, mode_settings; MODES, make_mode                                  mode_table.py (no torch), modes.py
    train_loader, test_set; train_run                                            data.py, runs.py
    TrainConfig; train(cfg): a new, resumed or --ddp run (CLI `train`)          config.py (no torch), launch.py
    compare(pde, out_dir, CompareConfig())                                       compare.py (CLI `compare`)

The names below load on first use, so that ``surrogate.mode_table`` (the CLI's choices) does not import torch.
"""

import importlib

_WHERE = {"FNO": "fno", "FNOConfig": "fno", "MODELS": "models", "build_model": "models", "model_spec": "models",
          "load_checkpoint": "checkpoint", "UNet": "unet", "UNetConfig": "unet"}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'pdestream.surrogate' has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
