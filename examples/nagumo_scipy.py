"""Nagumo's bistable reaction-diffusion front between two walls, solved by scipy (method of lines + solve_ivp).

    u_t = D u_xx + r u (1 - u) (u - a)   on [0, length],   u(0, t) = 1,  u(length, t) = 0   (Dirichlet walls)

Not in the catalog (its spectral solvers are periodic or wall-lifted): any solver can be an entry. Random per
sample: the diffusivity D, the threshold a and (from the seed) where the initial front sits and a small
random wiggle on it. Use it as any entry:

    PYTHONPATH=. pdestream generate --pde examples.nagumo_scipy:Nagumo --n 64 --out nagumo.h5
    PYTHONPATH=. pdestream train --pde examples.nagumo_scipy:Nagumo --reservoir --view next_step --steps 500 --out runs/nagumo
"""

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from scipy.integrate import solve_ivp
from scipy.sparse import diags

from pdestream.generator import ExternalSolver, Param


@dataclass(frozen=True)
class Nagumo(ExternalSolver):
    NAME: ClassVar[str] = "nagumo1d"
    EQUATION: ClassVar[str] = "u_t = D u_xx + r u (1 - u) (u - a), u(0) = 1, u(L) = 0"
    FIELDS: ClassVar[tuple] = ("u",)
    NDIM: ClassVar[int] = 1
    BC: ClassVar[str] = "dirichlet"  # nodes x_i = i L / (n - 1), both walls included
    PARAMS: ClassVar[dict] = {"D": Param("diffusivity", "length^2/time", positive=True),
                              "a": Param("bistability threshold")}
    VERSION: ClassVar[str] = "1"

    n: int = 64
    length: float = 1.0
    t_end: float = 2.0
    n_frames: int = 21
    r: float = 20.0  # reaction rate, 1/time (a setting: the same for every sample)
    D: Any = "loguniform(1e-3, 1e-2)"
    a: Any = "uniform(0.1, 0.4)"

    def solve(self, params, seed):
        rng = np.random.default_rng(seed)
        x = self.grid.coords().astype(np.float64)
        h = x[1] - x[0]
        front = rng.uniform(0.25, 0.75) * self.length
        u0 = 0.5 * (1 - np.tanh((x - front) / (0.05 * self.length))) + 0.05 * rng.standard_normal() * np.sin(
            np.pi * x / self.length)
        u0[0], u0[-1] = 1.0, 0.0
        D, a, r = params["D"], params["a"], self.r
        lap = diags([1.0, -2.0, 1.0], [-1, 0, 1], shape=(self.n - 2, self.n - 2)) / h**2  # interior nodes
        wall = np.zeros(self.n - 2)
        wall[0] = 1.0 / h**2  # u(0) = 1 enters the first interior row

        def rhs(t, v):
            return D * (lap @ v + wall) + r * v * (1 - v) * (v - a)

        def jac(t, v):
            return D * lap + diags(r * (-3 * v**2 + 2 * (1 + a) * v - a))

        sol = solve_ivp(rhs, (0.0, self.t_end), u0[1:-1], method="BDF", t_eval=self.times(), jac=jac,
                        rtol=1e-6, atol=1e-8)
        if not sol.success:
            raise RuntimeError(f"solve_ivp: {sol.message}")
        u = np.empty((self.n_frames, 1, self.n))
        u[:, 0, 0], u[:, 0, -1], u[:, 0, 1:-1] = 1.0, 0.0, sol.y.T
        return u
