"""Viscous Burgers: u_t + u u_x = nu u_xx (1D, written as u_t = nu u_xx - (u^2 / 2)_x); in 2D/3D the vector
equation u_t + (u . grad) u = nu Laplacian(u) for the velocity u = (u, v[, w])."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from pdestream.generator.lazy_jax import jnp

from ...boundaries import BOUNDARY_TYPES, pins_value
from ..domains import LogUniform
from ..ics import GaussianRandomField
from .base import PDE, Param
from .common import CFL, conservative_quadratic
from .terms import advection_of_velocity

VELOCITY_FIELDS = ("u", "v", "w")


@dataclass(frozen=True)
class Burgers(PDE):
    """Periodic viscous Burgers; velocity in length/time, nu in length^2/time, on [0, 1)^d.

    1D: default initial condition is the FNO paper's GRF N(0, 625(-Laplacian + 25 I)^-2) on [0, 1); the
    default viscosity range loguniform(0.01, 0.1) keeps shocks at least ~4 grid cells wide at n = 256.
    The FNO set-up is ``get_pde("burgers1d", n=1024, nu=0.1, t_end=1.0, n_frames=2)``.
    2D/3D: the vector equation in advective form, fields u, v(, w) (velocity components), each component an
    independent GRF (2D: n = 64, N(0, 625(-Laplacian + 25 I)^-2.5), max|u0| ~ 1.4; 3D: n = 32,
    N(0, 225(-Laplacian + 25 I)^-2.5), ~1.3), nu ~ loguniform(0.02, 0.1) (2D) / loguniform(0.04, 0.1) (3D):
    shocks >= ~3 cells. Same equation as Exponax's Burgers (diffusivity nu, convection_scale 1, not
    conservative). The mean velocity is conserved for potential flows u = grad(phi) (then (u . grad) u =
    grad |u|^2 / 2), not in general. Good ranges: nu >= ~3 dx max|u0| / 2.
    Stable step: advective CFL, dt <= CFL * dx / (d max|u0|) (each component obeys a maximum principle).
    """

    DIMENSIONS: ClassVar[dict] = {
        1: {},
        2: {"n": 64, "t_end": 0.5, "ic": GaussianRandomField(sigma=25.0, tau=5.0, alpha=2.5),
            "nu": LogUniform(0.02, 0.1)},
        3: {"n": 32, "t_end": 0.5, "n_frames": 26, "ic": GaussianRandomField(sigma=15.0, tau=5.0, alpha=2.5),
            "nu": LogUniform(0.04, 0.1)},
    }
    EQUATION: ClassVar[str] = "u_t + u u_x = nu u_xx"
    BOUNDARIES: ClassVar[tuple] = BOUNDARY_TYPES  # `--set bc=...` (generator.pdes.walls)
    PARAMS: ClassVar[dict] = {"nu": Param("viscosity", "length^2/time", positive=True)}
    FIELD_UNITS: ClassVar[dict] = {name: "length/time" for name in VELOCITY_FIELDS}  # velocity components

    n: int = 256
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = GaussianRandomField(sigma=25.0, tau=5.0, alpha=2.0)
    nu: Any = LogUniform(0.01, 0.1)

    def linear(self, grid, p):
        op = (p["nu"] * grid.laplacian())[None]
        return op if self.NDIM == 1 else jnp.broadcast_to(op, (self.NDIM, *grid.kshape))  # one per component

    @classmethod
    def for_dimension(cls, ndim):
        if ndim == 1:
            return {}
        return {"FIELDS": VELOCITY_FIELDS[:ndim], "EQUATION": "u_t + (u . grad) u = nu Laplacian(u)"}

    def nonlinear(self, grid, p):
        return conservative_quadratic(grid, -0.5) if self.NDIM == 1 else advection_of_velocity(grid)

    def stable_dt(self):
        return CFL * self.grid.dx / (self.NDIM * self.ic.bound(self.grid))

    def wall_terms(self, grid, p):
        """-(u . grad) u in physical space (no-slip walls on a Dirichlet axis); None where wall_flux takes it."""
        if self.wall_flux(grid, p) is not None:
            return None
        return lambda u, grad: -sum(u[j] * grad(j) for j in range(self.NDIM))

    def wall_flux(self, grid, p):
        """1D between Dirichlet walls: -(u^2 / 2)_x, as on the periodic box (u^2 is even about the walls, so its
        cosine series differentiates into the sine basis exactly: one transform fewer than u u_x)."""
        return (lambda u: [0.5 * u * u]) if len(grid.bc) == 1 and pins_value(grid.bc) else None
