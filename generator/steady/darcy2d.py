"""Steady Darcy flow on the unit square: a random coefficient field in, a pressure out.

-div(a grad u) = f on (0, L)^2, u = 0 on the boundary, with a = a_pos where a random field g is positive and
a_neg elsewhere. The field g (``ic``) is a Gaussian random field g ~ N(0, (-Laplacian + tau^2 I)^(-alpha))
(``neumann_grf``; defaults tau = 3, alpha = 2, a_pos = 12, a_neg = 3, f = 1: the FNO paper's set-up, Li et al.
2021) or five Gaussian bumps less their expected mean (``bumps``: PDEBench's, with a_pos = 1, a_neg = 0.1).
Solved by second-order finite differences with harmonic-mean face coefficients and Jacobi-preconditioned CG
(generator/elliptic.py).

A sample has no time axis: it is (a [1, n, n], u [1, n, n]) at ``points``: ``nodes``, the n x n nodes
x_i = i L / (n - 1) including the boundary, which holds u = 0 (FNO's 421 x 421 data has n = 421), or ``cells``,
the n x n cell centres (i + 1/2) L / n with u = 0 held at the ghost centres half a cell outside the walls
(PDEBench's placement; the solve runs on the n + 2 nodes the ghosts add, a copied into them). Sample identity
follows the sampler's key discipline: the key of (seed, index) is split into a parameter key and a field key;
the set-up and the solve each run as a fixed-size compiled program per chunk of samples, and each CG solve
stops on its own residual, so a sample is bit-identical alone and in any batch.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ..chunked import chunked_map
from ..domains import Fixed
from ..grids import GhostCellGrid, NodeGrid
from ..problem import MAX_TRAJECTORY_BYTES, Param, resolve_params
from . import elliptic
from .base import SteadyProblem

# Samples per compiled set-up / solve call: a fixed program shape makes a sample independent of its batch.
CHUNK = 8
# The FNO threshold field's contrast (a_pos / a_neg = 4) needs ~2.6 n CG iterations on an n x n grid;
# non-convergence within max_iter is reported like a blow-up (BlowUpError, or a redraw).
MAX_BACKWARD_ERROR = 1e-5  # ~100 float32 epsilons: a returned u solves the discrete system to this backward error
# Where a sample's values sit: {points: (grid class, ghost layers the node solver adds around the points)}
LAYOUTS = {"nodes": (NodeGrid, 0), "cells": (GhostCellGrid, 1)}
BUMP_QUADRATURE = 256  # Gauss-Legendre nodes for the bumps' expected mean (its integrand is smooth in sqrt(w))


@dataclass(frozen=True)
class NeumannGRF:
    """g ~ N(0, (-Laplacian + tau^2 I)^(-alpha)) on [0, length]^2 with zero-flux boundaries, mean mode dropped.

    g = sum_k sqrt(lambda_k) xi_k phi_k over k = (k1, k2) in {0..n-1}^2 minus (0, 0), with the L2-orthonormal
    cosine modes phi_k(x, y) = c_k1 c_k2 cos(pi k1 x / L) cos(pi k2 y / L) / L (c_0 = 1, c_k = sqrt 2),
    lambda_k = (pi^2 |k|^2 / L^2 + tau^2)^(-alpha) and xi_k independent standard normals. Only the sign of g
    matters to Darcy's coefficient, so no overall scale is offered.
    """

    tau: float = 3.0
    alpha: float = 2.0
    kind = "neumann_grf"
    field_count = 1

    def check(self, grid) -> None:
        if not self.tau >= 0:
            raise ValueError(f"ic.tau={self.tau} not allowed: must be >= 0")
        if not self.alpha > 0:
            raise ValueError(f"ic.alpha={self.alpha} not allowed: must be > 0")

    def eigenvalues(self, grid: NodeGrid) -> np.ndarray:
        """lambda_k, float64 [n, n] over (k1, k2); 0 at k = (0, 0)."""
        k = np.arange(grid.n)
        k2 = (np.pi / grid.length) ** 2 * (k[:, None] ** 2 + k[None, :] ** 2)
        with np.errstate(divide="ignore"):  # k = 0 with tau = 0; that mode is dropped
            lam = (k2 + self.tau**2) ** (-self.alpha)
        lam[0, 0] = 0.0
        return lam

    def modes(self, grid: NodeGrid) -> np.ndarray:
        """phi's 1D factors at the nodes: float64 [n points, n modes], c_k cos(pi k x / L) / sqrt(L)."""
        x, k = grid.coords().astype(np.float64), np.arange(grid.n)
        c = np.where(k == 0, 1.0, np.sqrt(2.0))
        return c * np.cos(np.pi * np.outer(x, k) / grid.length) / np.sqrt(grid.length)

    def covariance(self, grid: NodeGrid, p: tuple[int, int], q: tuple[int, int]) -> float:
        """E[g(p) g(q)] for node index pairs p, q, from the definition (the sum over modes)."""
        phi = self.modes(grid)
        return float(np.sum(self.eigenvalues(grid) * np.outer(phi[p[0]], phi[p[1]]) * np.outer(phi[q[0]], phi[q[1]])))

    def sample(self, key: jax.Array, grid: NodeGrid, n_fields: int = 1) -> jax.Array:
        """float32 [n_fields, n, n]: Phi (sqrt(lambda) * xi) Phi^T per field."""
        phi = jnp.asarray(self.modes(grid), jnp.float32)
        scale = jnp.asarray(np.sqrt(self.eigenvalues(grid)), jnp.float32)
        xi = jax.random.normal(key, (n_fields, grid.n, grid.n), jnp.float32)
        return jnp.einsum("ik,fkl,jl->fij", phi, scale * xi, phi)

    def bound(self, grid) -> float:
        return 1.0  # only the sign is used: a is a_pos or a_neg


@dataclass(frozen=True)
class GaussianBumps:
    """g = s - c with s(x, y) = sum over m = 1..count of exp(-((x - x_m)^2 + (y - y_m)^2) / w_m): centres (x_m, y_m)
    uniform on [0, length]^2, widths w_m ~ U(0, w_max] (length^2), all independent; c = E[mean of s over the grid's
    points], the expectation under this measure (``threshold``).

    PDEBench's 2D Darcy coefficient (count 5, w_max = 0.5 (x_R - x_L) on the unit square) is 1 where s exceeds the
    mean of s over its whole batch of 200 samples and 0.1 elsewhere: that mean estimates c, so thresholding at c
    keeps its law and makes a sample independent of its batch. Only the sign of g is used.
    """

    count: int = 5
    w_max: float = 0.5
    kind = "bumps"
    field_count = 1

    def check(self, grid) -> None:
        if isinstance(self.count, bool) or not isinstance(self.count, int) or self.count < 1:
            raise ValueError(f"ic.count={self.count!r} not allowed: the number of bumps must be an integer >= 1")
        points = len(grid.coords()) ** 2
        most = max(1, MAX_TRAJECTORY_BYTES // (4 * CHUNK * points))  # ``sample`` holds [n, n, count] per sample
        if self.count > most:
            raise ValueError(f"ic.count={self.count} not allowed on {points} points: a chunk's bump distances would "
                             f"take {4 * CHUNK * points * self.count / 2**30:.3g} GiB; allowed: 1 <= count <= {most}")
        if not self.w_max > 0:
            raise ValueError(f"ic.w_max={self.w_max} not allowed: the widest bump's w must be > 0")

    def mean_profile(self, grid, w: np.ndarray) -> np.ndarray:
        """M(w) [len(w)]: the mean over the grid's points of one bump's profile along one axis, averaged over its
        centre: mean_i (1/L) int_0^L exp(-(x_i - c)^2 / w) dc, float64."""
        x, length = grid.coords().astype(np.float64), grid.length
        r = np.sqrt(np.asarray(w, np.float64))[:, None]
        erf = np.vectorize(math.erf)
        return (np.sqrt(np.pi) * r / (2 * length) * (erf((length - x) / r) + erf(x / r))).mean(-1)

    def threshold(self, grid) -> float:
        """c = E[mean of s over the grid's points] = count E_w[M(w)^2] (the bump separates into x and y factors and
        the points are the same on both axes), by Gauss-Legendre quadrature in t = sqrt(w / w_max)."""
        t, weights = np.polynomial.legendre.leggauss(BUMP_QUADRATURE)
        t, weights = 0.5 * (t + 1), 0.5 * weights  # on [0, 1]
        # E_w[F(w)] = (1 / w_max) int_0^w_max F dw = int_0^1 F(w_max t^2) 2 t dt
        return float(self.count * np.sum(weights * 2 * t * self.mean_profile(grid, self.w_max * t * t) ** 2))

    def sample(self, key: jax.Array, grid, n_fields: int = 1) -> jax.Array:
        """float32 [n_fields, n, n]: s - c at the grid's points, one independent draw per field."""
        x = jnp.asarray(grid.coords())
        c = jnp.float32(self.threshold(grid))

        def one(k):
            kx, ky, kw = jax.random.split(k, 3)
            cx = grid.length * jax.random.uniform(kx, (self.count,))
            cy = grid.length * jax.random.uniform(ky, (self.count,))
            w = self.w_max * (1.0 - jax.random.uniform(kw, (self.count,)))  # in (0, w_max]: no division by 0
            d2 = (x[:, None, None] - cx) ** 2 + (x[None, :, None] - cy) ** 2  # [n, n, count]
            return jnp.sum(jnp.exp(-d2 / w), axis=-1) - c

        return jnp.stack([one(k) for k in jax.random.split(key, n_fields)]).astype(jnp.float32)

    def bound(self, grid) -> float:
        return 1.0  # only the sign is used: a is a_pos or a_neg


@dataclass(frozen=True)
class Darcy2D(SteadyProblem):
    """-div(a grad u) = f on (0, length)^2, u = 0 on the boundary; a = a_pos where g > 0, a_neg elsewhere.

    ``ic`` is the distribution of the random field g (NeumannGRF or GaussianBumps); ``points`` where the values
    sit (a key of LAYOUTS: ``nodes``, n per side with the boundary, or ``cells``, n cell centres per side); tol is
    CG's relative-residual tolerance and max_iter its iteration limit. Parameters a_pos, a_neg, f are per-sample
    coefficients (fixed by default, any domain allowed); a sample is (a [1, n, n], u [1, n, n]) float32, no time
    axis.
    """

    NAME: ClassVar[str] = "darcy2d"
    EQUATION: ClassVar[str] = "-div(a grad u) = f on (0,1)^2, u = 0 on the boundary; a = a_pos where g > 0 else a_neg"
    FIELDS: ClassVar[tuple] = ("u",)
    FIELD_UNITS: ClassVar[dict] = {"a": "1", "u": "1"}  # -div(a grad u) = f with f in "1": u in length^2
    INPUTS: ClassVar[tuple] = ("a",)  # random input fields stored per sample beside the solution
    NDIM: ClassVar[int] = 2
    PARAMS: ClassVar[dict] = {
        "a_pos": Param("coefficient a where the random field is positive", "1", positive=True),
        "a_neg": Param("coefficient a where the random field is <= 0", "1", positive=True),
        "f": Param("source term (constant over the square)", "1"),
    }
    # `--set ic=...` names this vocabulary
    IC_KINDS: ClassVar[dict] = {NeumannGRF.kind: NeumannGRF, GaussianBumps.kind: GaussianBumps}
    IC_LABEL: ClassVar[str] = "ic (random field g)"

    n: int = 64
    length: float = 1.0
    ic: Any = NeumannGRF()
    points: str = "nodes"
    tol: float = 1e-5
    max_iter: int = 5000
    a_pos: Any = Fixed(12.0)
    a_neg: Any = Fixed(3.0)
    f: Any = Fixed(1.0)

    @property
    def grid(self):
        """NodeGrid (points=nodes) or GhostCellGrid (points=cells), n per side."""
        return LAYOUTS[self.points][0](self.NDIM, self.n, self.length)

    @property
    def ghosts(self) -> int:
        """Node layers the solve adds around the points (1 for cells: the ghosts holding u = 0)."""
        return LAYOUTS[self.points][1]

    def check_settings(self) -> None:
        if self.points not in LAYOUTS:
            raise ValueError(f"{self.NAME}: points={self.points!r} not allowed; allowed: {', '.join(LAYOUTS)} (nodes: n "
                             "per side with the boundary; cells: n cell centres, u = 0 half a cell outside)")
        if not 0 < self.tol < 1:
            raise ValueError(f"{self.NAME}: tol={self.tol} not allowed: the relative residual tolerance must be in (0, 1)")
        if not self.max_iter >= 1:
            raise ValueError(f"{self.NAME}: max_iter={self.max_iter} not allowed: must be an integer >= 1")
        if not isinstance(self.ic, tuple(self.IC_KINDS.values())):
            raise ValueError(f"{self.NAME}: ic={self.ic.kind!r} not allowed: the coefficient field comes from "
                             f"ic={' or '.join(map(repr, self.IC_KINDS))}")

    def config(self) -> dict:
        """``ProblemBase.config``; ``points`` only when it is not the default nodes, so the configs and hashes of
        every darcy2d cache and run written before the setting existed are unchanged."""
        out = super().config()
        if self.points == "nodes":
            out.pop("points", None)
        return out

    def describe_solver(self) -> str:
        return f"PCG to relative residual {self.tol:g} (at most {self.max_iter} iterations)"

    def failure(self) -> tuple[str, str]:
        """(what a failed sample did, how to avoid it), for BlowUpError's message."""
        return (f"solves did not converge (PCG relative residual > tol={self.tol:g} after max_iter={self.max_iter} "
                f"iterations, or a backward error > {MAX_BACKWARD_ERROR:g}, or NaN)",
                "a larger max_iter, a larger tol or a milder coefficient contrast avoids this")

    def coefficient(self, g: jax.Array, p) -> jax.Array:
        """a from the random field g [..., n, n]: a_pos where g > 0, a_neg elsewhere."""
        return jnp.where(g > 0, p["a_pos"], p["a_neg"]).astype(jnp.float32)

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """keys [B], explicit float32 [B, P], given bool [B, P] -> (u [B, 1, n, n], params {name: [B]},
        ok bool [B] (converged), inputs [B, 1, n, n] (the coefficient a)): the sampler's interface."""
        u, params, ok, a, _ = self.solve_keys(keys, explicit, given)
        return u, params, ok, a

    def solve_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """``run_keys`` plus the CG iterations each sample took, int32 [B]."""
        setup, solve = _compiled_setup(self), _compiled_solve(self)

        def chunk(keys, explicit, given):  # dispatched asynchronously: set-up and solves overlap
            params, a = setup(keys, explicit, given)
            return (params, a, *solve(a, params["f"]))

        params, a, u, ok, iters = chunked_map(chunk, CHUNK, keys, explicit, given, report=True)
        return u[:, None], params, ok, a[:, None], iters


def _draw(pde: Darcy2D, key, explicit, given):
    k_param, k_field = jax.random.split(key)
    p = resolve_params(pde, k_param, explicit, given)
    return p, pde.coefficient(pde.ic.sample(k_field, pde.grid)[0], p)


@functools.lru_cache(maxsize=32)
def _compiled_setup(pde: Darcy2D):
    """jit of (keys [K], explicit [K, P], given [K, P]) -> (params {name: [K]}, a [K, n, n]), one key per
    loop iteration (like the sampler's set-up: the matrix products round the same whatever the batch)."""
    return jax.jit(lambda keys, explicit, given: jax.lax.map(lambda t: _draw(pde, *t), (keys, explicit, given)))


@functools.lru_cache(maxsize=32)
def _compiled_solve(pde: Darcy2D):
    """jit(vmap) of (a [K, n, n], f [K]) -> (u [K, n, n], converged [K], iterations [K]); with ghosts the solve runs
    on the points plus that many node layers, a copied into them (the face coefficient there is the edge value)."""
    g = pde.ghosts

    def one(a, f):
        a_nodes = jnp.pad(a, g, mode="edge")
        sol = elliptic.solve(a_nodes, jnp.full(a_nodes.shape, f, a.dtype), pde.grid.spacing, pde.tol, pde.max_iter)
        ok = sol.reached & (sol.backward_error <= MAX_BACKWARD_ERROR) & jnp.all(jnp.isfinite(sol.u))
        return sol.u[g:sol.u.shape[0] - g, g:sol.u.shape[1] - g], ok, sol.iterations

    return jax.jit(jax.vmap(one))
