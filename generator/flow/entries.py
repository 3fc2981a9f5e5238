"""The incompressible-flow entries: a vortex street behind a cylinder, the lid-driven cavity, a channel with
random obstacles and a buoyant smoke plume (the family and the sample layout: ``generator.flow.problem``).

Each entry states its box (sides, aspect), its random parameters with units and the Reynolds number's
definition, how a sample's solver parameters follow from them, and the geometry it refuses: an obstacle outside
the box, touching a wall or the inflow, too small for the grid, or a set of obstacles that could close the
channel; a Reynolds number the grid cannot resolve is refused by the family (cell Reynolds limit).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

from pdestream.generator.lazy_jax import jax, jnp

from ..domains import Fixed
from ..problem import Output, Param
from . import forces
from .grid import DEFAULT_BODY, Params
from .noise import SmokeNoise
from .problem import FlowProblem

MIN_CELLS_ACROSS = 4.0  # an obstacle narrower than this many cells is a staircase of a few cells, not a body
CLEARANCE_CELLS = 2.0  # cells of fluid kept between an obstacle and a wall or the inflow


def _bounds(problem, name: str) -> tuple[float, float]:
    return tuple(getattr(problem, name).bounds)


# velocity on faces and pressure over density (generator.flow.step): SI units, as the flows' parameters
FLOW_UNITS = {"u": "m/s", "v": "m/s", "p": "m^2/s^2"}


@dataclass(frozen=True)
class Karman2D(FlowProblem):
    """Flow past a cylinder in a channel: parabolic (or blunter) inflow on the left, outflow on the right, no-slip
    walls at the bottom and top. Re = U D / nu with U the mean inflow speed and D = 2 radius; a vortex street
    forms for Re above ~47 in free stream, later in this confined channel on the default grid.

    Defaults hold a developed street (issue 28; measured with long runs from rest, frames every 0.05 s, the
    ``developed`` detector on sliding 4-period windows, the other parameters at their range ends): Re 60 does not
    shed reliably on the default 64x32 grid (radius 0.12: the lift oscillation decays; cx 0.6 with plug 0.3: no
    oscillation at all), Re 80 sheds but the slowest corner (radius 0.12, cy 0.42, cx 0.6, plug 0.3) still
    drifts 2.2% over 3 periods at t 12.5-16; at Re 90-120 every measured corner drifts < 2% from t <= 9.5 on.
    So Re ~ uniform(90, 120), the window starts at t 12 (>= 2.5 s, ~3 periods, after that spin-up) and spans
    t 12-16 (4.5-6.5 shedding periods of 0.61-0.89 s) in 81 frames (0.05 s apart: >= 12 frames per period).
    The cylinder sits below the centre line (cy ~ uniform(0.42, 0.46), at least 1.3 cells off it): a centred
    mask is mirror-symmetric and sheds only once rounding has grown (lift 0.0003 at t 12, 0.014 at t 16, Re 100),
    one within a cell of the centre starts late; the channel is
    mirror-symmetric, so a cylinder above the line is the mirror image of one below.
    Checked on the first 64 default samples (seed 0, the sharp body): every one developed (docs/guides/flows.md).

    Outputs beside the fields (``OUTPUTS``, computed from each stored frame in JAX by ``sample_outputs``):
    ``drag`` and ``lift`` [T], C_d, C_l = 2 (Fx, Fy) / (U^2 D) with F the force per unit depth and density on the
    cylinder, a surface integral of pressure and wall shear: on the exact circle where ``body`` is 'sharp'
    (``generator.flow.forces.circle_force``, second order in h), over the mask's staircase faces where it is
    'staircase' (``forces.body_force``, first order), U the mean inflow speed (``speed``: Schaefer and
    Turek's U_mean) and D = 2 radius; ``sdf`` [nx, ny], the exact signed distance of each cell centre to the
    circle (m, negative inside: solid == sdf < 0); ``strouhal``, ``sheds``, ``developed``, ``lift_amplitude``,
    ``lift_drift``: ``forces.shedding`` of the lift over the stored window (St = f D / U from the lift's mean
    crossings; developed: the fitted amplitude drifts < 2% over 3 periods and the window holds 3; a sample that
    does not shed has sheds = 0 and St = amplitude = drift = 0, never NaN)."""

    NAME: ClassVar[str] = "karman2d"
    # `pdestream generate karman2d --n 4` on 2 shared CPU cores (load 4, 2026-11-29: chunks row by row, the ghosts
    # filled from their list), no compilation cache (the progress history's record)
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 15.0, "unit_s": 1.33}
    EQUATION: ClassVar[str] = ("u_t + (u.grad)u = -grad p + nu lap u, div u = 0; cylinder in a channel, "
                               "nu = U D / Re")
    FIELDS: ClassVar[tuple] = ("u", "v", "p", "solid")
    FIELD_UNITS: ClassVar[dict] = {**FLOW_UNITS, "solid": "1"}
    SIDES: ClassVar[tuple] = ("inflow", "outflow", "wall", "wall")
    PARAMS: ClassVar[dict] = {
        "re": Param("Reynolds number U D / nu", "1", positive=True),
        "radius": Param("cylinder radius", "m", positive=True),
        "cx": Param("cylinder centre x", "m", positive=True),
        "cy": Param("cylinder centre y", "m", positive=True),
        "speed": Param("mean inflow speed U", "m/s", positive=True),
        "plug": Param("inflow profile: 0 parabolic, 1 uniform (same flux)", "1"),
    }

    n: int = 32
    aspect: int = 2
    t_start: float = 12.0
    t_end: float = 16.0
    n_frames: int = 81
    re: Any = "uniform(90, 120)"
    radius: Any = "uniform(0.08, 0.12)"
    cx: Any = "uniform(0.4, 0.6)"
    cy: Any = "uniform(0.42, 0.46)"
    speed: Any = Fixed(1.0)
    plug: Any = "uniform(0, 0.3)"
    body: str = DEFAULT_BODY  # one of grid.BODIES: 'sharp' (the exact circle: cut faces, ghost velocities) or
    # 'staircase' (the cells whose centre lies inside); benchmarks/flow_bodies.py compares them

    OUTPUTS: ClassVar[dict] = {
        "drag": Output("drag coefficient C_d = 2 Fx / (U^2 D) on the cylinder (U mean inflow, D diameter; pressure "
                       "and wall shear integrated over the body's surface: the exact circle, or the mask's faces "
                       "where body = staircase)", "1", "time"),
        "lift": Output("lift coefficient C_l = 2 Fy / (U^2 D) on the cylinder", "1", "time"),
        "sdf": Output("signed distance of the cell centre to the cylinder's surface (negative inside)", "m", "space"),
        "strouhal": Output("Strouhal number f D / U of the lift over the stored window (0 where sheds = 0)", "1"),
        "sheds": Output("1 where the lift oscillates (>= 3 mean crossings, amplitude >= "
                        f"{forces.MIN_LIFT_AMPLITUDE:g}), else 0", "1", "", "int8"),
        "developed": Output(f"1 where the shedding is developed: the lift amplitude drifts < {forces.MAX_DRIFT:.0%} "
                            f"over {forces.DRIFT_PERIODS} periods, and the window holds that many", "1", "", "int8"),
        "lift_amplitude": Output("fitted lift amplitude at the window's middle (0 where sheds = 0)", "1"),
        "lift_drift": Output(f"relative change of the lift amplitude over {forces.DRIFT_PERIODS} periods "
                             "(0 where sheds = 0)", "1"),
    }

    def sample_outputs(self, frames: jax.Array, p: Mapping[str, jax.Array]) -> dict[str, jax.Array]:
        geom = self.geometry()
        fp = self.flow_params(p, None)
        diameter, speed = 2 * p["radius"], p["speed"]
        solid = frames[0, self.FIELDS.index("solid")].T > 0.5

        def coefficients(frame):
            state = self.state_of(frame, fp)
            if self.body == "sharp":
                fx, fy = forces.circle_force(geom, state, fp.nu, p["cx"], p["cy"], p["radius"])
            else:
                fx, fy = forces.body_force(geom, solid, state, fp.nu)
            return jnp.stack(forces.force_coefficients(fx, fy, speed, diameter))

        cd, cl = jax.lax.map(coefficients, frames).T
        st, sheds, developed, amp, drift = forces.shedding(cl, jnp.asarray(self.times()), diameter, speed)
        return {"drag": cd, "lift": cl, "sdf": forces.circle_distance(geom, p["cx"], p["cy"], p["radius"]).T,
                "strouhal": st, "sheds": sheds, "developed": developed, "lift_amplitude": amp, "lift_drift": drift}

    def flow_params(self, p: Mapping[str, jax.Array], key: jax.Array | None) -> Params:
        nu = p["speed"] * 2 * p["radius"] / p["re"]
        return Params(nu=nu, inflow=1.5 * p["speed"], plug=p["plug"], circle=(p["cx"], p["cy"], p["radius"]))

    def oracle_params(self, p: Mapping[str, jax.Array], frame: jax.Array) -> Params:
        # the cylinder is a parameter: the frame's mask adds nothing to a staircase and would staircase a sharp one
        return self.flow_params(p, None)

    def speed_bound(self) -> float:
        return 1.5 * _bounds(self, "speed")[1]

    def viscosity_range(self) -> tuple[float, float]:
        (u0, u1), (r0, r1), (re0, re1) = _bounds(self, "speed"), _bounds(self, "radius"), _bounds(self, "re")
        return u0 * 2 * r0 / re1, u1 * 2 * r1 / re0

    def check_flow(self) -> None:
        lo, hi = _bounds(self, "plug")
        if not 0 <= lo <= hi <= 1:
            raise ValueError(f"{self.NAME}: plug={self.plug} not allowed: the profile blend must lie in [0, 1]")
        _check_disc(self, "cylinder", _bounds(self, "cx"), _bounds(self, "cy"), _bounds(self, "radius"))


class UnderResolved(UserWarning):
    """A setting the entry runs but whose grid does not resolve its parameter range to the entry's checked
    accuracy (the message names the grid it needs)."""


# cavity2d: the cell Reynolds number Re h / L up to which the steady centrelines were within 0.02 of Ghia et al.
# (1982) where a table exists: 64^2 at Re 400 and 16^2 at Re 100 (both 6.25) were, 32^2 at Re 400 (12.5) and 64^2
# at Re 1000 (15.6) were not (docs/results/flows.md)
CAVITY_CELL_RE = 400 / 64


@dataclass(frozen=True)
class Cavity2D(FlowProblem):
    """The lid-driven cavity: a closed square box whose top wall slides at the lid speed U. Re = U L / nu.

    Defaults resolve their range (issue 28): run to steady state, 64^2 cells at Re 400, the top of the default
    range, stay within 0.02 of Ghia, Ghia & Shin's (1982) centreline tables (max |du|, |dv|, lid speed 1); 32^2 at
    Re 400 and 64^2 at Re 1000 do not, and Ghia has no table between Re 400 and 1000 to check a higher cap against
    (``python -m benchmarks.flow_validation --parts steady``; figures in docs/results/flows.md). A range whose
    largest Re exceeds ``CAVITY_CELL_RE`` n still runs (up to the family's cell Reynolds limit) with one
    ``UnderResolved`` warning naming the n it needs (the linear rule through the measured 64^2 at Re 400).
    The window t in [0, 4] is the spin-up from rest, said plainly: the primary vortex forming under the lid, not
    the steady state, which comes near t 25-35 at Re 400 (``--parts transient`` checks the spin-up against a finer
    grid); ``t_start`` ~ 30 burns in to it, at ~8x the cost of a default sample."""

    NAME: ClassVar[str] = "cavity2d"
    # `pdestream generate cavity2d --n 4` on 2 shared CPU cores (load 5-6, 2026-11-27: chunks row by row), no
    # compilation cache (the progress history's record; 64^2 at the viscous step limit of Re 100: 729 steps)
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 12.7, "unit_s": 1.5}
    EQUATION: ClassVar[str] = "u_t + (u.grad)u = -grad p + nu lap u, div u = 0; lid-driven cavity, nu = U L / Re"
    FIELDS: ClassVar[tuple] = ("u", "v", "p")
    FIELD_UNITS: ClassVar[dict] = FLOW_UNITS
    SIDES: ClassVar[tuple] = ("wall", "wall", "wall", "wall")
    PARAMS: ClassVar[dict] = {
        "re": Param("Reynolds number U L / nu", "1", positive=True),
        "lid": Param("lid speed U (top wall, towards +x)", "m/s", positive=True),
    }

    n: int = 64
    aspect: int = 1
    t_end: float = 4.0
    re: Any = "uniform(100, 400)"
    lid: Any = Fixed(1.0)

    def flow_params(self, p: Mapping[str, jax.Array], key: jax.Array | None) -> Params:
        return Params(nu=p["lid"] * self.length / p["re"], lid=p["lid"])

    def speed_bound(self) -> float:
        return _bounds(self, "lid")[1]

    def viscosity_range(self) -> tuple[float, float]:
        (u0, u1), (re0, re1) = _bounds(self, "lid"), _bounds(self, "re")
        return u0 * self.length / re1, u1 * self.length / re0

    def validate(self) -> None:
        super().validate()  # a refused setting (the family's cell Reynolds limit) raises before any warning
        if self.refine > 1:  # the solve grid's problem warned (``FlowProblem._check_refine`` validated it)
            return
        re_max = _bounds(self, "re")[1]
        if re_max / self.n > CAVITY_CELL_RE:
            need = 2 * math.ceil(re_max / CAVITY_CELL_RE / 2)
            warnings.warn(f"{self.NAME}: re={self.re} on n={self.n} is under-resolved: the steady centrelines stay "
                          f"within 0.02 of Ghia et al. up to Re = {CAVITY_CELL_RE:g} n ({CAVITY_CELL_RE * self.n:g} "
                          f"here); Re {re_max:g} needs n >= {need}", UnderResolved, stacklevel=2)


@dataclass(frozen=True)
class Channel2D(FlowProblem):
    """A channel (inflow left, outflow right, walls bottom and top) with ``obstacles`` random bodies: each a
    circle, box or ellipse (equally likely) of half-sizes in [size_min, size_max] at a random position in its
    own slot of the channel's length (so bodies never overlap and none alone closes the channel). Re = U H / nu
    with U the mean inflow speed and H the channel height. The bodies come from the sample's geometry key.
    ``body`` (grid.BODIES): 'staircase' (the default) makes the cells whose centre lies inside a body solid;
    'sharp' puts the exact bodies below the cell, as karman2d's sharp circle (cut faces with open fractions,
    ghost velocities through no-slip on the true surface; grid's sharp-body protocol: Circle, Box, Ellipse).
    Either way the stored ``solid`` field is the cells whose centre lies inside.

    Outputs beside the fields (``OUTPUTS``): ``drag`` and ``lift`` [T] of all the bodies together, C = 2 F / (U^2
    H): 'staircase': ``forces.body_force`` over the mask's fluid-solid faces (first order in h); 'sharp':
    ``forces.bodies_force``, the surface integral of pressure and wall shear on the exact bodies. ``sdf`` [nx, ny]:
    the exact signed distance to the bodies the solver sees ('staircase': the union of solid cells,
    ``forces.mask_distance``; 'sharp': the exact circles, boxes and ellipses, ``forces.bodies_distance``;
    solid == sdf < 0). A sharp sample's geometry is not in its frames: its outputs are computed from the sample's
    key (``sample_outputs``' key); the oracle (``interactive.advance``) continuing a frame sees the frame's
    ``solid`` cells, a staircase, so it continues a sharp sample only approximately (docs/results/flows.md)."""

    NAME: ClassVar[str] = "channel2d"
    # `pdestream generate channel2d --n 4` on 2 shared CPU cores (load 5-6, 2026-11-27: chunks row by row), no
    # compilation cache (the progress history's record)
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 13.0, "unit_s": 1.4}
    EQUATION: ClassVar[str] = ("u_t + (u.grad)u = -grad p + nu lap u, div u = 0; channel with random obstacles, "
                               "nu = U H / Re")
    FIELDS: ClassVar[tuple] = ("u", "v", "p", "solid")
    FIELD_UNITS: ClassVar[dict] = {**FLOW_UNITS, "solid": "1"}
    SIDES: ClassVar[tuple] = ("inflow", "outflow", "wall", "wall")
    PARAMS: ClassVar[dict] = {
        "re": Param("Reynolds number U H / nu", "1", positive=True),
        "speed": Param("mean inflow speed U", "m/s", positive=True),
    }

    n: int = 32
    aspect: int = 3
    t_start: float = 2.0
    t_end: float = 6.0
    obstacles: int = 2  # bodies per sample
    size_min: float = 0.07  # half-size range of a body (m)
    size_max: float = 0.14
    re: Any = "uniform(200, 600)"
    speed: Any = Fixed(1.0)
    body: str = "staircase"  # one of grid.BODIES: 'staircase' (cells whose centre lies inside) or 'sharp' (the
    # exact bodies: cut faces, ghost velocities; ~8x the staircase's time per sample); not the default: on a square
    # it is no more accurate (benchmarks/square_cylinder.py, docs/results/flows.md "Sharp squares")
    BODY_NOUN: ClassVar[str] = "bodies"

    OUTPUTS: ClassVar[dict] = {
        "drag": Output("drag coefficient C_d = 2 Fx / (U^2 H) of all the bodies together (U mean inflow speed, H the "
                       "channel height; pressure and wall shear integrated over the bodies the solver sees: the "
                       "staircase's fluid-solid faces, first order in h, or the exact surfaces where body = sharp)",
                       "1", "time"),
        "lift": Output("lift coefficient C_l = 2 Fy / (U^2 H) of all the bodies together", "1", "time"),
        "sdf": Output("signed distance of the cell centre to the bodies' surface (the union of their solid cells, or "
                      "the exact bodies where body = sharp; negative inside; the channel's walls are not part of it)",
                      "m", "space"),
    }
    @property
    def OUTPUTS_NEED_KEY(self) -> bool:  # noqa: N802 (the base's class constant): a sharp sample's bodies come
        return self.body == "sharp"  # from its key (sample_outputs)

    def sample_outputs(self, frames: jax.Array, p: Mapping[str, jax.Array], key: jax.Array | None = None
                       ) -> dict[str, jax.Array]:
        """The outputs of one sample; key: the sample's key (its bodies, needed where body is 'sharp')."""
        geom = self.geometry()
        fp = self.flow_params(p, None)
        solid = frames[0, self.FIELDS.index("solid")].T > 0.5  # the bodies do not move: the first frame's mask
        if self.body == "sharp":
            if key is None:
                raise ValueError(f"{self.NAME}: body='sharp' outputs need the sample's key (its bodies)")
            fp = self.flow_params(p, jax.random.split(key)[1])  # the geometry key, as the solver's (_programs)

        def coefficients(frame):
            state = self.state_of(frame, fp)
            if self.body == "sharp":
                fx, fy = forces.bodies_force(geom, state, fp.nu, fp)
            else:
                fx, fy = forces.body_force(geom, solid, state, fp.nu)
            return jnp.stack(forces.force_coefficients(fx, fy, p["speed"], self.length))

        cd, cl = jax.lax.map(coefficients, frames).T
        sdf = forces.bodies_distance(geom, fp) if self.body == "sharp" else forces.mask_distance(geom, solid)
        return {"drag": cd, "lift": cl, "sdf": sdf.T}

    def slots(self) -> tuple[float, float]:
        """(x of the first slot's left end, slot width) (m): bodies sit in equal slots of [0.3, lx - 0.3]."""
        lx = self.aspect * self.length
        return 0.3 * self.length, (lx - 0.6 * self.length) / self.obstacles

    def flow_params(self, p: Mapping[str, jax.Array], key: jax.Array | None) -> Params:
        nu, inflow = p["speed"] * self.length / p["re"], 1.5 * p["speed"]
        if key is None:
            return Params(nu=nu, inflow=inflow)
        x0, width = self.slots()
        k = self.obstacles
        u = jax.random.uniform(key, (k, 5), jnp.float32)
        kind = 1 + jnp.floor(3 * u[:, 0]).clip(0, 2)
        a = self.size_min + (self.size_max - self.size_min) * u[:, 3]
        b = self.size_min + (self.size_max - self.size_min) * u[:, 4]
        b = jnp.where(kind == 1, a, b)
        margin = self.size_max + CLEARANCE_CELLS * self.h
        cx = x0 + width * jnp.arange(k) + margin + (width - 2 * margin) * u[:, 1]
        cy = margin + (self.length - 2 * margin) * u[:, 2]
        rows = jnp.stack([kind, cx, cy, a, b], axis=1)
        return Params(nu=nu, inflow=inflow, obstacles=rows)

    def describe_geometry(self) -> str:
        return (f"obstacles: {self.obstacles} per sample, each a circle, box or ellipse of half-sizes in "
                f"[{self.size_min:g}, {self.size_max:g}] m, one per slot of {self.slots()[1]:.3g} m from x = "
                f"{self.slots()[0]:g} m (drawn from the sample's key)")

    def speed_bound(self) -> float:
        return 1.5 * _bounds(self, "speed")[1]

    def viscosity_range(self) -> tuple[float, float]:
        (u0, u1), (re0, re1) = _bounds(self, "speed"), _bounds(self, "re")
        return u0 * self.length / re1, u1 * self.length / re0

    def check_flow(self) -> None:
        if not 1 <= self.obstacles <= 8:
            raise ValueError(f"{self.NAME}: obstacles={self.obstacles} not allowed: bodies per sample must be 1..8")
        cells = 2 * self.size_min / self.h
        if not 0 < self.size_min <= self.size_max:
            raise ValueError(f"{self.NAME}: size_min={self.size_min:g}, size_max={self.size_max:g} not allowed: need "
                             "0 < size_min <= size_max")
        if cells < MIN_CELLS_ACROSS:
            need = 2 * math.ceil(MIN_CELLS_ACROSS * self.length / (2 * self.size_min) / 2)
            raise ValueError(f"{self.NAME}: size_min={self.size_min:g} not allowed: a body {cells:.2g} cells across is "
                             f"below {MIN_CELLS_ACROSS:g} cells on this grid (h={self.h:.4g}); it needs n >= {need}, "
                             f"or size_min >= {MIN_CELLS_ACROSS * self.h / 2:.3g}")
        margin = self.size_max + CLEARANCE_CELLS * self.h
        if 2 * margin >= self.length:
            raise ValueError(f"{self.NAME}: size_max={self.size_max:g} not allowed: a body could close the channel "
                             f"(height {self.length:g}); size_max must be < {self.length / 2 - CLEARANCE_CELLS * self.h:.3g}")
        if 2 * margin >= self.slots()[1]:
            raise ValueError(f"{self.NAME}: obstacles={self.obstacles} with size_max={self.size_max:g} not allowed: "
                             f"each body gets a slot {self.slots()[1]:.3g} m long and needs {2 * margin:.3g} m "
                             "(fewer obstacles, smaller bodies or a larger aspect)")


@dataclass(frozen=True)
class Smoke2D(FlowProblem):
    """A buoyant smoke plume: a source disc near the floor emits smoke at ``rate``; smoke pushes the fluid up with
    acceleration buoyancy * smoke. Walls left, right and at the bottom, an open (outflow) top."""

    NAME: ClassVar[str] = "smoke2d"
    # `pdestream generate smoke2d --n 4` on 2 shared CPU cores (load 3-4), no compilation cache (progress lines)
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 17.1, "unit_s": 1.62}
    EQUATION: ClassVar[str] = ("u_t + (u.grad)u = -grad p + nu lap u + b s e_y, div u = 0, s_t + u.grad s = "
                               "source; buoyant plume")
    FIELDS: ClassVar[tuple] = ("u", "v", "p", "smoke")
    FIELD_UNITS: ClassVar[dict] = {**FLOW_UNITS, "smoke": "1"}
    SIDES: ClassVar[tuple] = ("wall", "wall", "wall", "outflow")
    PARAMS: ClassVar[dict] = {
        "buoyancy": Param("buoyancy b per unit smoke", "m/s^2", positive=True),
        "sx": Param("source centre x", "m", positive=True),
        "radius": Param("source radius", "m", positive=True),
        "nu": Param("kinematic viscosity", "m^2/s", positive=True),
    }

    n: int = 32
    aspect: int = 1
    t_end: float = 3.0
    source_y: float = 0.2  # source centre height (m)
    rate: float = 2.0  # smoke emitted per second inside the source disc
    buoyancy: Any = "uniform(0.5, 1.5)"
    sx: Any = "uniform(0.3, 0.7)"
    radius: Any = "uniform(0.07, 0.12)"
    nu: Any = Fixed(2e-3)

    def flow_params(self, p: Mapping[str, jax.Array], key: jax.Array | None) -> Params:
        return Params(nu=p["nu"], buoyancy=p["buoyancy"], source=(p["sx"], self.source_y, p["radius"], self.rate))

    def speed_bound(self) -> float:
        # a plume of unit smoke rises at ~ sqrt(b L) (free fall over the box height against its own drag); the
        # advection stays stable above it, so this only sets the accuracy of the step
        return math.sqrt(_bounds(self, "buoyancy")[1] * self.length)

    def viscosity_range(self) -> tuple[float, float]:
        return _bounds(self, "nu")

    def check_flow(self) -> None:
        if not self.rate >= 0:
            raise ValueError(f"{self.NAME}: rate={self.rate:g} not allowed: must be >= 0")
        _check_disc(self, "source", _bounds(self, "sx"), (self.source_y, self.source_y), _bounds(self, "radius"),
                    inflow=False)


@dataclass(frozen=True)
class SmokeBox2D(FlowProblem):
    """Random smoke rising in a closed box (PDEArena's smoke set-up, Gupta & Brandstetter 2022; recipe
    ``pdearena_smoke2d``): walls on all four sides (zero normal velocity), no source, the fluid at rest at t = 0
    and the smoke a random field, by default |PhiFlow Noise| (``generator.flow.noise.SmokeNoise``: PDEArena's
    scale 11 and smoothness 6 on its 32 x 32 box are scale 11 / 32 on this unit box). Smoke pushes the fluid up
    with acceleration buoyancy * smoke and is carried by it (no diffusion): with no source and closed walls its
    total is conserved to the advection scheme's accuracy (tests/test_smoke_box.py measures the drift)."""

    NAME: ClassVar[str] = "smoke_box2d"
    # `pdestream generate smoke_box2d --n 4` on 2 shared CPU cores at load 11-12 (2026-11-28: the compile took most
    # of it; smoke2d's 17 s was at load 3-4), no compilation cache (progress history's record)
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 84.1, "unit_s": 0.61}
    EQUATION: ClassVar[str] = ("u_t + (u.grad)u = -grad p + nu lap u + b s e_y, div u = 0, s_t + u.grad s = 0; "
                               "closed box, random smoke")
    FIELDS: ClassVar[tuple] = ("u", "v", "p", "smoke")
    FIELD_UNITS: ClassVar[dict] = {**FLOW_UNITS, "smoke": "1"}
    SIDES: ClassVar[tuple] = ("wall", "wall", "wall", "wall")
    IC_KINDS: ClassVar[Mapping[str, type]] = {SmokeNoise.kind: SmokeNoise}
    PARAMS: ClassVar[dict] = {
        "buoyancy": Param("buoyancy b per unit smoke", "m/s^2", positive=True),
        "nu": Param("kinematic viscosity", "m^2/s", positive=True),
    }

    n: int = 32
    aspect: int = 1
    t_end: float = 3.0
    ic: Any = SmokeNoise(scale=11 / 32)
    buoyancy: Any = "uniform(0.5, 1.5)"
    nu: Any = Fixed(2e-3)

    def flow_params(self, p: Mapping[str, jax.Array], key: jax.Array | None) -> Params:
        return Params(nu=p["nu"], buoyancy=p["buoyancy"])

    def speed_bound(self) -> float:
        # smoke of order 1 (the noise has spatial std 1) rising over the box height: ~ sqrt(b L), as smoke2d's
        # plume (PDEArena's set, bound 4 m/s: its peaks were 3.7-4.1 m/s in PhiFlow, 4.1-4.3 in ours; docs/results/
        # recipes.md); the bound sets the step's accuracy and the blow-up check at 100x, nothing is clipped at it
        return math.sqrt(_bounds(self, "buoyancy")[1] * self.length)

    def viscosity_range(self) -> tuple[float, float]:
        return _bounds(self, "nu")


def _check_disc(problem: FlowProblem, what: str, xs, ys, rs, inflow: bool = True) -> None:
    """Refuse a disc domain that reaches outside the box, within CLEARANCE_CELLS of a wall (or of the inflow),
    or narrower than MIN_CELLS_ACROSS cells."""
    h, lx, ly = problem.h, problem.aspect * problem.length, problem.length
    gap = CLEARANCE_CELLS * h
    name = problem.NAME
    if 2 * rs[0] / h < MIN_CELLS_ACROSS:  # (named as channel2d names it; it said "a finer n or a larger radius")
        need = 2 * math.ceil(MIN_CELLS_ACROSS * problem.length / (2 * rs[0]) / 2)
        raise ValueError(f"{name}: radius={problem.radius} not allowed: a {what} {2 * rs[0] / h:.2g} cells across is "
                         f"below {MIN_CELLS_ACROSS:g} cells on this grid (h={h:.4g}); it needs n >= {need}, or radius "
                         f">= {MIN_CELLS_ACROSS * h / 2:.3g}")
    if not (xs[0] - rs[1] >= gap and xs[1] + rs[1] <= lx - gap):
        side = "blocks the inflow" if inflow and xs[0] - rs[1] < gap else "reaches outside the box"
        raise ValueError(f"{name}: the {what} {side}: x in [{xs[0]:g}, {xs[1]:g}] with radius up to {rs[1]:g} must "
                         f"stay within [{gap:.3g}, {lx - gap:.3g}] ({CLEARANCE_CELLS:g} cells from the sides)")
    if not (ys[0] - rs[1] >= gap and ys[1] + rs[1] <= ly - gap):
        raise ValueError(f"{name}: the {what} touches a wall or closes the channel: y in [{ys[0]:g}, {ys[1]:g}] with "
                         f"radius up to {rs[1]:g} must stay within [{gap:.3g}, {ly - gap:.3g}]")
