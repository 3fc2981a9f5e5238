"""Masked variable-coefficient pressure Poisson solve: CG preconditioned by a geometric multigrid V-cycle.

Operator (h^2-scaled, symmetric positive semi-definite): (A p)_P = sum over the 4 faces c_f (p_P - p_nb)
+ solid_P p_P, where a closed face has c = 0 (walls, inflow, obstacle faces: Neumann), an open boundary face
is Dirichlet p = 0 (ghost = -p_P) and a periodic face wraps. Coarse levels are Galerkin P^T A P with
piecewise-constant P over 2x2 blocks: the coarse face coefficient is the sum of the two fine ones, so the
V-cycle (damped Jacobi, nu1 = nu2, the same sweeps before and after) is a symmetric preconditioner.
Without a Dirichlet side A is singular: the rhs and each preconditioned residual have their mean projected
out. Each sample stops on its own relative residual (a masked while loop), so batches don't change bits.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from generator.flow.grid import Faces


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


def hierarchy(fc: Faces, min_cells: int = 4) -> list:
    """Coefficient levels, finest first, halving while both dims stay even and >= min_cells."""
    levels = [fc]
    while all(n % 2 == 0 and n // 2 >= min_cells for n in levels[-1].solid.shape):
        levels.append(coarsen(levels[-1]))
    return levels


def vcycle(levels, r, px, py, sweeps=2, coarse_sweeps=40, omega=0.8):
    """One V-cycle approximating A^-1 r from zero (damped Jacobi smoothing): [ny, nx]."""
    fc = levels[0]
    inv_d = omega / jnp.maximum(diagonal(fc, px, py), 1e-30)
    n = coarse_sweeps if len(levels) == 1 else sweeps
    x = inv_d * r
    for _ in range(n - 1):
        x = x + inv_d * (r - apply(fc, x, px, py))
    if len(levels) == 1:
        return x
    res = r - apply(fc, x, px, py)
    rc = res[0::2, 0::2] + res[1::2, 0::2] + res[0::2, 1::2] + res[1::2, 1::2]
    xc = vcycle(levels[1:], rc, px, py, sweeps, coarse_sweeps, omega)
    x = x + jnp.repeat(jnp.repeat(xc, 2, 0), 2, 1)
    for _ in range(n):
        x = x + inv_d * (r - apply(fc, x, px, py))
    return x


class Solve(NamedTuple):
    """p [ny, nx]; iterations; residual: recomputed relative residual ||b - A p|| / ||b||."""

    p: jax.Array
    iterations: jax.Array
    residual: jax.Array


def solve(fc: Faces, b, periodic_x: bool, periodic_y: bool, singular: bool, tol: float = 1e-5,
          max_iter: int = 200) -> Solve:
    """Solve A p = b (b [ny, nx], zero in solid cells) by multigrid-preconditioned CG from p = 0."""
    levels = hierarchy(fc)
    fluid = 1.0 - fc.solid
    nfl = jnp.maximum(jnp.sum(fluid), 1.0)

    def proj(x):
        return x - fluid * (jnp.sum(x * fluid) / nfl) if singular else x

    b = proj(b)
    bn2 = jnp.sum(b * b)
    stop2 = tol * tol * bn2

    def prec(r):
        return proj(vcycle(levels, r, periodic_x, periodic_y))

    def cond(s):
        return (s[0] < max_iter) & (s[5] > stop2)

    def body(s):
        k, x, r, d, rz, _ = s
        ad = apply(fc, d, periodic_x, periodic_y)
        alpha = rz / jnp.sum(d * ad)
        x = x + alpha * d
        r = r - alpha * ad
        z = prec(r)
        rz_new = jnp.sum(r * z)
        return k + 1, x, r, z + (rz_new / rz) * d, rz_new, jnp.sum(r * r)

    z0 = prec(b)
    s0 = (jnp.zeros((), jnp.int32), jnp.zeros_like(b), b, z0, jnp.sum(b * z0), bn2)
    s0 = jax.lax.cond(bn2 > 0, lambda s: s, lambda s: s[:5] + (jnp.zeros_like(bn2),), s0)
    k, x, *_ = jax.lax.while_loop(cond, body, s0)
    x = proj(x)
    r = b - apply(fc, x, periodic_x, periodic_y)
    return Solve(x, k, jnp.sqrt(jnp.sum(r * r) / jnp.maximum(bn2, 1e-30)))
