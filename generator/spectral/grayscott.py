"""Gray-Scott reaction-diffusion on the periodic square and cube (Pearson 1993 pattern formation)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream.generator.lazy_jax import jnp

from ..domains import Fixed, Uniform
from ..ics import GrayScottSpots
from .base import PDE, Param

# The reaction Jacobian stays below ~1.5 in norm for 0 <= u, v <= 1; ETDRK4's real-axis limit is ~2.8,
# so dt <= 1 keeps a margin (diffusion is integrated exactly and sets no limit).
REACTION_DT = 1.0


@dataclass(frozen=True)
class GrayScott(PDE):
    """Gray-Scott: u_t = Du Lap u - u v^2 + F (1 - u),  v_t = Dv Lap v + u v^2 - (F + k) v.

    Defaults are Pearson's (Du = 2e-5, Dv = 1e-5, grid spacing 0.01) on a 0.64-wide box, with F and k
    drawn from the spot/stripe-forming part of the (F, k) plane. Linear parts (diffusion, -F u,
    -(F + k) v) are integrated exactly; the step is limited by the reaction, dt <= 1 / max(1, max|u0|)^2.
    3D: the same equations and spacing on a 0.32-wide cube (n = 32, 32^3 points, 256 KB per frame of both
    fields), t_end = 1000, spots of radius 0.04 (0.03, as in 2D, left v = 0 everywhere in 2 of 4 samples; 0.04
    in none of 4). Fields u, v: concentrations (dimensionless).
    """

    EQUATION: ClassVar[str] = "u_t = Du Lap(u) - u v^2 + F (1 - u);  v_t = Dv Lap(v) + u v^2 - (F + k) v"
    FIELDS: ClassVar[tuple] = ("u", "v")
    FIELD_UNITS: ClassVar[dict] = {"u": "1", "v": "1"}  # concentrations
    DIMENSIONS: ClassVar[dict] = {2: {}, 3: {"n": 32, "length": 0.32, "t_end": 1000.0,
                                             "ic": GrayScottSpots(radius=0.04)}}
    PARAMS: ClassVar[dict] = {
        "F": Param("feed rate", "1/time", positive=True),
        "k": Param("kill rate", "1/time", positive=True),
        "Du": Param("diffusivity of u", "length^2/time", positive=True),
        "Dv": Param("diffusivity of v", "length^2/time", positive=True),
    }

    n: int = 64
    length: float = 0.64
    t_end: float = 2000.0
    n_frames: int = 41
    ic: Any = GrayScottSpots()
    F: Any = Uniform(0.03, 0.05)
    k: Any = Uniform(0.058, 0.063)
    Du: Any = Fixed(2e-5)
    Dv: Any = Fixed(1e-5)

    def linear(self, grid, p):
        lap = grid.laplacian()
        return jnp.stack([p["Du"] * lap - p["F"], p["Dv"] * lap - (p["F"] + p["k"])])

    def nonlinear(self, grid, p):
        # the constant feed F enters only the k = 0 mode (rfft of a constant F is F * n^ndim there)
        feed = np.zeros((2, *grid.kshape), np.float32)
        feed[(0,) + (0,) * grid.ndim] = grid.n**grid.ndim
        feed = p["F"] * jnp.asarray(feed)

        def nonlinear(v):
            u, w = grid.irfft(v)
            r = grid.rfft(u * w * w)
            return jnp.stack([-r, r]) + feed

        return nonlinear

    def stable_dt(self):
        # the reaction's Jacobian (v^2, 2 u v) grows as b^2 for |u|, |v| <= b: an IC beyond [0, 1] (a GRF, a larger
        # amplitude) needs a step b^2 smaller, or every trajectory blows up (grayscott3d with ic=grf did at dt=1)
        return REACTION_DT / max(1.0, self.ic.bound(self.grid)) ** 2
