"""Staggered MAC grid, side boundary kinds and masked obstacles (JAX).

Cells: nx x ny on [0, lx] x [0, ly], square cells h = lx / nx = ly / ny. Arrays are [y, x]:
p [ny, nx] at centres, u [ny, nx+1] on vertical faces, v [ny+1, nx] on horizontal faces.
Sides (left, right, bottom, top) are each one of SIDE_KINDS: 'wall' (no-slip, top may move at params.lid),
'slip' (a free-slip wall: no flow through it, no shear stress on it: the tangential velocity's normal derivative
is zero), 'inflow' (normal velocity params.inflow * parabolic profile, times 1 + A sin(2 pi f t) where
params.pulse = (A, f) pulses it; left side only), 'outflow' (zero-gradient velocity, pressure 0: the only
Dirichlet pressure side), 'convective' (a convective outflow, right or top: its normal velocity is carried out by
the flow, du/dt + U du/dn = 0 through the step's own advection, then shifted evenly so what leaves is what
enters; pressure zero-gradient there, so vortices leave without the reflection a fixed pressure makes) or
'periodic' (left/right or bottom/top pairs).

Bodies (``Geometry.body``, one of BODIES; DEFAULT_BODY declared once here): 'staircase' makes every cell whose
centre lies inside a body solid (first order in h for forces). 'sharp' treats the circle of Params.circle and the
rows of Params.obstacles (circles, boxes, ellipses) below the cell, each through the sharp-body protocol below
(Circle, Box, Ellipse, ObstacleRow: exact chords, nearest surface points, signed distances): the pressure operator
takes each face's open fraction of the exact bodies (``cut_faces``: a cut-face finite volume, so the projection
sees the true geometry; a cut face's flux is its open fraction times the velocity at its open part's centroid,
step._fluxes), and the velocity faces inside a body next to the fluid are ghost values, extrapolated along the
normal by the quadratic through u = 0 on the surface and image points 1.5 h and 3 h outside it (``body_ghosts``;
a ghost-cell immersed boundary), so viscosity and advection see no-slip on the true surface. Params.mask stays a
staircase in both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ...boundaries import Boundary, is_periodic

# A side's conditions on velocity and pressure; not boundaries.Boundary (a per-axis condition on a field, which
# FlowGrid.bc derives from a pair of sides): only 'periodic' is shared, and is asked of that module (is_periodic).
SIDE_KINDS = ("wall", "slip", "inflow", "outflow", "convective", Boundary.PERIODIC.value)
OPEN_SIDES = ("outflow", "convective")  # where the fluid leaves: a frame's unstored faces follow from continuity
BODIES = ("staircase", "sharp")  # how Params.circle and Params.obstacles meet the grid (module docstring)
DEFAULT_BODY = "sharp"
# A face open by less than this fraction counts as closed: a cut cell's sliver would otherwise give the pressure
# operator a row ~1e-6 of the others' size (CG's conditioning), for a flux below the solve's tolerance.
MIN_APERTURE = 0.01
IMAGE_DISTANCE = 1.5  # cells from the circle to a ghost's image point: its bilinear stencil is then all fluid
GHOST_ORDER = 2
GHOST_BAND = 2.0  # cells inside the circle that get ghost values (stencils reach 1 cell; deeper faces are 0)


@dataclass(frozen=True)
class Geometry:
    """Static part of a flow problem (shapes and boundary kinds; hashable, so jit-static)."""

    nx: int
    ny: int
    lx: float
    ly: float
    left: str = "wall"
    right: str = "wall"
    bottom: str = "wall"
    top: str = "wall"
    body: str = DEFAULT_BODY

    def __post_init__(self):
        if self.body not in BODIES:
            raise ValueError(f"body={self.body!r}: allowed are {BODIES}")
        for name in ("left", "right", "bottom", "top"):
            if getattr(self, name) not in SIDE_KINDS:
                raise ValueError(f"{name}={getattr(self, name)!r}: allowed side kinds are {SIDE_KINDS}")
        if "convective" in (self.left, self.bottom):
            raise ValueError(f"left={self.left!r}, bottom={self.bottom!r}: a convective outflow is a right or top "
                             "side (the flow leaves through it)")
        if is_periodic(self.left) != is_periodic(self.right):
            raise ValueError(f"left={self.left!r}, right={self.right!r}: periodic sides come in pairs")
        if is_periodic(self.bottom) != is_periodic(self.top):
            raise ValueError(f"bottom={self.bottom!r}, top={self.top!r}: periodic sides come in pairs")
        if abs(self.lx / self.nx - self.ly / self.ny) > 1e-9 * self.lx / self.nx:
            raise ValueError(f"lx/nx={self.lx / self.nx} != ly/ny={self.ly / self.ny}: cells must be square")

    @property
    def h(self) -> float:
        return self.lx / self.nx

    @property
    def periodic_x(self) -> bool:
        return is_periodic(self.left)

    @property
    def periodic_y(self) -> bool:
        return is_periodic(self.bottom)

    @property
    def singular(self) -> bool:
        """True when no side fixes the pressure level (no outflow): the pressure is defined up to a constant."""
        return "outflow" not in (self.left, self.right, self.bottom, self.top)


class Params(NamedTuple):
    """Traced values (changing them does not recompile): kinematic viscosity nu [m^2/s], lid speed of a top
    wall, inflow peak speed, circle obstacle (cx, cy, r) [m] (r <= 0: none), buoyancy [m/s^2 per unit smoke];
    plug: the inflow profile's blend of a plug into the parabola (0 parabolic, 1 uniform; the mean flux is
    2/3 * inflow * ly either way); obstacles: more solid primitives, an array [K, 5] of rows
    (kind, cx, cy, a, b) [m] with kind one of OBSTACLE_KINDS' codes (None: none); source: a smoke source disc
    (sx, sy, r [m], rate [smoke/s]) (rate 0: none); mask: a given solid mask [ny, nx] (bool; None: none), e.g. a
    frame's ``solid`` field when the solver continues from a frame; force: a body force per unit mass [m/s^2]
    on the faces, a pair (fx [ny, nx+1] on u faces, fy [ny+1, nx] on v faces), steady (None: none; e.g. a
    manufactured solution's forcing); pulse: a pulsed inflow (A, f): the inflow profile times 1 + A sin(2 pi f t)
    (f in Hz; None: steady, the same program as before pulses existed); prepared: the bodies' geometry a rollout
    computed once (``step.prepare``: the bodies do not move), None where each step computes it (a step alone)."""

    nu: float = 0.01
    lid: float = 0.0
    inflow: float = 0.0
    circle: tuple = (0.0, 0.0, 0.0)
    buoyancy: float = 0.0
    plug: float = 0.0
    obstacles: Any = None
    source: tuple = (0.0, 0.0, 0.0, 0.0)
    mask: Any = None
    force: Any = None
    pulse: Any = None
    prepared: Any = None


# Obstacle primitives of Params.obstacles rows (kind, cx, cy, a, b): code -> what a and b are.
OBSTACLE_KINDS = {0: "none", 1: "circle (radius a)", 2: "box (half-widths a, b)", 3: "ellipse (semi-axes a, b)"}


def centres(geom: Geometry, dtype=np.float32):
    """Cell-centre coordinates (x [ny, nx], y [ny, nx]) in m."""
    h = geom.h
    x = (jnp.arange(geom.nx, dtype=dtype) + 0.5) * h
    y = (jnp.arange(geom.ny, dtype=dtype) + 0.5) * h
    return jnp.meshgrid(x, y)


def circle_solid(geom: Geometry, cx, cy, r, dtype=np.float32):
    """Boolean solid mask [ny, nx]: cell centres inside the circle (traced cx, cy, r; r <= 0 gives none)."""
    x, y = centres(geom, dtype)
    return (x - cx) ** 2 + (y - cy) ** 2 < r * r


def box_solid(geom: Geometry, x0, y0, x1, y1, dtype=np.float32):
    """Boolean solid mask [ny, nx]: cell centres inside the box [x0, x1] x [y0, y1]."""
    x, y = centres(geom, dtype)
    return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)


def ellipse_solid(geom: Geometry, cx, cy, ax, ay, dtype=np.float32):
    """Boolean solid mask [ny, nx]: cell centres inside the axis-aligned ellipse with semi-axes ax, ay."""
    x, y = centres(geom, dtype)
    return ((x - cx) / ax) ** 2 + ((y - cy) / ay) ** 2 < 1


def obstacles_solid(geom: Geometry, rows, dtype=np.float32):
    """Boolean solid mask [ny, nx] of obstacle rows [K, 5] (kind, cx, cy, a, b) (traced; kind 0 adds nothing)."""
    x, y = centres(geom, dtype)
    solid = jnp.zeros((geom.ny, geom.nx), bool)
    for k in range(rows.shape[0]):
        kind, cx, cy, a, b = (rows[k, i] for i in range(5))
        a, b = jnp.maximum(a, 1e-12), jnp.maximum(b, 1e-12)
        dx, dy = x - cx, y - cy
        circle = dx * dx + dy * dy < a * a
        box = (jnp.abs(dx) <= a) & (jnp.abs(dy) <= b)
        ellipse = (dx / a) ** 2 + (dy / b) ** 2 < 1
        solid = solid | ((kind == 1) & circle) | ((kind == 2) & box) | ((kind == 3) & ellipse)
    return solid


def _safe_sqrt(a):
    """sqrt(max(a, 0)) with a finite derivative at and below 0 (the geometry is differentiated in float64)."""
    return jnp.sqrt(jnp.maximum(a, 1e-30))


# The sharp-body protocol (grid.BODIES' 'sharp'): a body is anything with
#   chord(pos, along_y) -> (lo, hi): the interval it covers on the line x = pos (along_y: an interval in y) or
#       y = pos (an interval in x), m; empty where hi <= lo. Convex bodies only (one interval per line).
#   ghost_frame(x, y, d) -> (depth, x1, y1, x2, y2): depth (m, > 0 inside, <= 0 outside) of points (x, y) and the
#       image points d and 2 d outside the surface along the outward normal through the nearest surface point.
#   distance(x, y) -> signed distance (m) to the surface, negative inside.
#   surface(n) -> (x, y, nx, ny, w) [n]: quadrature points on the surface, outward normals and weights (m).
# Circle (karman2d's cylinder), Box and Ellipse are exact; ObstacleRow picks one of them by a traced kind code.
# Bodies of one problem must not overlap (their blocked lengths add; channel2d's slots keep them apart).


class Circle(NamedTuple):
    """The circle (cx, cy, r) [m] (r <= 0: none)."""

    cx: Any
    cy: Any
    r: Any

    def chord(self, pos, along_y: bool):
        c_pos, c_lo = (self.cx, self.cy) if along_y else (self.cy, self.cx)
        s = _safe_sqrt(self.r * self.r - (pos - c_pos) ** 2) * (self.r > 0)
        return c_lo - s, c_lo + s

    def ghost_frame(self, x, y, d):
        cx, cy, r = self
        dx, dy = x - cx, y - cy
        dist = _safe_sqrt(dx * dx + dy * dy)
        small = 1e-12 * d / IMAGE_DISTANCE
        nx_, ny_ = dx / jnp.maximum(dist, small), dy / jnp.maximum(dist, small)
        depth = jnp.where(r > 0, r - dist, -d)
        return depth, cx + (r + d) * nx_, cy + (r + d) * ny_, cx + (r + 2 * d) * nx_, cy + (r + 2 * d) * ny_

    def distance(self, x, y):
        return jnp.sqrt((x - self.cx) ** 2 + (y - self.cy) ** 2) - self.r

    def surface(self, n: int):
        theta = jnp.arange(n, dtype=jnp.result_type(self.r, jnp.float32)) * (2 * math.pi / n)
        c, s = jnp.cos(theta), jnp.sin(theta)
        return self.cx + self.r * c, self.cy + self.r * s, c, s, jnp.full_like(c, self.r * (2 * math.pi / n))


class _AxisAligned(NamedTuple):
    """An axis-aligned body of centre (cx, cy) and half-widths / semi-axes (a, b) [m] (Box and Ellipse add the shape)."""

    cx: Any
    cy: Any
    a: Any
    b: Any

    def axes(self, along_y: bool):
        """(centre across the line, centre along it, half-width across, half-width along) for a grid line x = pos
        (along_y) or y = pos."""
        return (self.cx, self.cy, self.a, self.b) if along_y else (self.cy, self.cx, self.b, self.a)


class Box(_AxisAligned):
    """The axis-aligned box of centre (cx, cy) and half-widths (a, b) [m]: x in [cx - a, cx + a], y likewise."""

    __slots__ = ()

    def chord(self, pos, along_y: bool):
        c_pos, c_lo, half_pos, half = self.axes(along_y)
        hit = jnp.abs(pos - c_pos) <= half_pos
        return c_lo - half, jnp.where(hit, c_lo + half, c_lo - half)

    def _edges(self, x, y):  # distances inside from the left, right, bottom, top edges (negative beyond them)
        return x - (self.cx - self.a), self.cx + self.a - x, y - (self.cy - self.b), self.cy + self.b - y

    def ghost_frame(self, x, y, d):
        left, right, bottom, top = self._edges(x, y)
        depth = jnp.minimum(jnp.minimum(left, right), jnp.minimum(bottom, top))
        # the nearest edge's outward normal; its foot keeps the tangential coordinate
        nx_ = jnp.where(left == depth, -1.0, jnp.where(right == depth, 1.0, 0.0))
        ny_ = jnp.where(nx_ != 0, 0.0, jnp.where(bottom == depth, -1.0, 1.0))
        return depth, x + (depth + d) * nx_, y + (depth + d) * ny_, x + (depth + 2 * d) * nx_, y + (depth + 2 * d) * ny_

    def distance(self, x, y):
        qx, qy = jnp.abs(x - self.cx) - self.a, jnp.abs(y - self.cy) - self.b
        outside = jnp.sqrt(jnp.maximum(qx, 0) ** 2 + jnp.maximum(qy, 0) ** 2)
        return outside + jnp.minimum(jnp.maximum(qx, qy), 0)

    def surface(self, n: int):
        """n // 4 midpoints per edge (the midpoint rule on each: the corners are no quadrature points)."""
        k = n // 4
        s = (jnp.arange(k, dtype=jnp.result_type(self.a, jnp.float32)) + 0.5) / k * 2 - 1  # (-1, 1)
        one, zero = jnp.ones_like(s), jnp.zeros_like(s)
        x = jnp.concatenate([self.cx - self.a * one, self.cx + self.a * one, self.cx + self.a * s, self.cx + self.a * s])
        y = jnp.concatenate([self.cy + self.b * s, self.cy + self.b * s, self.cy - self.b * one, self.cy + self.b * one])
        nx_ = jnp.concatenate([-one, one, zero, zero])
        ny_ = jnp.concatenate([zero, zero, -one, one])
        w = jnp.concatenate([one * (2 * self.b / k), one * (2 * self.b / k), one * (2 * self.a / k), one * (2 * self.a / k)])
        return x, y, nx_, ny_, w


ELLIPSE_BISECTIONS = 40  # bisections for an ellipse's nearest point (its bracket halves to ~1e-12 of its width)


class Ellipse(_AxisAligned):
    """The axis-aligned ellipse of centre (cx, cy) and semi-axes (a, b) [m]."""

    __slots__ = ()

    def chord(self, pos, along_y: bool):
        c_pos, c_lo, half_pos, half = self.axes(along_y)
        arg = 1 - ((pos - c_pos) / half_pos) ** 2
        s = half * _safe_sqrt(arg) * (arg > 0)
        return c_lo - s, c_lo + s

    def _foot(self, x, y):
        """Nearest surface point (fx, fy) of points (x, y) and whether they are inside (Eberly's robust method:
        in the points' quadrant, axes sorted e0 >= e1, the root t > -e1^2 of F(t) = (e0 y0 / (t + e0^2))^2 +
        (e1 y1 / (t + e1^2))^2 - 1, decreasing there, by ELLIPSE_BISECTIONS bisections; the foot
        (e0^2 y0 / (t + e0^2), e1^2 y1 / (t + e1^2)); on the major axis inside the evolute, the off-axis foot)."""
        px, py = x - self.cx, y - self.cy
        swap = self.a < self.b
        e0, e1 = jnp.maximum(self.a, self.b), jnp.minimum(self.a, self.b)
        y0, y1 = jnp.where(swap, jnp.abs(py), jnp.abs(px)), jnp.where(swap, jnp.abs(px), jnp.abs(py))
        lo = -e1 * e1 + e1 * y1
        hi = -e1 * e1 + jnp.sqrt(e0 * e0 * y0 * y0 + e1 * e1 * y1 * y1) + 1e-30

        def bisect(_, bounds):
            lo, hi = bounds
            t = 0.5 * (lo + hi)
            f = (e0 * y0 / (t + e0 * e0)) ** 2 + (e1 * y1 / jnp.maximum(t + e1 * e1, 1e-30)) ** 2 - 1
            return jnp.where(f > 0, t, lo), jnp.where(f > 0, hi, t)

        lo, hi = jax.lax.fori_loop(0, ELLIPSE_BISECTIONS, bisect, (lo, hi))
        t = 0.5 * (lo + hi)
        x0 = e0 * e0 * y0 / (t + e0 * e0)
        x1 = e1 * e1 * y1 / jnp.maximum(t + e1 * e1, 1e-30)
        # on the major axis (y1 = 0) inside the evolute the foot leaves the axis
        axis = y1 <= 1e-7 * e1
        evolute = y0 < (e0 * e0 - e1 * e1) / e0
        xa = jnp.where(evolute, e0 * e0 * y0 / jnp.maximum(e0 * e0 - e1 * e1, 1e-30), e0)
        ya = jnp.where(evolute, e1 * _safe_sqrt(1 - (xa / e0) ** 2), 0.0)
        x0, x1 = jnp.where(axis, xa, x0), jnp.where(axis, ya, x1)
        fx, fy = jnp.where(swap, x1, x0), jnp.where(swap, x0, x1)
        fx = jnp.where(px < 0, -fx, fx)
        fy = jnp.where(py < 0, -fy, fy)
        inside = (px / self.a) ** 2 + (py / self.b) ** 2 < 1
        return self.cx + fx, self.cy + fy, inside

    def ghost_frame(self, x, y, d):
        fx, fy, inside = self._foot(x, y)
        gx, gy = (fx - self.cx) / (self.a * self.a), (fy - self.cy) / (self.b * self.b)  # outward normal there
        g = _safe_sqrt(gx * gx + gy * gy)
        nx_, ny_ = gx / g, gy / g
        dist = _safe_sqrt((x - fx) ** 2 + (y - fy) ** 2)
        depth = jnp.where(inside, dist, -dist)
        return depth, fx + d * nx_, fy + d * ny_, fx + 2 * d * nx_, fy + 2 * d * ny_

    def distance(self, x, y):
        fx, fy, inside = self._foot(x, y)
        dist = jnp.sqrt((x - fx) ** 2 + (y - fy) ** 2)
        return jnp.where(inside, -dist, dist)

    def surface(self, n: int):
        theta = jnp.arange(n, dtype=jnp.result_type(self.a, jnp.float32)) * (2 * math.pi / n)
        c, s = jnp.cos(theta), jnp.sin(theta)
        g = jnp.sqrt((self.b * c) ** 2 + (self.a * s) ** 2)  # |d(x, y)/dt|, and the normal's length
        return self.cx + self.a * c, self.cy + self.b * s, self.b * c / g, self.a * s / g, g * (2 * math.pi / n)


class ObstacleRow(NamedTuple):
    """A row (kind, cx, cy, a, b) of Params.obstacles (OBSTACLE_KINDS; traced kind): the circle, box or ellipse it
    codes, each computed and the row's kind selected (kind 0: no body)."""

    kind: Any
    cx: Any
    cy: Any
    a: Any
    b: Any

    def _shapes(self):
        a, b = jnp.maximum(self.a, 1e-12), jnp.maximum(self.b, 1e-12)
        return ((1, Circle(self.cx, self.cy, a)), (2, Box(self.cx, self.cy, a, b)), (3, Ellipse(self.cx, self.cy, a, b)))

    def _select(self, results, empty):
        out = empty
        for code, res in results:
            out = tuple(jnp.where(self.kind == code, r, o) for r, o in zip(res, out))
        return out

    def chord(self, pos, along_y: bool):
        res = [(k, s.chord(pos, along_y)) for k, s in self._shapes()]
        zero = jnp.zeros_like(res[0][1][0])
        return self._select(res, (zero, zero))

    def ghost_frame(self, x, y, d):
        res = [(k, s.ghost_frame(x, y, d)) for k, s in self._shapes()]
        none = jnp.full_like(res[0][1][0], -1.0) * d
        return self._select(res, (none, x, y, x, y))

    def distance(self, x, y):
        res = [(k, (s.distance(x, y),)) for k, s in self._shapes()]
        return self._select(res, (jnp.full_like(res[0][1][0], 1e15),))[0]

    def surface(self, n: int):
        res = [(k, s.surface(n)) for k, s in self._shapes()]
        zero = jnp.zeros_like(res[0][1][0])
        return self._select(res, (zero, zero, zero, zero, zero))


def cut_faces(geom: Geometry, bodies, dtype=np.float32):
    """Open fractions of the faces against the exact bodies (a list of the sharp-body protocol's bodies, not
    overlapping): ax [ny, nx+1] of the vertical faces (x = i h, y in [j h, (j+1) h]), ay [ny+1, nx] of the
    horizontal ones (1 where no body meets the face, 0 where they cover it; below MIN_APERTURE counted as 0), and
    the centroids of the faces' open parts along them (m): my [ny, nx+1] (the y of each vertical face's open part),
    mx [ny+1, nx] (the x of each horizontal one's); the face's centre where it is whole or closed."""
    h = geom.h

    def fraction(pos, lo, along_y):
        blocked, moment = None, None
        centre = lo + 0.5 * h
        for body in bodies:
            c0, c1 = body.chord(pos, along_y)
            b0, b1 = jnp.maximum(lo, c0), jnp.minimum(lo + h, c1)
            part = jnp.clip(b1 - b0, 0.0, h)
            # centroid of the open part: the face's first moment less the blocked intervals', (h c - sum b m) /
            # (h - sum b) for the face's centre c and the blocked intervals' m, written c + sum b (c - m) /
            # (h - sum b): no product feeds a sum, so LLVM has no multiply-add to contract (XLA's CPU backend
            # lets it, and whether it fused h c - b m followed the vector width: cut faces' last bits differed
            # between CPUs)
            first = part * (centre - 0.5 * (b0 + b1))
            blocked = part if blocked is None else blocked + part
            moment = first if moment is None else moment + first
        blocked = jnp.minimum(blocked, h)
        a = 1.0 - blocked / h
        a = jnp.where(a < MIN_APERTURE, 0.0, a)
        centroid = centre + moment / jnp.maximum(h - blocked, 1e-6 * h)
        centroid = jnp.where((a > 0) & (a < 1), centroid, centre)
        return a.astype(dtype), centroid.astype(dtype)

    xf = jnp.arange(geom.nx + 1, dtype=dtype) * h
    yc = jnp.arange(geom.ny, dtype=dtype) * h
    ax, my = fraction(xf[None, :], yc[:, None], True)
    xc = jnp.arange(geom.nx, dtype=dtype) * h
    yf = jnp.arange(geom.ny + 1, dtype=dtype) * h
    ay, mx = fraction(yf[:, None], xc[None, :], False)
    return ax, ay, my, mx


def circle_apertures(geom: Geometry, cx, cy, r, dtype=np.float32):
    """Open fractions of the faces against the exact circle (cx, cy, r) [m]: ax [ny, nx+1] of the vertical faces
    (x = i h, y in [j h, (j+1) h]), ay [ny+1, nx] of the horizontal ones; 1 where the circle misses the face
    (r <= 0: no circle), 0 where it covers it; below MIN_APERTURE counted as 0."""
    return circle_cut_faces(geom, cx, cy, r, dtype)[:2]


def circle_cut_faces(geom: Geometry, cx, cy, r, dtype=np.float32):
    """``cut_faces`` of the one circle (cx, cy, r) [m]: (ax, ay, my, mx)."""
    return cut_faces(geom, [Circle(cx, cy, r)], dtype)


class Ghosts(NamedTuple):
    """Ghost faces of one velocity component inside the bodies: ghost [m, n] bool (faces inside by less than
    GHOST_BAND cells: they get w1 u(x1, y1) + w2 u(x2, y2)), deep [m, n] bool (faces further inside: 0),
    the weights w1, w2 [m, n] of the quadratic through 0 on the surface and the two image points (x1, y1),
    (x2, y2) [m, n] (m) on the outward normal, IMAGE_DISTANCE and twice that many cells outside the surface."""

    ghost: jnp.ndarray
    deep: jnp.ndarray
    w1: jnp.ndarray
    w2: jnp.ndarray
    x1: jnp.ndarray
    y1: jnp.ndarray
    x2: jnp.ndarray
    y2: jnp.ndarray


def body_ghosts(geom: Geometry, bodies, ox: float, oy: float, shape, dtype=np.float32) -> Ghosts:
    """Ghosts of the faces of a velocity component whose index (i, j) sits at ((i+ox) h, (j+oy) h), array
    ``shape`` [m, n], for the bodies (the sharp-body protocol; each face is inside one body at most)."""
    h = geom.h
    m, n = shape
    x, y = jnp.meshgrid((jnp.arange(n, dtype=dtype) + ox) * h, (jnp.arange(m, dtype=dtype) + oy) * h)
    d1 = IMAGE_DISTANCE * h
    frame = None
    for body in bodies:
        f = body.ghost_frame(x, y, d1)
        frame = f if frame is None else tuple(jnp.where(f[0] > frame[0], a, b) for a, b in zip(f, frame))
    depth, x1, y1, x2, y2 = frame
    inside = depth > 0
    ghost = inside & (depth < GHOST_BAND * h)
    # Lagrange weights at -depth of the quadratic through (0, 0), (d1, u1), (2 d1, u2)
    w1 = jnp.where(ghost, -depth * (depth + 2 * d1) / (d1 * d1), 0.0).astype(dtype)
    w2 = jnp.where(ghost, depth * (depth + d1) / (2 * d1 * d1), 0.0).astype(dtype)
    if GHOST_ORDER == 1:
        w1, w2 = jnp.where(ghost, -depth / d1, 0.0).astype(dtype), jnp.zeros_like(w2)
    return Ghosts(ghost, inside & ~ghost, w1, w2, x1, y1, x2, y2)


def circle_ghosts(geom: Geometry, cx, cy, r, ox: float, oy: float, shape, dtype=np.float32) -> Ghosts:
    """``body_ghosts`` of the one circle (cx, cy, r) [m] (r <= 0: none)."""
    return body_ghosts(geom, [Circle(cx, cy, r)], ox, oy, shape, dtype)


class Faces(NamedTuple):
    """Pressure-operator face coefficients: cx [ny, nx+1], cy [ny+1, nx] (1 open, 0 closed; a boundary face
    with 1 is a Dirichlet p = 0 side), solid [ny, nx] (1 in solid cells, an identity row there)."""

    cx: jnp.ndarray
    cy: jnp.ndarray
    solid: jnp.ndarray


def faces(geom: Geometry, solid, apertures=None) -> Faces:
    """Face coefficients from a boolean solid mask [ny, nx]; apertures: open fractions (ax [ny, nx+1],
    ay [ny+1, nx]) of a sharp body (``circle_apertures``) that scale them (a cell all of whose faces it closes is
    solid), or None."""
    if apertures is not None:
        ax, ay = apertures
        covered = (ax[:, :-1] == 0) & (ax[:, 1:] == 0) & (ay[:-1] == 0) & (ay[1:] == 0)
        solid = solid | covered
    f = 1.0 - solid.astype(jnp.float32)
    inner_x = f[:, :-1] * f[:, 1:]
    inner_y = f[:-1] * f[1:]
    if geom.periodic_x:
        wrap = f[:, -1:] * f[:, :1]
        lx, rx = wrap, wrap
    else:
        lx = f[:, :1] * float(geom.left == "outflow")
        rx = f[:, -1:] * float(geom.right == "outflow")
    if geom.periodic_y:
        wrap = f[-1:] * f[:1]
        by, ty = wrap, wrap
    else:
        by = f[:1] * float(geom.bottom == "outflow")
        ty = f[-1:] * float(geom.top == "outflow")
    cx = jnp.concatenate([lx, inner_x, rx], axis=1)
    cy = jnp.concatenate([by, inner_y, ty], axis=0)
    if apertures is not None:
        cx, cy = cx * ax, cy * ay
    return Faces(cx, cy, 1.0 - f)


def velocity_masks(geom: Geometry, solid):
    """Faces that may carry velocity: mu [ny, nx+1], mv [ny+1, nx] (0 on faces touching a solid cell)."""
    f = 1.0 - solid.astype(jnp.float32)
    fx = jnp.pad(f, ((0, 0), (1, 1)), constant_values=1.0)
    fy = jnp.pad(f, ((1, 1), (0, 0)), constant_values=1.0)
    return fx[:, :-1] * fx[:, 1:], fy[:-1] * fy[1:]
