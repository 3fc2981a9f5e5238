"""The 3D incompressible-flow entries, on the 3D MAC solver (``generator.flow.mac3d``) and the flow family's
sampling (``generator.flow.problem.FlowProblem``: chunks of CHUNK rows, bounded calls, the blow-up checks).

A 3D sample is u [T, C, nx, ny, nz] float32 over FIELDS, the solver's own staggered values as in 2D: u on the
cell's lower x face, v on its lower y face, w on its lower z face (m/s), p the pressure over density at the cell
centre (m^2/s^2) and the scalar at the centre; the faces not stored (the upper ends) are walls, so a frame is
the solver's whole state (``state_of``) and the solver continues from any frame.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

from pdestream.generator.lazy_jax import jax, jnp

from ..problem import Param, resolve_params
from . import mac3d
from .entries import CLEARANCE_CELLS, FLOW_UNITS, MIN_CELLS_ACROSS, _bounds
from .problem import FlowProblem


@dataclass(frozen=True)
class Plume3D(FlowProblem):
    """A 3D buoyant plume in a closed box (no-slip walls on all six sides, gravity along -z): a heater ball of
    ``radius`` centred at (sx, sy, ``source_z``) near the floor holds its scalar (temperature or smoke
    concentration) towards 1 at ``rate`` (ds/dt = rate (1 - s) inside it), and the scalar pushes the fluid up with
    acceleration buoyancy * s (Boussinesq). The scalar is advected without diffusion by a limited (clamped)
    scheme, so it stays in [0, 1]; the plume rises, spreads under the lid and overturns. Re = sqrt(b L) L / nu
    with L the box height, the buoyancy velocity sqrt(b L) the speed bound of the step."""

    NAME: ClassVar[str] = "plume3d"
    NDIM: ClassVar[int] = 3
    # `pdestream generate plume3d --n 4` on 2 shared CPU cores (load 6-7), no compilation cache (progress lines)
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 22.0, "unit_s": 23.9}
    EQUATION: ClassVar[str] = ("u_t + (u.grad)u = -grad p + nu lap u + b s e_z, div u = 0, s_t + u.grad s = "
                               "rate (1 - s) in the heater; 3D buoyant plume in a closed box")
    FIELDS: ClassVar[tuple] = ("u", "v", "w", "p", "smoke")
    FIELD_UNITS: ClassVar[dict] = {**FLOW_UNITS, "w": "m/s", "smoke": "1"}
    FIELD_LOCATIONS: ClassVar[Mapping[str, str]] = {**FlowProblem.FIELD_LOCATIONS, "w": "face_z"}
    SIDES: ClassVar[tuple] = ("wall",) * 6
    PROJECTION: ClassVar[str] = "direct (DCT) projection"
    UNUSED: ClassVar[frozenset] = frozenset({"tol", "max_iter"})  # the 2D pressure solve's: this one is direct
    PARAMS: ClassVar[dict] = {
        "nu": Param("kinematic viscosity", "m^2/s", positive=True),
        "buoyancy": Param("buoyancy b per unit scalar (along +z)", "m/s^2", positive=True),
        "rate": Param("heater strength: the scalar's relaxation rate to 1 inside the heater", "1/s", positive=True),
        "sx": Param("heater centre x", "m", positive=True),
        "sy": Param("heater centre y", "m", positive=True),
    }

    n: int = 24
    aspect: int = 1
    t_end: float = 3.0
    n_frames: int = 16
    source_z: float = 0.2  # heater centre height (m)
    radius: float = 0.1  # heater radius (m)
    nu: Any = "loguniform(0.002, 0.01)"
    buoyancy: Any = "uniform(0.5, 1.5)"
    rate: Any = "loguniform(2, 10)"
    sx: Any = "uniform(0.35, 0.65)"
    sy: Any = "uniform(0.35, 0.65)"

    def geometry(self) -> mac3d.Box:
        """The solver's static box (arrays [x, y, z])."""
        return mac3d.Box(self.grid.shape, self.h, (False,) * 3)

    def flow_params(self, p: Mapping[str, jax.Array], key: jax.Array | None) -> mac3d.Params3:
        return mac3d.Params3(nu=p["nu"], buoyancy=p["buoyancy"],
                             source=(p["sx"], p["sy"], self.source_z, self.radius, p["rate"]))

    def speed_bound(self) -> float:
        # a plume of unit scalar rises at ~ sqrt(b L) (smoke2d's estimate); this sets the step's accuracy only
        return math.sqrt(_bounds(self, "buoyancy")[1] * self.length)

    def viscosity_range(self) -> tuple[float, float]:
        return _bounds(self, "nu")

    def _check_multigrid(self) -> None:
        """Nothing to check: the projection is a direct transform solve, no multigrid levels."""

    def check_flow(self) -> None:
        if self.advection != "maccormack":
            raise ValueError(f"{self.NAME}: advection={self.advection!r} not allowed: the 3D solver advects by "
                             "maccormack only")
        h, gap, lx = self.h, CLEARANCE_CELLS * self.h, self.aspect * self.length
        if 2 * self.radius / h < MIN_CELLS_ACROSS:
            need = 2 * math.ceil(MIN_CELLS_ACROSS * self.length / (2 * self.radius) / 2)  # (as channel2d says it)
            raise ValueError(f"{self.NAME}: radius={self.radius:g} not allowed: a heater {2 * self.radius / h:.2g} "
                             f"cells across is below {MIN_CELLS_ACROSS:g} cells on this grid (h={h:.4g}); it needs n >= "
                             f"{need}, or radius >= {MIN_CELLS_ACROSS * h / 2:.3g}")
        for name, (lo, hi), top in (("sx", _bounds(self, "sx"), lx), ("sy", _bounds(self, "sy"), self.length),
                                    ("source_z", (self.source_z, self.source_z), self.length)):
            if not (lo - self.radius >= gap and hi + self.radius <= top - gap):
                raise ValueError(f"{self.NAME}: {name} in [{lo:g}, {hi:g}] with radius {self.radius:g} not allowed: "
                                 f"the heater must stay within [{gap:.3g}, {top - gap:.3g}] ({CLEARANCE_CELLS:g} "
                                 "cells from the walls)")
        rate_max = _bounds(self, "rate")[1]
        if not rate_max * self.step_dt <= 1:
            raise ValueError(f"{self.NAME}: rate up to {rate_max:g} not allowed with step {self.step_dt:.3g} s: "
                             "rate * step must be <= 1 (a smaller rate, or a finer grid)")

    def describe_geometry(self) -> str:
        return (f"heater: a ball of radius {self.radius:g} m at height {self.source_z:g} m, centre (sx, sy) drawn "
                "per sample")

    # --- a sample ------------------------------------------------------------------------------------
    def frame_fields(self, box: mac3d.Box, state: mac3d.State, fp: mac3d.Params3) -> jax.Array:
        """One frame [C, nx, ny, nz] over FIELDS from a solver state: each velocity on its lower faces."""
        u, v, w = state.vel
        made = {"u": u[:-1], "v": v[:, :-1], "w": w[:, :, :-1], "p": state.p, "smoke": state.scalar}
        return jnp.stack([made[f] for f in self.FIELDS])

    def state_of(self, frame: jax.Array, fp: mac3d.Params3) -> mac3d.State:
        """The solver state of one frame [C, nx, ny, nz] (``frame_fields``' inverse: the upper faces are walls)."""
        field = dict(zip(self.FIELDS, frame))
        vel = tuple(jnp.concatenate([field[c], jnp.zeros_like(jax.lax.slice_in_dim(field[c], 0, 1, axis=k))], k)
                    for k, c in enumerate("uvw"))
        zero = jnp.zeros((), jnp.int32)
        return mac3d.State(vel, field["p"], field["smoke"], jnp.zeros((), frame.dtype), zero, zero)

    def oracle_params(self, p: Mapping[str, jax.Array], frame: jax.Array) -> mac3d.Params3:
        return self.flow_params(p, None)

    def rollout(self, box: mac3d.Box, state: mac3d.State, fp: mac3d.Params3, dt, n_steps: int) -> mac3d.State:
        return mac3d.run(box, state, fp, dt, n_steps)

    def programs(self):
        return _programs(self)


@functools.lru_cache(maxsize=16)
def _programs(problem: Plume3D):
    """(start, advance, frame) with FlowProblem.run_keys's signatures (``problem._programs``); the operator slot
    carries nothing (the projection is a direct solve)."""
    box = problem.geometry()

    def start_one(key, explicit, given):
        k_param, k_geom = jax.random.split(key)
        p = resolve_params(problem, k_param, explicit, given)
        return p, problem.flow_params(p, k_geom), mac3d.initial_state(box), jnp.zeros((), jnp.float32)

    start = jax.jit(lambda keys, ex, gv: jax.lax.map(lambda t: start_one(*t), (keys, ex, gv)))
    # vectorised over the fixed chunk, as the 2D flows (a row's bits do not depend on its chunk-mates)
    advance = jax.jit(lambda states, fps, ops, dt, k: jax.vmap(
        lambda s, fp: mac3d.run_counted(box, s, fp, dt, k))(states, fps))
    frame = jax.jit(lambda states, fps: jax.lax.map(lambda t: problem.frame_fields(box, *t), (states, fps)))
    return start, advance, frame
