"""Compressible Navier-Stokes of an ideal gas, 1D and 2D: ``euler``'s MUSCL-HLLC schemes plus a viscous stress
(JAX, one sample unbatched; jit/vmap-able). The 2D functions (``*_2d``) are below, with their stress.

1D state: conserved U [3, n] = (rho, rho u, E) as in ``euler``. phys [3] = (gamma, eta, zeta): the ratio of specific
heats and the shear and bulk viscosities, kinematic (length^2 / time): the stress is
tau = rho (4/3 eta + zeta) u_x, so the dynamic viscosities are rho eta and rho zeta (PDEBench's compressible
model, whose viscous update multiplies its eta and zeta by the density). No heat conduction. The viscous fluxes
are central at the faces: tau_f = rho_f nu_l (u_R - u_L) / h and its work tau_f u_f in the energy, rho_f and u_f
the two cells' means, nu_l = 4/3 eta + zeta; the ends take the ghost cells' kinds (``scheme.ghosts``: a wall
mirrors u, an outflow end has zero gradient and so no stress). Time: SSP-RK3 of the sum of both rates, one fixed
step; the step's CFL number is dt (max(|u| + c) / h + 2 nu_l / h^2) (the advective and diffusive limits added).
"""

from __future__ import annotations

from pdestream.generator.lazy_jax import jax, jnp

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


# --- 2D: PDEBench's stress, axis by axis -----------------------------------------------------------------------------
# State q [4, nx, ny] = (rho, rho u, rho v, E) as in ``euler``'s 2D functions. Each axis's faces carry the stress of
# that axis's derivatives only: nu_l rho d(u_n)/dn on the normal momentum, eta rho d(u_t)/dn on the transverse one,
# and their work; PDEBench's update_vis does the same (the full Navier-Stokes stress's cross terms, d(u_t)/dt along
# the other axis in tau_nt and the divergence's other half in tau_nn, are absent from its model and so from ours).

def to_conserved_2d(w: jax.Array, phys: jax.Array) -> jax.Array:
    """Primitive w [4, ...] (rho, u, v, p) -> conserved [4, ...]; phys [3] = (gamma, eta, zeta)."""
    return euler.to_conserved_2d(w, phys[0])


def to_primitive_2d(q: jax.Array, phys: jax.Array) -> jax.Array:
    """Conserved q [4, ...] -> primitive [4, ...] (rho, u, v, p)."""
    return euler.to_primitive_2d(q, phys[0])


def _axis_fluxes(w: jax.Array, lo_kind, hi_kind, nu_n, nu_t, h) -> jax.Array:
    """Viscous fluxes [3, ..., n + 1] (normal momentum, transverse momentum, energy) at the faces along the last
    axis of w [3, ..., n] = (rho, u_n, u_t); the ends' ghost cells by kind (a wall mirrors u_n)."""
    flip = jnp.array((1.0, -1.0, 1.0), w.dtype)
    lo = scheme.ghosts(w, lo_kind, True, flip)[..., -1:]
    hi = scheme.ghosts(w, hi_kind, False, flip)[..., :1]
    wp = jnp.concatenate([lo, w, hi], -1)
    rho_f = 0.5 * (wp[0, ..., 1:] + wp[0, ..., :-1])
    mean = 0.5 * (wp[1:, ..., 1:] + wp[1:, ..., :-1])
    grad = (wp[1:, ..., 1:] - wp[1:, ..., :-1]) / h
    tau_n, tau_t = nu_n * rho_f * grad[0], nu_t * rho_f * grad[1]
    return jnp.stack([tau_n, tau_t, tau_n * mean[0] + tau_t * mean[1]])


def viscous_rate_2d(q: jax.Array, phys: jax.Array, h, sides: jax.Array) -> jax.Array:
    """dq/dt [4, nx, ny] of the stress alone for conserved q [4, nx, ny] on square cells of side h; sides int [4]
    (x low, x high, y low, y high)."""
    rho = q[0]
    u, v = q[1] / rho, q[2] / rho
    nu_l, eta = longitudinal(phys), phys[1]
    fx = _axis_fluxes(jnp.stack([rho, u, v]).swapaxes(1, 2), sides[0], sides[1], nu_l, eta, h)  # [3, ny, nx + 1]
    fy = _axis_fluxes(jnp.stack([rho, v, u]), sides[2], sides[3], nu_l, eta, h)  # [3, nx, ny + 1]
    dx = ((fx[..., 1:] - fx[..., :-1]) / h).swapaxes(1, 2)  # (mom u, mom v, E) [3, nx, ny]
    dy = (fy[..., 1:] - fy[..., :-1]) / h  # (mom v, mom u, E)
    return jnp.stack([jnp.zeros_like(rho), dx[0] + dy[1], dx[1] + dy[0], dx[2] + dy[2]])


def cfl_number_2d(q: jax.Array, phys: jax.Array, dt, h) -> jax.Array:
    """dt ((max(|u| + c) + max(|v| + c)) / h + 2 (nu_l + eta) / h^2): the 2D step's advective and diffusive CFL
    numbers added (u's diffusion is nu_l along x and eta along y; v's the reverse)."""
    return euler.cfl_2d(q, phys[0], dt, h) + dt * 2 * (longitudinal(phys) + phys[1]) / (h * h)


def run_2d(q: jax.Array, health: scheme.Health, phys: jax.Array, dt, n_steps, h, sides: jax.Array, limiter,
           cfl_limit: float):
    """``euler.run_2d`` with the stress: n_steps SSP-RK3 steps of dt from (q [4, nx, ny], health); phys [3] =
    (gamma, eta, zeta); a step whose ``cfl_number_2d`` exceeds cfl_limit fails the sample."""
    def rate(y):
        return euler.rate_2d(y, phys[0], h, sides, limiter) + viscous_rate_2d(y, phys, h, sides)

    def code(new, cfl):
        rho, _, _, p = euler.to_primitive_2d(new, phys[0])
        return euler.failure_code(rho, p, new, cfl, cfl_limit)

    return scheme.run(q, health, lambda x: scheme.ssp_rk3(x, rate, dt), lambda x: cfl_number_2d(x, phys, dt, h),
                      code, n_steps)
