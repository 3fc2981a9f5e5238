"""Staggered MAC grid, side boundary kinds and masked obstacles (JAX).

Cells: nx x ny on [0, lx] x [0, ly], square cells h = lx / nx = ly / ny. Arrays are [y, x]:
p [ny, nx] at centres, u [ny, nx+1] on vertical faces, v [ny+1, nx] on horizontal faces.
Sides (left, right, bottom, top) are each one of SIDE_KINDS: 'wall' (no-slip, top may move at params.lid),
'inflow' (normal velocity params.inflow * parabolic profile; left side only), 'outflow' (zero-gradient
velocity, pressure 0: the only Dirichlet pressure side) or 'periodic' (left/right or bottom/top pairs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax.numpy as jnp

from ...boundaries import Boundary, is_periodic

# A side's conditions on velocity and pressure; not boundaries.Boundary (a per-axis condition on a field, which
# FlowGrid.bc derives from a pair of sides): only 'periodic' is shared, and is asked of that module (is_periodic).
SIDE_KINDS = ("wall", "inflow", "outflow", Boundary.PERIODIC.value)


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

    def __post_init__(self):
        for name in ("left", "right", "bottom", "top"):
            if getattr(self, name) not in SIDE_KINDS:
                raise ValueError(f"{name}={getattr(self, name)!r}: allowed side kinds are {SIDE_KINDS}")
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
    manufactured solution's forcing)."""

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


# Obstacle primitives of Params.obstacles rows (kind, cx, cy, a, b): code -> what a and b are.
OBSTACLE_KINDS = {0: "none", 1: "circle (radius a)", 2: "box (half-widths a, b)", 3: "ellipse (semi-axes a, b)"}


def centres(geom: Geometry, dtype=jnp.float32):
    """Cell-centre coordinates (x [ny, nx], y [ny, nx]) in m."""
    h = geom.h
    x = (jnp.arange(geom.nx, dtype=dtype) + 0.5) * h
    y = (jnp.arange(geom.ny, dtype=dtype) + 0.5) * h
    return jnp.meshgrid(x, y)


def circle_solid(geom: Geometry, cx, cy, r, dtype=jnp.float32):
    """Boolean solid mask [ny, nx]: cell centres inside the circle (traced cx, cy, r; r <= 0 gives none)."""
    x, y = centres(geom, dtype)
    return (x - cx) ** 2 + (y - cy) ** 2 < r * r


def box_solid(geom: Geometry, x0, y0, x1, y1, dtype=jnp.float32):
    """Boolean solid mask [ny, nx]: cell centres inside the box [x0, x1] x [y0, y1]."""
    x, y = centres(geom, dtype)
    return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)


def ellipse_solid(geom: Geometry, cx, cy, ax, ay, dtype=jnp.float32):
    """Boolean solid mask [ny, nx]: cell centres inside the axis-aligned ellipse with semi-axes ax, ay."""
    x, y = centres(geom, dtype)
    return ((x - cx) / ax) ** 2 + ((y - cy) / ay) ** 2 < 1


def obstacles_solid(geom: Geometry, rows, dtype=jnp.float32):
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


class Faces(NamedTuple):
    """Pressure-operator face coefficients: cx [ny, nx+1], cy [ny+1, nx] (1 open, 0 closed; a boundary face
    with 1 is a Dirichlet p = 0 side), solid [ny, nx] (1 in solid cells, an identity row there)."""

    cx: jnp.ndarray
    cy: jnp.ndarray
    solid: jnp.ndarray


def faces(geom: Geometry, solid) -> Faces:
    """Face coefficients from a boolean solid mask [ny, nx]."""
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
    return Faces(cx, cy, 1.0 - f)


def velocity_masks(geom: Geometry, solid):
    """Faces that may carry velocity: mu [ny, nx+1], mv [ny+1, nx] (0 on faces touching a solid cell)."""
    f = 1.0 - solid.astype(jnp.float32)
    fx = jnp.pad(f, ((0, 0), (1, 1)), constant_values=1.0)
    fy = jnp.pad(f, ((1, 1), (0, 0)), constant_values=1.0)
    return fx[:, :-1] * fx[:, 1:], fy[:-1] * fy[1:]
