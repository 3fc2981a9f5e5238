"""Linear advection in 1D/2D/3D: u_t + c . grad(u) = 0 (solution: the initial condition translated by c t)."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ..domains import Uniform
from ..ics import FourierSeries
from .base import LinearPDE, Param
from .common import drift, velocity_params


@dataclass(frozen=True)
class Advection(LinearPDE):
    """Periodic linear advection with a random constant velocity c (length/time).

    Parameters: ``c`` in 1D; ``c_x, c_y`` (``c_z``) in 2D (3D), each uniform(-1, 1) on the unit box, so a
    feature crosses at most one box length per unit time. Linear, so each step is the exact exponential
    e^{-i (c . k) h}: no step limit. The default 5-mode Fourier-series IC is resolved on every default grid
    and no new modes ever appear.
    """

    EQUATION: ClassVar[str] = "u_t + c u_x = 0"
    PARAMS: ClassVar[dict] = {"c": Param("advection speed", "length/time")}
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64}, 3: {"n": 32, "n_frames": 26}}

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    c: Any = Uniform(-1.0, 1.0)
    c_x: Any = Uniform(-1.0, 1.0)
    c_y: Any = Uniform(-1.0, 1.0)
    c_z: Any = Uniform(-1.0, 1.0)

    @classmethod
    def for_dimension(cls, ndim):
        return velocity_params(ndim, "advection", "u_t + c u_x = 0" if ndim == 1 else "u_t + c . grad(u) = 0")

    def linear(self, grid, p):
        return drift(grid, p, self.NDIM)[None]
