"""Masked variable-coefficient pressure Poisson solve: CG preconditioned by a geometric multigrid V-cycle.

Operator (h^2-scaled, symmetric positive semi-definite): (A p)_P = sum over the 4 faces c_f (p_P - p_nb)
+ solid_P p_P, where a closed face has c = 0 (walls, inflow, obstacle faces: Neumann), an open boundary face
is Dirichlet p = 0 (ghost = -p_P) and a periodic face wraps. Coarse levels are Galerkin P^T A P with
piecewise-constant P over 2x2 blocks: the coarse face coefficient is the sum of the two fine ones, so the
V-cycle (damped Jacobi, nu1 = nu2, the same sweeps before and after, the coarse correction weighted; the coarsest level, at most COARSE_CELLS
cells, solved by a dense pseudo-inverse prepared once per rollout) is a symmetric preconditioner.
Without a Dirichlet side A is singular: the rhs and each preconditioned residual have their mean projected
out. Each sample stops on its own relative residual (a masked while loop), so batches don't change bits. Its
sums (CG's dot products, the mean, the coarse solve's product) are added in a fixed order (_tree_sum), not by
XLA's reductions, whose order follows the vector width XLA prefers on the host CPU.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from .grid import Faces


def _ghost_pad(p, periodic_x, periodic_y):
    """p [ny, nx] with one ghost layer: wrap on periodic axes, else -p (used only on Dirichlet faces; a
    closed face multiplies its difference by 0)."""
    p = jnp.concatenate([p[:, -1:] if periodic_x else -p[:, :1], p, p[:, :1] if periodic_x else -p[:, -1:]], 1)
    return jnp.concatenate([p[-1:] if periodic_y else -p[:1], p, p[:1] if periodic_y else -p[-1:]], 0)


def apply(fc: Faces, p, periodic_x: bool, periodic_y: bool):
    """A p for p [ny, nx] -> [ny, nx]."""
    g = _ghost_pad(p, periodic_x, periodic_y)
    fx = fc.cx * (g[1:-1, 1:] - g[1:-1, :-1])
    fy = fc.cy * (g[1:, 1:-1] - g[:-1, 1:-1])
    return -(fx[:, 1:] - fx[:, :-1] + fy[1:] - fy[:-1]) + fc.solid * p


def diagonal(fc: Faces, periodic_x: bool, periodic_y: bool):
    """Diagonal of A [ny, nx] (Dirichlet boundary faces count twice)."""
    cx, cy = fc.cx, fc.cy
    dx = cx[:, 1:] + cx[:, :-1]
    dy = cy[1:] + cy[:-1]
    if not periodic_x:
        dx = dx.at[:, 0].add(cx[:, 0]).at[:, -1].add(cx[:, -1])
    if not periodic_y:
        dy = dy.at[0].add(cy[0]).at[-1].add(cy[-1])
    return dx + dy + fc.solid


def coarsen(fc: Faces) -> Faces:
    """Galerkin coarse coefficients over 2x2 blocks (needs even nx, ny)."""
    cx = fc.cx[:, ::2]
    cy = fc.cy[::2]
    cx = cx[0::2] + cx[1::2]
    cy = cy[:, 0::2] + cy[:, 1::2]
    s = fc.solid
    return Faces(cx, cy, s[0::2, 0::2] + s[1::2, 0::2] + s[0::2, 1::2] + s[1::2, 1::2])


# V-cycle settings, chosen on the karman-like channel (benchmarks/flow_validation.py, float64 cold solves at
# 64x32/128x64/256x128): piecewise-constant Galerkin coarse operators are ~2x too stiff on smooth error (their
# face coefficient is 2 where the rediscretised one is 1), so the coarse correction is scaled by COARSE_WEIGHT
# (< 2 keeps I - w P Ac^-1 P^T A an A-contraction; the preconditioner stays SPD, tests/test_flow_numerics.py).
# Iterations 16/23/34 (2.1x) with weight 1, 2 sweeps, omega 0.8; 9/10/13 (1.44x) with these.
COARSE_WEIGHT = 1.9
SWEEPS = 3
OMEGA = 0.9
COARSE_CELLS = 128  # the coarsest level holds at most this many cells: solved exactly by a dense pseudo-inverse


# the largest coarsest level whose dense pseudo-inverse is built (m^2 floats, an O(m^3) eigendecomposition on the
# host): a grid side with few factors of 2 stops the halving early (686 = 2 x 343 left 343 x 64 = 21,952 cells, which
# took more than 9 GB before it was refused)
MAX_COARSE_CELLS = 4096


def coarsest_shape(shape: tuple[int, ...], coarse_cells: int = COARSE_CELLS) -> tuple[int, ...]:
    """The shape of the multigrid's coarsest level for a grid of ``shape`` cells (``hierarchy``'s rule: halve while
    every side is even and the level has more than ``coarse_cells`` cells)."""
    while all(n % 2 == 0 for n in shape) and math.prod(shape) > coarse_cells:
        shape = tuple(n // 2 for n in shape)
    return shape


def hierarchy(fc: Faces, coarse_cells: int = COARSE_CELLS) -> list:
    """Coefficient levels, finest first, halving while both dims stay even and the level has more than
    ``coarse_cells`` cells (``coarsest_shape``)."""
    levels = [fc]
    while all(n % 2 == 0 for n in levels[-1].solid.shape) and levels[-1].solid.size > coarse_cells:
        levels.append(coarsen(levels[-1]))
    return levels


def check_coarsest(shape: tuple[int, ...]) -> None:
    """ValueError (one line) when the coarsest level of a grid of ``shape`` cells [ny, nx] or [nx, ny] exceeds
    MAX_COARSE_CELLS, naming the grid sides' factors of 2 as the cause."""
    coarse = coarsest_shape(shape)
    if math.prod(coarse) > MAX_COARSE_CELLS:
        raise ValueError(f"a {'x'.join(map(str, shape))} grid is not allowed: the pressure multigrid halves it while "
                         f"every side is even and stops at {'x'.join(map(str, coarse))} = {math.prod(coarse)} cells, "
                         f"more than the {MAX_COARSE_CELLS} its dense coarse solve allows (sides with more factors of "
                         "2 halve further)")


class Operator(NamedTuple):
    """What a pressure solve needs of one geometry, computed once per rollout (not per step): the coefficient
    levels (finest first) and the coarsest level's dense pseudo-inverse [m, m] (m = its cell count)."""

    levels: list
    coarse_inverse: jax.Array


def prepare(fc: Faces, periodic_x: bool, periodic_y: bool) -> Operator:
    """The multigrid hierarchy of ``fc`` and the pseudo-inverse of its coarsest operator (its null space: the
    constant mode of a box without an open side, and of cells cut off by obstacles; see _pseudo_inverse)."""
    check_coarsest(fc.solid.shape)
    levels = hierarchy(fc)
    coarse = levels[-1]
    shape = coarse.solid.shape
    m = coarse.solid.size
    eye = jnp.eye(m, dtype=coarse.solid.dtype).reshape(m, *shape)
    a = jax.vmap(lambda e: apply(coarse, e, periodic_x, periodic_y).reshape(m))(eye)
    a = jax.lax.stop_gradient(0.5 * (a + a.T))  # geometry only: nothing to differentiate
    # On the host (numpy, elementwise operations only: the same bits on every CPU), one matrix at a time: XLA's
    # own CPU eigh kernel waits on XLA's intra-op thread pool from inside it, so two programs decomposing at once
    # (a stream thread sampling flows while the training thread runs solver-in-the-loop's differentiable step)
    # parked both pool threads and hung for good (gdb: both tf_XLAEigen threads in
    # EigenvalueDecompositionSymmetric, on 2 cores).
    # float32 across the callback: its host thread does not see a caller's jax.enable_x64, so a float64 answer came
    # back float32 and was refused (a sharp body's apertures are float64 under x64); a preconditioner needs no more
    dtype = a.dtype
    a = a.astype(jnp.float32)
    shape = jax.ShapeDtypeStruct(a.shape, a.dtype)
    return Operator(levels, jax.pure_callback(_pseudo_inverse, shape, a, vmap_method="sequential").astype(dtype))


def _components(a) -> tuple[np.ndarray, int]:
    """Labels [m] of the connected components of the graph of symmetric a's nonzero off-diagonal entries, and
    their count."""
    m = a.shape[0]
    adj = (a != 0) & ~np.eye(m, dtype=bool)
    label = np.full(m, -1)
    count = 0
    for seed in range(m):
        if label[seed] >= 0:
            continue
        label[seed] = count
        todo = [seed]
        while todo:
            nb = np.flatnonzero(adj[todo.pop()] & (label < 0))
            label[nb] = count
            todo.extend(nb.tolist())
        count += 1
    return label, count


def _pseudo_inverse(a) -> np.ndarray:
    """Pseudo-inverse of symmetric positive semi-definite a [m, m] in float64, returned in a's dtype: the same
    bits on every CPU. LAPACK's eigh (and any BLAS product) differs in the last bits between CPU kernels
    (OpenBLAS picks them per CPU: 1e-14 relative), so this uses elementwise numpy operations only (each
    correctly rounded, in a fixed order). a = A is a weighted graph Laplacian plus a non-negative diagonal (the
    coarse operator), so its null space is spanned by the indicators of the connected components whose
    normalised indicator has a Rayleigh quotient of zero (below 1e-5 of a's Gershgorin bound here: no Dirichlet
    face, no solid cell; e.g. a closed box, or cells cut off by obstacles). With N those indicators normalised,
    pinv(A) = (A + N N^T)^-1 - N N^T, the inverse by Gauss-Jordan elimination (A + N N^T is positive
    definite: no pivoting needed)."""
    a = np.asarray(a)
    s = a.astype(np.float64)
    s = 0.5 * (s + s.T)
    m = s.shape[0]
    label, count = _components(s)
    bound = np.max(np.sum(np.abs(s), 1))  # only compared with: its last bits do not matter
    nn = np.zeros_like(s)
    for c in range(count):
        idx = np.flatnonzero(label == c)
        block = np.ix_(idx, idx)
        if np.sum(s[block]) / idx.size <= 1e-5 * bound:
            nn[block] = 1.0 / idx.size
    x = s + nn
    inv = np.eye(m)
    for k in range(m):
        rx, ri = x[k] / x[k, k], inv[k] / x[k, k]
        col = x[:, k].copy()
        col[k] = 0.0
        x -= np.multiply.outer(col, rx)
        inv -= np.multiply.outer(col, ri)
        x[k], inv[k] = rx, ri
    return (0.5 * (inv + inv.T) - nn).astype(a.dtype)


def _tree_sum(x):
    """Sum over x's last axis in a fixed order: zero-padded to a power of two, the halves added elementwise until
    one is left. XLA vectorises a reduction (jnp.sum, a dot) by the width it prefers on the host CPU, which
    reorders the additions: the flows' bits then differed between CPUs of one instruction set."""
    n = x.shape[-1]
    size = 1 << max(0, (n - 1).bit_length())
    x = jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, size - n)])
    while x.shape[-1] > 1:
        half = x.shape[-1] // 2
        x = x[..., :half] + x[..., half:]
    return x[..., 0]


def _total(x):
    """Sum of all of x's elements in a fixed order (_tree_sum)."""
    return _tree_sum(x.reshape(-1))


def _jacobi(fc: Faces, x, r, inv_d, px, py, sweeps: int):
    # a loop, not unrolled: each unrolled sweep was compiled on its own (XLA compile time grows with the program)
    return jax.lax.fori_loop(0, sweeps, lambda _, x: x + inv_d * (r - apply(fc, x, px, py)), x)


def vcycle(op: Operator, r, px, py, sweeps=SWEEPS, omega=OMEGA, level: int = 0):
    """One V-cycle approximating A^-1 r from zero: damped-Jacobi smoothing (``sweeps`` before and after, default
    SWEEPS, OMEGA) on each level, the coarse correction scaled by COARSE_WEIGHT, the coarsest level solved
    exactly; a symmetric positive definite preconditioner. r [ny, nx] -> [ny, nx]."""
    levels = op.levels
    if level == len(levels) - 1:
        return _tree_sum(op.coarse_inverse * r.reshape(1, -1)).reshape(r.shape)
    fc = levels[level]
    inv_d = omega / jnp.maximum(diagonal(fc, px, py), 1e-30)
    x = _jacobi(fc, inv_d * r, r, inv_d, px, py, sweeps - 1)
    res = r - apply(fc, x, px, py)
    # the weight on the restricted residual (the coarse V-cycle is linear): XLA's CPU backend lets LLVM contract a
    # product into the sum that uses it (one fused multiply-add), and whether it did for the weighted correction
    # x + w P xc followed the vector width, so the bits differed between CPUs
    rc = COARSE_WEIGHT * (res[0::2, 0::2] + res[1::2, 0::2] + res[0::2, 1::2] + res[1::2, 1::2])
    xc = vcycle(op, rc, px, py, sweeps, omega, level + 1)
    x = x + jnp.repeat(jnp.repeat(xc, 2, 0), 2, 1)
    return _jacobi(fc, x, r, inv_d, px, py, sweeps)


MAX_CHECKS = 4  # true-residual checks (each a restart) a solve may make before it accepts the rounding floor


class Solve(NamedTuple):
    """p [ny, nx]; iterations; residual: recomputed relative residual ||b - A p|| / ||b||."""

    p: jax.Array
    iterations: jax.Array
    residual: jax.Array


def solve(fc: Faces, b, periodic_x: bool, periodic_y: bool, singular: bool, tol: float = 1e-5,
          max_iter: int = 200, op: Operator | None = None, x0=None) -> Solve:
    """Solve A p = b (b [ny, nx], zero in solid cells) by multigrid-preconditioned CG to ||b - A p|| <= tol ||b||;
    ``op``: the prepared operator of fc (computed here when None); ``x0``: a first guess (the last step's
    pressure: CG then solves for the correction, and stops at the same absolute residual)."""
    op = prepare(fc, periodic_x, periodic_y) if op is None else op
    fluid = 1.0 - fc.solid
    nfl = jnp.maximum(_total(fluid), 1.0)

    def proj(x):
        return x - fluid * (_total(x * fluid) / nfl) if singular else x

    def prec(r):
        return proj(vcycle(op, r, periodic_x, periodic_y))

    def matvec(x):
        return apply(fc, x, periodic_x, periodic_y)

    def cg(_, rhs):  # (x, iterations): also the transposed solve of reverse-mode derivatives (A is symmetric)
        rhs = proj(rhs)
        bn2 = _total(rhs * rhs)
        stop2 = jnp.maximum(tol * tol * bn2, floor2)  # floor2: the warm start's target, tol ||b||, squared

        def cond(s):
            return (s[0] < max_iter) & ~s[5] & (s[6] <= MAX_CHECKS)

        def body(s):
            # the preconditioner opens the iteration (its only call, so the program holds one V-cycle): the
            # direction d = z + beta d of the residual r left by the last iteration, beta = 0 on the first and
            # after a restart (z + 0 d is z's bits)
            k, x, r, d, rz, _, checks, restart = s
            z = prec(r)
            rz_new = _total(r * z)
            beta = jnp.where(restart, 0.0, rz_new / rz).astype(rz.dtype)
            d = z + beta * d
            ad = matvec(d)
            alpha = rz_new / _total(d * ad)
            x = x + alpha * d
            r = r - alpha * ad
            # In float32 the recursive residual drifts below the true one (measured 3x at 32x16): when it claims
            # tol ||b||, replace it by the true residual b - A x, stop if that is within tol ||b|| too, else
            # restart from it (beta = 0); at most MAX_CHECKS times, so a target under the rounding floor cannot
            # spin to max_iter. (Claiming at tol / 2 cost float64 solves a 14th iteration at 256x128.)
            claims = _total(r * r) <= stop2
            r = jax.lax.cond(claims, lambda: proj(rhs - matvec(x)), lambda: r)
            done = claims & (_total(r * r) <= stop2)
            return k + 1, x, r, d, rz_new, done, checks + claims.astype(jnp.int32), claims

        zero = jnp.zeros((), jnp.int32)
        s0 = (zero, jnp.zeros_like(rhs), rhs, jnp.zeros_like(rhs), jnp.ones((), rhs.dtype), bn2 <= 0, zero,
              jnp.ones((), bool))
        k, x, *_ = jax.lax.while_loop(cond, body, s0)
        return proj(x), k

    # custom_linear_solve: reverse-mode derivatives solve with A^T = A instead of differentiating the loop
    b = proj(b)
    if x0 is None:
        floor2 = jnp.zeros((), b.dtype)
        x, k = jax.lax.custom_linear_solve(matvec, b, cg, symmetric=True, has_aux=True)
    else:
        x0 = proj(jax.lax.stop_gradient(x0) * fluid)  # a guess: derivatives do not flow through it
        floor2 = tol * tol * _total(b * b)
        # A guess worse than zero (the impulsive start's pressure, measured 3.9 ||b||) is dropped: its rounding
        # (||x0|| ~ 60 ||b||) put the float32 floor of ||b - A (x0 + dx)|| at ~4e-5 ||b||, above tol.
        r0 = b - matvec(x0)
        good = _total(r0 * r0) < _total(b * b)
        x0, r0 = jnp.where(good, x0, 0.0), jnp.where(good, r0, b)
        dx, k = jax.lax.custom_linear_solve(matvec, r0, cg, symmetric=True, has_aux=True)
        x = x0 + dx
    r = b - matvec(x)
    return Solve(x, k, jnp.sqrt(_total(r * r) / jnp.maximum(_total(b * b), 1e-30)))
