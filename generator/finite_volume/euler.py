"""Compressible Euler of an ideal gas on uniform finite-volume grids, 1D and 2D (JAX, one sample unbatched;
jit/vmap-able).

State: conserved cell averages, 1D U [3, n] = (rho, rho u, E), 2D U [4, nx, ny] = (rho, rho u, rho v, E), with
E = p / (gamma - 1) + rho |u|^2 / 2. Space: MUSCL reconstruction of the primitive variables with a TVD limiter
(``scheme.LIMITERS``), two ghost cells per side, HLLC fluxes (Toro 1994) with Einfeldt's wave speeds; in 2D each
axis's faces solve their 1D problem with the transverse velocity carried through the contact (dimension by
dimension, unsplit). Time: SSP-RK3, a fixed step dt per call. Every face value lies between its cell's
neighbours, so positive cell values give positive face states; positivity of the update itself is checked, not
assumed (``Health``).
"""

from __future__ import annotations

from pdestream.generator.lazy_jax import jax, jnp

from . import scheme
from .scheme import BAD_DENSITY, BAD_PRESSURE, CFL_EXCEEDED, NOT_FINITE, OK, Health

CAUSES = {BAD_DENSITY: "density went non-positive", BAD_PRESSURE: "pressure went non-positive",
          NOT_FINITE: "a value went NaN/Inf", CFL_EXCEEDED: "the waves outran the step"}
# 2D channel orders: primitive (rho, u, v, p) into each axis's normal frame (rho, u_n, p, u_t), and the frame's
# fluxes (mass, normal momentum, energy, transverse momentum) back to conserved (rho, rho u, rho v, E)
PERMS_2D = (((0, 1, 3, 2), (0, 1, 3, 2)), ((0, 2, 3, 1), (0, 3, 1, 2)))


def to_conserved(w: jax.Array, gamma) -> jax.Array:
    """Primitive w [3, ...] (rho, u, p) -> conserved [3, ...] (rho, rho u, E)."""
    rho, u, p = w[0], w[1], w[2]
    return jnp.stack([rho, rho * u, p / (gamma - 1) + 0.5 * rho * u * u])


def to_primitive(q: jax.Array, gamma) -> jax.Array:
    """Conserved q [3, ...] -> primitive [3, ...] (rho, u, p)."""
    rho, m, e = q[0], q[1], q[2]
    u = m / rho
    return jnp.stack([rho, u, (gamma - 1) * (e - 0.5 * m * u)])


def to_conserved_2d(w: jax.Array, gamma) -> jax.Array:
    """Primitive w [4, ...] (rho, u, v, p) -> conserved [4, ...] (rho, rho u, rho v, E)."""
    rho, u, v, p = w[0], w[1], w[2], w[3]
    return jnp.stack([rho, rho * u, rho * v, p / (gamma - 1) + 0.5 * rho * u * u + 0.5 * rho * v * v])


def to_primitive_2d(q: jax.Array, gamma) -> jax.Array:
    """Conserved q [4, ...] (rho, rho u, rho v, E) -> primitive [4, ...] (rho, u, v, p)."""
    rho, m, n, e = q[0], q[1], q[2], q[3]
    u, v = m / rho, n / rho
    return jnp.stack([rho, u, v, (gamma - 1) * (e - 0.5 * m * u - 0.5 * n * v)])


def _flux(rho, u, p, e, passive):
    """Physical flux [3 + k, m] normal to a face: mass, normal momentum, energy, then each transverse momentum."""
    return jnp.stack([rho * u, rho * u * u + p, (e + p) * u, *(rho * u * t for t in passive)])


def hllc(wl: jax.Array, wr: jax.Array, gamma) -> jax.Array:
    """HLLC flux [3 + k, m] between left and right primitive face states wl, wr [3 + k, m] = (rho, u_n, p, then k
    transverse velocities carried through the contact) (Toro, Riemann Solvers, 10.4), signal speeds after
    Einfeldt (the extremes of the outer states' and the Roe average's speeds)."""
    rl, ul, pl, *tl = wl
    rr, ur, pr, *tr = wr
    el = pl / (gamma - 1) + 0.5 * rl * ul * ul
    er = pr / (gamma - 1) + 0.5 * rr * ur * ur
    for a, b in zip(tl, tr):  # the transverse kinetic energy (none in 1D: its ops and bits are the 1D scheme's)
        el = el + 0.5 * rl * a * a
        er = er + 0.5 * rr * b * b
    cl, cr = jnp.sqrt(gamma * pl / rl), jnp.sqrt(gamma * pr / rr)
    sl_, sr_ = jnp.sqrt(rl), jnp.sqrt(rr)
    u_roe = (sl_ * ul + sr_ * ur) / (sl_ + sr_)
    h_roe = (sl_ * (el + pl) / rl + sr_ * (er + pr) / rr) / (sl_ + sr_)
    k_roe = h_roe - 0.5 * u_roe * u_roe
    for a, b in zip(tl, tr):
        t_roe = (sl_ * a + sr_ * b) / (sl_ + sr_)
        k_roe = k_roe - 0.5 * t_roe * t_roe
    c_roe = jnp.sqrt(jnp.maximum((gamma - 1) * k_roe, 0.0))
    s_l = jnp.minimum(ul - cl, u_roe - c_roe)
    s_r = jnp.maximum(ur + cr, u_roe + c_roe)
    ml, mr = rl * (s_l - ul), rr * (s_r - ur)  # mass fluxes through the outer waves (ml < 0 < mr)
    s_star = (pr - pl + ul * ml - ur * mr) / (ml - mr)
    fl, fr = _flux(rl, ul, pl, el, tl), _flux(rr, ur, pr, er, tr)

    def star(rho, u, p, e, s, m, t):  # the star state on one side of the contact
        scale = m / (s - s_star)
        return jnp.stack([scale, scale * s_star, scale * (e / rho + (s_star - u) * (s_star + p / m)),
                          *(scale * a for a in t)])

    ql = jnp.stack([rl, rl * ul, el, *(rl * a for a in tl)])
    qr = jnp.stack([rr, rr * ur, er, *(rr * b for b in tr)])
    f_star_l = fl + s_l * (star(rl, ul, pl, el, s_l, ml, tl) - ql)
    f_star_r = fr + s_r * (star(rr, ur, pr, er, s_r, mr, tr) - qr)
    return jnp.where(s_l >= 0, fl, jnp.where(s_star >= 0, f_star_l, jnp.where(s_r > 0, f_star_r, fr)))


_FLIP_1D = (1.0, -1.0, 1.0)  # a wall mirrors u
_FLIP_2D = (1.0, -1.0, 1.0, 1.0)  # ... u_n in the normal frame (rho, u_n, p, u_t)


def rate(q: jax.Array, gamma, h, sides: jax.Array, limiter) -> jax.Array:
    """dq/dt [3, n] of conserved q [3, n]: cell size h, sides int [2] (left, right: indices in SIDE_KINDS),
    limiter (index in LIMITERS); all may be traced."""
    w = to_primitive(q, gamma)
    f = hllc(*scheme.faces(w, sides[0], sides[1], limiter, jnp.array(_FLIP_1D, w.dtype)), gamma)  # [3, n + 1]
    return -(f[:, 1:] - f[:, :-1]) / h


def rate_2d(q: jax.Array, gamma, h, sides: jax.Array, limiter) -> jax.Array:
    """dq/dt [4, nx, ny] of conserved q [4, nx, ny] on square cells of side h: sides int [4] (x low, x high, y
    low, y high: indices in SIDE_KINDS), limiter (index in LIMITERS); all may be traced."""
    w = to_primitive_2d(q, gamma)
    return scheme.divergence_2d(w, lambda a, b: hllc(a, b, gamma), h, sides, limiter, jnp.array(_FLIP_2D, w.dtype),
                                PERMS_2D)


def max_speed(q: jax.Array, gamma) -> jax.Array:
    """max over cells of |u| + c (a scalar; c = sqrt(gamma p / rho))."""
    rho, u, p = to_primitive(q, gamma)
    return jnp.max(jnp.abs(u) + jnp.sqrt(jnp.abs(gamma * p / rho)))


def cfl_2d(q: jax.Array, gamma, dt, h) -> jax.Array:
    """The 2D step's CFL number dt (max(|u| + c) + max(|v| + c)) / h (a scalar)."""
    rho, u, v, p = to_primitive_2d(q, gamma)
    c = jnp.sqrt(jnp.abs(gamma * p / rho))
    return (jnp.max(jnp.abs(u) + c) + jnp.max(jnp.abs(v) + c)) * dt / h


def failure_code(rho, p, q, cfl, cfl_limit: float) -> jax.Array:
    finite = jnp.all(jnp.isfinite(q))
    return jnp.where(~finite, NOT_FINITE, jnp.where(jnp.any(rho <= 0), BAD_DENSITY, jnp.where(
        jnp.any(p <= 0), BAD_PRESSURE, jnp.where(cfl > cfl_limit, CFL_EXCEEDED, OK)))).astype(jnp.int32)


def step(q: jax.Array, gamma, dt, h, sides: jax.Array, limiter) -> jax.Array:
    """One SSP-RK3 step of dt of conserved q [3, n]."""
    return scheme.ssp_rk3(q, lambda x: rate(x, gamma, h, sides, limiter), dt)


def run(q: jax.Array, health: Health, gamma, dt, n_steps, h, sides: jax.Array, limiter, cfl_limit: float):
    """n_steps steps of dt from (q [3, n], health): (q, health). A step that leaves a non-positive density or
    pressure, a NaN/Inf, or whose CFL number max(|u| + c) dt / h (at the step's start) exceeds cfl_limit marks
    the sample failed (``scheme.run``). Everything but q's shape may be traced (one program per grid size)."""
    def code(new, cfl):
        rho, _, p = to_primitive(new, gamma)
        return failure_code(rho, p, new, cfl, cfl_limit)

    return scheme.run(q, health, lambda x: step(x, gamma, dt, h, sides, limiter),
                      lambda x: max_speed(x, gamma) * dt / h, code, n_steps)


def run_2d(q: jax.Array, health: Health, gamma, dt, n_steps, h, sides: jax.Array, limiter, cfl_limit: float):
    """``run`` for the 2D state q [4, nx, ny] (sides [4]); the CFL number is ``cfl_2d``'s."""
    def code(new, cfl):
        rho, _, _, p = to_primitive_2d(new, gamma)
        return failure_code(rho, p, new, cfl, cfl_limit)

    return scheme.run(q, health, lambda x: scheme.ssp_rk3(x, lambda y: rate_2d(y, gamma, h, sides, limiter), dt),
                      lambda x: cfl_2d(x, gamma, dt, h), code, n_steps)
