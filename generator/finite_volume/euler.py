"""1D compressible Euler on a uniform finite-volume grid (JAX, one sample unbatched; jit/vmap-able).

State: conserved cell averages U [3, n] = (rho, rho u, E) with E = p / (gamma - 1) + rho u^2 / 2 (ideal gas).
Space: MUSCL reconstruction of the primitive variables (rho, u, p) with a TVD limiter (``LIMITERS``: minmod, or
the monotonized-central MC), two ghost cells per side, HLLC fluxes (Toro 1994) with Einfeldt's wave speeds.
Time: SSP-RK3 (Shu-Osher), a fixed step dt per call. Every face value lies between its cell's neighbours (both
limiters), so positive cell values give positive face states; positivity of the update itself is checked, not
assumed (``Health``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

SIDE_KINDS = ("outflow", "periodic", "wall")  # outflow: zero gradient; wall: reflective (mirror, u -> -u)
OUTFLOW, PERIODIC, WALL = range(3)
LIMITERS = ("minmod", "mc")

# Health codes of a sample (the first failure wins; the state is held at the last good step from then on)
OK, BAD_DENSITY, BAD_PRESSURE, NOT_FINITE, CFL_EXCEEDED = 0, 1, 2, 3, 4
CAUSES = {BAD_DENSITY: "density went non-positive", BAD_PRESSURE: "pressure went non-positive",
          NOT_FINITE: "a value went NaN/Inf", CFL_EXCEEDED: "the waves outran the step"}


class Health(NamedTuple):
    """Per sample: ``code`` (OK or the first failure, int32), ``step`` (steps taken when it failed, -1: none),
    ``cfl`` (largest CFL number max(|u| + c) dt / h seen), ``steps`` (steps taken so far)."""

    code: jax.Array
    step: jax.Array
    cfl: jax.Array
    steps: jax.Array


def healthy(dtype=jnp.float32) -> Health:
    return Health(jnp.int32(OK), jnp.int32(-1), jnp.zeros((), dtype), jnp.int32(0))


def to_conserved(w: jax.Array, gamma) -> jax.Array:
    """Primitive w [3, ...] (rho, u, p) -> conserved [3, ...] (rho, rho u, E)."""
    rho, u, p = w[0], w[1], w[2]
    return jnp.stack([rho, rho * u, p / (gamma - 1) + 0.5 * rho * u * u])


def to_primitive(q: jax.Array, gamma) -> jax.Array:
    """Conserved q [3, ...] -> primitive [3, ...] (rho, u, p)."""
    rho, m, e = q[0], q[1], q[2]
    u = m / rho
    return jnp.stack([rho, u, (gamma - 1) * (e - 0.5 * m * u)])


def _ghosts(w: jax.Array, kind, lo: bool) -> jax.Array:
    """Two ghost cells [3, 2] of primitive w [3, n] on one side (lo: the left one), left to right; ``kind`` is
    the side's index in SIDE_KINDS (traced: one compiled program serves every boundary)."""
    wrap = w[:, -2:] if lo else w[:, :2]
    edge = jnp.repeat(w[:, :1] if lo else w[:, -1:], 2, axis=1)
    mirror = (w[:, 1::-1] if lo else w[:, :-3:-1]) * jnp.array([1.0, -1.0, 1.0], w.dtype)[:, None]  # u -> -u
    return jnp.where(kind == PERIODIC, wrap, jnp.where(kind == OUTFLOW, edge, mirror))


def _slope(a, b, limiter):
    """Limited slope of one cell from its backward and forward differences a, b (TVD: 0 at an extremum);
    ``limiter`` is the index in LIMITERS (traced): minmod(a, b), or MC's minmod(2a, 2b, (a + b) / 2)."""
    small = jnp.minimum(jnp.abs(a), jnp.abs(b))
    mc = jnp.minimum(2 * small, 0.5 * jnp.abs(a + b))
    return jnp.where(a * b > 0, jnp.sign(a) * jnp.where(limiter == 0, small, mc), 0.0)


def _flux(w):
    """Physical flux of primitive w [3, m] given E (appended as w[3])."""
    rho, u, p, e = w
    return jnp.stack([rho * u, rho * u * u + p, (e + p) * u])


def hllc(wl: jax.Array, wr: jax.Array, gamma) -> jax.Array:
    """HLLC flux [3, m] between left and right primitive face states wl, wr [3, m] (Toro, Riemann Solvers, 10.4),
    signal speeds after Einfeldt (the extremes of the outer states' and the Roe average's speeds)."""
    rl, ul, pl = wl
    rr, ur, pr = wr
    el = pl / (gamma - 1) + 0.5 * rl * ul * ul
    er = pr / (gamma - 1) + 0.5 * rr * ur * ur
    cl, cr = jnp.sqrt(gamma * pl / rl), jnp.sqrt(gamma * pr / rr)
    sl_, sr_ = jnp.sqrt(rl), jnp.sqrt(rr)
    u_roe = (sl_ * ul + sr_ * ur) / (sl_ + sr_)
    h_roe = (sl_ * (el + pl) / rl + sr_ * (er + pr) / rr) / (sl_ + sr_)
    c_roe = jnp.sqrt(jnp.maximum((gamma - 1) * (h_roe - 0.5 * u_roe * u_roe), 0.0))
    s_l = jnp.minimum(ul - cl, u_roe - c_roe)
    s_r = jnp.maximum(ur + cr, u_roe + c_roe)
    ml, mr = rl * (s_l - ul), rr * (s_r - ur)  # mass fluxes through the outer waves (ml < 0 < mr)
    s_star = (pr - pl + ul * ml - ur * mr) / (ml - mr)
    fl, fr = _flux((rl, ul, pl, el)), _flux((rr, ur, pr, er))

    def star(rho, u, p, e, s, m):  # the star state on one side of the contact
        scale = m / (s - s_star)
        return jnp.stack([scale, scale * s_star, scale * (e / rho + (s_star - u) * (s_star + p / m))])

    ql = jnp.stack([rl, rl * ul, el])
    qr = jnp.stack([rr, rr * ur, er])
    f_star_l = fl + s_l * (star(rl, ul, pl, el, s_l, ml) - ql)
    f_star_r = fr + s_r * (star(rr, ur, pr, er, s_r, mr) - qr)
    return jnp.where(s_l >= 0, fl, jnp.where(s_star >= 0, f_star_l, jnp.where(s_r > 0, f_star_r, fr)))


def rate(q: jax.Array, gamma, h, sides: jax.Array, limiter) -> jax.Array:
    """dq/dt [3, n] of conserved q [3, n]: cell size h, sides int [2] (left, right: indices in SIDE_KINDS),
    limiter (index in LIMITERS); all may be traced."""
    w = to_primitive(q, gamma)
    wp = jnp.concatenate([_ghosts(w, sides[0], True), w, _ghosts(w, sides[1], False)], 1)  # [3, n + 4]
    d = wp[:, 1:] - wp[:, :-1]  # [3, n + 3]
    s = _slope(d[:, :-1], d[:, 1:], limiter)  # slopes of padded cells 1 .. n + 2: [3, n + 2]
    wl = wp[:, 1:-2] + 0.5 * s[:, :-1]  # faces between padded cells j, j + 1 for j = 1 .. n + 1
    wr = wp[:, 2:-1] - 0.5 * s[:, 1:]
    f = hllc(wl, wr, gamma)  # [3, n + 1]
    return -(f[:, 1:] - f[:, :-1]) / h


def max_speed(q: jax.Array, gamma) -> jax.Array:
    """max over cells of |u| + c (a scalar; c = sqrt(gamma p / rho))."""
    rho, u, p = to_primitive(q, gamma)
    return jnp.max(jnp.abs(u) + jnp.sqrt(jnp.abs(gamma * p / rho)))


def _code(q: jax.Array, gamma, cfl, cfl_limit: float) -> jax.Array:
    rho, _, p = to_primitive(q, gamma)
    finite = jnp.all(jnp.isfinite(q))
    return jnp.where(~finite, NOT_FINITE, jnp.where(jnp.any(rho <= 0), BAD_DENSITY, jnp.where(
        jnp.any(p <= 0), BAD_PRESSURE, jnp.where(cfl > cfl_limit, CFL_EXCEEDED, OK)))).astype(jnp.int32)


def step(q: jax.Array, gamma, dt, h, sides: jax.Array, limiter) -> jax.Array:
    """One SSP-RK3 step of dt (Shu-Osher form) of conserved q [3, n]."""
    def lin(x):
        return x + dt * rate(x, gamma, h, sides, limiter)

    q1 = lin(q)
    q2 = 0.75 * q + 0.25 * lin(q1)
    return q / 3 + (2 / 3) * lin(q2)


def run(q: jax.Array, health: Health, gamma, dt, n_steps, h, sides: jax.Array, limiter, cfl_limit: float):
    """n_steps steps of dt from (q [3, n], health): (q, health). A step that leaves a non-positive density or
    pressure, a NaN/Inf, or whose CFL number (at the step's start) exceeds cfl_limit marks the sample failed;
    from then on the state is held (no NaN spreads through later arithmetic). Everything but q's shape may be
    traced (one program per grid size); a Python int n_steps makes it a scan (reverse-mode differentiable)."""
    def body(_, carry):
        q, hl = carry
        cfl = max_speed(q, gamma) * dt / h
        new = step(q, gamma, dt, h, sides, limiter)
        code = _code(new, gamma, cfl, cfl_limit)
        fresh = (hl.code == OK) & (code != OK)
        keep = hl.code == OK
        hl = Health(jnp.where(keep, code, hl.code), jnp.where(fresh, hl.steps, hl.step),
                    jnp.where(keep, jnp.maximum(hl.cfl, cfl), hl.cfl), hl.steps + 1)
        return jnp.where(keep & (code == OK), new, q), hl

    return jax.lax.fori_loop(0, n_steps, body, (q, health))
