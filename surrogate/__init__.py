"""pdestream.surrogate: torch models and the training loop (never imports JAX).

    MODELS, build_model(name, ndim, in_channels, out_channels, n_params, **cfg)   models.py (fno.py, unet.py)
    train.train(model, loader, steps, out_dir), load_checkpoint(path)            train.py: one loop, any DataLoader
    rel_l2, nrmse; evaluate, rollout_error                                       metrics.py, evaluate.py
    train_loader, test_set; train_run                                            data.py, runs.py (CLI `train`)
    compare(pde, out_dir, CompareConfig())                                       compare.py (CLI `compare`)
"""

from .fno import FNO, FNOConfig
from .models import MODELS, build_model, model_spec
from .train import load_checkpoint
from .unet import UNet, UNetConfig

__all__ = ["FNO", "FNOConfig", "MODELS", "UNet", "UNetConfig", "build_model", "load_checkpoint",
           "model_spec"]
