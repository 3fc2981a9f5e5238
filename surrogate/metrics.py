"""Evaluation metrics, per sample then averaged over the batch by the caller.

- ``rel_l2``: ||pred - y||_2 / ||y||_2 over all channels, frames and grid points of one sample.
- ``nrmse``: PDEBench's normalized RMSE: RMSE over space divided by the RMS of the target, computed per
  sample, per field (and per frame when there are frames), then averaged over fields/frames.
"""

from __future__ import annotations

import torch

EPS = 1e-12  # keeps an all-zero target from dividing by zero


def rel_l2(pred: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """pred, y [B, ...] -> [B] relative L2 error per sample."""
    diff = (pred - y).flatten(1).norm(dim=1)  # [B]
    return diff / (y.flatten(1).norm(dim=1) + EPS)


def nrmse(pred: torch.Tensor, y: torch.Tensor, ndim: int) -> torch.Tensor:
    """pred, y [B, ..., C, *space] (ndim space dims) -> [B] nRMSE per sample (PDEBench)."""
    dims = tuple(range(y.ndim - ndim, y.ndim))
    rmse = (pred - y).pow(2).mean(dim=dims).sqrt()  # [B, ..., C]
    rms = y.pow(2).mean(dim=dims).sqrt()  # [B, ..., C]
    return (rmse / (rms + EPS)).flatten(1).mean(dim=1)  # [B]


def summarize(errors: dict[str, list[torch.Tensor]]) -> dict[str, float]:
    """{"rel_l2": [per-batch [B] tensors]} -> {"rel_l2": mean over all samples}."""
    return {k: float(torch.cat(v).mean()) for k, v in errors.items()}
