"""pdestream.surrogate: torch models and the training loop (never imports JAX).

    MODELS, build_model(name, ndim, in_channels, out_channels, n_params, **cfg)   models.py (fno.py, unet.py)
    stack_frames, predict, pairs, rollout, relative_errors                       predict.py: the network's side
    train.train(model, loader, steps, out_dir)                                   train.py: one loop, any DataLoader
    save/load_checkpoint, train_state, atomic_write                              checkpoint.py: a run's files
    rel_l2, nrmse; evaluate, rollout_errors                                      metrics.py, evaluate.py
    train_loader, test_set; train_run                                            data.py, runs.py (CLI `train`)
    compare(pde, out_dir, CompareConfig())                                       compare.py (CLI `compare`)
"""

from .checkpoint import load_checkpoint
from .fno import FNO, FNOConfig
from .models import MODELS, build_model, model_spec
from .unet import UNet, UNetConfig

__all__ = ["FNO", "FNOConfig", "MODELS", "UNet", "UNetConfig", "build_model", "load_checkpoint",
           "model_spec"]
