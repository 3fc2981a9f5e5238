"""2D shallow water on a flat bed, with wet/dry fronts, on a uniform finite-volume grid (JAX, one sample
unbatched; jit/vmap-able).

State: conserved cell averages U [3, nx, ny] = (h, h u, h v), depth h >= 0, gravity g. Space: MUSCL
reconstruction of (h, u, v) (``scheme``: the limiter, ghost cells, the dimension-by-dimension divergence), HLL
fluxes with Toro's two-rarefaction wave-speed estimates, and at a dry face (h <= DRY on one side) the exact
speeds of a front running into a dry bed (u + 2c of the wet side). Time: SSP-RK3, a fixed step dt per call.

Wet/dry without hydrostatic reconstruction (the bed is flat: there is no bed slope source to balance). h >= 0 is
kept by the scheme (to rounding, below): the reconstructed face depths lie between neighbouring cell depths (>= 0); a
cell's depth is the mean of its two face depths per axis (a linear reconstruction), so its forward Euler update
is a convex combination of first-order HLL updates on half cells, and HLL with speeds bounding the true ones
keeps h >= 0 when dt (max|s_x| + max|s_y|) / h <= 1/2 (Audusse et al. 2004; Berthon 2006); SSP-RK3 is a convex
combination of forward Euler steps. In float32 that holds to rounding: a step can leave a front or draining
cell at -1e-9 or so, which is set to 0 (``rounded_dry``: depths in [-DRY, 0) only, a mass change below DRY per
cell); a depth below -DRY is a failure (``Health``), never clipped. In cells with h <= DRY the velocity is taken
as 0 (no division by a vanishing depth).
"""

from __future__ import annotations

from pdestream.generator.lazy_jax import jax, jnp

from . import scheme
from .scheme import CFL_EXCEEDED, NOT_FINITE, OK, Health

BAD_DEPTH = scheme.BAD_DENSITY
CAUSES = {BAD_DEPTH: "depth went negative", NOT_FINITE: "a value went NaN/Inf",
          CFL_EXCEEDED: "the waves outran the step"}
DRY = 1e-6  # depth (length units) at or below which a cell is dry: its velocity is 0, its faces use dry speeds
# primitive (h, u, v) into each axis's normal frame (h, u_n, u_t), and the frame's fluxes back (both involutions)
PERMS = (((0, 1, 2), (0, 1, 2)), ((0, 2, 1), (0, 2, 1)))
_FLIP = (1.0, -1.0, 1.0)  # a wall mirrors u_n


def velocities(q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(u, v) of conserved q [3, ...]: momentum / depth where wet, 0 where h <= DRY."""
    wet = q[0] > DRY
    depth = jnp.where(wet, q[0], 1.0)
    return jnp.where(wet, q[1] / depth, 0.0), jnp.where(wet, q[2] / depth, 0.0)


def to_primitive(q: jax.Array) -> jax.Array:
    """Conserved q [3, ...] (h, hu, hv) -> primitive [3, ...] (h, u, v)."""
    return jnp.stack([q[0], *velocities(q)])


def celerity(h: jax.Array, g) -> jax.Array:
    """c = sqrt(g h), 0 where h <= 0, with a finite derivative there (0, not sqrt's infinite one: a dry cell's
    gradient stays finite)."""
    wet = h > 0
    return jnp.where(wet, jnp.sqrt(g * jnp.where(wet, h, 1.0)), 0.0)


def hll(wl: jax.Array, wr: jax.Array, g) -> jax.Array:
    """HLL flux [3, m] between primitive face states wl, wr [3, m] = (h >= 0, u_n, u_t) under gravity g: mass,
    normal momentum hu_n^2 + g h^2 / 2, transverse momentum hu_n u_t. Wave speeds: Toro's two-rarefaction
    estimates (Shock-capturing methods for free-surface shallow flows, 2001, 10.5) where both sides are wet; a dry
    side's are the wet side's front speeds u -/+ 2c."""
    hl, ul, tl = wl
    hr, ur, tr = wr
    cl, cr = celerity(hl, g), celerity(hr, g)
    u_star = 0.5 * (ul + ur) + cl - cr
    c_star = 0.5 * (cl + cr) + 0.25 * (ul - ur)
    s_l = jnp.where(hl <= DRY, ur - 2 * cr, jnp.minimum(ul - cl, u_star - c_star))
    s_r = jnp.where(hr <= DRY, ul + 2 * cl, jnp.maximum(ur + cr, u_star + c_star))
    ql = jnp.stack([hl, hl * ul, hl * tl])
    qr = jnp.stack([hr, hr * ur, hr * tr])
    fl = jnp.stack([hl * ul, hl * ul * ul + 0.5 * g * hl * hl, hl * ul * tl])
    fr = jnp.stack([hr * ur, hr * ur * ur + 0.5 * g * hr * hr, hr * ur * tr])
    width = s_r - s_l
    mid = (s_r * fl - s_l * fr + s_l * s_r * (qr - ql)) / jnp.where(width > 0, width, 1.0)  # both dry: all zero
    return jnp.where(s_l >= 0, fl, jnp.where(s_r <= 0, fr, mid))


def rate(q: jax.Array, g, h, sides: jax.Array, limiter) -> jax.Array:
    """dq/dt [3, nx, ny] of conserved q [3, nx, ny] on square cells of side h: sides int [4] (x low, x high, y
    low, y high: indices in scheme.SIDE_KINDS), limiter (index in scheme.LIMITERS); all may be traced."""
    w = to_primitive(q)
    return scheme.divergence_2d(w, lambda a, b: hll(a, b, g), h, sides, limiter, jnp.array(_FLIP, w.dtype), PERMS)


def cfl(q: jax.Array, g, dt, h) -> jax.Array:
    """The step's CFL number dt (max(|u| + c) + max(|v| + c)) / h, c = sqrt(g h) (a scalar)."""
    u, v = velocities(q)
    c = celerity(q[0], g)
    return (jnp.max(jnp.abs(u) + c) + jnp.max(jnp.abs(v) + c)) * dt / h


def run(q: jax.Array, health: Health, g, dt, n_steps, h, sides: jax.Array, limiter, cfl_limit: float):
    """n_steps steps of dt from (q [3, nx, ny], health): (q, health). A step that leaves a depth below -DRY
    (``rounded_dry`` zeroes the rounding-level ones above it), a NaN/Inf, or whose CFL number (at its start)
    exceeds cfl_limit marks the sample failed (``scheme.run``)."""
    def code(new, c):
        finite = jnp.all(jnp.isfinite(new))
        return jnp.where(~finite, NOT_FINITE, jnp.where(jnp.any(new[0] < 0), BAD_DEPTH, jnp.where(
            c > cfl_limit, CFL_EXCEEDED, OK))).astype(jnp.int32)

    def step(x):
        new = scheme.ssp_rk3(x, lambda y: rate(y, g, h, sides, limiter), dt)
        return new.at[0].set(rounded_dry(new[0]))

    return scheme.run(q, health, step, lambda x: cfl(x, g, dt, h), code, n_steps)


def rounded_dry(depth: jax.Array) -> jax.Array:
    """Depths in [-DRY, 0) set to 0: float32 rounding of a step's flux sums leaves a cell that the exact scheme
    keeps at h >= 0 (a front, a draining cell) at -1e-9 or so (measured on dry-bed radial dam breaks); the mass
    this adds is below DRY per cell, rounding level. Deeper negatives stay (a failure: the scheme's bound broke)."""
    return jnp.where((depth < 0) & (depth >= -DRY), 0.0, depth)
