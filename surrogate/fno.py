"""Fourier Neural Operator (Li et al., 2021) for 1D, 2D and 3D fields, periodic or with walls.

Input ``x: [B, C_in, *space]`` (frames stacked into channels), optional conditioning ``params: [B, P]``
(broadcast over space as P extra input channels), output ``[B, C_out, *space]``. Normalized grid
coordinates are appended as input channels, as in the paper. Each layer is
``gelu(SpectralConv(v) + Conv1x1(v))``; the spectral convolution keeps the lowest ``modes`` Fourier modes.

The FFT treats every axis as periodic. On an axis with walls (``bc`` not 'periodic') the lifted field is padded
with zeros by PAD_FRACTION of its size at the far end before the Fourier layers and cropped after them (domain
padding, as neuraloperator's DomainPadding does), so the operator does not wrap one wall onto the other.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..boundaries import BOUNDARY_TYPES, all_periodic, kinds


@dataclass(frozen=True)
class FNOConfig:
    """width: channels inside the operator; modes: Fourier modes kept per dimension; layers: Fourier layers."""

    width: int = 32
    modes: int = 12
    layers: int = 4

    def __post_init__(self):
        for name in ("width", "modes", "layers"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"fno: {name}={value!r} not allowed; must be an integer >= 1")


PAD_FRACTION = 1 / 8  # domain padding on an axis with walls, as a share of its size (at least MIN_PAD points)
MIN_PAD = 4


def wall_padding(bc: tuple[str, ...] | None, space: tuple[int, ...]) -> tuple[int, ...]:
    """Points of zero padding per spatial axis: 0 on periodic axes, max(MIN_PAD, PAD_FRACTION n) on the others."""
    if bc is None:
        return (0,) * len(space)
    return tuple(0 if b.periodic else max(MIN_PAD, round(PAD_FRACTION * n)) for b, n in zip(kinds(bc), space))


def check_bc(bc, ndim: int, name: str) -> tuple[str, ...] | None:
    """None for all-periodic (the model as it always was), else the per-axis boundary conditions; ValueError
    for a wrong count or word."""
    if bc is None:
        return None
    bc = tuple(str(b) for b in bc)
    if len(bc) != ndim or any(b not in BOUNDARY_TYPES for b in bc):
        raise ValueError(f"{name}: bc={list(bc)} not allowed: need {ndim} of {', '.join(BOUNDARY_TYPES)} (one per axis)")
    return None if all_periodic(bc) else bc


# the FNO of the compare commands (model_cfg), small enough for a comparison in ~10 minutes on 2 CPU cores
COMPARE_FNO = {"width": 32, "modes": 12, "layers": 3}


class Pointwise(nn.Module):
    """A per-point linear map over channels, [B, C_in, *space] -> [B, C_out, *space] (a 1x1 convolution;
    nn.Linear on channels-last is about twice as fast as Conv1d(kernel_size=1) on CPU)."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.linear = nn.Linear(c_in, c_out)
        self.out_channels = c_out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.linear(x.movedim(1, -1)).movedim(-1, 1)  # [B, C_out, *space]


def pointwise(ndim: int, c_in: int, c_out: int) -> nn.Module:
    """A 1x1 convolution in 1D, 2D or 3D (ndim is accepted for symmetry with the other layer builders)."""
    return Pointwise(c_in, c_out)


class SpectralConv(nn.Module):
    """Multiply the lowest Fourier modes by learned complex weights; zero the rest.

    Weights are stored as real tensors with a trailing (re, im) axis so checkpoints hold only real floats.
    The rfft halves the last axis only, so every other axis keeps both signs of its wavenumbers: one block of
    weights per sign pattern, 2**(ndim-1) blocks (2D: [:m, :m] and [-m:, :m]; 3D: four corners).
    """

    def __init__(self, ndim: int, c_in: int, c_out: int, modes: int):
        super().__init__()
        self.ndim, self.modes = ndim, modes
        blocks = 2 ** (ndim - 1)
        scale = 1.0 / (c_in * c_out)
        shape = (blocks, c_in, c_out) + (modes,) * ndim + (2,)
        self.weight = nn.Parameter(scale * torch.rand(shape))  # [blocks, C_in, C_out, *modes, 2]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = torch.view_as_complex(self.weight)  # [blocks, C_in, C_out, *modes]
        space = x.shape[2:]
        x_ft = torch.fft.rfftn(x, dim=tuple(range(2, x.ndim)))  # [B, C_in, *space[:-1], n_last//2+1]
        out = torch.zeros(x.shape[0], w.shape[2], *x_ft.shape[2:], dtype=x_ft.dtype, device=x.device)
        kept = [min(self.modes, n // 2) for n in space[:-1]] + [min(self.modes, x_ft.shape[-1])]
        low = tuple(slice(0, m) for m in kept)  # the weights' own index: the first m of each axis
        for block, signs in enumerate(itertools.product((False, True), repeat=self.ndim - 1)):
            corner = (*(slice(-m, None) if neg else slice(0, m) for m, neg in zip(kept, signs)), low[-1])
            out[(..., *corner)] = torch.einsum("bi...,io...->bo...", x_ft[(..., *corner)], w[(block, ..., *low)])
        return torch.fft.irfftn(out, s=space, dim=tuple(range(2, x.ndim)))  # [B, C_out, *space]


def grid_channels(x: torch.Tensor, ndim: int) -> torch.Tensor:
    """Normalized coordinates in [0, 1), [B, ndim, *space], matching x [B, C, *space]."""
    space = x.shape[2:]
    axes = [torch.arange(n, dtype=x.dtype, device=x.device) / n for n in space]
    mesh = torch.meshgrid(*axes, indexing="ij")  # ndim x [*space]
    return torch.stack(mesh).unsqueeze(0).expand(x.shape[0], ndim, *space)


def condition(x: torch.Tensor, params: torch.Tensor | None, n_params: int) -> torch.Tensor:
    """Append params [B, P] broadcast over space as P channels: [B, C, *space] -> [B, C + P, *space]."""
    if n_params == 0:
        return x
    if params is None or params.shape != (x.shape[0], n_params):
        got = None if params is None else tuple(params.shape)
        raise ValueError(f"model expects params of shape [B={x.shape[0]}, P={n_params}], got {got}")
    p = params.to(x.dtype).reshape(*params.shape, *([1] * (x.ndim - 2)))  # [B, P, 1, ...]
    return torch.cat([x, p.expand(-1, -1, *x.shape[2:])], dim=1)


def check_input(x: torch.Tensor, ndim: int, in_channels: int, name: str) -> None:
    """Clear error for an input of the wrong dimensionality or channel count."""
    if x.ndim != ndim + 2 or x.shape[1] != in_channels:
        raise ValueError(f"{name} ({ndim}D, {in_channels} input channels) expects input [B, {in_channels}, "
                         f"{', '.join('n' * ndim)}], got shape {tuple(x.shape)}")


class FNO(nn.Module):
    """FNO: lift (1x1) -> ``layers`` Fourier layers -> project (1x1, 1x1)."""

    name = "fno"  # its name in surrogate.models.MODELS and in checkpoints
    Config = FNOConfig

    def __init__(self, ndim: int, in_channels: int, out_channels: int, n_params: int = 0,
                 config: FNOConfig = FNOConfig(), bc: tuple[str, ...] | None = None):
        super().__init__()
        self.ndim, self.in_channels, self.out_channels, self.n_params = ndim, in_channels, out_channels, n_params
        self.config = config
        self.bc = check_bc(bc, ndim, "fno")  # None: every axis periodic
        width = config.width
        self.lift = pointwise(ndim, in_channels + n_params + ndim, width)
        self.spectral = nn.ModuleList(SpectralConv(ndim, width, width, config.modes) for _ in range(config.layers))
        self.skip = nn.ModuleList(pointwise(ndim, width, width) for _ in range(config.layers))
        self.project = nn.Sequential(pointwise(ndim, width, 4 * width), nn.GELU(), pointwise(ndim, 4 * width, out_channels))

    def output_layer(self) -> nn.Linear:
        """The last linear map, width*4 -> out_channels per point (``surrogate.models.zero_output``)."""
        return self.project[-1].linear

    def forward(self, x: torch.Tensor, params: torch.Tensor | None = None) -> torch.Tensor:
        check_input(x, self.ndim, self.in_channels, "fno")
        x = condition(x, params, self.n_params)  # [B, C_in + P, *space]
        v = self.lift(torch.cat([x, grid_channels(x, self.ndim)], dim=1))  # [B, width, *space]
        space = v.shape[2:]
        pads = wall_padding(self.bc, tuple(space))
        if any(pads):  # zeros after each wall axis's far end: F.pad takes the last axis first
            v = F.pad(v, [q for pad in reversed(pads) for q in (0, pad)])  # [B, width, *(space + pads)]
        for i, (spec, skip) in enumerate(zip(self.spectral, self.skip)):
            v = spec(v) + skip(v)  # [B, width, *padded space]
            if i < len(self.spectral) - 1:  # no activation after the last layer, as in the paper
                v = F.gelu(v)
        if any(pads):
            v = v[(..., *(slice(0, n) for n in space))]  # [B, width, *space]
        return self.project(v)  # [B, C_out, *space]


__all__ = ["COMPARE_FNO", "FNO", "FNOConfig", "SpectralConv", "check_bc", "check_input", "condition", "pointwise",
           "wall_padding"]
