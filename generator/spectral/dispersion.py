"""Linear dispersion (the linear part of KdV) in 1D: u_t + beta u_xxx = 0."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from pdestream.generator.lazy_jax import jnp

from ..domains import LogUniform
from ..ics import FourierSeries
from .base import LinearPDE, Param


@dataclass(frozen=True)
class Dispersion(LinearPDE):
    """Periodic linear dispersion on the unit interval: mode k travels at phase speed -beta k^2.

    beta ~ loguniform(1e-4, 1e-3) length^3/time: the IC's top mode (m = 5, k = 10 pi) moves 0.1..1 box
    lengths per unit time and its lowest (m = 1) 1/25 of that, so waves disperse visibly but slowly enough for
    51 frames to follow. Symbol -beta (ik)^3 = i beta k^3: linear, so each step is the exact exponential (no step
    limit); the 5-mode Fourier-series IC is resolved on the default grid (128).
    """

    EQUATION: ClassVar[str] = "u_t + beta u_xxx = 0"
    PARAMS: ClassVar[dict] = {"beta": Param("dispersion coefficient", "length^3/time", positive=True)}
    DIMENSIONS: ClassVar[dict] = {1: {}}

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    beta: Any = LogUniform(1e-4, 1e-3)

    def linear(self, grid, p):
        (k,) = grid.wavenumbers()
        return (1j * p["beta"] * k**3)[None].astype(jnp.complex64)
