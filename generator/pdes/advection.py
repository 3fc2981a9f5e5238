"""Linear advection: u_t + c u_x = 0 (solution: the initial condition translated by c t)."""

from dataclasses import dataclass
from typing import Any, ClassVar

import jax.numpy as jnp

from ..domains import Uniform
from ..ics import FourierSeries
from .base import PDE, Param


@dataclass(frozen=True)
class Advection1D(PDE):
    """Periodic linear advection. Linear, so each step is the exact exponential e^{-i c k h}: no step limit."""

    NAME: ClassVar[str] = "advection1d"
    EQUATION: ClassVar[str] = "u_t + c u_x = 0"
    PARAMS: ClassVar[dict] = {"c": Param("advection speed", "length/time")}

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    c: Any = Uniform(-1.0, 1.0)

    def linear(self, grid, p):
        (k,) = grid.wavenumbers()
        return (-1j * p["c"] * k)[None].astype(jnp.complex64)
