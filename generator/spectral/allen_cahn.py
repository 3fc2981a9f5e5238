"""Allen-Cahn phase separation: u_t = nu Laplacian(u) + u - u^3, in 1D and 2D."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ...boundaries import BOUNDARY_TYPES
from ..domains import LogUniform
from ..ics import FourierSeries
from .base import PDE, Param
from .terms import hermitian_damping, polynomial

# The reaction u - u^3 has Jacobian 1 - 3 u^2; the linear 1 is integrated exactly, the explicit part
# -3 u^2 reaches 3 b^2 for |u| <= b. ETDRK4's real-axis limit is ~2.8, so dt <= 0.5 / b^2 keeps a margin
# of ~1.7 (|u| never exceeds max(1, max|u0|): the equation has a maximum principle).
REACTION_CFL = 0.5


@dataclass(frozen=True)
class AllenCahn(PDE):
    """Periodic Allen-Cahn, the gradient flow of E(u) = int nu/2 |grad u|^2 + (u^2 - 1)^2 / 4 dx.

    Field u (order parameter, 1 in one phase, -1 in the other); interfaces of width ~ sqrt(2 nu) form and
    coarsen. Units: length of the box, time of the reaction (rate 1). E never increases.
    Defaults: [0, 1)^d; 1D: n = 128, nu ~ loguniform(1e-3, 1e-2) (interfaces 0.045-0.14 wide, >= 5 cells);
    2D: n = 64, nu ~ loguniform(2e-3, 1e-2) (>= 4 cells); a random Fourier-series IC with max|u0| = 1. Good ranges: nu in [1e-4, 1e-1] with dx <= sqrt(2 nu) / 4.
    Stable step: the reaction's, dt <= 0.5 / max(1, max|u0|)^2 (diffusion is integrated exactly).
    Same equation as Exponax's AllenCahn (diffusivity nu, first/third order coefficients 1 and -1).
    """

    EQUATION: ClassVar[str] = "u_t = nu Laplacian(u) + u - u^3"
    BOUNDARIES: ClassVar[tuple] = BOUNDARY_TYPES  # `--set bc=...` (generator.pdes.walls)
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64, "nu": LogUniform(2e-3, 1e-2)}}
    PARAMS: ClassVar[dict] = {"nu": Param("interface diffusivity (width^2 / 2)", "length^2/time", positive=True)}

    n: int = 128
    length: float = 1.0
    t_end: float = 10.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=8, decay=1.0, amplitude=1.0)
    nu: Any = LogUniform(1e-3, 1e-2)

    def linear(self, grid, p):
        return (p["nu"] * grid.laplacian() + 1.0)[None]

    def nonlinear(self, grid, p):
        reaction, damping = polynomial(grid, 0.0, -1.0), hermitian_damping(grid, 2.0)  # L <= 1: see hermitian_damping
        return lambda v: reaction(v) + damping(v)

    def stable_dt(self):
        return REACTION_CFL / max(1.0, self.ic.bound(self.grid)) ** 2

    def wall_terms(self, grid, p):
        return lambda u, grad: -u * u * u

    def lift_rate(self, p):
        return 1.0  # L = nu Laplacian + 1

    def damping_rate(self):
        return 2.0
