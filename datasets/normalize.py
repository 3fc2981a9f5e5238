"""Normalization statistics from a calibration draw: per-field mean/std of u, per-parameter mean/std."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from . import _bridge


@dataclass(frozen=True)
class Normalization:
    """mean/std: float32 [C] per field; params_mean/params_std: float32 [P]; ndim: spatial dimensions.

    ``normalize`` takes any tensor whose dimension -(ndim+1) is the field axis: [..., C, *space]
    (every view's u, x and y have that layout).
    """

    fields: tuple[str, ...]
    mean: torch.Tensor
    std: torch.Tensor
    params: tuple[str, ...]
    params_mean: torch.Tensor
    params_std: torch.Tensor
    ndim: int

    def _shape(self, stat: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        return stat.to(like.device, like.dtype).reshape(-1, *([1] * self.ndim))

    def normalize(self, u: torch.Tensor) -> torch.Tensor:
        return (u - self._shape(self.mean, u)) / self._shape(self.std, u)

    def denormalize(self, u: torch.Tensor) -> torch.Tensor:
        return u * self._shape(self.std, u) + self._shape(self.mean, u)

    def normalize_params(self, p: torch.Tensor) -> torch.Tensor:
        """p: [..., P] in the PDE's PARAMS order."""
        return (p - self.params_mean.to(p.device, p.dtype)) / self.params_std.to(p.device, p.dtype)

    def to_dict(self) -> dict:
        """Plain lists (JSON-able, for checkpoints); ``Normalization.from_dict`` inverts it."""
        return {k: (v.tolist() if isinstance(v, torch.Tensor) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "Normalization":
        tensors = ("mean", "std", "params_mean", "params_std")
        return cls(**{k: (torch.tensor(v, dtype=torch.float32) if k in tensors else
                          (tuple(v) if isinstance(v, list) else v)) for k, v in d.items()})


def _safe_std(var: torch.Tensor) -> torch.Tensor:
    std = var.clamp_min(0).sqrt()
    return torch.where(std > 1e-12, std, torch.ones_like(std))  # a constant field is left unscaled


def compute_normalization(pde, seed: int = 0, n: int = 64, solve_batch: int = 16) -> Normalization:
    """Statistics over samples 0..n-1 of (pde, seed), all frames and grid points; float64 accumulation."""
    pde = _bridge.resolve_pde(pde)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n={n!r} not allowed; the calibration draw needs an integer n >= 1")
    if isinstance(solve_batch, bool) or not isinstance(solve_batch, (int, np.integer)) or solve_batch < 1:
        raise ValueError(f"solve_batch={solve_batch!r} not allowed; must be an integer >= 1")
    total = s1 = s2 = p1 = p2 = 0
    for lo in range(0, n, solve_batch):
        indices = np.arange(lo, min(lo + solve_batch, n))
        data = _bridge.sample_tensors(pde, np.resize(indices, solve_batch), seed)
        u = data["u"][: len(indices)].double().transpose(0, 2).flatten(1)  # [C, B*T*space]
        p = data["params"][: len(indices)].double()  # [B, P]
        s1, s2, total = s1 + u.sum(1), s2 + (u * u).sum(1), total + u.shape[1]
        p1, p2 = p1 + p.sum(0), p2 + (p * p).sum(0)
    mean, pmean = s1 / total, p1 / n
    return Normalization(
        fields=tuple(pde.FIELDS), mean=mean.float(), std=_safe_std(s2 / total - mean**2).float(),
        params=tuple(pde.PARAMS), params_mean=pmean.float(), params_std=_safe_std(p2 / n - pmean**2).float(),
        ndim=pde.NDIM,
    )
