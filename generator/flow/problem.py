"""The incompressible-flow family: a ``generator.problem.Problem`` whose samples are rolled out by the MAC-grid
solver of this package (walls, inflow, outflow, obstacles, smoke).

A sample is u [T, C, nx, ny] float32 over FIELDS at ``times()`` (generator order: x first), one value per cell:
u on the cell's left face (x_i - h/2, y_j) and v on its bottom face (x_i, y_j - h/2) (m/s), the MAC grid's own
values (staggered, as PhiFlow's and jax-cfd's staggered grids store them), p the pressure over density of the
last projection at the centre (m^2/s^2), and per entry ``solid`` (1 in obstacle cells, 0 in fluid: the mask,
constant in time) or ``smoke`` (a passive density at the centre). The faces not stored (the right-most u, the
top v) are walls (zero), periodic copies, or follow from the discrete continuity of the last cell, so a frame
is the solver's whole state (``state_of``) and the solver can continue from any frame (the oracle). The box is ``aspect * n`` x ``n`` square cells on [0, aspect * length] x
[0, length]; each side is a wall, inflow, outflow or periodic (``SIDES``), and the grid states its per-axis
``bc`` (both sides walls: dirichlet; any open side: neumann; periodic) plus ``sides`` for the record.

Time: the flow starts at rest (inflow and lid switched on) and is advanced ``t_start`` (a warm-up, not recorded,
so that a vortex street has formed), then frames are recorded at ``times()`` = linspace(t_start, t_end,
n_frames). The step is one fixed dt per configuration (the CFL number ``cfl`` at the largest speed the parameter
domains allow, and the explicit viscous limit), so the compiled program never depends on a sample's parameters.

Identity: the key of (seed, index) splits into a parameter key (``resolve_params``) and a geometry key (random
obstacles, sources); each sample runs in a chunk of CHUNK rows (padded; ``generator.chunked``), set up one row
at a time and advanced vectorised over the chunk, so its bits are the same alone and in any batch, and the rollout advances in bounded
calls (``generator.dispatch``: a Ctrl-C or a gone consumer stops it between two).
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ...boundaries import DIRICHLET, NEUMANN, PERIODIC, is_periodic
from .. import dispatch
from ..chunked import join, split
from ..grids import GridBase
from ..problem import MAX_GRID_POINTS, MAX_STEPS, ProblemBase, check_refine, check_solve_grid, resolve_params
from . import interactive
from .grid import BODIES, OPEN_SIDES, SIDE_KINDS, Geometry, Params
from .pressure import MAX_COARSE_CELLS, coarsest_shape
from .step import ADVECTION, State, body_apertures, initial_state, operator, run, run_counted, solid_mask

CHUNK = 4  # samples per compiled call (a fixed program shape: a sample's bits never depend on its batch)
# Work of one flow step per cell, in the spectral family's point-steps (generator.dispatch): a projection's
# ~20 multigrid-preconditioned CG iterations cost ~200x a spectral point-step here (2-core CPU, 64x32 cells).
STEP_WORK_PER_CELL = 256
IC_KEY = 3  # fold_in(sample key, IC_KEY): a random initial smoke field's key (split(key) gives the other two)
BLOW_UP_FACTOR = 100.0  # a speed above this many times the largest inflow/lid speed counts as blown up


@dataclass(frozen=True)
class FlowGrid(GridBase):
    """``aspect * n`` x ``n`` (x ``n`` in 3D) square cells of side h = length / n on [0, aspect * length] x
    [0, length] (x [0, length]); sides (left, right, bottom, top, and in 3D down, up: the z ends) each one of
    SIDE_KINDS. ``shape`` is (nx, ny[, nz]), the generator's axis order."""

    POINTS: ClassVar[str] = "cell centres of a MAC grid (velocities averaged from the faces)"

    aspect: int = 1
    sides: tuple = ("wall", "wall", "wall", "wall")

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.aspect * self.n,) + (self.n,) * (self.ndim - 1)

    @property
    def bc(self) -> tuple[str, ...]:
        """Per axis (x, y[, z]): periodic; dirichlet where both sides are walls; neumann where a side is open."""
        return tuple((PERIODIC if is_periodic(lo) else DIRICHLET if lo == hi == "wall" else NEUMANN).value
                     for lo, hi in zip(self.sides[0::2], self.sides[1::2]))

    def coords(self, axis: int = 0) -> np.ndarray:
        """Cell-centre positions along ``axis`` (0: x, 1: y), float32 (length units)."""
        h = self.length / self.n
        return ((np.arange(self.shape[axis]) + 0.5) * h).astype(np.float32)

    def geometry(self) -> Geometry:
        """The solver's static geometry (its arrays are [y, x])."""
        nx, ny = self.shape
        return Geometry(nx, ny, self.aspect * self.length, self.length, *self.sides)

    def describe(self) -> str:
        named = ", ".join(f"{s}={k}" for s, k in zip(("left", "right", "bottom", "top", "down", "up"), self.sides))
        box = " x ".join(f"[0, {self.aspect * self.length if i == 0 else self.length:g}]" for i in range(self.ndim))
        return f"{'x'.join(map(str, self.shape))} cells on {box} ({named})"


@dataclass(frozen=True)
class AtRest:
    """The flow's initial condition: fluid at rest, inflow and lid on, no smoke (nothing random)."""

    kind = "rest"
    field_count = None

    def sample(self, key: jax.Array, grid, n_fields: int) -> jax.Array:
        """float32 [n_fields, *grid.shape] zeros (the velocity at rest; boundary values are the solver's)."""
        return jnp.zeros((n_fields, *grid.shape), jnp.float32)

    def check(self, grid) -> None:
        return None

    def bound(self, grid) -> float:
        return 0.0

    def __str__(self) -> str:
        return "fluid at rest (inflow and lid switched on at t = 0)"


@dataclass(frozen=True)
class FlowProblem(ProblemBase):
    """Base of the incompressible flows. A subclass sets SIDES, FIELDS, PARAMS and supplies ``flow_params``
    (the solver's traced Params of one sample), ``speed_bound`` and ``viscosity_bound`` (over the domains),
    and may check its own settings in ``check_flow``."""

    NDIM: ClassVar[int] = 2
    SIDES: ClassVar[tuple] = ("wall", "wall", "wall", "wall")  # left, right, bottom, top
    IC_KINDS: ClassVar[Mapping[str, type]] = {AtRest.kind: AtRest}
    FIELD_LOCATIONS: ClassVar[Mapping[str, str]] = {"u": "face_x", "v": "face_y", "p": "centre", "solid": "mask",
                                                    "smoke": "centre"}
    MIN_CELLS: ClassVar[int] = 8
    # cell Reynolds number u_max h / nu above which the grid does not resolve the flow (its boundary layers are
    # thinner than a cell); the advection stays stable there but the data would be numerical noise
    MAX_CELL_REYNOLDS: ClassVar[float] = 40.0
    PROJECTION: ClassVar[str] = "multigrid-CG projection"  # describe()'s words for the pressure solve
    BODY_NOUN: ClassVar[str] = "circle"  # describe()'s word for the bodies of an entry with a ``body`` setting
    OUTPUTS_NEED_KEY: ClassVar[bool] = False  # sample_outputs takes the sample's key (geometry not in its frames)

    n: int = 32  # cells across the box (y)
    aspect: int = 1  # nx = aspect * n
    length: float = 1.0  # box height (m)
    ic: Any = AtRest()
    t_start: float = 0.0  # warm-up before the first frame (s), not recorded
    t_end: float = 2.0  # last frame time (s)
    n_frames: int = 21
    cfl: float = 0.5  # u_max dt / h at the largest speed the domains allow
    tol: float = 1e-5  # pressure solve: relative residual
    max_iter: int = 100  # pressure solve: CG iterations per step at most
    advection: str = "maccormack"  # a key of generator.flow.step.ADVECTION: second order (Ghia and Schaefer-Turek
    # checks in benchmarks/flow_validation.py), ~8% slower per karman2d trajectory than "semi_lagrangian" (first order)
    refine: int = 1  # solve on n * refine cells per axis, store each refine x refine block's means (``restrict``)

    # --- what an entry provides --------------------------------------------------------------------
    @abc.abstractmethod
    def flow_params(self, p: Mapping[str, jax.Array], key: jax.Array | None) -> Params:
        """The solver's Params of one sample from its parameters p {name: traced scalar} and a geometry key
        (None: no random geometry; the oracle takes the obstacles from the frame instead)."""

    @abc.abstractmethod
    def speed_bound(self) -> float:
        """Largest boundary speed (inflow peak, lid) any sample can have (m/s): sets dt and the blow-up bound."""

    @abc.abstractmethod
    def viscosity_range(self) -> tuple[float, float]:
        """(smallest, largest) kinematic viscosity any sample can have (m^2/s)."""

    def check_flow(self) -> None:  # noqa: B027 (an optional hook)
        """Subclass hook: refuse settings of the entry's own geometry (obstacles, sources)."""

    def describe_geometry(self) -> str:
        """Subclass hook: describe()'s line on random geometry drawn per sample (obstacles), or ''."""
        return ""

    # --- the grid and the time window --------------------------------------------------------------
    @property
    def grid(self) -> FlowGrid:
        return FlowGrid(self.NDIM, self.n, self.length, self.aspect, self.SIDES)

    def geometry(self) -> Geometry:
        """The solver's static geometry: the grid's, with the entry's ``body`` setting where it has one (karman2d's
        circle, channel2d's obstacles). An entry without one runs 'staircase'."""
        g = self.grid.geometry()
        return Geometry(g.nx, g.ny, g.lx, g.ly, g.left, g.right, g.bottom, g.top, getattr(self, "body", "staircase"))

    @property
    def h(self) -> float:
        return self.length / self.n

    def config(self) -> dict:
        """``ProblemBase.config``; ``refine`` only above 1, so every cache and run written before it is unchanged."""
        out = super().config()
        if self.refine == 1:
            out.pop("refine", None)
        return out

    @functools.cached_property
    def solved(self) -> "FlowProblem":
        """The problem the solver runs: this one on n * refine cells per axis (refine 1: itself); its samples,
        each refine x refine block's means stored (``restrict``), are this problem's."""
        if self.refine == 1:
            return self
        return dataclasses.replace(self, n=self.n * self.refine, refine=1)

    def restrict(self, u: jax.Array) -> jax.Array:
        """Frames [..., C, nx * r, ny * r] of ``solved`` -> [..., C, nx, ny], r = refine: a centre field the mean of
        its r x r fine cells, u on a coarse cell's left face the mean of the r fine faces that tile it (v likewise
        on the bottom face). The face means are the fine fluxes through the coarse face, so a divergence-free fine
        field stays divergence-free on the coarse cells. The sums run in a fixed order of whole-array adds (the
        same bits in any batch)."""
        r = self.refine
        if r == 1:
            return u

        def mean(parts):
            total = parts[0]
            for part in parts[1:]:
                total = total + part
            return total / r

        fields = []
        for i, name in enumerate(self.FIELDS):
            f = u[..., i, :, :]
            where = self.FIELD_LOCATIONS[name]
            if where == "face_x":  # the coarse left faces lie on every r-th fine x-face
                fields.append(mean([f[..., ::r, j::r] for j in range(r)]))
            elif where == "face_y":
                fields.append(mean([f[..., i2::r, ::r] for i2 in range(r)]))
            else:  # a cell-centred field: the block's mean (rows of the block summed first, then the rows' means)
                fields.append(mean([mean([f[..., a::r, b::r] for b in range(r)]) for a in range(r)]))
        return jnp.stack(fields, axis=-3)

    def times(self) -> np.ndarray:
        """Frame times, float32 [n_frames] (s)."""
        return np.linspace(self.t_start, self.t_end, self.n_frames).astype(np.float32)

    def stable_dt(self) -> float:
        """Largest step (s): ``cfl`` h / u_max and the explicit viscous limit h^2 / (2 d nu_max), at the domains'
        extremes (both advection schemes are stable beyond CFL 1 but loses accuracy as h^2 / dt grows)."""
        if self.refine > 1:  # the solve grid's step
            return self.solved.stable_dt()
        return min(self.cfl * self.h / self.speed_bound(), 0.9 * self.h**2 / (2 * self.NDIM * self.viscosity_range()[1]))

    @property
    def frame_dt(self) -> float:
        return (self.t_end - self.t_start) / (self.n_frames - 1)

    @property
    def steps_per_frame(self) -> int:
        return max(1, math.ceil(self.frame_dt / self.stable_dt() * (1 - 1e-9)))

    @property
    def step_dt(self) -> float:
        return self.frame_dt / self.steps_per_frame

    @property
    def warmup_steps(self) -> int:
        """Steps of the warm-up (each t_start / warmup_steps <= stable_dt)."""
        return math.ceil(self.t_start / self.stable_dt() * (1 - 1e-9)) if self.t_start > 0 else 0

    # --- validation --------------------------------------------------------------------------------
    def validate(self) -> None:
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < self.MIN_CELLS or self.n % 2:
            raise ValueError(f"{self.NAME}: n={self.n!r} not allowed: cells across the box must be an even integer "
                             f">= {self.MIN_CELLS}")
        if not 1 <= self.aspect <= 16:
            raise ValueError(f"{self.NAME}: aspect={self.aspect} not allowed: the box is aspect * n x n cells with "
                             "aspect an integer in 1..16")
        self._check_length()
        # the grid's size before the multigrid's, whose search for a nearby n is linear in n (a huge n or refine hung)
        self._check_size()
        if self._check_refine():
            return  # the solve grid's problem held every check of the flow (``solved``)
        self._check_multigrid()
        if not 0 <= self.t_start < self.t_end:
            raise ValueError(f"{self.NAME}: t_start={self.t_start:g}, t_end={self.t_end:g} not allowed: need "
                             "0 <= t_start < t_end")
        if self.n_frames < 2:
            raise ValueError(f"{self.NAME}: n_frames={self.n_frames} not allowed: must be >= 2")
        if not 0 < self.cfl <= 2:
            raise ValueError(f"{self.NAME}: cfl={self.cfl:g} not allowed: the CFL number u_max dt / h must be in (0, 2]")
        if not 0 < self.tol < 1:
            raise ValueError(f"{self.NAME}: tol={self.tol:g} not allowed: the relative residual must be in (0, 1)")
        if not self.max_iter >= 1:
            raise ValueError(f"{self.NAME}: max_iter={self.max_iter} not allowed: must be an integer >= 1")
        if getattr(self, "body", BODIES[0]) not in BODIES:
            raise ValueError(f"{self.NAME}: body={self.body!r} not allowed: allowed are {', '.join(BODIES)}")
        if self.advection not in ADVECTION:
            raise ValueError(f"{self.NAME}: advection={self.advection!r} not allowed: allowed are "
                             f"{', '.join(sorted(ADVECTION))}")
        self._check_ic_on_grid()
        self.check_flow()
        nu_min = self.viscosity_range()[0]
        cell_re = self.speed_bound() * self.h / nu_min
        if not cell_re <= self.MAX_CELL_REYNOLDS:
            raise ValueError(f"{self.NAME}: the grid cannot resolve this flow: cell Reynolds number u_max h / nu = "
                             f"{self.speed_bound():g} * {self.h:.4g} / {nu_min:.3g} = {cell_re:.3g}; the limit is "
                             f"{self.MAX_CELL_REYNOLDS:g} (a finer grid n, or a smaller Reynolds number domain)")
        steps = self.warmup_steps + (self.n_frames - 1) * self.frame_dt / self.stable_dt()
        if not steps <= MAX_STEPS:
            raise ValueError(f"{self.NAME}: t_end={self.t_end:g} with step {self.stable_dt():.3g} would take ~{steps:.3g}"
                             f" steps per trajectory; the limit is {MAX_STEPS} (a shorter time window or a coarser grid)")

    def _check_refine(self) -> bool:
        """refine is an integer >= 1; above 1 only for a 2D entry without bodies (a coarse cell partly solid has no
        one mask or force), and the solve grid's problem must pass every check (its cell Reynolds number, steps,
        multigrid). Whether the solve grid was checked (refine > 1)."""
        check_refine(self, "1: solve on the n cells stored; k: solve on n * k cells per axis and store each k x k "
                           "block's means")
        r = self.refine
        if r == 1:
            return False
        if self.NDIM != 2 or "solid" in self.FIELDS or self.OUTPUTS:
            what = "3D flows" if self.NDIM != 2 else "entries with bodies or per-sample outputs (forces)"
            raise ValueError(f"{self.NAME}: refine={r} not allowed: {what} store their own grid's solve; allowed: "
                             f"refine=1 (or n={self.n * r} to solve and store the finer grid)")
        if math.prod(self.grid.shape) * r**2 <= MAX_GRID_POINTS:  # (a larger one: the solve grid's size refuses it)
            self._check_multigrid(r)  # named with the n that work at this refine (the solve grid's n would not)
        check_solve_grid(self, "cells across")
        return True

    def _check_multigrid(self, r: int = 1) -> None:
        """One line when n (solved on n * r cells across) leaves the pressure multigrid a coarsest level too large
        for its dense solve (generator.flow.pressure.MAX_COARSE_CELLS), naming the nearest n on either side that it
        accepts with this r."""
        def coarse_cells(n):
            return math.prod(coarsest_shape((self.aspect * n * r, n * r)))

        if coarse_cells(self.n) <= MAX_COARSE_CELLS:
            return
        below = next((n for n in range(self.n - 2, self.MIN_CELLS - 1, -2) if coarse_cells(n) <= MAX_COARSE_CELLS), None)
        above = next((n for n in range(self.n + 2, 4 * self.n, 2) if coarse_cells(n) <= MAX_COARSE_CELLS), None)
        coarse = "x".join(map(str, coarsest_shape((self.aspect * self.n * r, self.n * r))))
        grid = f"n={self.n}" if r == 1 else f"refine={r} with n={self.n} (solved on {self.n * r} cells across)"
        odd = r // (r & -r)  # what no halving removes: every n leaves at least aspect * odd^2 cells
        hint = (f"nearby n that halve further{f' with refine={r}' if r > 1 else ''}: "
                + " or ".join(str(n) for n in (below, above) if n is not None) if below or above else
                f"no n halves further with refine={r} (its odd factor {odd} leaves aspect * {odd}^2 cells or more); "
                "allowed: a refine with a smaller odd factor")
        raise ValueError(f"{self.NAME}: {grid} not allowed: the pressure multigrid halves the grid while both sides "
                         f"are even and stops at {coarse} = {coarse_cells(self.n)} cells, more than the "
                         f"{MAX_COARSE_CELLS} its dense coarse solve allows; {hint}")

    def describe_setup(self) -> str:
        if self.refine > 1:
            run, r = self.solved, self.refine
            return run.describe_setup().replace(
                f"grid: {run.grid.describe()}",
                f"grid: {self.grid.describe()}, solved on {'x'.join(map(str, run.grid.shape))} cells (each {r}x{r} "
                "block's means stored)", 1)
        start = "after a warm-up from rest" if self.t_start > 0 else "from rest"
        return (f"  fields: {', '.join(self.FIELDS)}   grid: {self.grid.describe()}\n"
                f"  t in [{self.t_start:g}, {self.t_end:g}] {start}, {self.n_frames} frames, "
                f"step {self.step_dt:.4g} s ({self.steps_per_frame}/frame, {self.describe_step_limit()}); MAC grid, {self.advection.replace('_', '-')} advection, {self.PROJECTION}"
                + (f", {self.body} {self.BODY_NOUN}" if hasattr(self, "body") else "")
                + (f"\n  {self.describe_geometry()}" if self.describe_geometry() else ""))

    def describe_step_limit(self) -> str:
        """What sets the step: the CFL number u_max dt / h the step has at the domains' fastest flow, and whether
        the ``cfl`` setting or the viscous limit h^2 / (4 nu_max) bound it (the frame spacing rounds it down)."""
        cfl = self.speed_bound() * self.step_dt / self.h
        viscous = 0.9 * self.h**2 / (2 * self.NDIM * self.viscosity_range()[1]) < self.cfl * self.h / self.speed_bound()
        bound = "the viscous limit" if viscous else f"cfl={self.cfl:g}"
        return f"CFL {cfl:.2g} at {self.speed_bound():g} m/s, set by {bound}"

    def failure(self) -> tuple[str, str]:
        return (f"flows blew up (NaN/Inf, or a speed above {BLOW_UP_FACTOR:g}x the largest boundary speed) with "
                f"step {self.step_dt:.4g} s, or a pressure solve stopped at max_iter={self.max_iter} above "
                f"tol={self.tol:g}", "a smaller cfl, a larger max_iter or a narrower parameter domain avoids this")

    # --- a sample ------------------------------------------------------------------------------------
    def frame_fields(self, geom: Geometry, state: State, fp: Params) -> jax.Array:
        """One frame [C, nx, ny] over FIELDS at cell centres from a solver state (arrays [y, x])."""
        cut = body_apertures(geom, fp, state.u.dtype)
        if cut is not None:  # faces a sharp body covers whole hold ghost values: stored as no flow (the solver
            # rebuilds them from the fluid before every use, so a frame still continues exactly)
            ax, ay = cut[:2]
            state = state._replace(u=jnp.where(ax > 0, state.u, 0.0), v=jnp.where(ay > 0, state.v, 0.0))
        made = {
            "u": lambda: state.u[:, :-1],
            "v": lambda: state.v[:-1],
            "p": lambda: state.p,
            "solid": lambda: solid_mask(geom, fp).astype(state.u.dtype),
            "smoke": lambda: state.smoke,
        }
        return jnp.stack([made[f]().T for f in self.FIELDS])

    def oracle_params(self, p: Mapping[str, jax.Array], frame: jax.Array) -> Params:
        """The solver's Params to continue from a frame [C, nx, ny]: the parameters' part, and the obstacles from
        the frame's own ``solid`` field (random geometry is not a parameter)."""
        fp = self.flow_params(p, None)
        if "solid" in self.FIELDS:
            fp = fp._replace(mask=frame[self.FIELDS.index("solid")].T > 0.5)
        return fp

    def sample_outputs(self, frames: jax.Array, p: Mapping[str, jax.Array]) -> dict[str, jax.Array]:
        """Subclass hook: the OUTPUTS of one sample, frames [T, C, nx, ny] and parameters p {name: scalar},
        traced: {name: array [*dims]} (an entry that declares OUTPUTS defines it; one whose outputs need the
        sample's key sets OUTPUTS_NEED_KEY and takes it as a third argument)."""
        raise NotImplementedError(f"{self.NAME} declares no per-sample outputs")

    def outputs(self, u: jax.Array, params: Mapping[str, jax.Array], keys: jax.Array | None = None
                ) -> dict[str, jax.Array]:
        """The OUTPUTS of samples u [B, T, C, nx, ny] (params {name: [B]}; keys [B]: the samples' keys, used where
        OUTPUTS_NEED_KEY) from ``sample_outputs`` of each sample in one compiled per-sample program inside
        jax.lax.map over chunks of CHUNK rows (padded), so a sample's outputs have the same bits alone and in any
        batch; {} where the entry declares none."""
        if not self.OUTPUTS:
            return {}
        cols = [jnp.asarray(params[name], jnp.float32) for name in self.PARAMS]
        if self.OUTPUTS_NEED_KEY:
            if keys is None:
                raise ValueError(f"{self.NAME}: the outputs of this setting need the samples' keys (its bodies are "
                                 "drawn from them): outputs(u, params, keys)")
            cols.append(jax.random.key_data(keys))
        parts = [_outputs_program(self)(*part) for part in split([jnp.asarray(u), *cols], CHUNK)]
        out = join(parts, int(u.shape[0]))
        return {name: out[name] for name in self.OUTPUTS}  # OUTPUTS order (a pytree's dict comes back sorted)

    def advance_frames(self, u: jax.Array, params: Mapping[str, jax.Array], frames: int):
        """Frames u [B, C, nx, ny] advanced ``frames`` frame intervals: (u_k, finite [B]) (generator.interactive)."""
        self._check_interactive()
        return interactive.advance(self, u, params, frames)

    def advance_frames_vjp(self, u: jax.Array, params: Mapping[str, jax.Array], frames: int, wrt_params: bool):
        """``advance_frames`` with its VJP (generator.interactive.advance_vjp's contract)."""
        self._check_interactive()
        return interactive.advance_vjp(self, u, params, frames, wrt_params)

    def _check_interactive(self) -> None:
        if self.refine > 1:  # a stored frame is a block mean of a finer state, not a state this grid's solver holds
            raise ValueError(f"{self.NAME}: refine={self.refine} not allowed here: the interactive modes step the "
                             "frames they are given on their own grid, and this problem's frames are block means of a "
                             f"grid {self.refine} times finer; allowed: refine=1 (n={self.n * self.refine} steps the "
                             "fine grid itself)")

    def state_of(self, frame: jax.Array, fp: Params) -> State:
        """The solver state of one frame [C, nx, ny] (the inverse of ``frame_fields``): the right-most u and top v
        faces rebuilt as walls (0), periodic copies, or from the last cells' discrete continuity (an open side)."""
        geom = self.geometry()
        field = {name: frame[i].T for i, name in enumerate(self.FIELDS)}  # [ny, nx]
        u, v = field["u"], field["v"]
        left, right, bottom, top = self.SIDES
        if right in OPEN_SIDES and top in OPEN_SIDES:
            raise ValueError(f"{self.NAME}: a box open on the right and the top has no unique corner state")
        v_top = v[:1] if is_periodic(top) else jnp.zeros_like(v[:1])  # an outflow top: set below
        if is_periodic(right):
            u_right = u[:, :1]
        elif right in OPEN_SIDES:  # continuity of the last column: u_R = u_L - (v_top - v_bottom)
            v_up = jnp.concatenate([v[1:, -1:], v_top[:, -1:]], 0)
            u_right = u[:, -1:] - (v_up - v[:, -1:])
        else:
            u_right = jnp.zeros_like(u[:, :1])
        u = jnp.concatenate([u, u_right], 1)
        if top in OPEN_SIDES:  # continuity of the top row: v_T = v_B - (u_right - u_left)
            v_top = v[-1:] - (u[-1:, 1:] - u[-1:, :-1])
        v = jnp.concatenate([v, v_top], 0)
        zero = jnp.zeros((geom.ny, geom.nx), frame.dtype)
        return State(u, v, field.get("p", zero), field.get("smoke", zero), jnp.zeros((), frame.dtype),
                     jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))

    def rollout(self, geom, state, fp, dt, n_steps: int):
        """``n_steps`` (static) steps of dt from a solver state: the oracle's and SolverStep's rollout
        (generator.flow.interactive; reverse-differentiable). A family member on another solver supplies its own."""
        return run(geom, state, fp, dt, n_steps, tol=self.tol, max_iter=self.max_iter, advection=self.advection)

    def programs(self):
        """(start, advance, frame): the compiled per-chunk programs run_keys calls (``_programs``: the 2D solver's;
        a family member on another solver supplies its own with the same signatures)."""
        return _programs(self, vectorise_chunks())

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """keys [B], explicit float32 [B, P], given bool [B, P] -> (u [B, T, C, nx, ny], params {name: [B]},
        ok bool [B] (finite, below the blow-up speed, every pressure solve within max_iter), None): the
        sampler's interface. With ``refine``: solved on the finer grid, blocks' means stored (``restrict``)."""
        if self.refine > 1:
            u, params, ok, _ = self.solved.run_keys(keys, explicit, given)
            return self.restrict(u), params, ok, None
        start, advance, frame = self.programs()
        speed_cap = BLOW_UP_FACTOR * self.speed_bound()
        cells = math.prod(self.grid.shape)
        per_step = CHUNK * cells * STEP_WORK_PER_CELL + dispatch.step_overhead()
        results = []
        parts = split([jnp.asarray(keys), jnp.asarray(explicit), jnp.asarray(given)], CHUNK)
        count = _Steps(len(parts) * (self.warmup_steps + (self.n_frames - 1) * self.steps_per_frame))
        for part in parts:
            p, fp, state, op = start(*part)
            state = _advance(advance, state, fp, op, self.t_start / max(self.warmup_steps, 1), self.warmup_steps,
                             per_step, count)
            frames = []
            for i in range(self.n_frames):
                frames.append(frame(state, fp))
                if i < self.n_frames - 1:
                    state = _advance(advance, state, fp, op, self.step_dt, self.steps_per_frame, per_step, count)
            u = jnp.stack(frames, axis=1)
            ok = jnp.all(jnp.isfinite(u), axis=tuple(range(1, u.ndim))) & jnp.all(
                jnp.abs(u[:, :, :self.NDIM]) <= speed_cap, axis=tuple(range(1, u.ndim))) & (state.capped == 0)
            results.append((u, p, ok))
        u, params, ok = join(results, int(keys.shape[0]))
        return u, params, ok, None


class _Steps:
    """Steps done of a solve's ``total`` (warm-up and frames of every chunk), reported after each call."""

    def __init__(self, total: int):
        self.done, self.total = 0, total

    def add(self, k: int) -> None:
        self.done += k
        dispatch.report(self.done, self.total)


def _advance(advance, state, fp, op, dt: float, n_steps: int, per_step: int, count: _Steps | None = None):
    """state advanced n_steps steps of dt in calls of at most ~DISPATCH_WORK point-steps (a sync between two),
    each call's steps added to ``count`` (progress)."""
    if n_steps == 0:
        return state
    for k in dispatch.pieces(n_steps, per_step):
        state = advance(state, fp, op, jnp.float32(dt), jnp.int32(k))
        dispatch.sync([(state.p,)])
        if count is not None:
            count.add(k)
    return state


@functools.lru_cache(maxsize=16)
def _outputs_program(problem: FlowProblem):
    """(u [K, T, C, nx, ny], *params [K]) -> {name: [K, *dims]}: ``sample_outputs`` one row at a time."""
    names = list(problem.PARAMS)

    def one(row):
        frames, *values = row
        if problem.OUTPUTS_NEED_KEY:
            *values, key = values
            out = problem.sample_outputs(frames, dict(zip(names, values)), jax.random.wrap_key_data(key))
        else:
            out = problem.sample_outputs(frames, dict(zip(names, values)))
        return {name: out[name].astype(spec.dtype) for name, spec in problem.OUTPUTS.items()}

    return jax.jit(lambda u, *cols: jax.lax.map(one, (u, *cols)))


def vectorise_chunks() -> bool:
    """Whether a chunk's rows advance as one vectorised program (``jax.vmap``: a GPU's batch) or one after another
    (``jax.lax.map``: on a CPU, where a vectorised chunk runs every row's pressure iterations until its slowest
    row converges and loses the scalar code's cache locality; docs/guides/flows.md has the measurement). Either
    way every chunk is one fixed program, so a row's bits do not depend on its batch; they differ between the two
    (as between devices)."""
    return jax.default_backend() != "cpu"


@functools.lru_cache(maxsize=16)
def _programs(problem: FlowProblem, vectorise: bool = True):
    """(start, advance, frame): compiled per-chunk programs, each sample the same unbatched program inside
    jax.lax.map. start: (keys [K], explicit [K, P], given [K, P]) -> (params {name: [K]}, Params [K], State [K],
    pressure Operator [K]); advance: (State, Params, Operator, dt, k) -> State k steps later; frame: (State, Params) -> [K, C, nx, ny]."""
    geom = problem.geometry()

    def start_one(key, explicit, given):
        k_param, k_geom = jax.random.split(key)
        p = resolve_params(problem, k_param, explicit, given)
        fp = problem.flow_params(p, k_geom)
        state = initial_state(geom, fp)
        if "smoke" in problem.FIELDS and not isinstance(problem.ic, AtRest):  # a random smoke field: its own key
            # (fold_in leaves the parameter and geometry keys, and so every at-rest sample's bits, as they were)
            frame0 = problem.ic.sample(jax.random.fold_in(key, IC_KEY), problem.grid, len(problem.FIELDS))
            state = state._replace(smoke=frame0[problem.FIELDS.index("smoke")].T)
        return p, fp, state, operator(geom, fp)

    start = jax.jit(lambda keys, ex, gv: jax.lax.map(lambda t: start_one(*t), (keys, ex, gv)))

    def advance_one(state, fp, op, dt, k):
        return run_counted(geom, state, fp, dt, k, op, tol=problem.tol, max_iter=problem.max_iter,
                           advection=problem.advection)

    # over the fixed chunk, vectorised or row by row (``vectorise_chunks``): every chunk has CHUNK rows (padded),
    # and a row's bits do not depend on its place or its chunk-mates (tests/test_flows.py); the step count k is
    # traced and shared by the rows, so one program serves every count
    if vectorise:
        advance = jax.jit(lambda states, fps, ops, dt, k: jax.vmap(advance_one, (0, 0, 0, None, None))(
            states, fps, ops, dt, k))
    else:
        advance = jax.jit(lambda states, fps, ops, dt, k: jax.lax.map(
            lambda t: advance_one(*t, dt, k), (states, fps, ops)))

    frame = jax.jit(lambda states, fps: jax.lax.map(lambda t: problem.frame_fields(geom, *t), (states, fps)))
    return start, advance, frame


__all__ = ["AtRest", "FlowGrid", "FlowProblem", "SIDE_KINDS"]
