"""``diffusion_sorption1d``: 1D diffusion with Freundlich sorption (PDEBench's diffusion-sorption equation), by
conservative finite volumes in space and TR-BDF2 in time (JAX; one sample unbatched, jit/vmap-able).

    R(u) u_t = D u_xx on (0, L),   u(0, t) = u_left,   u(L, t) = -D u_x(L, t)   (PDEBench's code; t, x in s, m)
    R(u) = 1 + K n_f u^(n_f - 1),  K = (1 - por) / por rho_s k_f

i.e. S(u)_t = D u_xx for the retarded mass S(u) = u + K u^n_f (dissolved plus sorbed, per pore volume), which the
scheme conserves: cell i's S changes by the difference of the diffusive fluxes F = -D u_x through its faces.

Space: n cells of h = L / n, values at the centres. Interior faces F = -D (u_i - u_{i-1}) / h; the left face sees
u_left at distance h / 2, F_0 = -2 D (u_0 - u_left) / h; the right face value u_b satisfies the Robin condition
with the gradient (u_b - u_{n-1}) / (h / 2), so u_b = g u_{n-1}, g = (2 D / h) / (1 + 2 D / h), and F_n = u_b (the
outflow -D u_x equals u there). Both ends are second order and a linear profile is exact, so the discrete steady
state is the exact one, u = u_left (1 - x / (L + D)). PDEBench puts u_left and its Robin value in ghost cells a
whole cell from the last centre (first order at the ends).

Time: TR-BDF2 (a trapezoidal stage to t + gamma dt, gamma = 2 - sqrt 2, then BDF2; second order, L-stable, one
step of state: a frame advanced from a stored frame takes the sampler's steps), each stage's nonlinear system
S(u) - c dt (A u + b) = r solved by NEWTON Newton iterations with the tridiagonal Jacobian diag(R(u)) - c dt A
(LAPACK's gtsv through jax.lax.linalg.tridiagonal_solve). The sorbed term is stiff where u -> 0 (R grows as
u^(n_f - 1) for n_f < 1): an implicit step is stable at any dt; the regularisation eps (PDEBench's 1e-6) bounds R
as R(0) = 1 + K n_f eps^(n_f - 1) (13.3 at PDEBench's constants). Below u = 0, where u^n_f is not real, S is
continued linearly with slope R(0) (a step may undershoot a little; S stays monotone and smooth enough for Newton).

Health: a sample fails if a value is not finite, a stage's Newton residual stays above NEWTON_TOL (relative to
max |S|), or u leaves [lo - 0.05 span, hi + 0.05 span], with [lo, hi] the range a maximum principle allows (its
IC and u_left, and 0); its state is held at its last good step from then on (no NaN written).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

GAMMA = 2.0 - math.sqrt(2.0)  # TR-BDF2's stage point
NEWTON = 4  # Newton iterations per stage: 3 leave the first step (u0 meeting u_left at x = 0) above NEWTON_TOL
NEWTON_TOL = 1e-4  # a stage whose residual max|G| / max|S| stays above this fails (the step did not converge)
OVERSHOOT = 0.05  # u may leave its maximum-principle range by this fraction of the range before it fails

OK, NOT_FINITE, NOT_CONVERGED, OUT_OF_RANGE = 0, 1, 2, 3
CAUSES = {NOT_FINITE: "a NaN/Inf", NOT_CONVERGED: "Newton did not converge in a stage",
          OUT_OF_RANGE: "u left the range a maximum principle allows"}


class Coefficients(NamedTuple):
    """One sample's traced constants: D (m^2/s), K = (1 - por) / por rho_s k_f, n_f, u_left, eps, h (m)."""

    D: jax.Array
    K: jax.Array
    n_f: jax.Array
    u_left: jax.Array
    eps: jax.Array
    h: jax.Array


class Health(NamedTuple):
    """Per sample: ``code`` (OK or the first failure), ``step`` (steps taken when it failed, -1: none),
    ``residual`` (largest relative Newton residual seen), ``steps`` (steps taken so far)."""

    code: jax.Array
    step: jax.Array
    residual: jax.Array
    steps: jax.Array


def healthy(dtype="float32") -> Health:
    return Health(jnp.int32(OK), jnp.int32(-1), jnp.zeros((), dtype), jnp.int32(0))


def healthy_batch(k: int, dtype=np.float32) -> Health:
    """``healthy()`` for k samples: each field [k]."""
    return jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (k,)), healthy(dtype))


def storage(u: jax.Array, c: Coefficients) -> jax.Array:
    """The retarded mass per pore volume S(u) = u + K ((u + eps)^n_f - eps^n_f) for u >= 0, continued linearly
    (slope R(0)) below 0: [n], the units of u."""
    up = jnp.maximum(u, 0.0)
    return u + c.K * ((up + c.eps) ** c.n_f - c.eps**c.n_f) + c.K * c.n_f * c.eps ** (c.n_f - 1) * jnp.minimum(u, 0.0)


def retardation(u: jax.Array, c: Coefficients) -> jax.Array:
    """R(u) = dS/du = 1 + K n_f (max(u, 0) + eps)^(n_f - 1): [n], dimensionless (PDEBench's factor, its eps)."""
    return 1.0 + c.K * c.n_f * (jnp.maximum(u, 0.0) + c.eps) ** (c.n_f - 1)


def outflow_gain(c: Coefficients) -> jax.Array:
    """g: the right face's value u_b = g u_{n-1} under u_b = -D (u_b - u_{n-1}) / (h / 2)."""
    r = 2 * c.D / c.h
    return r / (1 + r)


def fluxes(u: jax.Array, c: Coefficients) -> jax.Array:
    """The diffusive fluxes -D u_x through the n + 1 faces [n + 1] (units of u times m/s; > 0: towards +x)."""
    left = 2 * c.D * (c.u_left - u[:1]) / c.h
    inner = -c.D * (u[1:] - u[:-1]) / c.h
    return jnp.concatenate([left, inner, outflow_gain(c) * u[-1:]])


def rate(u: jax.Array, c: Coefficients) -> jax.Array:
    """dS/dt of every cell, (F_i - F_{i+1}) / h: [n] (the semi-discrete equation; A u + b)."""
    f = fluxes(u, c)
    return (f[:-1] - f[1:]) / c.h


def _operator(n: int, c: Coefficients):
    """The tridiagonal of A (rate = A u + b): (lower [n], diagonal [n], upper [n]), lapack's layout."""
    a = c.D / c.h**2
    lower = jnp.full((n,), a).at[0].set(0.0)
    upper = jnp.full((n,), a).at[-1].set(0.0)
    diag = jnp.full((n,), -2 * a).at[0].set(-3 * a).at[-1].set(-a - outflow_gain(c) / c.h)
    return lower, diag, upper


def _stage(guess: jax.Array, r: jax.Array, cdt, c: Coefficients):
    """u solving S(u) - cdt rate(u) = r by NEWTON Newton steps from ``guess``: (u, relative residual)."""
    lower, diag, upper = _operator(guess.shape[0], c)

    def newton(_, u):
        g = storage(u, c) - cdt * rate(u, c) - r
        du = jax.lax.linalg.tridiagonal_solve(-cdt * lower, retardation(u, c) - cdt * diag, -cdt * upper, -g[:, None])
        return u + du[:, 0]

    u = jax.lax.fori_loop(0, NEWTON, newton, guess)
    g = storage(u, c) - cdt * rate(u, c) - r
    return u, jnp.max(jnp.abs(g)) / jnp.maximum(jnp.max(jnp.abs(r)), 1e-30)


def step(u: jax.Array, dt, c: Coefficients):
    """One TR-BDF2 step of dt from u [n]: (u, the larger of its two stages' relative Newton residuals)."""
    s0 = storage(u, c)
    mid, res1 = _stage(u, s0 + 0.5 * GAMMA * dt * rate(u, c), 0.5 * GAMMA * dt, c)
    w = 1.0 / (GAMMA * (2 - GAMMA))
    r2 = w * storage(mid, c) - (1 - GAMMA) ** 2 * w * s0
    new, res2 = _stage(mid, r2, (1 - GAMMA) / (2 - GAMMA) * dt, c)
    return new, jnp.maximum(res1, res2)


def run(u: jax.Array, health: Health, c: Coefficients, dt, n_steps, lo, hi):
    """n_steps steps of dt from (u [n], health): (u, health). ``lo``, ``hi``: the range a maximum principle
    allows this sample (its IC, u_left and 0). A failed sample's state is held from then on; a Python int n_steps
    makes it a scan (reverse-mode differentiable)."""
    slack = OVERSHOOT * jnp.maximum(hi - lo, 1e-6)

    def body(_, carry):
        u, hl = carry
        new, res = step(u, dt, c)
        got = jnp.where(~jnp.isfinite(new).all() | ~jnp.isfinite(res), NOT_FINITE,
                        jnp.where(res > NEWTON_TOL, NOT_CONVERGED,
                                  jnp.where((new.min() < lo - slack) | (new.max() > hi + slack), OUT_OF_RANGE, OK)))
        keep = hl.code == OK
        fresh = keep & (got != OK)
        hl = Health(jnp.where(keep, got, hl.code), jnp.where(fresh, hl.steps, hl.step),
                    jnp.where(keep, jnp.maximum(hl.residual, jnp.where(jnp.isfinite(res), res, 0.0)), hl.residual),
                    hl.steps + 1)
        return jnp.where(keep & (got == OK), new, u), hl

    return jax.lax.fori_loop(0, n_steps, body, (u, health))
