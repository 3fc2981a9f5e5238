"""Fisher-KPP travelling fronts: u_t = D Laplacian(u) + r u (1 - u), in 1D and 2D."""

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

from ..domains import LogUniform, Uniform
from ..ics import FourierSeries, RandomSines
from .base import PDE, Param
from .terms import hermitian_damping, polynomial

# The growth r u is linear and integrated exactly; the explicit part -r u^2 has Jacobian -2 r u, at most
# 2 r b for 0 <= u <= b. ETDRK4's real-axis limit is ~2.8: dt <= 0.7 / (r_max b) keeps a margin of 2.
REACTION_CFL = 0.7


@dataclass(frozen=True)
class FisherKPP(PDE):
    """Periodic Fisher-KPP: a population u in [0, 1] (fraction of the carrying capacity) diffuses with D and
    grows logistically at rate r; fronts of width ~ sqrt(D / r) invade the empty regions at speed 2 sqrt(D r).

    Units: length of the box [0, 1)^d (n = 128 in 1D, 64 in 2D), time of the box's time unit (r in 1/time).
    0 <= u0 <= 1 keeps 0 <= u <= 1 (maximum principle).
    Defaults: D ~ loguniform(2e-3, 2e-2), r ~ uniform(0.5, 2) (fronts sqrt(D / r) >= 0.032 wide: >= 4 cells at
    n = 128, >= 2 in 2D at n = 64), IC a random Fourier series up to mode 4 on [0, 1] (amplitude 0.5 about 0.5):
    the troughs are invaded while the rest saturates. Good ranges: sqrt(D / r) >= 2 dx. Same equation as
    Exponax's FisherKPP (diffusivity D, reactivity r).
    Stable step: dt <= 0.7 / (r_max max(1, max|u0|)) (diffusion is integrated exactly).
    """

    EQUATION: ClassVar[str] = "u_t = D Laplacian(u) + r u (1 - u)"
    # zero-flux (Neumann) walls; a Dirichlet wall u = 0 would need an IC >= 0 that vanishes there (not offered)
    BOUNDARIES: ClassVar[tuple] = ("periodic", "neumann")
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64}}
    # u0 must be >= 0: where u < 0 the reaction -r u^2 drives u to -infinity in finite time (the equation itself
    # blows up, not the scheme), so a signed GRF is not offered and a Fourier series must sit above zero.
    # u0 >= 0 only: a Fourier series above zero, or sines rescaled to [0, 1] (PDEBench's IC; check_settings)
    IC_KINDS: ClassVar[Mapping[str, type]] = {"fourier": FourierSeries, "sines": RandomSines}
    PARAMS: ClassVar[dict] = {
        "D": Param("diffusivity", "length^2/time", positive=True),
        "r": Param("growth rate", "1/time", positive=True),
    }

    n: int = 128
    length: float = 1.0
    t_end: float = 5.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=4, decay=1.0, amplitude=0.5, offset=0.5)
    D: Any = LogUniform(2e-3, 2e-2)
    r: Any = Uniform(0.5, 2.0)

    def check_settings(self):
        if getattr(self.ic, "kind", None) == "sines" and not self.ic.normalise:
            raise ValueError(f"{self.NAME}: ic.normalise=false not allowed with ic=sines: u0 goes below 0, where "
                             "u (1 - u) blows up in finite time; need ic.normalise=true (u0 in [0, 1])")
        offset, amplitude = getattr(self.ic, "offset", None), getattr(self.ic, "amplitude", None)
        if offset is not None and amplitude is not None and offset < amplitude:
            raise ValueError(f"{self.NAME}: ic.offset={offset:g} with ic.amplitude={amplitude:g} not allowed: u0 "
                             f"reaches {offset - amplitude:g} < 0, where u (1 - u) blows up in finite time; "
                             "need ic.offset >= ic.amplitude (default 0.5, 0.5)")

    def linear(self, grid, p):
        return (p["D"] * grid.laplacian() + p["r"])[None]

    def nonlinear(self, grid, p):
        reaction = polynomial(grid, -p["r"], 0.0)
        damping = hermitian_damping(grid, 2 * self.param_upper("r"))  # L <= r: see hermitian_damping
        return lambda v: reaction(v) + damping(v)

    def stable_dt(self):
        return REACTION_CFL / (self.param_upper("r") * max(1.0, self.ic.bound(self.grid)))

    def wall_terms(self, grid, p):
        return lambda u, grad: -p["r"] * u * u

    def lift_rate(self, p):
        return p["r"]  # L = D Laplacian + r

    def damping_rate(self):
        return 2 * self.param_upper("r")
