"""One incompressible Navier-Stokes step on the MAC grid: advect, diffuse, force, project.

Advection (``advection=``): 'semi_lagrangian' (default), a midpoint (RK2) backtrace by u^n and bilinear
interpolation: unconditionally stable; first order overall (O(dt + h^2 / dt) per unit time; the pressure
acts only at the arrival point), so keep the CFL number u dt / h near 1 (stable_dt uses cfl = 1 by default).
'maccormack': limited MacCormack interpolation, the backtrace by a half-step velocity and the forces by a
Lagrangian trapezoid: second order in space and time (Taylor-Green, tests/test_flow_validation.py), still
stable beyond CFL 1 (the clamp adds no extrema); about 2.5x the advection work. Viscosity: explicit 5-point Laplacian, stable for nu dt / h^2 <= 1/4. Buoyancy:
v += dt * buoyancy * smoke (smoke advected by the same velocity); Params.force, a steady body force on the faces
(None: none), with the viscous force (trapezoid under maccormack). Projection: the masked Poisson solve of
generator.flow.pressure; afterwards the discrete divergence is zero to the solver tolerance.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from . import pressure
from .grid import (
    OPEN_SIDES,
    Circle,
    Geometry,
    ObstacleRow,
    Params,
    body_ghosts,
    circle_solid,
    cut_faces,
    faces,
    obstacles_solid,
    velocity_masks,
)


class State(NamedTuple):
    """u [ny, nx+1], v [ny+1, nx] (m/s), p [ny, nx] (pressure / density, m^2/s^2), smoke [ny, nx],
    t (s), iterations of the last pressure solve, capped: how many steps' pressure solves stopped at max_iter
    (int32; > 0 means the divergence may be above the tolerance, reported as a failed sample)."""

    u: jax.Array
    v: jax.Array
    p: jax.Array
    smoke: jax.Array
    t: jax.Array
    iterations: jax.Array
    capped: jax.Array


def solid_mask(geom: Geometry, params: Params):
    """Solid cells [ny, nx] of the circle obstacle and the obstacle rows in params (traced)."""
    cx, cy, r = params.circle
    solid = circle_solid(geom, cx, cy, r)
    if params.mask is not None:
        solid = solid | params.mask
    return solid if params.obstacles is None else solid | obstacles_solid(geom, jnp.asarray(params.obstacles))


def sharp_bodies(geom: Geometry, params: Params) -> list:
    """The bodies the sharp treatment sees where geom.body is 'sharp' (grid's sharp-body protocol): Params.circle
    (left out where its radius is a Python number <= 0: no circle) and each row of Params.obstacles; [] for
    'staircase'. With none, every sharp path reduces to the staircase's bits."""
    if geom.body == "staircase":
        return []
    cx, cy, r = params.circle
    bodies = [] if isinstance(r, (int, float)) and r <= 0 else [Circle(cx, cy, r)]
    if params.obstacles is not None:
        rows = jnp.asarray(params.obstacles)
        bodies += [ObstacleRow(*(rows[k, i] for i in range(5))) for k in range(rows.shape[0])]
    return bodies


def _staircase_solid(geom: Geometry, params: Params):
    """The cells the solver treats as solid: solid_mask's, less the sharp bodies (they enter through their
    apertures and ghosts instead)."""
    if not sharp_bodies(geom, params):
        return solid_mask(geom, params)
    solid = jnp.zeros((geom.ny, geom.nx), bool)
    return solid if params.mask is None else solid | params.mask


def body_apertures(geom: Geometry, params: Params, dtype=None):
    """``grid.cut_faces`` (ax, ay, my, mx) of params' sharp bodies, or None where there are none; dtype: the
    coefficients' (float64 under x64 where the geometry is traced in it: they are differentiated)."""
    bodies = sharp_bodies(geom, params)
    if not bodies:
        return None
    if dtype is None:
        dtype = jnp.result_type(*(jnp.asarray(b[-1]) for b in bodies))  # the radius / last half-size
    return cut_faces(geom, bodies, dtype)


def body_faces(geom: Geometry, params: Params):
    """The pressure operator's face coefficients (grid.Faces) of params' bodies: staircase cells, and the exact
    bodies' open fractions where geom.body is 'sharp'."""
    if params.prepared is not None:
        return params.prepared.faces
    cut = body_apertures(geom, params)
    if cut is None:
        return faces(geom, solid_mask(geom, params))
    return faces(geom, _staircase_solid(geom, params), cut[:2])


def _neighbours(a, axis: int):
    """a's next and previous values along axis (each edge repeats its own value): (up, down), a's shape."""
    n = a.shape[axis]
    take = lambda i, j: jax.lax.slice_in_dim(a, i, j, axis=axis)  # noqa: E731
    return (jnp.concatenate([take(1, n), take(n - 1, n)], axis), jnp.concatenate([take(0, 1), take(0, n - 1)], axis))


def _centroid_weights(geom: Geometry, params: Params, dtype):
    """Where geom.body is 'sharp' (with bodies): the open fractions (ax, ay) and, per face, the weights (up, down)
    [face shape] of its neighbours along the face in the linear interpolation of the velocity at the open part's
    centroid: u(centroid) = (1 - up - down) u + up u_next + down u_prev. Nonzero on cut faces only, toward the
    fluid (the neighbour is then a whole face: a convex body's chord ends in at most one face per side, for a body
    at least 2 cells across), < 1/2."""
    ready = params.prepared
    if ready is not None and ready.weights is not None and ready.weights[0][1].dtype == dtype:
        return [(*w, axis) for w, axis in zip(ready.weights, (0, 1))]
    ax, ay, my, mx = body_apertures(geom, params, dtype)
    h = geom.h
    out = []
    for a, m, offset, axis in ((ax, my, 0.5, 0), (ay, mx, 0.5, 1)):
        shape = a.shape
        pos = jnp.arange(shape[axis], dtype=dtype) + offset  # the face centres in cells (exact)
        pos = pos[:, None] if axis == 0 else pos[None, :]
        # 0 on whole and closed faces (their centroid is the centre); m / h - pos, not (m - pos h) / h: a product
        # feeding a difference is a multiply-add LLVM may contract or not by the vector width (bits by CPU)
        s = m / h - pos
        a_up, a_down = _neighbours(a, axis)
        cut = (a > 0) & (a < 1)
        up = jnp.where(cut & (s > 0) & (a_up == 1), s, 0.0).astype(dtype)
        down = jnp.where(cut & (s < 0) & (a_down == 1), -s, 0.0).astype(dtype)
        out.append((a, up, down, axis))
    return out


def _to_centroid(q, up, down, axis):
    """The velocity at the open parts' centroids (``_centroid_weights``) of a face field q."""
    q_up, q_down = _neighbours(q, axis)
    return jnp.where((up > 0) | (down > 0), (1 - up - down) * q + up * q_up + down * q_down, q)  # whole: q's bits


def _from_centroid(qc, up, down, axis):
    """Inverse of _to_centroid where the neighbours it reads are not cut (the case of _centroid_weights): the
    face-centre velocity whose centroid value is qc."""
    q_up, q_down = _neighbours(qc, axis)
    return jnp.where((up > 0) | (down > 0), (qc - up * q_up - down * q_down) / (1 - up - down), qc)


def _fluxes(geom: Geometry, params: Params, u, v):
    """Volume fluxes per face width (m/s): u, v, and on the sharp bodies' cut faces its open fraction
    (grid.cut_faces) times the velocity at the open part's centroid, interpolated linearly along the face
    (``_centroid_weights``; at the face's centre, the flux misses a h (1 - a) du/ds / 2 per face: an O(1)
    divergence in the cut cells, a first-order mass source along the wall)."""
    if not sharp_bodies(geom, params):
        return u, v
    (ax, uu, ud, _), (ay, vu, vd, _) = _centroid_weights(geom, params, u.dtype)
    return ax * _to_centroid(u, uu, ud, 0), ay * _to_centroid(v, vu, vd, 1)


def fill_ghosts(geom: Geometry, params: Params, u, v):
    """u, v with the sharp bodies' ghost faces set (grid.body_ghosts: the quadratic through no-slip on the
    surface and two image points) and the faces deeper inside zero; unchanged without sharp bodies."""
    bodies = sharp_bodies(geom, params)
    if not bodies:
        return u, v
    ready = params.prepared
    if ready is not None and ready.ghosts is not None and ready.ghosts[0].w1.dtype == u.dtype:
        gu, gv = ready.ghosts
        if ready.listed is None:
            return _fill_everywhere(geom, u, v, gu, gv)
        listed = lambda uv: tuple(_fill_listed(geom, q, g, lg, o) for q, g, lg, o in zip(  # noqa: E731
            uv, ready.ghosts, ready.listed, ((0.0, 0.5), (0.5, 0.0))))
        everywhere = lambda uv: _fill_everywhere(geom, *uv, gu, gv)  # noqa: E731
        return jax.lax.cond(ready.listed_fits, listed, everywhere, (u, v))
    gu = body_ghosts(geom, bodies, 0.0, 0.5, u.shape, u.dtype)
    gv = body_ghosts(geom, bodies, 0.5, 0.0, v.shape, v.dtype)
    return _fill_everywhere(geom, u, v, gu, gv)


def _ghost_values(geom: Geometry, q, g, ox: float, oy: float):
    """q's ghost values w1 q(x1, y1) + w2 q(x2, y2) at g's points (grid.Ghosts or ``ListedGhosts``: any shape)."""
    sq = _sampler(geom, q, ox, oy)
    return g.w1 * sq(g.x1, g.y1) + g.w2 * sq(g.x2, g.y2)


def _fill_everywhere(geom: Geometry, u, v, gu, gv):
    """fill_ghosts evaluated at every face (then kept on the ghosts): what a step alone computes."""
    # the image stencils hold fluid faces only (IMAGE_DISTANCE), so one pass is exact: no ghost reads a ghost
    u = jnp.where(gu.ghost, _ghost_values(geom, u, gu, 0.0, 0.5), jnp.where(gu.deep, 0.0, u))
    v = jnp.where(gv.ghost, _ghost_values(geom, v, gv, 0.5, 0.0), jnp.where(gv.deep, 0.0, v))
    return u, v


def _fill_listed(geom: Geometry, q, g, listed, offset):
    """fill_ghosts of one component evaluated on its listed ghost faces only (``ListedGhosts``; the same
    arithmetic per face as ``_fill_everywhere``, equal to float32 rounding: the compiled kernels may round a
    multiply-add differently): its interpolations gather a few dozen faces' stencils, not the whole grid's
    (karman2d: 1-2% of the faces are ghosts; evaluated everywhere, the three fills of a step were twice the rest
    of its work)."""
    flat = jnp.where(g.deep, 0.0, q).reshape(-1)
    return flat.at[listed.index].set(_ghost_values(geom, q, listed, *offset), mode="drop").reshape(q.shape)


class ListedGhosts(NamedTuple):
    """The ghost faces of one component as a list of fixed length (``prepare``): index [K] (int32, into the
    component's flattened faces; its size where the list has no more ghosts: such rows are dropped) and grid.Ghosts'
    w1, w2, x1, y1, x2, y2 at them [K]."""

    index: jax.Array
    w1: jax.Array
    w2: jax.Array
    x1: jax.Array
    y1: jax.Array
    x2: jax.Array
    y2: jax.Array


# A rollout lists up to this many times (nx + ny) ghost faces per velocity component (``prepare``); bodies with more
# (many or large ones; 64 default samples of karman2d reach 0.2 of it, of channel2d 0.4, at twice their default
# grid 0.23 and 0.44) fill every face instead.
GHOST_LIST = 2


def _listed(g, capacity: int):
    """(``ListedGhosts`` of g's first ``capacity`` ghost faces in index order, whether g has no more)."""
    flat = g.ghost.reshape(-1)
    index = jnp.nonzero(flat, size=capacity, fill_value=flat.size)[0].astype(jnp.int32)
    at = jnp.minimum(index, flat.size - 1)
    return ListedGhosts(index, *(a.reshape(-1)[at] for a in (g.w1, g.w2, g.x1, g.y1, g.x2, g.y2))), \
        jnp.sum(flat) <= capacity


class Prepared(NamedTuple):
    """The bodies' geometry every step reads, computed once per rollout by ``prepare`` (Params.prepared): the
    velocity masks (mu [ny, nx+1], mv [ny+1, nx]) of the staircase cells, the pressure operator's face
    coefficients (grid.Faces), and where geom.body is 'sharp' with bodies the centroid weights ((ax, up, down) of
    the u faces, the same of the v faces: ``_centroid_weights``) and the ghosts (grid.Ghosts of u, of v) in the
    velocity's dtype, with the ghosts also listed (``ListedGhosts`` of u, of v; listed_fits: whether the lists
    hold every ghost, else each fill evaluates every face; None where not listed); None for those without sharp
    bodies."""

    masks: tuple
    faces: Any
    weights: Any
    ghosts: Any
    listed: Any = None
    listed_fits: Any = None


def prepare(geom: Geometry, params: Params, dtype=np.float32, ghost_list: bool | None = None) -> Params:
    """params with ``prepared`` set: the bodies' geometry (``Prepared``) for velocities of dtype, the values each
    step would compute (the same bits), computed once. A rollout calls it before its loop: XLA left this geometry
    inside the loop, where a sharp body's apertures, ghosts and centroid weights (an ellipse's nearest points by
    bisection, every shape of an obstacle row since its kind is traced) are recomputed every step.
    ghost_list: fill the ghosts from their list (``ListedGhosts``); None: on a CPU only. A GPU's batches are
    vectorised, where ``lax.cond`` evaluates both of its branches and a gather over every face runs in parallel:
    there the list would only add work (not measured on a GPU)."""
    params = params._replace(prepared=None)
    masks = velocity_masks(geom, _staircase_solid(geom, params))
    bodies = sharp_bodies(geom, params)
    weights = ghosts = listed = fits = None
    ghost_list = jax.default_backend() == "cpu" if ghost_list is None else ghost_list
    if bodies:
        weights = tuple(w[:3] for w in _centroid_weights(geom, params, dtype))
        ghosts = (body_ghosts(geom, bodies, 0.0, 0.5, (geom.ny, geom.nx + 1), dtype),
                  body_ghosts(geom, bodies, 0.5, 0.0, (geom.ny + 1, geom.nx), dtype))
        if ghost_list:
            (lu, fits_u), (lv, fits_v) = (_listed(g, int(GHOST_LIST * (geom.nx + geom.ny))) for g in ghosts)
            listed, fits = (lu, lv), fits_u & fits_v
    return params._replace(prepared=Prepared(masks, body_faces(geom, params), weights, ghosts, listed, fits))


def inflow_profile(geom: Geometry, params: Params, dtype=np.float32, t=None):
    """Left-side inflow u [ny]: parabolic with peak params.inflow at mid-height (zero at walls), blended with
    a plug of the same flux by params.plug (0: parabola; 1: uniform 2/3 * inflow); at time t (s) times
    1 + A sin(2 pi f t) where params.pulse = (A, f) pulses it."""
    # 4 y (1 - y) at y = (j + 1/2) / ny as 4 (j + 1/2) (ny - j - 1/2) / ny^2: exact until the division, and no
    # product feeds a sum (LLVM's multiply-add contraction followed the vector width: the bits, the CPU)
    j = jnp.arange(geom.ny, dtype=dtype) + 0.5
    parabola = 4 * j * (geom.ny - j) / float(geom.ny * geom.ny)
    profile = params.inflow * ((1 - params.plug) * parabola + params.plug * (2.0 / 3.0))
    if params.pulse is None:
        return profile
    if t is None:
        raise ValueError("a pulsed inflow (params.pulse) needs the time t of the velocities it bounds")
    amplitude, frequency = params.pulse
    return profile * (1 + amplitude * jnp.sin(2 * jnp.pi * frequency * t)).astype(dtype)


def initial_state(geom: Geometry, params: Params, dtype=np.float32) -> State:
    """Fluid at rest (inflow faces set), zero smoke."""
    z = jnp.zeros
    s = State(z((geom.ny, geom.nx + 1), dtype), z((geom.ny + 1, geom.nx), dtype), z((geom.ny, geom.nx), dtype),
              z((geom.ny, geom.nx), dtype), jnp.zeros((), dtype), jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
    u, v = apply_bc(geom, params, s.u, s.v, 0.0)
    return s._replace(u=u, v=v)


def apply_bc(geom: Geometry, params: Params, u, v, t=None):
    """Normal velocities on boundary faces and zero on obstacle faces; t (s): the velocities' time (a pulsed
    inflow's phase; unused otherwise)."""
    if geom.periodic_x:
        u = u.at[:, -1].set(u[:, 0])
    else:
        u = u.at[:, 0].set(inflow_profile(geom, params, u.dtype, t) if geom.left == "inflow" else
                           (u[:, 1] if geom.left == "outflow" else 0.0))
        if geom.right != "convective":  # (a convective side keeps the value the step carried out to it)
            u = u.at[:, -1].set(u[:, -2] if geom.right == "outflow" else 0.0)
    if geom.periodic_y:
        v = v.at[-1].set(v[0])
    else:
        v = v.at[0].set(v[1] if geom.bottom == "outflow" else 0.0)
        if geom.top != "convective":
            v = v.at[-1].set(v[-2] if geom.top == "outflow" else 0.0)
    mu, mv = velocity_masks(geom, _staircase_solid(geom, params)) if params.prepared is None else \
        params.prepared.masks
    u, v = fill_ghosts(geom, params, u * mu, v * mv)
    return _balance_convective(geom, u, v, mu, mv)


def _balance_convective(geom: Geometry, u, v, mu, mv):
    """u, v with the open faces of convective sides shifted evenly so the boundary's net flux is zero: the
    pressure is zero-gradient there, and a Neumann pressure solve needs a box that loses nothing."""
    right, top = geom.right == "convective", geom.top == "convective"
    if not (right or top):
        return u, v
    net = 0.0  # inflow minus outflow through the sides, per unit h (periodic pairs cancel)
    if not geom.periodic_x:
        net = net + jnp.sum(u[:, 0]) - jnp.sum(u[:, -1])
    if not geom.periodic_y:
        net = net + jnp.sum(v[0]) - jnp.sum(v[-1])
    open_right = mu[:, -1] if right else jnp.zeros_like(mu[:, -1])
    open_top = mv[-1] if top else jnp.zeros_like(mv[-1])
    shift = net / jnp.maximum(jnp.sum(open_right) + jnp.sum(open_top), 1.0)
    return u.at[:, -1].add(shift * open_right), v.at[-1].add(shift * open_top)


def source_rate(geom: Geometry, params: Params, dtype=np.float32):
    """Smoke added per second [ny, nx]: params.source's rate inside its disc (sx, sy, r), zero elsewhere."""
    sx, sy, r, rate = params.source
    return rate * circle_solid(geom, sx, sy, r, dtype).astype(dtype)


def _corners(a, x0, y0, per_x: int, per_y: int):
    """a [m, n] at the 4 integer index pairs (x0, y0), (x0+1, y0), (x0, y0+1), (x0+1, y0+1) (x0, y0 whole numbers
    as floats, x along n): [4, *x0.shape]. Indices wrap modulo per_x / per_y on a periodic axis (the number of
    cells), else clamp to the array. One gather for all 4: XLA compiles each gather on its own, and the flow
    step's interpolations were most of its compile time (4 gathers each)."""
    m, n = a.shape

    def idx(i, size, per):
        i = i.astype(jnp.int32)
        return jnp.mod(i, per) if per else jnp.clip(i, 0, size - 1)

    i0, i1 = idx(x0, n, per_x), idx(x0 + 1, n, per_x)
    j0, j1 = idx(y0, m, per_y) * n, idx(y0 + 1, m, per_y) * n
    return a.reshape(-1)[jnp.stack([j0 + i0, j0 + i1, j1 + i0, j1 + i1])]


def _sample(a, x, y, per_x: int, per_y: int):
    """Bilinear sample of a [m, n] at fractional indices (x along n, y along m): indices wrap modulo per_x /
    per_y on a periodic axis (the number of cells), else clamp to the array."""
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = x - x0, y - y0
    c = _corners(a, x0, y0, per_x, per_y)
    return (1 - fy) * ((1 - fx) * c[0] + fx * c[1]) + fy * ((1 - fx) * c[2] + fx * c[3])


def _sampler(geom: Geometry, a, ox: float, oy: float):
    """Function (x, y) [m] -> a at those points, for a field whose index (i, j) sits at ((i+ox) h, (j+oy) h)."""
    h = geom.h
    px = geom.nx if geom.periodic_x else 0
    py = geom.ny if geom.periodic_y else 0
    return lambda x, y: _sample(a, x / h - ox, y / h - oy, px, py)


def _departure(geom: Geometry, u, v, shape, ox: float, oy: float, dt, dtype):
    """Departure points (x, y) [m] of the nodes of a field at offsets (ox, oy): midpoint (RK2) backtrace by u, v
    (the velocity at the half step for second order in time; u^n itself gives first)."""
    h = geom.h
    m, n = shape
    x, y = jnp.meshgrid((jnp.arange(n, dtype=dtype) + ox) * h, (jnp.arange(m, dtype=dtype) + oy) * h)
    su, sv = _sampler(geom, u, 0.0, 0.5), _sampler(geom, v, 0.5, 0.0)
    xm, ym = x - 0.5 * dt * su(x, y), y - 0.5 * dt * sv(x, y)
    return x - dt * su(xm, ym), y - dt * sv(xm, ym)


def advect(geom: Geometry, u, v, q, ox: float, oy: float, dt):
    """Semi-Lagrangian transport of q (at offsets ox, oy in cells) by the face velocities u, v over dt."""
    xd, yd = _departure(geom, u, v, q.shape, ox, oy, dt, q.dtype)
    return _sampler(geom, q, ox, oy)(xd, yd)


def _stencil_bounds(geom: Geometry, q, ox: float, oy: float, x, y):
    """Min and max of the 4 values of q that bilinear interpolation at (x, y) [m] blends."""
    px = geom.nx if geom.periodic_x else 0
    py = geom.ny if geom.periodic_y else 0
    c = _corners(q, jnp.floor(x / geom.h - ox), jnp.floor(y / geom.h - oy), px, py)
    return jnp.minimum(jnp.minimum(c[0], c[1]), jnp.minimum(c[2], c[3])), \
        jnp.maximum(jnp.maximum(c[0], c[1]), jnp.maximum(c[2], c[3]))


def advect_maccormack(geom: Geometry, u, v, q, ox: float, oy: float, dt):
    """MacCormack on semi-Lagrangian (Selle et al. 2008): q1 = SL(q, dt), q2 = SL(q1, -dt), result
    q1 + (q - q2) / 2, clamped to the departure stencil's range (no new extrema). The back-and-forth
    cancels SL's leading interpolation error: second order in space for smooth fields (first where the clamp
    acts), still unconditionally stable; 2 interpolations per field instead of 1."""
    xd, yd = _departure(geom, u, v, q.shape, ox, oy, dt, q.dtype)
    q1 = _sampler(geom, q, ox, oy)(xd, yd)
    q2 = advect(geom, u, v, q1, ox, oy, -dt)
    lo, hi = _stencil_bounds(geom, q, ox, oy, xd, yd)
    return jnp.clip(q1 + 0.5 * (q - q2), lo, hi)


ADVECTION = {"semi_lagrangian": advect, "maccormack": advect_maccormack}


def _laplacian(a, lo_x, hi_x, lo_y, hi_y):
    """5-point h^2-Laplacian of a with the given ghost rows/columns (each shaped like the edge it pads)."""
    g = jnp.concatenate([lo_x, a, hi_x], 1)
    g = jnp.concatenate([jnp.concatenate([lo_y[:, :1] * 0, lo_y, lo_y[:, :1] * 0], 1), g,
                         jnp.concatenate([hi_y[:, :1] * 0, hi_y, hi_y[:, :1] * 0], 1)], 0)
    return g[1:-1, 2:] + g[1:-1, :-2] + g[2:, 1:-1] + g[:-2, 1:-1] - 4 * a


def _tangential_ghost(kind: str, edge, wall_speed=0.0):
    """Ghost of a tangential velocity across a side: no-slip wall/inflow 2 U - u, open sides and free-slip wall u
    (zero normal derivative: no shear stress)."""
    if kind in (*OPEN_SIDES, "slip"):
        return edge
    return 2 * wall_speed - edge


def viscous(geom: Geometry, params: Params, u, v):
    """nu * Laplacian of u and v (m/s^2), tangential wall conditions by ghost values."""
    h2 = geom.h ** 2
    if geom.periodic_x:
        ulx, uhx = u[:, -2:-1], u[:, 1:2]
        vlx, vhx = v[:, -1:], v[:, :1]
    else:
        ulx, uhx = u[:, :1], u[:, -1:]  # normal faces: values beyond are not used (boundary faces are set)
        vlx, vhx = _tangential_ghost(geom.left, v[:, :1]), _tangential_ghost(geom.right, v[:, -1:])
    if geom.periodic_y:
        uly, uhy = u[-1:], u[:1]
        vly, vhy = v[-2:-1], v[1:2]
    else:
        uly = _tangential_ghost(geom.bottom, u[:1])
        uhy = _tangential_ghost(geom.top, u[-1:], params.lid if geom.top == "wall" else 0.0)
        vly, vhy = v[:1], v[-1:]
    lu = _laplacian(u, ulx, uhx, uly, uhy)
    lv = _laplacian(v, vlx, vhx, vly, vhy)
    return params.nu * lu / h2, params.nu * lv / h2


def divergence(geom: Geometry, u, v, params: Params | None = None):
    """Discrete divergence [ny, nx] in 1/s: of the fluxes through the faces' open fractions where geom.body is
    'sharp' and params (with its bodies) is given (what ``project`` makes zero), else of the face velocities."""
    if params is not None:
        u, v = _fluxes(geom, params, u, v)
    return (u[:, 1:] - u[:, :-1] + v[1:] - v[:-1]) / geom.h


def operator(geom: Geometry, params: Params) -> pressure.Operator:
    """The pressure operator of params' obstacles (multigrid levels, coarse pseudo-inverse): computed once per
    rollout by ``run`` and handed to every step."""
    return pressure.prepare(body_faces(geom, params), geom.periodic_x, geom.periodic_y)


def project(geom: Geometry, params: Params, u, v, dt, tol=1e-5, max_iter=200, op: pressure.Operator | None = None,
            p_guess=None):
    """Make (u, v) discretely divergence-free: returns u, v, pressure p [ny, nx] (m^2/s^2), iterations.
    op: ``operator(geom, params)`` when already computed; p_guess: a first guess of p (the last step's)."""
    op = operator(geom, params) if op is None else op
    fc = op.levels[0]
    h = geom.h
    sharp = bool(sharp_bodies(geom, params))
    if sharp:  # project the centroid velocities (the fluxes' own), then recover the face centres' from them
        (ax, uu, ud, _), (ay, vu, vd, _) = _centroid_weights(geom, params, u.dtype)
        u, v = _to_centroid(u, uu, ud, 0), _to_centroid(v, vu, vd, 1)
        fu, fv = ax * u, ay * v
    else:
        fu, fv = u, v
    b = -h * (fu[:, 1:] - fu[:, :-1] + fv[1:] - fv[:-1]) * (1 - fc.solid)
    x0 = None if p_guess is None else p_guess * dt
    sol = pressure.solve(fc, b, geom.periodic_x, geom.periodic_y, geom.singular, tol, max_iter, op, x0)
    g = pressure._ghost_pad(sol.p, geom.periodic_x, geom.periodic_y)
    # the operator's coefficient is the open fraction (the flux of the gradient's velocity): the velocity of an
    # open face itself moves by the whole gradient
    ox, oy = _open(geom, fc)
    u = u - ox * (g[1:-1, 1:] - g[1:-1, :-1]) / h
    v = v - oy * (g[1:, 1:-1] - g[:-1, 1:-1]) / h
    if sharp:  # exact: a cut face's neighbours it reads are whole faces, whose two velocities are one
        u, v = _from_centroid(u, uu, ud, 0), _from_centroid(v, vu, vd, 1)
    return u, v, sol.p / dt, sol.iterations


def _open(geom: Geometry, fc):
    """Faces the pressure gradient acts on: fc's coefficients (0 or 1) for staircase bodies, else coefficient > 0
    (the same where a sharp geometry has no bodies)."""
    if geom.body == "staircase":
        return fc.cx, fc.cy
    return (fc.cx > 0).astype(fc.cx.dtype), (fc.cy > 0).astype(fc.cy.dtype)


def stable_dt(geom: Geometry, params: Params, umax, cfl: float = 1.0):
    """Largest dt (s): min(cfl h / umax, h^2 / (4 nu)) (advective accuracy limit and explicit viscous limit)."""
    h = geom.h
    return jnp.minimum(cfl * h / jnp.maximum(umax, 1e-12), h * h / (4 * jnp.maximum(params.nu, 1e-12)))


def _pressure_gradient(geom: Geometry, params: Params, p):
    """grad p on open faces: gx [ny, nx+1], gy [ny+1, nx] (1/m times p's unit; 0 on closed faces)."""
    ox, oy = _open(geom, body_faces(geom, params))
    g = pressure._ghost_pad(p, geom.periodic_x, geom.periodic_y)
    return ox * (g[1:-1, 1:] - g[1:-1, :-1]) / geom.h, oy * (g[1:, 1:-1] - g[:-1, 1:-1]) / geom.h


def _second_order_velocity(geom: Geometry, params: Params, state: State, lu, lv, dt, adv):
    """Predicted u, v of a step second order in time (Lagrangian trapezoid rule): the particles' path uses the
    half-step velocity u + dt/2 (-(u.grad)u - grad p^n + nu lap u) (u^n alone misses the pressure's
    acceleration), half of the forces -grad p^n + nu lap u^n ride along from the departure point and half act
    at the arrival point, where the projection adds the other half of the pressure (step stores the mean of
    p^n and twice the projection's increment: the pressure at t^{n+1/2}). Explicit forces at t^n alone, or the pressure only at the arrival point,
    leave an O(dt^2) non-gradient error per step: first order overall (Taylor-Green measured 0.83/0.92)."""
    gx, gy = _pressure_gradient(geom, params, state.p)
    u, v = state.u, state.v
    if params.force is not None:  # a steady body force rides the trapezoid with the viscous force
        lu, lv = lu + params.force[0], lv + params.force[1]
    fu, fv = lu - gx, lv - gy
    uh = advect(geom, u, v, u, 0.0, 0.5, 0.5 * dt) + 0.5 * dt * fu
    vh = advect(geom, u, v, v, 0.5, 0.0, 0.5 * dt) + 0.5 * dt * fv
    uh, vh = apply_bc(geom, params, uh, vh, state.t + 0.5 * dt)
    un = adv(geom, uh, vh, u + 0.5 * dt * fu, 0.0, 0.5, dt) + 0.5 * dt * lu
    vn = adv(geom, uh, vh, v + 0.5 * dt * fv, 0.5, 0.0, dt) + 0.5 * dt * lv
    return uh, vh, un, vn


def predict(geom: Geometry, state: State, params: Params, dt, advection: str = "semi_lagrangian"):
    """The step before its projection: advected, diffused and forced u [ny, nx+1], v [ny+1, nx] with boundary
    values set, and the advected smoke [ny, nx] (what ``step`` projects; exposed to measure the projection).
    advection: a key of ADVECTION."""
    if advection not in ADVECTION:
        raise ValueError(f"advection={advection!r}: allowed are {sorted(ADVECTION)}")
    adv = ADVECTION[advection]
    # the last projection moved the cut faces inside a sharp body: their ghost values again, before any stencil
    state = state._replace(**dict(zip("uv", fill_ghosts(geom, params, state.u, state.v))))
    u, v = state.u, state.v
    lu, lv = viscous(geom, params, u, v)
    if advection == "semi_lagrangian":
        # diffuse the advected field (Lie splitting): adding nu lap u^n to SL(u^n) instead was unstable above
        # nu dt / h^2 = 1/8 (interpolation damps a checkerboard's u^n part but not its -8 r u^n), half of
        # stable_dt's limit: the Re-100 cavity at 64^2 blew up within 200 steps at 0.9 of it
        ua, va = u, v
        un, vn = adv(geom, u, v, u, 0.0, 0.5, dt), adv(geom, u, v, v, 0.5, 0.0, dt)
        lu, lv = viscous(geom, params, *apply_bc(geom, params, un, vn, state.t + dt))
        un, vn = un + dt * lu, vn + dt * lv
        if params.force is not None:
            un, vn = un + dt * params.force[0], vn + dt * params.force[1]
    else:
        ua, va, un, vn = _second_order_velocity(geom, params, state, lu, lv, dt, adv)
    smoke = adv(geom, ua, va, state.smoke, 0.5, 0.5, dt) + dt * source_rate(geom, params, state.smoke.dtype)
    sm = jnp.concatenate([smoke[:1], 0.5 * (smoke[1:] + smoke[:-1]), smoke[-1:]], 0)
    vn = vn + dt * params.buoyancy * sm
    un, vn = apply_bc(geom, params, un, vn, state.t + dt)
    return un, vn, smoke


def check_dt(geom: Geometry, params: Params, dt) -> None:
    """Refuse, in one line, a dt (s) above the explicit viscous limit h^2 / (4 nu) where dt and nu are known
    outside a trace: past it the step blows up to finite but meaningless values (1e17-1e31 were seen), which no
    NaN check catches. Under jit the entries' ``stable_dt`` keeps dt inside the limit."""
    if isinstance(dt, jax.core.Tracer) or isinstance(params.nu, jax.core.Tracer):
        return
    # numpy, not jnp: inside a trace jnp would turn these constants into tracers
    nu, dt = float(np.max(np.asarray(params.nu))), float(np.max(np.asarray(dt)))
    dt_max = geom.h * geom.h / (4 * max(nu, 1e-12))
    if dt > dt_max * (1 + 1e-6):
        raise ValueError(f"dt={dt:.4g} s is above the explicit viscous limit "
                         f"h^2 / (4 nu) = {dt_max:.4g} s (h={geom.h:.4g} m, nu={nu:.4g} m^2/s): allowed is "
                         f"dt <= {dt_max:.4g} (stable_dt gives it)")


def step(geom: Geometry, state: State, params: Params, dt, tol=1e-5, max_iter=200,
         op: pressure.Operator | None = None, advection: str = "semi_lagrangian") -> State:
    """Advance one step of dt (s): advection (a key of ADVECTION), explicit viscosity, buoyancy, projection
    (op: ``operator(geom, params)``, computed here when None). A dt above the viscous limit is refused where
    dt and nu are concrete (``check_dt``)."""
    check_dt(geom, params, dt)
    un, vn, smoke = predict(geom, state, params, dt, advection)
    half = advection != "semi_lagrangian"  # the projection adds half the pressure force (see predict)
    un, vn, p, it = project(geom, params, un, vn, dt, tol, max_iter, op, 0.5 * state.p if half else state.p)
    # p^{n+1} = 2 increment would take a pressure error e to -e (a neutral odd-even mode in time: the cavity
    # never settled); averaging with p^n damps it and keeps p at t^{n+1/2}, second order there.
    capped = state.capped + (it >= max_iter).astype(jnp.int32)
    return State(un, vn, 0.5 * (state.p + 2 * p) if half else p, smoke, state.t + dt, it, capped)


def run(geom: Geometry, state: State, params: Params, dt, n_steps: int, tol=1e-5, max_iter=200,
        advection: str = "semi_lagrangian") -> State:
    """n_steps steps of dt in a lax.scan (jit this with geom and n_steps static); tol, max_iter: step's. The
    pressure operator is prepared once, before the loop (the obstacles do not move)."""
    check_dt(geom, params, dt)
    params = prepare(geom, params, state.u.dtype)
    op = operator(geom, params)
    return jax.lax.scan(lambda s, _: (step(geom, s, params, dt, tol, max_iter, op, advection), None), state, None,
                        length=n_steps)[0]


def run_counted(geom: Geometry, state: State, params: Params, dt, n_steps, op: pressure.Operator, tol=1e-5,
                max_iter=200, advection: str = "semi_lagrangian") -> State:
    """``run`` with a traced step count n_steps (int32 []) and the pressure operator op given (``operator``): one
    compiled program serves every count (the sampler calls it with a few different counts: one compile instead
    of one each, 30-60 s apiece on 2 cores at n=16), and it holds no host callback (the operator's
    pseudo-inverse is one), so JAX's persistent compilation cache can keep it for the next run.
    Not reverse-differentiable (a loop of traced length): differentiate ``run``."""
    check_dt(geom, params, dt)
    params = prepare(geom, params, state.u.dtype)
    return jax.lax.fori_loop(0, n_steps, lambda _, s: step(geom, s, params, dt, tol, max_iter, op, advection), state)


def vorticity(geom: Geometry, state: State):
    """Vorticity dv/dx - du/dy at interior cell corners [ny-1, nx-1] (1/s)."""
    h = geom.h
    return (state.v[1:-1, 1:] - state.v[1:-1, :-1] - state.u[1:, 1:-1] + state.u[:-1, 1:-1]) / h


def is_finite(state: State):
    """True when every field is finite (a blown-up run gives False)."""
    return jnp.isfinite(state.u).all() & jnp.isfinite(state.v).all() & jnp.isfinite(state.p).all()
