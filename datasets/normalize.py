"""Normalization statistics: per-field mean/std of u, per-parameter mean/std.

One accumulator (``Moments``, float64 sums) serves every source: a stream's calibration draw
(``compute_normalization``), a cache's stored samples (``CachedTrajectories.normalization``) and, as a
fallback for other loaders, one batch (``Normalization.from_batch``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from . import _bridge


@dataclass(frozen=True)
class Normalization:
    """mean/std: float32 [C] per field; params_mean/params_std: float32 [P]; ndim: spatial dimensions.

    ``normalize`` takes any tensor whose dimension -(ndim+1) is the field axis: [..., C, *space]
    (every view's u, x and y have that layout). ``inputs``: how many leading fields are a steady PDE's input
    fields (0 otherwise; ``datasets._bridge.sample_channels``): an operator view's x holds those and y the
    rest, so ``of_x`` / ``of_y`` give the statistics of each (both are the whole set when inputs is 0).
    """

    fields: tuple[str, ...]
    mean: torch.Tensor
    std: torch.Tensor
    params: tuple[str, ...]
    params_mean: torch.Tensor
    params_std: torch.Tensor
    ndim: int
    samples: int = 0  # trajectories the statistics came from (0: unknown)
    inputs: int = 0  # leading fields that are a steady PDE's input fields

    def _part(self, part: slice) -> "Normalization":
        return dataclasses.replace(self, fields=self.fields[part], mean=self.mean[part], std=self.std[part], inputs=0)

    @property
    def of_x(self) -> "Normalization":
        """The statistics of a view's x: a steady PDE's input fields, else every field."""
        return self._part(slice(0, self.inputs)) if self.inputs else self

    @property
    def of_y(self) -> "Normalization":
        """The statistics of a view's y: a steady PDE's solution fields, else every field."""
        return self._part(slice(self.inputs, None)) if self.inputs else self

    def _shape(self, stat: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        return stat.to(like.device, like.dtype).reshape(-1, *([1] * self.ndim))

    def to(self, device: torch.device | str) -> "Normalization":
        """The same statistics held on ``device``, so that normalizing a batch there copies nothing to it (a
        copy from pageable host memory waits for the device's queue: a stall per call in a GPU training step)."""
        return dataclasses.replace(self, mean=self.mean.to(device), std=self.std.to(device),
                                   params_mean=self.params_mean.to(device), params_std=self.params_std.to(device))

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
    def from_batch(cls, batch: dict, ndim: int, fields=None, params=None) -> "Normalization":
        """Statistics of one batch dict (a fallback for sources without their own): fields over "x" and "y"
        (or "u"), [..., C, *space]; parameters over "params" [B, P]. Names default to field0.., param0.."""
        moments = Moments(ndim)
        for key in ("x", "y") if "x" in batch else ("u",):
            moments.add(batch[key])
        moments.add(params=batch["params"])
        c, p = batch["x" if "x" in batch else "u"].shape[-ndim - 1], batch["params"].shape[-1]
        n = len(torch.unique(batch["index"])) if "index" in batch else len(batch["params"])
        return moments.result(fields or [f"field{i}" for i in range(c)], params or [f"param{i}" for i in range(p)], n)

    @classmethod
    def from_dict(cls, d: dict) -> "Normalization":
        tensors = ("mean", "std", "params_mean", "params_std")
        return cls(**{k: (torch.tensor(v, dtype=torch.float32) if k in tensors else
                          (tuple(v) if isinstance(v, list) else v)) for k, v in d.items()})


def _safe_std(var: torch.Tensor, mean: torch.Tensor) -> torch.Tensor:
    # a constant field or fixed parameter is left unscaled; var = E[u^2] - E[u]^2 leaves a rounding residue
    # of ~1e-8 |mean| for constants, hence the relative floor
    std = var.clamp_min(0).sqrt()
    return torch.where(std > torch.maximum(1e-6 * mean.abs(), torch.full_like(std, 1e-12)), std, torch.ones_like(std))


class Moments:
    """Float64 running sums of u and u^2 per field and of p and p^2 per parameter (the one place that
    accumulates normalization statistics: calibration draws, caches and single batches)."""

    def __init__(self, ndim: int):
        self.ndim = ndim
        self.s1 = self.s2 = self.p1 = self.p2 = 0
        self.count = self.n_params = 0

    def add(self, u: torch.Tensor | None = None, params: torch.Tensor | None = None) -> None:
        """u: [..., C, *space] (any leading axes); params: [B, P]."""
        if u is not None:
            u = u.double().movedim(-self.ndim - 1, 0).flatten(1)  # [C, N]
            self.s1, self.s2, self.count = self.s1 + u.sum(1), self.s2 + (u * u).sum(1), self.count + u.shape[1]
        if params is not None:
            p = params.double()
            self.p1, self.p2, self.n_params = self.p1 + p.sum(0), self.p2 + (p * p).sum(0), self.n_params + len(p)

    def result(self, fields, params, samples: int = 0, inputs: int = 0) -> Normalization:
        """Population mean/std (std floored to 1 where ~0) as float32 Normalization (``inputs``: see there)."""
        if not self.count or not self.n_params:
            raise ValueError("no data to compute normalization statistics from (empty draw or batch)")
        mean, pmean = self.s1 / self.count, self.p1 / self.n_params
        return Normalization(
            fields=tuple(fields), mean=mean.float(), std=_safe_std(self.s2 / self.count - mean**2, mean).float(),
            params=tuple(params), params_mean=pmean.float(),
            params_std=_safe_std(self.p2 / self.n_params - pmean**2, pmean).float(), ndim=self.ndim, samples=int(samples),
            inputs=int(inputs),
        )


def compute_normalization(pde, seed: int = 0, n: int = 64, solve_batch: int = 16) -> Normalization:
    """Statistics over samples 0..n-1 of (pde, seed), all frames and grid points; float64 accumulation."""
    pde = _bridge.resolve_pde(pde)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n={n!r} not allowed; the calibration draw needs an integer n >= 1")
    if isinstance(solve_batch, bool) or not isinstance(solve_batch, (int, np.integer)) or solve_batch < 1:
        raise ValueError(f"solve_batch={solve_batch!r} not allowed; must be an integer >= 1")
    moments = Moments(pde.NDIM)
    for lo in range(0, n, solve_batch):
        indices = np.arange(lo, min(lo + solve_batch, n))
        data = _bridge.sample_tensors(pde, np.resize(indices, solve_batch), seed)
        moments.add(data["u"][: len(indices)], data["params"][: len(indices)])  # [B, T, C, *space], [B, P]
    return moments.result(_bridge.sample_channels(pde), pde.PARAMS, samples=n, inputs=len(pde.INPUTS))
