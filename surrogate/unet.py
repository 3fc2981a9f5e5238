"""A small U-Net for periodic 1D and 2D fields.

Input ``x: [B, C_in, *space]`` (frames stacked into channels), optional conditioning ``params: [B, P]``
(broadcast over space as P extra input channels), output ``[B, C_out, *space]``. Convolutions pad
circularly because every pdestream domain is periodic. Each level halves the resolution and doubles the
channels, so every spatial size must be divisible by ``2**depth``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .fno import check_input, condition, pointwise


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


def conv(ndim: int, c_in: int, c_out: int) -> nn.Module:
    """3-point (1D) or 3x3 (2D) convolution with periodic padding."""
    return (nn.Conv1d if ndim == 1 else nn.Conv2d)(c_in, c_out, 3, padding=1, padding_mode="circular")


class Block(nn.Module):
    """Two convolutions with GroupNorm and GELU, plus a 1x1 residual path."""

    def __init__(self, ndim: int, c_in: int, c_out: int):
        super().__init__()
        groups = 4 if c_out % 4 == 0 else 1
        self.body = nn.Sequential(conv(ndim, c_in, c_out), nn.GroupNorm(groups, c_out), nn.GELU(),
                                  conv(ndim, c_out, c_out), nn.GroupNorm(groups, c_out), nn.GELU())
        self.skip = pointwise(ndim, c_in, c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x) + self.skip(x)  # [B, C_out, *space]


class UNet(nn.Module):
    """Encoder (Block, avg-pool) x depth -> bottleneck -> decoder (upsample, concat skip, Block) x depth."""

    name = "unet"  # its name in surrogate.models.MODELS and in checkpoints
    Config = UNetConfig

    def __init__(self, ndim: int, in_channels: int, out_channels: int, n_params: int = 0,
                 config: UNetConfig = UNetConfig()):
        super().__init__()
        self.ndim, self.in_channels, self.out_channels, self.n_params = ndim, in_channels, out_channels, n_params
        self.config = config
        widths = [config.channels * 2**i for i in range(config.depth + 1)]  # per level, finest first
        self.stem = Block(ndim, in_channels + n_params, widths[0])
        self.down = nn.ModuleList(Block(ndim, widths[i], widths[i + 1]) for i in range(config.depth))
        self.up = nn.ModuleList(Block(ndim, widths[i + 1] + widths[i], widths[i]) for i in reversed(range(config.depth)))
        self.head = pointwise(ndim, widths[0], out_channels)

    def forward(self, x: torch.Tensor, params: torch.Tensor | None = None) -> torch.Tensor:
        check_input(x, self.ndim, self.in_channels, "unet")
        factor = 2**self.config.depth
        if any(n % factor for n in x.shape[2:]):
            raise ValueError(f"unet depth={self.config.depth} needs every grid size divisible by {factor}, "
                             f"got {tuple(x.shape[2:])}; lower depth or change the resolution")
        pool = F.avg_pool1d if self.ndim == 1 else F.avg_pool2d
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
