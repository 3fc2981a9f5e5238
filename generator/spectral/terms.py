"""Nonlinear terms shared by the PDEs defined in any dimension (Fourier state [C, *kshape] in, same out).

Each builder takes the grid (and traced coefficients) and returns N(v_hat). Inputs are already inside the
2/3-rule band (the solver masks every state and every N), so products of two fields are exact on the grid.
Sums over axes are written out term by term (Python ``sum``), not as reductions: XLA may reassociate a
reduction differently per batch size, which would change a sample's bits with its batch.
"""

from __future__ import annotations

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp


def ddx(k: np.ndarray, v: jax.Array) -> jax.Array:
    """Spectral derivative i k v in real arithmetic (exact, batch-invariant): k float32 broadcastable to v."""
    return jax.lax.complex(-k * v.imag, k * v.real)


def polynomial(grid, c2, c3):
    """N(v) = rfft(c2 u^2 + c3 u^3) for one field; c2, c3 numbers or traced scalars (per unit time)."""

    def nonlinear(v):
        u = grid.irfft(v)
        return grid.rfft(u * u * (c2 + c3 * u))

    return nonlinear


def advection_of_velocity(grid):
    """Vector Burgers transport N(v) = -(u . grad) u with u = irfft(v), v [ndim, *kshape] (ndim >= 2).

    The advective (not the conservative) form, so a vector field follows u_t + (u . grad) u = nu Laplacian(u)
    for any initial condition, not only potential flows.
    """
    ks = grid.wavenumbers()

    def nonlinear(v):
        u = grid.irfft(v)  # [d, *shape]
        du = [grid.irfft(ddx(k, v)) for k in ks]  # du[j][i] = d_j u_i, each [d, *shape]
        return -grid.rfft(sum(u[j] * du[j] for j in range(grid.ndim)))

    return nonlinear


def gradient_norm(grid):
    """N(v) = -|grad u|^2 / 2 without its mean (k = 0 mode), for one field: the scalar Kuramoto-Sivashinsky term.

    Dropping the mean removes the uniform drift of u (d<u>/dt = -<|grad u|^2>/2) that otherwise grows without
    bound; the dynamics of u - <u> are unchanged.
    """
    ks = grid.wavenumbers()
    keep = np.ones(grid.kshape, np.float32)
    keep[(0,) * grid.ndim] = 0.0
    factor = jnp.asarray(-0.5 * keep)

    def nonlinear(v):
        grads = [grid.irfft(ddx(k, v[0])) for k in ks]
        return (factor * grid.rfft(sum(g * g for g in grads)))[None]

    return nonlinear


def hermitian_damping(grid, rate):
    """N term -rate * a, where a is the part of the state that no real field has: the anti-Hermitian part of the
    plane k_last = 0 of the real-FFT layout (v[-m] != conj(v[m]) there). For PDEs whose linear part grows.

    Why: irfft ignores that part, so the nonlinear term never sees it and it evolves by e^{hL} alone; rounding
    seeds it at ~1e-7 of the state, and where L > 0 (Cahn-Hilliard's, Swift-Hohenberg's, Kuramoto-Sivashinsky's
    unstable band) it grows until it swamps the float32 state (Cahn-Hilliard at gamma = 1e-3 blew up at t ~ 15).
    With rate > max Re L it decays instead. It is zero for the transform of a real field, so the solution is
    unchanged. rate * dt must stay below ETDRK4's real-axis limit (~2.8): callers keep it below ~1.5.
    v [C, *kshape] -> same.
    """
    axes = tuple(range(1, grid.ndim))  # the plane's axes (none in 1D: there the plane is the mode 0)

    def term(v):
        plane = v[..., 0]
        mirror = plane
        for axis in axes:  # index m -> -m (mod n) on every axis of the plane
            mirror = jnp.roll(jnp.flip(mirror, axis), 1, axis)
        anti = (plane - jnp.conj(mirror)) * (-0.5 * rate)
        return jnp.zeros_like(v).at[..., 0].set(anti)

    return term
