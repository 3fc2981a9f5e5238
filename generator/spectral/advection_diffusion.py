"""Advection-diffusion in 1D/2D: u_t + c . grad(u) = nu Laplacian(u) (each Fourier mode travels and decays)."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ...boundaries import BOUNDARY_TYPES
from ..domains import LogUniform, Uniform
from ..ics import FourierSeries
from .base import LinearPDE, Param
from .common import CFL, drift, velocity_params


@dataclass(frozen=True)
class AdvectionDiffusion(LinearPDE):
    """Periodic advection-diffusion on the unit box with a random constant velocity and diffusivity.

    Parameters: velocity ``c`` (1D) or ``c_x, c_y`` (2D), each uniform(-1, 1) length/time, and diffusivity
    nu ~ loguniform(1e-3, 1e-2) length^2/time (as diffusion1d: the IC's modes neither freeze nor vanish by
    t = 1). Mode k evolves as exp((-i c . k - nu |k|^2) t): linear, so each step is that exact exponential
    (no step limit); the 5-mode Fourier-series IC is resolved on the default grids (128, 64^2).
    """

    EQUATION: ClassVar[str] = "u_t + c u_x = nu u_xx"
    PARAMS: ClassVar[dict] = {}  # set per dimension by for_dimension
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64}}
    BOUNDARIES: ClassVar[tuple] = BOUNDARY_TYPES  # `--set bc=...` (generator.pdes.walls)

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    c: Any = Uniform(-1.0, 1.0)
    c_x: Any = Uniform(-1.0, 1.0)
    c_y: Any = Uniform(-1.0, 1.0)
    c_z: Any = Uniform(-1.0, 1.0)
    nu: Any = LogUniform(1e-3, 1e-2)

    @classmethod
    def for_dimension(cls, ndim):
        nu = {"nu": Param("diffusivity", "length^2/time", positive=True)}
        equation = "u_t + c u_x = nu u_xx" if ndim == 1 else "u_t + c . grad(u) = nu Laplacian(u)"
        return velocity_params(ndim, "advection", equation, extra=nu)

    def linear(self, grid, p):
        return (drift(grid, p, self.NDIM) + p["nu"] * grid.laplacian())[None]

    # --- on walls: c . grad(u) is not diagonal in a sine / cosine basis, so it goes into the explicit part ---
    def _velocity(self):
        return ["c"] if self.NDIM == 1 else [f"c_{a}" for a in "xyz"[: self.NDIM]]

    def wall_linear(self, grid, p):
        return (p["nu"] * grid.laplacian())[None]

    def wall_terms(self, grid, p):
        names = self._velocity()
        return lambda u, grad: -sum(p[name] * grad(axis) for axis, name in enumerate(names))

    def wall_stable_dt(self):
        """Explicit advection: the advective CFL, dt <= CFL * dx / sum of max|c| over the axes."""
        return CFL * self.grid.dx / max(sum(self.param_upper(name) for name in self._velocity()), 1e-12)
