"""Forces on the bodies of a flow, its signed distance to them, and vortex-shedding detection (JAX).

- ``body_force``: the force on the masked body per unit depth and density, a surface integral over the staircase
  of fluid-solid cell faces: the pressure of each fluid cell next to the body on that face (h wide) plus the wall
  shear nu du_t/dn over the half cell between the fluid cell's centre velocity and the no-slip face. First order in
  h (the staircase); Schaefer-Turek 2D-1/2D-2 figures in benchmarks/flow_validation.py.
- ``circle_force`` (with ``circle_surface``): the force on an exact circle, a surface integral of the wall pressure
  and wall shear sampled along its normals (``wall_traction``): second order, the force of the sharp body
  (grid.BODIES); ``bodies_force``: the same integral over every sharp body of a Params (circles, boxes, ellipses:
  channel2d's sharp obstacles), ``bodies_distance`` their exact signed distance.
- ``force_coefficients``: C = 2 F / (U^2 D) (F per unit depth and density, U the reference speed, D the
  reference length), the Schaefer & Turek (1996) normalisation with U their mean inflow speed and D the diameter.
- ``circle_distance``: the exact signed distance of cell centres to a circle (negative inside); ``mask_distance``:
  to a staircase body (the union of its solid cells), exact for what the solver sees.
- ``shedding``: the Strouhal number of a lift series and whether its oscillation is developed (rules there).
"""

from __future__ import annotations

import math

import numpy as np

from pdestream.generator.lazy_jax import jnp

# Shedding rules (``shedding``): a lift oscillation of fitted amplitude below MIN_LIFT_AMPLITUDE (in C_l) is
# "no shedding" (karman2d's non-shedding sample of issue 28 had 0.004, the shedding ones 0.3-0.9); "developed"
# means the amplitude drifts by less than MAX_DRIFT over DRIFT_PERIODS periods, and the window holds that many.
MIN_LIFT_AMPLITUDE = 0.01
MAX_DRIFT = 0.02
DRIFT_PERIODS = 3


def body_force(geom, solid, state, nu):
    """Force on the masked body per unit depth and density (Fx, Fy) [m^3/s^2]: pressure on each fluid-solid
    cell face (the fluid cell's p, h wide) plus wall shear nu du/dn over the half cell between the fluid cell's
    centre velocity and the no-slip face. A staircase surface: first order in h.

    geom: a Geometry; solid [ny, nx] bool (all bodies); state: anything with u [ny, nx+1], v [ny+1, nx] and
    p [ny, nx] (pressure over density) of the solver's layout; nu: kinematic viscosity (m^2/s)."""
    f = 1.0 - solid.astype(state.p.dtype)
    sol = 1.0 - f
    p, h = state.p, geom.h
    uc = 0.5 * (state.u[:, 1:] + state.u[:, :-1])
    vc = 0.5 * (state.v[1:] + state.v[:-1])
    left = f[:, :-1] * sol[:, 1:]   # fluid cell (i) left of solid (i+1): pushes the body in +x
    right = sol[:, :-1] * f[:, 1:]
    below = f[:-1] * sol[1:]
    above = sol[:-1] * f[1:]
    fx = h * (jnp.sum(left * p[:, :-1]) - jnp.sum(right * p[:, 1:]))
    fy = h * (jnp.sum(below * p[:-1]) - jnp.sum(above * p[1:]))
    fx = fx + 2 * nu * (jnp.sum(below * uc[:-1]) + jnp.sum(above * uc[1:]))
    fy = fy + 2 * nu * (jnp.sum(left * vc[:, :-1]) + jnp.sum(right * vc[:, 1:]))
    return fx, fy


SURFACE_POINTS = 256  # quadrature points on the circle (trapezoid rule: spectrally accurate on a periodic integrand)
# Cells from the circle to the first sample point on the normal (the second at twice): nearer points shrink the
# extrapolation's curvature error; the force converges for any fixed choice (benchmarks/flow_bodies.py).
FORCE_DISTANCE = 1.0


# Layers of covered cells the wall samples' stencils reach: bilinear at d1 = FORCE_DISTANCE h from the wall takes
# cells up to sqrt(2) h nearer, and the correction's second differences one cell further.
FILL_LAYERS = 3


def _extend_from_fluid(a, solid, layers: int = FILL_LAYERS):
    """a [ny, nx] with its covered cells (solid [ny, nx] bool) overwritten, ``layers`` rings deep, by values
    extrapolated from the fluid: each cell of the next ring takes the mean over the grid directions of the
    linear extrapolation 2 a1 - a2 from its two known neighbours that way (where only a1 is known, a1). The
    solver's own covered-cell values never reach a wall sample this way (they are not the fluid's: the sharp
    body's stagnation pressure read from them moved with the cut cells' alignment)."""
    known = ~solid
    a = jnp.where(known, a, 0)

    def shifted(x, dj, di, fill):  # x at (j + dj, i + di), fill off the grid
        x = jnp.pad(x, 2, constant_values=fill)
        ny, nx = a.shape
        return x[2 + dj:2 + dj + ny, 2 + di:2 + di + nx]

    for _ in range(layers):
        num = jnp.zeros_like(a)
        cnt = jnp.zeros_like(a)
        for dj, di in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            k1, k2 = shifted(known, dj, di, False), shifted(known, 2 * dj, 2 * di, False)
            a1, a2 = shifted(a, dj, di, 0), shifted(a, 2 * dj, 2 * di, 0)
            lin = k1 & k2
            one = k1 & ~k2
            # linear where two known cells line up, the neighbour alone where one does; weighted so that any
            # linear direction outranks the constant ones
            num = num + jnp.where(lin, 2 * a1 - a2, 0) * 1e3 + jnp.where(one, a1, 0)
            cnt = cnt + lin * 1e3 + one
        new = ~known & (cnt > 0)
        a = jnp.where(new, num / jnp.where(cnt > 0, cnt, 1), a)
        known = known | new
    return a


def _corrected_sampler(geom, a, ox: float, oy: float):
    """Function (x, y) [m] -> a there, bilinear less its own leading error: - fx (1 - fx) / 2 times the second
    difference along x (likewise y), each interpolated bilinearly; exact for quadratics, so a derivative taken
    from samples a cell apart keeps second order (plain bilinear's O(h^2) over h made the wall shear first
    order)."""
    from .step import _sampler  # noqa: PLC0415 (step imports nothing of here; kept local all the same)

    dxx = jnp.pad(a[:, 2:] - 2 * a[:, 1:-1] + a[:, :-2], ((0, 0), (1, 1)), mode="edge")
    dyy = jnp.pad(a[2:] - 2 * a[1:-1] + a[:-2], ((1, 1), (0, 0)), mode="edge")
    plain, sxx, syy = (_sampler(geom, f, ox, oy) for f in (a, dxx, dyy))
    h = geom.h

    def sample(x, y):
        fx = x / h - ox - jnp.floor(x / h - ox)
        fy = y / h - oy - jnp.floor(y / h - oy)
        return plain(x, y) - 0.5 * fx * (1 - fx) * sxx(x, y) - 0.5 * fy * (1 - fy) * syy(x, y)

    return sample


def wall_traction(geom, state, nu, params, solid, nx_, ny_, at):
    """Pressure and wall shear on a body's surface at points whose outward normals are (nx_, ny_) [N]: (p [N]
    (m^2/s^2), shear [N] = nu du_t/dn (m^2/s^2), t = (-ny, nx) the counter-clockwise tangent). ``at(d)`` gives
    the points (x, y) [N] (m) d along the normals from the surface. Both from the fluid along the normal at
    d1 = FORCE_DISTANCE h and d2 = 2 d1 (bilinear samples less their leading error of the pressure, its covered
    cells (solid [ny, nx]) refilled from the fluid by ``_extend_from_fluid``, and of the ghost-filled velocities of
    params' sharp bodies): p linearly extrapolated to the wall, 2 p(d1) - p(d2), and du_t/dn by the quadratic
    through u_t = 0 on the wall, (4 u_t(d1) - u_t(d2)) / (2 d1): both second order on a smooth surface."""
    from .step import fill_ghosts  # noqa: PLC0415

    # the samples' stencils reach the ghost faces: rebuilt from the fluid (a stored frame holds 0 there)
    u, v = fill_ghosts(geom, params, state.u, state.v)
    state = state._replace(u=u, v=v)
    d1 = FORCE_DISTANCE * geom.h
    # the pressure of the covered cells is the solver's, not the fluid's: rebuilt from the fluid before sampling
    p = _extend_from_fluid(state.p, solid)
    sp, su, sv = (_corrected_sampler(geom, p, 0.5, 0.5), _corrected_sampler(geom, state.u, 0.0, 0.5),
                  _corrected_sampler(geom, state.v, 0.5, 0.0))

    def sample(d):
        x, y = at(d)
        return sp(x, y), -ny_ * su(x, y) + nx_ * sv(x, y)

    p1, t1 = sample(d1)
    p2, t2 = sample(2 * d1)
    return 2 * p1 - p2, nu * (4 * t1 - t2) / (2 * d1)


def circle_surface(geom, state, nu, cx, cy, r, theta):
    """Pressure and wall shear on the exact circle (cx, cy, r) [m] at angles theta [N] (rad, from +x):
    ``wall_traction`` there (p [N], shear [N] = nu du_t/dn, t = (-sin, cos), n the outward normal)."""
    from .grid import Params, circle_solid  # noqa: PLC0415

    nx_, ny_ = jnp.cos(theta), jnp.sin(theta)
    return wall_traction(geom, state, nu, Params(circle=(cx, cy, r)), circle_solid(geom, cx, cy, r, state.p.dtype),
                         nx_, ny_, lambda d: (cx + (r + d) * nx_, cy + (r + d) * ny_))


def circle_force(geom, state, nu, cx, cy, r, points: int = SURFACE_POINTS):
    """Force on the exact circle (cx, cy, r) [m] per unit depth and density (Fx, Fy) [m^3/s^2]: the surface
    integral of -p n + nu du_t/dn t (``circle_surface``; at a no-slip wall the viscous traction is tangential) by
    the trapezoid rule over ``points`` equally spaced angles. Second order in h (the sharp body of grid.BODIES).

    state: anything with u [ny, nx+1], v [ny+1, nx], p [ny, nx] of the solver's layout; nu (m^2/s)."""
    dtype = state.p.dtype
    theta = jnp.arange(points, dtype=dtype) * (2 * math.pi / points)
    p, tau = circle_surface(geom, state, nu, cx, cy, r, theta)
    c, s = jnp.cos(theta), jnp.sin(theta)
    ds = r * (2 * math.pi / points)
    from .pressure import _tree_sum  # noqa: PLC0415 (a fixed order of additions: the same bits on every CPU)

    return ds * _tree_sum(-p * c - tau * s), ds * _tree_sum(-p * s + tau * c)


def bodies_force(geom, state, nu, params, points: int = SURFACE_POINTS):
    """Force on all of params' sharp bodies together (generator.flow.step.sharp_bodies: Params.circle and the
    Params.obstacles rows, geom.body 'sharp') per unit depth and density (Fx, Fy) [m^3/s^2]: the surface integral
    of -p n + nu du_t/dn t over each body's exact surface (grid's protocol ``surface``: ``points`` quadrature
    points per body, the trapezoid rule in the angle on a circle or ellipse, the midpoint rule on each edge of a
    box) with ``wall_traction``. A box's corners are no quadrature points; the wall samples near them see the
    corner's singular pressure (docs/results/flows.md has the order measured on a square)."""
    from .pressure import _tree_sum  # noqa: PLC0415
    from .step import sharp_bodies, solid_mask  # noqa: PLC0415

    bodies = sharp_bodies(geom, params)
    if not bodies:
        raise ValueError(f"body={geom.body!r} with no circle or obstacle rows: bodies_force needs sharp bodies "
                         "(geom.body 'sharp' and Params.circle or Params.obstacles)")
    parts = [b.surface(points) for b in bodies]
    x, y, nx_, ny_, w = (jnp.concatenate([q[i] for q in parts]).astype(state.p.dtype) for i in range(5))
    p, tau = wall_traction(geom, state, nu, params, solid_mask(geom, params), nx_, ny_,
                           lambda d: (x + d * nx_, y + d * ny_))
    return _tree_sum(w * (-p * nx_ - tau * ny_)), _tree_sum(w * (-p * ny_ + tau * nx_))


def bodies_distance(geom, params, dtype=np.float32):
    """Exact signed distance [ny, nx] (m) of the cell centres to the surface of params' sharp bodies (the union:
    the minimum over the bodies; negative inside; grid's protocol ``distance``)."""
    from .grid import centres  # noqa: PLC0415
    from .step import sharp_bodies  # noqa: PLC0415

    x, y = centres(geom, dtype)
    out = None
    for body in sharp_bodies(geom, params):
        d = body.distance(x, y).astype(dtype)
        out = d if out is None else jnp.minimum(out, d)
    return jnp.full((geom.ny, geom.nx), 1e15, dtype) if out is None else out


def force_coefficients(fx, fy, speed, length):
    """(C_d, C_l) = 2 (Fx, Fy) / (U^2 D): F per unit depth and density (``body_force``), U = ``speed`` (m/s),
    D = ``length`` (m)."""
    scale = 2.0 / (speed * speed * length)
    return fx * scale, fy * scale


def circle_distance(geom, cx, cy, r, dtype=np.float32):
    """Signed distance [ny, nx] (m) of the cell centres to the circle (cx, cy, r): |x - c| - r, negative inside
    (exact for a circle; the solver's mask is the cells with a negative value, ``grid.circle_solid``)."""
    h = geom.h
    x = (jnp.arange(geom.nx, dtype=dtype) + 0.5) * h
    y = (jnp.arange(geom.ny, dtype=dtype) + 0.5) * h
    x, y = jnp.meshgrid(x, y)
    return jnp.sqrt((x - cx) ** 2 + (y - cy) ** 2) - r


def mask_distance(geom, solid, dtype=np.float32):
    """Signed distance [ny, nx] (m) of the cell centres to the surface of the masked body, the union of its
    solid cells (closed h x h squares; solid [ny, nx] bool): the distance to the nearest solid cell outside the
    body, minus the distance to the nearest fluid cell inside it, so solid == (value < 0) and a cell next to the
    surface is h / 2 from it. Exact for the staircase body the solver sees (the box walls are not a surface
    here); every cell at a large value (1e15 m) where there is no solid (or no fluid) cell.

    Separable: the squared distance to a square is g(dx) + g(dy) with g(d) = max(|d| - h / 2, 0)^2, so the
    minimum over cells is a minimum along rows, then along columns (O(nx ny (nx + ny)) per call)."""
    h = geom.h
    x = (jnp.arange(geom.nx, dtype=dtype) + 0.5) * h
    y = (jnp.arange(geom.ny, dtype=dtype) + 0.5) * h
    gx = jnp.maximum(jnp.abs(x[:, None] - x[None, :]) - h / 2, 0) ** 2  # [nx, nx]
    gy = jnp.maximum(jnp.abs(y[:, None] - y[None, :]) - h / 2, 0) ** 2  # [ny, ny]
    far = jnp.asarray(1e30, dtype)

    def distance_to(cells):  # [ny, nx] bool -> distance of every centre to the nearest closed square of cells
        rows = jnp.min(jnp.where(cells[:, None, :], gx[None], far), axis=2)  # [ny, nx]: along its row
        both = jnp.min(gy[:, :, None] + rows[None], axis=1)  # [ny, nx]: then along its column
        return jnp.sqrt(jnp.minimum(both, far))

    return jnp.where(solid, -distance_to(~solid), distance_to(solid))


def shedding(lift, t, length, speed, min_amplitude=MIN_LIFT_AMPLITUDE, max_drift=MAX_DRIFT,
             periods=DRIFT_PERIODS):
    """Vortex shedding in a lift series: (St, sheds, developed, amplitude, drift) (float32, bool, bool, float32,
    float32 scalars); lift [T] (C_l at the frame times t [T], s), length D (m) and speed U (m/s) of St = f D / U.

    Frequency: the crossings of the series' mean (linearly interpolated between frames), f = (n - 1) / (2 (t_last
    - t_first)) over the n crossings, then corrected once by the turn of the fitted phase below (refit at the
    corrected f: within 0.1% on a sine of 4 to 6 frames per period). Amplitude and drift: a least-squares fit over
    the window of
    C_l(t) ~ c0 + c1 s + (a0 + a1 s) cos(2 pi f t) + (b0 + b1 s) sin(2 pi f t), s = (t - t_mid) f (periods
    from the window's middle): amplitude A = hypot(a0, b0) at the middle, drift = ``periods`` * dA/ds / A (the
    relative change of the amplitude over ``periods`` periods; a pure phase drift from an inexact f adds nothing
    to first order). ``sheds``: at least 3 crossings (a whole period) and A >= ``min_amplitude``; ``developed``:
    sheds, the window spans >= ``periods`` periods and |drift| < ``max_drift``. Where it does not shed, St,
    amplitude and drift are 0 (never NaN: ``sheds`` says which)."""
    dtype = lift.dtype
    t = t.astype(dtype)
    c = lift - jnp.mean(lift)
    c0, c1 = c[:-1], c[1:]
    cross = (c0 < 0) != (c1 < 0)
    frac = jnp.where(cross, c0 / jnp.where(cross, c0 - c1, 1), 0)
    tc = t[:-1] + frac * (t[1:] - t[:-1])
    n = jnp.sum(cross)
    first = jnp.min(jnp.where(cross, tc, jnp.inf))
    last = jnp.max(jnp.where(cross, tc, -jnp.inf))
    enough = n >= 3
    freq = jnp.where(enough, (n - 1) / jnp.where(enough, 2 * (last - first), 1), 0).astype(dtype)
    mid = 0.5 * (t[0] + t[-1])

    def fit(freq):
        s = (t - mid) * freq
        cos, sin = jnp.cos(2 * math.pi * freq * t), jnp.sin(2 * math.pi * freq * t)
        design = jnp.stack([jnp.ones_like(t), s, cos, sin, s * cos, s * sin], 1)
        return jnp.linalg.lstsq(design, lift)[0]

    coef = fit(freq)  # the phase of (a, b) turns at -2 pi (f_true - f) / f per period: correct f once, refit
    amp2 = coef[2] ** 2 + coef[3] ** 2
    turn = (coef[2] * coef[5] - coef[3] * coef[4]) / jnp.where(amp2 > 0, amp2, 1)
    freq = jnp.where(enough, freq * (1 - turn / (2 * math.pi)), freq)
    coef = fit(freq)
    amp = jnp.hypot(coef[2], coef[3])
    slope = (coef[2] * coef[4] + coef[3] * coef[5]) / jnp.where(amp > 0, amp, 1)
    drift = periods * slope / jnp.where(amp > 0, amp, 1)
    sheds = enough & (amp >= min_amplitude)
    developed = sheds & ((t[-1] - t[0]) * freq >= periods) & (jnp.abs(drift) < max_drift)
    zero = jnp.zeros((), dtype)
    st = jnp.where(sheds, freq * length / speed, zero)
    return st, sheds, developed, jnp.where(sheds, amp, zero), jnp.where(sheds, drift, zero)


__all__ = ["DRIFT_PERIODS", "FILL_LAYERS", "FORCE_DISTANCE", "MAX_DRIFT", "MIN_LIFT_AMPLITUDE", "SURFACE_POINTS", "body_force", "circle_distance",
           "bodies_distance", "bodies_force", "circle_force", "circle_surface", "wall_traction",
           "force_coefficients", "shedding"]
