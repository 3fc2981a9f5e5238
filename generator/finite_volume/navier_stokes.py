"""1D compressible Navier-Stokes of an ideal gas: ``euler``'s MUSCL-HLLC scheme plus a viscous stress (JAX, one
sample unbatched; jit/vmap-able).

State: conserved U [3, n] = (rho, rho u, E) as in ``euler``. phys [3] = (gamma, eta, zeta): the ratio of specific
heats and the shear and bulk viscosities, kinematic (length^2 / time): the stress is
tau = rho (4/3 eta + zeta) u_x, so the dynamic viscosities are rho eta and rho zeta (PDEBench's compressible
model, whose viscous update multiplies its eta and zeta by the density). No heat conduction. The viscous fluxes
are central at the faces: tau_f = rho_f nu_l (u_R - u_L) / h and its work tau_f u_f in the energy, rho_f and u_f
the two cells' means, nu_l = 4/3 eta + zeta; the ends take the ghost cells' kinds (``scheme.ghosts``: a wall
mirrors u, an outflow end has zero gradient and so no stress). Time: SSP-RK3 of the sum of both rates, one fixed
step; the step's CFL number is dt (max(|u| + c) / h + 2 nu_l / h^2) (the advective and diffusive limits added).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import euler, scheme
from .euler import to_conserved as _to_conserved
from .euler import to_primitive as _to_primitive

CAUSES = euler.CAUSES
_FLIP = (1.0, -1.0)  # (rho, u): a wall mirrors u


def to_conserved(w: jax.Array, phys: jax.Array) -> jax.Array:
    """Primitive w [3, ...] (rho, u, p) -> conserved [3, ...]; phys [3] = (gamma, eta, zeta)."""
    return _to_conserved(w, phys[0])


def to_primitive(q: jax.Array, phys: jax.Array) -> jax.Array:
    """Conserved q [3, ...] -> primitive [3, ...] (rho, u, p); phys [3] = (gamma, eta, zeta)."""
    return _to_primitive(q, phys[0])


def longitudinal(phys: jax.Array) -> jax.Array:
    """nu_l = 4/3 eta + zeta (length^2 / time): the kinematic viscosity of 1D compression."""
    return (4.0 / 3.0) * phys[1] + phys[2]


def viscous_rate(q: jax.Array, nu_l, h, sides: jax.Array) -> jax.Array:
    """dq/dt [3, n] of the viscous stress alone for conserved q [3, n]: nu_l = 4/3 eta + zeta, cell size h, sides
    int [2] (indices in SIDE_KINDS). Conservative: a face's flux leaves one cell and enters the next."""
    w = jnp.stack([q[0], q[1] / q[0]])
    flip = jnp.array(_FLIP, w.dtype)
    lo = scheme.ghosts(w, sides[0], True, flip)[..., -1:]  # the ghost cell next to the first cell
    hi = scheme.ghosts(w, sides[1], False, flip)[..., :1]
    wp = jnp.concatenate([lo, w, hi], -1)  # [2, n + 2]
    rho_f = 0.5 * (wp[0, 1:] + wp[0, :-1])  # [n + 1], face j between cells j - 1 and j
    u_f = 0.5 * (wp[1, 1:] + wp[1, :-1])
    tau = nu_l * rho_f * (wp[1, 1:] - wp[1, :-1]) / h
    f = jnp.stack([tau, tau * u_f])  # momentum and energy fluxes (the stress enters with + sign)
    return jnp.concatenate([jnp.zeros_like(q[:1]), (f[:, 1:] - f[:, :-1]) / h])


def rate(q: jax.Array, phys: jax.Array, h, sides: jax.Array, limiter) -> jax.Array:
    """dq/dt [3, n]: ``euler.rate`` plus ``viscous_rate``."""
    return euler.rate(q, phys[0], h, sides, limiter) + viscous_rate(q, longitudinal(phys), h, sides)


def cfl_number(q: jax.Array, phys: jax.Array, dt, h) -> jax.Array:
    """dt (max(|u| + c) / h + 2 nu_l / h^2): the step's advective and diffusive CFL numbers added (a scalar)."""
    return dt * (euler.max_speed(q, phys[0]) / h + 2 * longitudinal(phys) / (h * h))


def run(q: jax.Array, health: scheme.Health, phys: jax.Array, dt, n_steps, h, sides: jax.Array, limiter,
        cfl_limit: float):
    """``euler.run`` with the viscous stress: n_steps SSP-RK3 steps of dt from (q [3, n], health); phys [3] =
    (gamma, eta, zeta); a step whose ``cfl_number`` exceeds cfl_limit fails the sample."""
    def code(new, cfl):
        rho, _, p = _to_primitive(new, phys[0])
        return euler.failure_code(rho, p, new, cfl, cfl_limit)

    return scheme.run(q, health, lambda x: scheme.ssp_rk3(x, lambda y: rate(y, phys, h, sides, limiter), dt),
                      lambda x: cfl_number(x, phys, dt, h), code, n_steps)
