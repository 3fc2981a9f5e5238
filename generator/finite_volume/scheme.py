"""The parts every finite-volume solver of the family shares (JAX, one sample unbatched; jit/vmap-able): ghost
cells, the MUSCL slope limiter and face states along an axis, the 2D dimension-by-dimension flux divergence, the
SSP-RK3 step and the guarded stepping loop with its ``Health``. The equations (a Riemann solver, the conversions
between conserved and primitive variables, what counts as a failure) come from each solver's module
(``euler``, ``shallow_water``).

Arrays are [C, ..., n] with the reconstructed axis last; channel 1 of a primitive state is the velocity normal to
the faces (a wall mirrors it: ``flip``).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

from pdestream.generator.lazy_jax import jax, jnp

SIDE_KINDS = ("outflow", "periodic", "wall")  # outflow: zero gradient; wall: reflective (mirror, u_n -> -u_n)
OUTFLOW, PERIODIC, WALL = range(3)
LIMITERS = ("minmod", "mc")

# Health codes of a sample (the first failure wins; the state is held at the last good step from then on). Code 1
# and 2 are the solver's own positivity failures (each module's CAUSES names them).
OK, BAD_DENSITY, BAD_PRESSURE, NOT_FINITE, CFL_EXCEEDED = 0, 1, 2, 3, 4


class Health(NamedTuple):
    """Per sample: ``code`` (OK or the first failure, int32), ``step`` (steps taken when it failed, -1: none),
    ``cfl`` (largest CFL number seen), ``steps`` (steps taken so far)."""

    code: jax.Array
    step: jax.Array
    cfl: jax.Array
    steps: jax.Array


def healthy(dtype="float32") -> Health:
    return Health(jnp.int32(OK), jnp.int32(-1), jnp.zeros((), dtype), jnp.int32(0))


def ghosts(w: jax.Array, kind, lo: bool, flip: jax.Array) -> jax.Array:
    """Two ghost cells [C, ..., 2] of w [C, ..., n] on one end of the last axis (lo: the first one), in axis
    order; ``kind`` is the side's index in SIDE_KINDS (traced: one compiled program serves every boundary),
    ``flip`` [C] the signs a wall's mirror image takes (-1 on the normal velocity)."""
    wrap = w[..., -2:] if lo else w[..., :2]
    edge = jnp.repeat(w[..., :1] if lo else w[..., -1:], 2, axis=-1)
    mirror = (w[..., 1::-1] if lo else w[..., :-3:-1]) * flip.reshape(flip.shape + (1,) * (w.ndim - 1))
    return jnp.where(kind == PERIODIC, wrap, jnp.where(kind == OUTFLOW, edge, mirror))


def slope(a, b, limiter):
    """Limited slope of one cell from its backward and forward differences a, b (TVD: 0 at an extremum);
    ``limiter`` is the index in LIMITERS (traced): minmod(a, b), or MC's minmod(2a, 2b, (a + b) / 2)."""
    small = jnp.minimum(jnp.abs(a), jnp.abs(b))
    mc = jnp.minimum(2 * small, 0.5 * jnp.abs(a + b))
    return jnp.where(a * b > 0, jnp.sign(a) * jnp.where(limiter == 0, small, mc), 0.0)


def faces(w: jax.Array, lo_kind, hi_kind, limiter, flip: jax.Array) -> tuple[jax.Array, jax.Array]:
    """MUSCL face states of w [C, ..., n] along its last axis: (left, right) [C, ..., n + 1], face j between
    cells j - 1 and j (the ends against the ghost cells). Every face value lies between its cell's neighbours."""
    wp = jnp.concatenate([ghosts(w, lo_kind, True, flip), w, ghosts(w, hi_kind, False, flip)], -1)  # [.., n + 4]
    d = wp[..., 1:] - wp[..., :-1]  # [..., n + 3]
    s = slope(d[..., :-1], d[..., 1:], limiter)  # slopes of padded cells 1 .. n + 2: [..., n + 2]
    return wp[..., 1:-2] + 0.5 * s[..., :-1], wp[..., 2:-1] - 0.5 * s[..., 1:]


def divergence_2d(w: jax.Array, riemann: Callable, h, sides: jax.Array, limiter, flip: jax.Array,
                  perms: tuple) -> jax.Array:
    """Minus the flux divergence [C, nx, ny] of primitive w [C, nx, ny] on square cells of side h, each axis's
    fluxes from its own 1D face problems (dimension by dimension, unsplit). ``riemann(wl, wr)`` takes primitive
    states in the normal frame (channel 1: the normal velocity) and gives fluxes in its frame; ``perms`` =
    ((into x frame, x flux to conserved order), (the same for y)), tuples of channel indices; sides int [4]
    (x low, x high, y low, y high)."""
    def pick(a, order):  # channels in a new order (a static permutation)
        return jnp.stack([a[i] for i in order])

    (in_x, out_x), (in_y, out_y) = perms
    wx = jnp.swapaxes(pick(w, in_x), 1, 2)  # [C, ny, nx]: x last
    fx = riemann(*faces(wx, sides[0], sides[1], limiter, flip))  # [C, ny, nx + 1]
    fy = riemann(*faces(pick(w, in_y), sides[2], sides[3], limiter, flip))  # [C, nx, ny + 1]
    dx = pick(jnp.swapaxes((fx[..., 1:] - fx[..., :-1]) / h, 1, 2), out_x)
    dy = pick((fy[..., 1:] - fy[..., :-1]) / h, out_y)
    return -(dx + dy)


def ssp_rk3(q: jax.Array, rate: Callable, dt) -> jax.Array:
    """One SSP-RK3 step of dt (Shu-Osher form: convex combinations of forward Euler steps, so any bound a forward
    Euler step keeps under a CFL condition, positivity included, the step keeps too)."""
    def lin(x):
        return x + dt * rate(x)

    q1 = lin(q)
    q2 = 0.75 * q + 0.25 * lin(q1)
    return q / 3 + (2 / 3) * lin(q2)


def run(q: jax.Array, health: Health, step: Callable, cfl: Callable, code: Callable, n_steps):
    """n_steps steps from (q, health): (q, health). ``step(q)`` the new state, ``cfl(q)`` the step's CFL number
    at its start, ``code(new, cfl)`` OK or the failure it shows. A failed sample's state is held from then on
    (no NaN spreads through later arithmetic); a Python int n_steps makes it a scan (reverse-mode differentiable)."""
    def body(_, carry):
        q, hl = carry
        c = cfl(q)
        new = step(q)
        got = code(new, c)
        fresh = (hl.code == OK) & (got != OK)
        keep = hl.code == OK
        hl = Health(jnp.where(keep, got, hl.code), jnp.where(fresh, hl.steps, hl.step),
                    jnp.where(keep, jnp.maximum(hl.cfl, c), hl.cfl), hl.steps + 1)
        return jnp.where(keep & (got == OK), new, q), hl

    return jax.lax.fori_loop(0, n_steps, body, (q, health))
