"""Gray-Scott reaction-diffusion on the periodic square (Pearson 1993 pattern formation)."""

from dataclasses import dataclass
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..domains import Fixed, Uniform
from ..ics import IC_KINDS
from .base import PDE, Param

# The reaction Jacobian stays below ~1.5 in norm for 0 <= u, v <= 1; ETDRK4's real-axis limit is ~2.8,
# so dt <= 1 keeps a margin (diffusion is integrated exactly and sets no limit).
REACTION_DT = 1.0
# The spot loop is unrolled into the compiled set-up program (written out for bit-identity), so its size
# bounds compile time and memory: 256 spots cover a 64^2 box many times over.
MAX_SPOTS = 256


@dataclass(frozen=True)
class GrayScottSpots:
    """u = 1 - 2 s, v = s for a sum s of n_spots Gaussian bumps (periodic distance, width ``radius``,
    peak ``height``) at uniform random centres, plus ``noise``-sized white noise on both fields."""

    n_spots: int = 6
    radius: float = 0.03
    height: float = 0.25
    noise: float = 0.01
    kind = "spots"
    field_count = 2  # (u, v) = (1 - 2 s, s): Gray-Scott's two fields

    def check(self, grid):
        if not 1 <= self.n_spots <= MAX_SPOTS:
            raise ValueError(f"ic.n_spots={self.n_spots} not allowed: need 1 <= n_spots <= {MAX_SPOTS}")
        if not self.radius > 0:
            raise ValueError(f"ic.radius={self.radius} not allowed: must be > 0")

    def sample(self, key, grid, n_fields=2):
        k_centre, k_noise = jax.random.split(key)
        centres = jax.random.uniform(k_centre, (self.n_spots, grid.ndim), jnp.float32, 0.0, grid.length)
        x = jnp.asarray(grid.coords())
        mesh = jnp.meshgrid(*([x] * grid.ndim), indexing="ij")
        # Sums are written out term by term: XLA may reassociate a reduce differently per batch size,
        # which would break bit-identity of a sample across batches.
        s = jnp.zeros(grid.shape, jnp.float32)
        for i in range(self.n_spots):
            d2 = jnp.zeros(grid.shape, jnp.float32)
            for axis in range(grid.ndim):
                # chord distance on the circle: smooth and periodic, ~ |x - c| for nearby points
                d2 = d2 + (grid.length / jnp.pi * jnp.sin(jnp.pi * (mesh[axis] - centres[i, axis]) / grid.length)) ** 2
            s = s + self.height * jnp.exp(-d2 / (2 * self.radius**2))
        noise = self.noise * jax.random.normal(k_noise, (2, *grid.shape), jnp.float32)
        return jnp.stack([1.0 - 2.0 * s, s]) + noise

    def bound(self, grid):
        return 1.0


IC_KINDS["spots"] = GrayScottSpots


@dataclass(frozen=True)
class GrayScott2D(PDE):
    """Gray-Scott: u_t = Du Lap u - u v^2 + F (1 - u),  v_t = Dv Lap v + u v^2 - (F + k) v.

    Defaults are Pearson's (Du = 2e-5, Dv = 1e-5, grid spacing 0.01) on a 0.64-wide box, with F and k
    drawn from the spot/stripe-forming part of the (F, k) plane. Linear parts (diffusion, -F u,
    -(F + k) v) are integrated exactly; the step is limited by the reaction, dt <= 1.
    """

    NAME: ClassVar[str] = "grayscott2d"
    EQUATION: ClassVar[str] = "u_t = Du Lap(u) - u v^2 + F (1 - u);  v_t = Dv Lap(v) + u v^2 - (F + k) v"
    FIELDS: ClassVar[tuple] = ("u", "v")
    NDIM: ClassVar[int] = 2
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
        return REACTION_DT
