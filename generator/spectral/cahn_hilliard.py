"""Cahn-Hilliard spinodal decomposition: u_t = M Laplacian(u^3 - u - gamma Laplacian(u)), in 2D."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ..domains import Fixed, LogUniform
from ..ics import FourierSeries
from .base import PDE, Param
from .terms import hermitian_damping

# The explicit term M Laplacian(u^3) grows like 3 M b^2 |k|^2 (|u| <= b) while the linear part damps like
# M gamma |k|^4; they balance at |k|^2 = 3 b^2 / gamma, where the explicit rate is 9 M b^4 / gamma. Above that
# wavenumber ETDRK4's exact linear factor keeps the step stable, so the rule is dt <= C gamma / (9 M b^4).
# Measured (gamma = 1e-3 and 4e-3, M = 1e-2, n = 64 and 128, t = 20): C = 8 stable, C = 16 blows up; C = 2 keeps 4x.
STEP_CONSTANT = 2.0
# |u| overshoots 1 a little near interfaces (no maximum principle for a fourth-order equation).
PHASE_BOUND = 1.2


@dataclass(frozen=True)
class CahnHilliard(PDE):
    """Periodic Cahn-Hilliard on [0, 1)^2: the H^-1 gradient flow of E(u) = int (u^2 - 1)^2 / 4 +
    gamma/2 |grad u|^2 dx, so the mass int u dx is conserved exactly and E never increases.

    Field u: concentration difference of two phases (-1 and 1). gamma [length^2]: interface energy, width
    ~ sqrt(2 gamma); M [length^2/time]: mobility. Defaults as Exponax's CahnHilliard (M = 1e-2,
    gamma ~ loguniform(1e-3, 4e-3) around its 1e-3): interfaces >= 3 cells at n = 64; a symmetric quench
    (max|u0| = 0.1 noise up to mode 10) separates in t ~ 5 and coarsens after. Good ranges: gamma >= (2 dx)^2.
    Stable step: dt <= 2 gamma_min / (9 M_max b^4), b = max(1.2, max|u0|).
    """

    EQUATION: ClassVar[str] = "u_t = M Laplacian(u^3 - u - gamma Laplacian(u))"
    DIMENSIONS: ClassVar[dict] = {2: {}}
    PARAMS: ClassVar[dict] = {
        "gamma": Param("interface energy (width^2 / 2)", "length^2", positive=True),
        "M": Param("mobility", "length^2/time", positive=True),
    }

    n: int = 64
    length: float = 1.0
    t_end: float = 20.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=10, decay=0.0, amplitude=0.1)
    gamma: Any = LogUniform(1e-3, 4e-3)
    M: Any = Fixed(1e-2)

    def linear(self, grid, p):
        lap = grid.laplacian()
        return (p["M"] * lap * (-1.0 - p["gamma"] * lap))[None]

    def nonlinear(self, grid, p):
        factor = p["M"] * grid.laplacian()
        # the linear part grows at up to M / (4 gamma) (at |k|^2 = 1 / (2 gamma)): see hermitian_damping
        damping = hermitian_damping(grid, 2 * self.param_upper("M") / (4 * min(self.gamma.bounds)))

        def nonlinear(v):
            u = grid.irfft(v)
            return factor * grid.rfft(u * u * u) + damping(v)

        return nonlinear

    def stable_dt(self):
        b = max(PHASE_BOUND, self.ic.bound(self.grid))
        return STEP_CONSTANT * min(self.gamma.bounds) / (9 * self.param_upper("M") * b**4)
