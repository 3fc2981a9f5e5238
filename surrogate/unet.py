"""A small U-Net for 1D, 2D and 3D fields, periodic or with walls.

Input ``x: [B, C_in, *space]`` (frames stacked into channels), optional conditioning ``params: [B, P]``
(broadcast over space as P extra input channels), output ``[B, C_out, *space]``. Convolutions pad each axis by
its boundary condition: circularly on a periodic axis, with zeros on a Dirichlet one (a wall of given value: the
normalized field's wall value is a constant the convolution learns around), by replication on a Neumann one
(zero gradient across the wall). Each level halves the resolution and doubles the channels, so every spatial
size must be divisible by ``2**depth``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..boundaries import Boundary
from .fno import check_bc, check_input, condition, pointwise

PAD_MODE = {b.value: b.pad_mode for b in Boundary}  # boundary word -> torch padding mode (Boundary.pad_mode)
CONV = {1: nn.Conv1d, 2: nn.Conv2d, 3: nn.Conv3d}
POOL = {1: F.avg_pool1d, 2: F.avg_pool2d, 3: F.avg_pool3d}


@dataclass(frozen=True)
class UNetConfig:
    """channels: width of the first level (doubled per level); depth: number of down/up-samplings."""

    channels: int = 16
    depth: int = 3

    def __post_init__(self):
        for name in ("channels", "depth"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"unet: {name}={value!r} not allowed; must be an integer >= 1")


class WallConv(nn.Module):
    """A 3-point / 3x3 / 3x3x3 convolution after padding each axis by one point in its boundary condition's mode."""

    def __init__(self, ndim: int, c_in: int, c_out: int, bc: tuple[str, ...]):
        super().__init__()
        self.conv = CONV[ndim](c_in, c_out, 3)
        self.modes = [Boundary.of(b).pad_mode for b in bc]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        ndim = len(self.modes)
        for axis, mode in enumerate(self.modes):  # one axis at a time; F.pad lists the last axis first
            pad = [0, 0] * ndim
            pad[2 * (ndim - 1 - axis) : 2 * (ndim - axis)] = [1, 1]
            x = F.pad(x, pad, mode=mode)
        return self.conv(x)  # [B, C_out, *space]


def conv(ndim: int, c_in: int, c_out: int, bc: tuple[str, ...] | None = None) -> nn.Module:
    """3-point (1D), 3x3 (2D) or 3x3x3 (3D) convolution: periodic padding (bc None), else padded per axis (WallConv)."""
    if bc is None:
        return CONV[ndim](c_in, c_out, 3, padding=1, padding_mode="circular")
    return WallConv(ndim, c_in, c_out, bc)


class Block(nn.Module):
    """Two convolutions with GroupNorm and GELU, plus a 1x1 residual path."""

    def __init__(self, ndim: int, c_in: int, c_out: int, bc: tuple[str, ...] | None = None):
        super().__init__()
        groups = 4 if c_out % 4 == 0 else 1
        self.body = nn.Sequential(conv(ndim, c_in, c_out, bc), nn.GroupNorm(groups, c_out), nn.GELU(),
                                  conv(ndim, c_out, c_out, bc), nn.GroupNorm(groups, c_out), nn.GELU())
        self.skip = pointwise(ndim, c_in, c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x) + self.skip(x)  # [B, C_out, *space]


class UNet(nn.Module):
    """Encoder (Block, avg-pool) x depth -> bottleneck -> decoder (upsample, concat skip, Block) x depth."""

    name = "unet"  # its name in surrogate.models.MODELS and in checkpoints
    Config = UNetConfig

    def __init__(self, ndim: int, in_channels: int, out_channels: int, n_params: int = 0,
                 config: UNetConfig = UNetConfig(), bc: tuple[str, ...] | None = None):
        super().__init__()
        self.ndim, self.in_channels, self.out_channels, self.n_params = ndim, in_channels, out_channels, n_params
        self.config = config
        self.bc = bc = check_bc(bc, ndim, "unet")  # None: every axis periodic
        widths = [config.channels * 2**i for i in range(config.depth + 1)]  # per level, finest first
        self.stem = Block(ndim, in_channels + n_params, widths[0], bc)
        self.down = nn.ModuleList(Block(ndim, widths[i], widths[i + 1], bc) for i in range(config.depth))
        self.up = nn.ModuleList(Block(ndim, widths[i + 1] + widths[i], widths[i], bc)
                                for i in reversed(range(config.depth)))
        self.head = pointwise(ndim, widths[0], out_channels)

    def output_layer(self) -> nn.Linear:
        """The head's linear map, channels -> out_channels per point (``surrogate.models.zero_output``)."""
        return self.head.linear

    def forward(self, x: torch.Tensor, params: torch.Tensor | None = None) -> torch.Tensor:
        check_input(x, self.ndim, self.in_channels, "unet")
        factor = 2**self.config.depth
        if any(n % factor for n in x.shape[2:]):
            raise ValueError(f"unet depth={self.config.depth} needs every grid size divisible by {factor}, "
                             f"got {tuple(x.shape[2:])}; lower depth or change the resolution")
        pool = POOL[self.ndim]
        h = self.stem(condition(x, params, self.n_params))  # [B, c, *space]
        skips = []
        for block in self.down:
            skips.append(h)
            h = block(pool(h, 2))  # [B, 2c, *space/2]
        for block in self.up:
            skip = skips.pop()
            h = F.interpolate(h, size=skip.shape[2:], mode="nearest")  # [B, 2c, *space]
            h = block(torch.cat([h, skip], dim=1))  # [B, c, *space]
        return self.head(h)  # [B, C_out, *space]
