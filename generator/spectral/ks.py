"""Kuramoto-Sivashinsky: u_t + u u_x + u_xx + nu u_xxxx = 0 in 1D; the scalar (combustion) form
u_t + |grad u|^2 / 2 + Laplacian(u) + nu Laplacian^2(u) = 0 in 2D."""

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from ..domains import Uniform
from ..ics import FourierSeries
from .base import PDE, Param
from .common import CFL, conservative_quadratic
from .terms import gradient_norm, hermitian_damping

# On the chaotic attractor of the standard form (nu = 1) |u| stays below about 3.6 whatever the initial
# data (measured peak over 8 default samples: 3.58 sqrt(nu)); the substitution u = u'/sqrt(nu),
# x = sqrt(nu) x', t = nu t' maps nu to 1, so the bound scales as 1/sqrt(nu). The CFL rule uses it.
ATTRACTOR_BOUND_NU1 = 4.0
# 2D: the transport velocity is grad u; |u_x| + |u_y| on the attractor (nu = 1) stays below GRADIENT_BOUND_NU1
# (measured peak over 8 samples at nu = 1, t <= 100: 7.6), scaling as 1/sqrt(nu) as in 1D.
GRADIENT_BOUND_NU1 = 9.0


@dataclass(frozen=True)
class KS(PDE):
    """Periodic Kuramoto-Sivashinsky on [0, 32 pi): spatio-temporal chaos after t ~ 50.

    nu scales the hyperviscosity (nu = 1 is the standard form). Linear part k^2 - nu k^4 is integrated
    exactly; the step obeys the advective CFL with the attractor bound.
    2D: the scalar form u_t + |grad u|^2 / 2 + Laplacian(u) + nu Laplacian^2(u) = 0 (its x-derivative in 1D is
    the 1D equation for u_x), on [0, 10 pi)^2 at n = 64, minus the mean of |grad u|^2 / 2 (the mean of u would
    otherwise drift down without bound; u - <u> is unchanged). Same equation as Exponax's KuramotoSivashinsky
    (gradient_norm_scale 1, second_order_scale 1, fourth_order_scale nu). Lengths and times dimensionless;
    unstable band |k| < 1/sqrt(nu). Step: CFL with |u_x| + |u_y| <= GRADIENT_BOUND_NU1 / sqrt(nu_min).
    """

    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64, "length": 10 * math.pi, "n_frames": 51}}
    EQUATION: ClassVar[str] = "u_t + u u_x + u_xx + nu u_xxxx = 0"
    PARAMS: ClassVar[dict] = {"nu": Param("hyperviscosity", "length^4/time", positive=True)}
    FIELD_UNITS: ClassVar[dict] = {"u": "length/time"}  # 1D: u u_x ~ u_t; 2D (for_dimension): |grad u|^2 ~ u_t

    n: int = 256
    length: float = 32 * math.pi
    t_end: float = 100.0
    n_frames: int = 101
    ic: Any = FourierSeries(max_mode=8, decay=1.0, amplitude=1.0)
    nu: Any = Uniform(0.5, 1.5)

    @classmethod
    def for_dimension(cls, ndim):
        # walls (`--set bc=...`, generator.pdes.walls). 1D: Dirichlet walls are hinged (u = u_xx = 0: the sine
        # basis); Neumann is not offered (u u_x moves the mean through the walls, and it blew up). 2D (the scalar
        # form): Neumann walls (u_x = u_xxx = 0: the cosine basis), whose constant mode carries the mean that is
        # dropped as on the periodic box; Dirichlet is not offered (no constant mode: -|grad u|^2 / 2 drives u down
        # without bound, every trajectory blew up).
        if ndim == 1:
            return {"BOUNDARIES": ("periodic", "dirichlet")}
        return {"EQUATION": "u_t + |grad u|^2 / 2 + Laplacian(u) + nu Laplacian^2(u) = 0",
                "FIELD_UNITS": {"u": "length^2/time"},
                "BOUNDARIES": ("periodic", "neumann")}

    def linear(self, grid, p):
        if self.NDIM == 1:
            (k,) = grid.wavenumbers()
            return (k**2 - p["nu"] * k**4)[None]
        lap = grid.laplacian()
        return (-lap - p["nu"] * lap * lap)[None]

    def nonlinear(self, grid, p):
        if self.NDIM == 1:
            return conservative_quadratic(grid, -0.5)
        # the linear part grows at up to 1 / (4 nu) (at |k|^2 = 1 / (2 nu)): see hermitian_damping
        transport, damping = gradient_norm(grid), hermitian_damping(grid, 2 / (4 * min(self.nu.bounds)))
        return lambda v: transport(v) + damping(v)

    def stable_dt(self):
        if self.NDIM > 1:  # the max(.) below keeps an IC steeper than the attractor covered
            bound = GRADIENT_BOUND_NU1 / math.sqrt(min(self.nu.bounds))
            ic_slope = self.ic.bound(self.grid) * 2 * math.pi * getattr(self.ic, "max_mode", self.n // 3) / self.length
            return CFL * self.grid.dx / max(bound, self.NDIM * ic_slope)
        bound = ATTRACTOR_BOUND_NU1 / math.sqrt(min(self.nu.bounds))
        return CFL * self.grid.dx / max(bound, self.ic.bound(self.grid))

    def wall_terms(self, grid, p):
        if self.NDIM == 1:
            return None  # wall_flux: -(u^2 / 2)_x between its (Dirichlet) walls
        return lambda u, grad: -0.5 * sum(grad(a) * grad(a) for a in range(self.NDIM))

    def wall_flux(self, grid, p):
        return (lambda u: [0.5 * u * u]) if self.NDIM == 1 else None

    def wall_drops_mean(self, grid) -> bool:
        return self.NDIM > 1  # as on the periodic box: the mean of |grad u|^2 / 2 would drift u without bound

    def damping_rate(self):
        return 0.0 if self.NDIM == 1 else 2 / (4 * min(self.nu.bounds))
