"""Swift-Hohenberg pattern formation: u_t = r u - (1 + Laplacian)^2 u + g u^2 - u^3, in 2D."""

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from ..domains import Uniform
from ..ics import FourierSeries
from .base import PDE, Param
from .terms import hermitian_damping, polynomial

# The explicit reaction g u^2 - u^3 has Jacobian 2 g u - 3 u^2, at most 2 g b + 3 b^2 for |u| <= b; ETDRK4's
# real-axis limit is ~2.8, so dt <= 1 / (2 g b + 3 b^2) keeps a margin of ~2.8.
REACTION_CFL = 1.0


def pattern_bound(r: float, g: float) -> float:
    """A bound on max|u| once patterns have formed: hexagons reach ~(g + sqrt(g^2 + 3 r)) / 1.5 (stripes less);
    1.5 times that, and at least 1 (2.6 at the default r <= 0.5, g <= 1; measured peak over 4 samples: 1.33)."""
    return max(1.0, g + math.sqrt(g * g + 3 * r))


@dataclass(frozen=True)
class SwiftHohenberg(PDE):
    """Periodic Swift-Hohenberg on [0, 20 pi)^2 (10 wavelengths of the critical mode |k| = 1).

    The gradient flow of E(u) = int -r u^2/2 + ((1 + Laplacian) u)^2 / 2 - g u^3/3 + u^4/4 dx: E never increases.
    Field u: pattern amplitude (dimensionless). r: distance above onset (patterns for r > 0); g: quadratic
    coefficient (g = 0: stripes; larger g: hexagons). Lengths in units of 1/k_c, time in units of the
    linear relaxation. Defaults: r ~ uniform(0.1, 0.5), g ~ uniform(0, 1), n = 128, small random IC (max|u0| = 0.1,
    modes up to 10, i.e. |k| <= 1).
    Same equation as Exponax's SwiftHohenberg (reactivity r, critical_number 1, polynomial (0, 0, g, -1)).
    Stable step: dt <= 1 / (2 g b + 3 b^2), b = max(max|u0|, pattern_bound(r_max, g_max)).
    """

    EQUATION: ClassVar[str] = "u_t = r u - (1 + Laplacian)^2 u + g u^2 - u^3"
    DIMENSIONS: ClassVar[dict] = {2: {}}
    PARAMS: ClassVar[dict] = {
        "r": Param("distance above onset", "1/time"),
        "g": Param("quadratic coefficient", "1/time"),
    }

    n: int = 128
    length: float = 20 * math.pi
    t_end: float = 50.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=10, decay=0.0, amplitude=0.1)
    r: Any = Uniform(0.1, 0.5)
    g: Any = Uniform(0.0, 1.0)

    def linear(self, grid, p):
        return (p["r"] - (1.0 + grid.laplacian()) ** 2)[None]

    def nonlinear(self, grid, p):
        reaction = polynomial(grid, p["g"], -1.0)
        damping = hermitian_damping(grid, 2 * max(self.param_upper("r"), 0.0))  # L <= r: see hermitian_damping
        return lambda v: reaction(v) + damping(v)

    def stable_dt(self):
        g = self.param_upper("g")
        b = max(self.ic.bound(self.grid), pattern_bound(self.param_upper("r"), g))
        return REACTION_CFL / (2 * g * b + 3 * b * b)
