"""pdestream.surrogate: torch models and the training loop (never imports JAX).

    MODELS                                   {"fno": (FNO, FNOConfig), "unet": (UNet, UNetConfig)}
    build_model(name, ndim, in_channels, out_channels, n_params, **cfg)
    train(model, loader, ...)                one loop for any DataLoader of batch dicts (train.py)
    rel_l2, nrmse, rollout_error             evaluation metrics (metrics.py)
"""

from .fno import FNO, FNOConfig
from .models import MODELS, build_model, model_spec
from .unet import UNet, UNetConfig

__all__ = ["FNO", "FNOConfig", "MODELS", "UNet", "UNetConfig", "build_model", "model_spec"]
