"""Viscous Burgers: u_t + u u_x = nu u_xx, written as u_t = nu u_xx - (u^2 / 2)_x."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ..domains import LogUniform
from ..ics import GaussianRandomField
from .base import PDE, Param
from .common import CFL, conservative_quadratic


@dataclass(frozen=True)
class Burgers(PDE):
    """Periodic viscous Burgers.

    Default initial condition is the FNO paper's GRF N(0, 625(-Laplacian + 25 I)^-2) on [0, 1); the
    default viscosity range loguniform(0.01, 0.1) keeps shocks at least ~4 grid cells wide at n = 256.
    The FNO set-up is ``get_pde("burgers1d", n=1024, nu=0.1, t_end=1.0, n_frames=2)``.
    Stable step: advective CFL, dt <= CFL * dx / max|u0| (max|u| never grows for Burgers).
    """

    DIMENSIONS: ClassVar[dict] = {1: {}}  # 2D (vector) and 3D: see the nonlinear family
    EQUATION: ClassVar[str] = "u_t + u u_x = nu u_xx"
    PARAMS: ClassVar[dict] = {"nu": Param("viscosity", "length^2/time", positive=True)}

    n: int = 256
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = GaussianRandomField(sigma=25.0, tau=5.0, alpha=2.0)
    nu: Any = LogUniform(0.01, 0.1)

    def linear(self, grid, p):
        return (p["nu"] * grid.laplacian())[None]

    def nonlinear(self, grid, p):
        return conservative_quadratic(grid, -0.5)

    def stable_dt(self):
        return CFL * self.grid.dx / self.ic.bound(self.grid)
