"""Two-field diffusion-reaction of FitzHugh-Nagumo type (PDEBench's 2D diffusion-reaction set), in 2D."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

from pdestream.generator.lazy_jax import jnp

from ..domains import LogUniform, Uniform
from ..ics import FourierSeries, GaussianRandomField, WhiteNoise
from .base import PDE, Param
from .terms import hermitian_damping

# The explicit part (-u^3 - k - v, u) has Jacobian [[-3 u^2, -1], [1, 0]]: eigenvalues near -3 u^2 and, where u is
# small, +-i. ETDRK4's real-axis limit is ~2.8, so dt <= 0.5 / b^2 for |u| <= b keeps a margin of ~1.9 (and
# |i dt| <= 0.5 on the imaginary axis). The linear parts (Du Lap + 1, Dv Lap - 1) are integrated exactly.
REACTION_CFL = 0.5
# The coupling (-v in u's equation, u in v's) is explicit too: at dt = 0.5 it cost 4e-4 relative error on the linear
# system's exact modes over t = 2, at dt <= 0.1 (ETDRK4's fourth order: ~6e-7) it is below float32's other errors.
COUPLING_DT = 0.1
LINEAR_GROWTH = 1.0  # the largest real part of the linear operator (u's +1): the Hermitian damping must exceed it


def reaction(u, p):
    """The explicit part in physical space: u [2, *space] (activator, inhibitor) -> [2, *space]
    (-u^3 - k - v, u) (per unit time)."""
    a, b = u[0], u[1]
    return jnp.stack([-a * a * a - p["k"] - b, a])


@dataclass(frozen=True)
class DiffusionReaction(PDE):
    """u_t = Du Lap u + u - u^3 - k - v,  v_t = Dv Lap v + u - v: an activator u and an inhibitor v
    (FitzHugh-Nagumo kinetics), the equations of PDEBench's 2D diffusion-reaction set (Takamoto et al. 2022,
    Appendix D; the recipe pdebench_diffusion_reaction2d). With Du < Dv the uniform state is Turing-unstable and
    spots and stripes form.

    Fields u, v (dimensionless), on [0, length]^2 (PDEBench's [-1, 1]^2 shifted by 1), time in the kinetics' unit.
    Periodic by default; ``--set bc=neumann`` gives PDEBench's no-flux walls (a cosine basis on cell centres).
    Defaults: n = 64 on [0, 2)^2, t <= 5 (51 frames), Du ~ loguniform(5e-4, 2e-3), Dv ~ loguniform(2.5e-3, 1e-2),
    k ~ uniform(0, 0.01) (PDEBench's Du = 1e-3, Dv = 5e-3, k = 5e-3 in the middle), a random Fourier-series IC up
    to mode 8 with max|u0| = 1 per field. ``ic=white`` is PDEBench's IC (a standard normal per cell).
    Stable step: dt <= min(0.1, 0.5 / max(1, max|u0|)^2) (the reaction's -3 u^2, and the explicit coupling's
    accuracy; diffusion is integrated exactly).
    """

    EQUATION: ClassVar[str] = "u_t = Du Lap(u) + u - u^3 - k - v;  v_t = Dv Lap(v) + u - v"
    FIELDS: ClassVar[tuple] = ("u", "v")
    FIELD_UNITS: ClassVar[dict] = {"u": "1", "v": "1"}  # activator, inhibitor (dimensionless)
    BOUNDARIES: ClassVar[tuple] = ("periodic", "neumann")  # `--set bc=neumann` (generator.spectral.walls)
    DIMENSIONS: ClassVar[dict] = {2: {}}
    IC_KINDS: ClassVar[Mapping[str, type]] = {"fourier": FourierSeries, "grf": GaussianRandomField,
                                              "white": WhiteNoise}
    PARAMS: ClassVar[dict] = {
        "Du": Param("diffusivity of the activator u", "length^2/time", positive=True),
        "Dv": Param("diffusivity of the inhibitor v", "length^2/time", positive=True),
        "k": Param("constant drain of u (the kinetics' threshold)", "1/time"),
    }

    n: int = 64
    length: float = 2.0
    t_end: float = 5.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=8, decay=1.0, amplitude=1.0)
    Du: Any = LogUniform(5e-4, 2e-3)
    Dv: Any = LogUniform(2.5e-3, 1e-2)
    k: Any = Uniform(0.0, 0.01)

    def linear(self, grid, p):
        lap = grid.laplacian()
        return jnp.stack([p["Du"] * lap + 1.0, p["Dv"] * lap - 1.0])

    def nonlinear(self, grid, p):
        damping = hermitian_damping(grid, 2 * LINEAR_GROWTH)  # L <= 1: see hermitian_damping
        return lambda v: grid.rfft(reaction(grid.irfft(v), p)) + damping(v)

    def stable_dt(self):
        return min(COUPLING_DT, REACTION_CFL / max(1.0, self.ic.bound(self.grid)) ** 2)

    def wall_terms(self, grid, p):
        return lambda u, grad: reaction(u, p)

    def damping_rate(self):
        return 2 * LINEAR_GROWTH
