"""Normalization statistics: per-field mean/std of u, per-parameter mean/std.

One accumulator (``Moments``: float64 Welford/Chan partials per sample, merged in sample order) serves every source: a stream's calibration draw
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
    # a constant field or fixed parameter is left unscaled (a relative floor: rounding leaves a residue)
    std = var.clamp_min(0).sqrt()
    return torch.where(std > torch.maximum(1e-6 * mean.abs(), torch.full_like(std, 1e-12)), std, torch.ones_like(std))


def _partial(x: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """(count, mean [C], M2 [C]) of x [C, N] float64: the sum of squared deviations, not E[u^2] - E[u]^2."""
    x = np.ascontiguousarray(x, dtype=np.float64)  # a fresh copy: the same bits whatever array it came from
    mean = x.sum(1) / x.shape[1]
    return x.shape[1], mean, ((x - mean[:, None]) ** 2).sum(1)


def _merge(a: tuple, b: tuple) -> tuple:
    """Chan et al.'s pairwise merge of two (count, mean, M2) partials (a first: the order fixes the bits)."""
    n = a[0] + b[0]
    d = b[1] - a[1]
    return n, a[1] + d * (b[0] / n), a[2] + b[2] + d * d * (a[0] * b[0] / n)


class Moments:
    """Welford/Chan moments per field of u and per parameter (the one place that accumulates normalization
    statistics: calibration draws, caches, single batches and ``datasets.stats``).

    Each sample's (count, mean, M2) is kept apart, keyed by its sample index (``add(..., index=)``), and
    ``result`` / ``raw`` merge them in index order: the same samples give the same bits however they were split
    into reads, workers or ranks (``merge`` joins partial accumulators; a sample may be in only one of them).
    Adds without an index are keyed after every earlier one, in the order they came.
    """

    def __init__(self, ndim: int):
        self.ndim = ndim
        self.parts: dict[tuple, list] = {}  # key -> [u partial or None, params partial or None]
        self._serial = 0

    def _keys(self, index, b: int) -> list[tuple]:
        if index is None:
            self._serial += 1
            return [(1, self._serial)] * b
        index = np.asarray(index).reshape(-1)
        if len(index) != b:
            raise ValueError(f"index has {len(index)} entries for {b} samples")
        return [(0, int(i)) for i in index]

    def _put(self, key: tuple, slot: int, part: tuple) -> None:
        have = self.parts.setdefault(key, [None, None])
        have[slot] = part if have[slot] is None else _merge(have[slot], part)

    def add(self, u=None, params=None, index=None) -> None:
        """u: [B, ..., C, *space] with index [B] sample indices (each sample its own partial), or without an index
        [..., C, *space] (any leading axes, one partial); params: [B, P] (with index, one row per sample)."""
        if u is not None:
            u = np.asarray(torch.as_tensor(u).detach().cpu().double())
            if index is None:
                keys, blocks = self._keys(None, 1), [u]
            else:
                keys, blocks = self._keys(index, len(u)), list(u)
            for key, x in zip(keys, blocks):
                self._put(key, 0, _partial(np.moveaxis(x, x.ndim - self.ndim - 1, 0).reshape(x.shape[-self.ndim - 1], -1)))
        if params is not None:
            p = np.asarray(torch.as_tensor(params).detach().cpu().double())
            keys = self._keys(None, 1) if index is None else self._keys(index, len(p))
            for key, rows in zip(keys, [p] if index is None else [row[None] for row in p]):
                self._put(key, 1, _partial(rows.T))

    def merge(self, other: "Moments") -> "Moments":
        """This accumulator joined with ``other``'s samples (in place; returned). ValueError when a sample index is
        in both (it would be counted twice)."""
        twice = sorted(k[1] for k in other.parts if k[0] == 0 and k in self.parts)
        if twice:
            raise ValueError(f"samples {twice[:8]} are in both partial statistics; each sample is counted once")
        for (kind, i), slots in other.parts.items():
            self.parts[(kind, i + self._serial if kind else i)] = list(slots)
        self._serial += other._serial
        return self

    @property
    def count(self) -> int:
        """Values per field accumulated so far (every frame and grid point of every sample)."""
        return sum(p[0][0] for p in self.parts.values() if p[0] is not None)

    def raw(self, slot: int = 0) -> tuple[int, np.ndarray, np.ndarray] | None:
        """(count, mean [C], variance [C]) in float64, merged in key order (slot 0: fields, 1: parameters); None
        when nothing was added there. The variance is the population one, not floored."""
        total = None
        for key in sorted(self.parts):
            part = self.parts[key][slot]
            if part is not None:
                total = part if total is None else _merge(total, part)
        return None if total is None else (total[0], total[1], total[2] / total[0])

    def result(self, fields, params, samples: int = 0, inputs: int = 0) -> Normalization:
        """Population mean/std (std floored to 1 where ~0) as float32 Normalization (``inputs``: see there)."""
        u, p = self.raw(0), self.raw(1)
        if u is None or p is None:
            raise ValueError("no data to compute normalization statistics from (empty draw or batch)")
        (_, mean, var), (_, pmean, pvar) = u, p
        mean, var, pmean, pvar = (torch.from_numpy(a) for a in (mean, var, pmean, pvar))
        return Normalization(
            fields=tuple(fields), mean=mean.float(), std=_safe_std(var, mean).float(),
            params=tuple(params), params_mean=pmean.float(), params_std=_safe_std(pvar, pmean).float(),
            ndim=self.ndim, samples=int(samples), inputs=int(inputs),
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
        moments.add(data["u"][: len(indices)], data["params"][: len(indices)], index=indices)  # [B, T, C, *space], [B, P]
    return moments.result(_bridge.sample_channels(pde), pde.PARAMS, samples=n, inputs=len(pde.INPUTS))
