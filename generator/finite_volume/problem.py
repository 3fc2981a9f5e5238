"""The finite-volume family's one entry so far: ``euler1d``, 1D compressible Euler with shocks (a
``generator.problem.Problem``; the scheme is ``generator.finite_volume.euler``'s).

A sample is u [T, 3, n] float32 at ``times()``: the primitive fields rho, u, p at the cell centres (from the
solver's conserved cell averages), n cells of h = length / n on [0, length]. Both ends are ``bc``: outflow
(zero gradient), periodic or wall (reflective); one word for both, or two ("wall,outflow").

Time: one fixed step per configuration, dt = frame_dt / steps_per_frame <= cfl h / s0, with s0 the largest
|u| + c the initial condition's distribution allows (at the largest gamma), so the compiled program never depends
on a sample. Waves speed up after t = 0 (Sod: 2.19 behind the shock against 1.18 at t = 0); a sample whose own
CFL number max(|u| + c) dt / h passes MAX_CFL fails with that cause, as does one whose density or pressure goes
non-positive or non-finite: ``ok`` is False, the sampler raises BlowUpError, redraws or skips it (on_blowup) and
``failure_causes`` says which and when. A failed sample's state is held at its last good step (no NaN written).

Identity: the key of (seed, index) splits into a parameter key and an IC key; every sample runs the same
unbatched program inside ``jax.lax.map`` over a fixed chunk of CHUNK rows (padded, ``generator.chunked``), so its
bits are the same alone and in any batch; the steps run in bounded calls (``generator.dispatch``).
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import numpy as np

from pdestream.generator.lazy_jax import jax, jit, jnp

from ...boundaries import DIRICHLET, NEUMANN, PERIODIC, is_periodic
from .. import dispatch
from ..chunked import chunked_map, join, split
from ..domains import Fixed, parse_domain
from ..grids import GridBase
from ..ics import RandomSines
from ..problem import MAX_STEPS, Param, ProblemBase, resolve_params
from . import euler, navier_stokes, scheme, shallow_water
from .scheme import LIMITERS, SIDE_KINDS, Health

CHUNK = 4  # samples per compiled call (a fixed program shape: a sample's bits never depend on its batch)
MAX_CFL = 0.8  # a sample whose own CFL number passes this fails (the step no longer resolves its fastest wave)
STEP_WORK_PER_CELL = 32  # one RK3 step's work per cell in the spectral family's point-steps (generator.dispatch)


@dataclass(frozen=True)
class FVGrid(GridBase):
    """n cells of side h = length / n per axis on [0, length]^ndim; ``sides`` (low, high) per axis in axis order
    (x low, x high, y low, y high in 2D), each one of SIDE_KINDS."""

    POINTS: ClassVar[str] = "cell centres of a finite-volume grid (values from the cell averages)"

    sides: tuple = ("outflow", "outflow")

    @property
    def bc(self) -> tuple[str, ...]:
        """Per axis: periodic; dirichlet where both ends are walls (normal velocity 0 there); neumann where an end
        is open."""
        pairs = [self.sides[2 * i:2 * i + 2] for i in range(self.ndim)]
        return tuple((PERIODIC if is_periodic(lo) else DIRICHLET if lo == hi == "wall" else NEUMANN).value
                     for lo, hi in pairs)

    def coords(self, axis: int = 0) -> np.ndarray:
        """Cell-centre positions, float32 [n] (length units), the same on every axis."""
        return ((np.arange(self.n) + 0.5) * (self.length / self.n)).astype(np.float32)

    def describe(self) -> str:
        if self.ndim == 1:
            return f"{self.n} cells on [0, {self.length:g}] (left={self.sides[0]}, right={self.sides[1]})"
        return (f"{self.n}x{self.n} cells on [0, {self.length:g}]^2 (x: {self.sides[0]}, "
                f"y: {self.sides[2]})")


# --- initial conditions: primitive (rho, u, p) [3, n] at the cell centres -----------------------------------------
def _step_profile(grid, left, right, x0):
    """[3, n]: the left state (3 scalars) at cell centres x < x0, the right one elsewhere."""
    x = jnp.asarray(grid.coords())
    return jnp.where(x[None] < x0, jnp.stack(left)[:, None], jnp.stack(right)[:, None]).astype(jnp.float32)


def ic_domains(ic, names) -> dict:
    """{name: Domain} of an IC's domain-string settings; a bad one is refused naming it (ic.NAME=...)."""
    doms = {}
    for name in names:
        try:
            doms[name] = parse_domain(getattr(ic, name))
        except ValueError as err:
            raise ValueError(f"ic.{name}={getattr(ic, name)!r} not allowed: must be a finite number or a domain of "
                             f"finite numbers ({err})") from None
    return doms


@dataclass(frozen=True)
class Riemann:
    """A random Riemann problem: left and right states (rho, u, p) and the discontinuity position x0, each drawn
    from its domain (a domain string, as for parameters)."""

    rho_l: str = "uniform(0.2, 1)"
    u_l: str = "uniform(-0.5, 0.5)"
    p_l: str = "loguniform(0.1, 1)"
    rho_r: str = "uniform(0.2, 1)"
    u_r: str = "uniform(-0.5, 0.5)"
    p_r: str = "loguniform(0.1, 1)"
    x0: str = "uniform(0.3, 0.7)"
    kind = "riemann"
    field_count = 3
    NAMES: ClassVar[tuple] = ("rho_l", "u_l", "p_l", "rho_r", "u_r", "p_r", "x0")

    def domains(self) -> dict:
        """{name: Domain} of the seven settings; a bad one is refused naming it (ic.NAME=...)."""
        return ic_domains(self, self.NAMES)

    def sample(self, key: jax.Array, grid, n_fields: int = 3) -> jax.Array:
        v = [d.sample(jax.random.fold_in(key, j)) for j, d in enumerate(self.domains().values())]
        return _step_profile(grid, v[0:3], v[3:6], v[6])

    def check(self, grid) -> None:
        doms = self.domains()
        for name in ("rho_l", "p_l", "rho_r", "p_r"):
            if not min(doms[name].bounds) > 0:
                raise ValueError(f"ic.{name}={doms[name]} not allowed: densities and pressures must be > 0")
        lo, hi = doms["x0"].bounds
        if not 0 < lo <= hi < grid.length:
            raise ValueError(f"ic.x0={doms['x0']} not allowed: the discontinuity must lie in (0, {grid.length:g})")

    def bound(self, grid) -> float:
        return max(max(abs(b) for b in d.bounds) for d in self.domains().values())

    def speed(self, gamma: float) -> float:
        """Largest |u| + c of the initial states over the domains (c = sqrt(gamma p / rho))."""
        d = self.domains()
        return max(max(abs(b) for b in d[f"u_{s}"].bounds) + math.sqrt(gamma * max(d[f"p_{s}"].bounds)
                                                                        / min(d[f"rho_{s}"].bounds)) for s in "lr")

    def __str__(self) -> str:
        return ("Riemann problem: left (rho, u, p) = ({rho_l}, {u_l}, {p_l}), right ({rho_r}, {u_r}, {p_r}), "
                "jump at x0 = {x0}").format(**{n: getattr(self, n) for n in self.NAMES})


@dataclass(frozen=True)
class _Classic:
    """A named Riemann problem of fixed states (rho, u, p) left and right of x0 (nothing random)."""

    x0: float = 0.5
    field_count = 3
    LEFT: ClassVar[tuple] = ()
    RIGHT: ClassVar[tuple] = ()
    TITLE: ClassVar[str] = ""

    def sample(self, key: jax.Array, grid, n_fields: int = 3) -> jax.Array:
        return _step_profile(grid, [jnp.float32(v) for v in self.LEFT], [jnp.float32(v) for v in self.RIGHT],
                             jnp.float32(self.x0))

    def check(self, grid) -> None:
        if not 0 < self.x0 < grid.length:
            raise ValueError(f"ic.x0={self.x0:g} not allowed: the discontinuity must lie in (0, {grid.length:g})")

    def bound(self, grid) -> float:
        return max(map(abs, (*self.LEFT, *self.RIGHT)))

    def speed(self, gamma: float) -> float:
        return max(abs(u) + math.sqrt(gamma * p / r) for r, u, p in (self.LEFT, self.RIGHT))

    def __str__(self) -> str:
        return f"{self.TITLE}: left (rho, u, p) = {self.LEFT}, right {self.RIGHT}, jump at x0 = {self.x0:g}"


@dataclass(frozen=True)
class Sod(_Classic):
    kind = "sod"
    LEFT: ClassVar[tuple] = (1.0, 0.0, 1.0)
    RIGHT: ClassVar[tuple] = (0.125, 0.0, 0.1)
    TITLE: ClassVar[str] = "Sod's shock tube (compare at t = 0.2)"


@dataclass(frozen=True)
class Lax(_Classic):
    kind = "lax"
    LEFT: ClassVar[tuple] = (0.445, 0.698, 3.528)
    RIGHT: ClassVar[tuple] = (0.5, 0.0, 0.571)
    TITLE: ClassVar[str] = "Lax's shock tube (compare at t = 0.14)"


@dataclass(frozen=True)
class Toro123(_Classic):
    kind = "123"
    LEFT: ClassVar[tuple] = (1.0, -2.0, 0.4)
    RIGHT: ClassVar[tuple] = (1.0, 2.0, 0.4)
    TITLE: ClassVar[str] = "Toro's test 2, two strong rarefactions (compare at t = 0.15)"


@dataclass(frozen=True)
class Smooth:
    """A random smooth periodic state: rho = 1 + amplitude f1, u = amplitude f2, p = 1 + amplitude f3, each f a
    random Fourier series of modes 1..max_mode on [0, length) scaled to max |f| = 1."""

    amplitude: float = 0.2
    max_mode: int = 3
    kind = "smooth"
    field_count = 3

    def sample(self, key: jax.Array, grid, n_fields: int = 3) -> jax.Array:
        x = jnp.asarray(grid.coords()) * (2 * np.pi / grid.length)
        m = jnp.arange(1, self.max_mode + 1, dtype=jnp.float32)
        a, b = jax.random.normal(key, (2, 3, self.max_mode), jnp.float32) / m
        f = a @ jnp.cos(m[:, None] * x) + b @ jnp.sin(m[:, None] * x)  # [3, n]
        f = f / jnp.max(jnp.abs(f), axis=1, keepdims=True)
        return jnp.array([1.0, 0.0, 1.0], jnp.float32)[:, None] + self.amplitude * f

    def check(self, grid) -> None:
        if not 0 < self.amplitude < 1:
            raise ValueError(f"ic.amplitude={self.amplitude:g} not allowed: must be in (0, 1) (density and "
                             "pressure stay positive)")
        if not 1 <= self.max_mode <= grid.n // 8:
            raise ValueError(f"ic.max_mode={self.max_mode} not allowed on n={grid.n}: need 1 <= max_mode <= n//8 = "
                             f"{grid.n // 8}")

    def bound(self, grid) -> float:
        return 1 + self.amplitude

    def speed(self, gamma: float) -> float:
        return self.amplitude + math.sqrt(gamma * (1 + self.amplitude) / (1 - self.amplitude))

    def __str__(self) -> str:
        return f"smooth periodic state, amplitude {self.amplitude:g} about (1, 0, 1), modes 1..{self.max_mode}"


@dataclass(frozen=True)
class SineStates:
    """A random gas state of sines, PDEBench's 1D compressible measure (its ``init_multi_HD``, mode 1D_rand): rho,
    u and p each an independent ``RandomSines`` shape s (modes 1..max_mode, n_modes of them drawn, |s| with
    probability abs_prob, a random sign) times, with probability window_prob, the window
    0.5 (tanh((x - x_l) / w) - tanh((x - x_r) / w)), x_l ~ window_left, x_r ~ window_right, w = window_width (all
    fractions of the length); then rho = rho_scale (s - min s) / (max s - min s) + rho_base, p likewise with
    p_scale and p_base (each scale and base drawn per sample from its domain), u = u_scale s."""

    max_mode: int = 3
    n_modes: int = 2
    abs_prob: float = 0.1
    window_prob: float = 0.5
    window_left: str = "uniform(0.55, 0.725)"
    window_right: str = "uniform(0.775, 0.95)"
    window_width: float = 0.005
    rho_scale: str = "loguniform(1, 10)"
    rho_base: str = "loguniform(1, 10)"
    p_scale: str = "loguniform(10, 100)"
    p_base: str = "loguniform(10, 100)"
    u_scale: float = 1.0
    kind = "sines"
    field_count = 3
    DRAWN: ClassVar[tuple] = ("window_left", "window_right", "rho_scale", "rho_base", "p_scale", "p_base")

    def domains(self) -> dict:
        """{name: Domain} of the drawn settings; a bad one is refused naming it (ic.NAME=...)."""
        return ic_domains(self, self.DRAWN)

    def _shape(self) -> RandomSines:
        return RandomSines(max_mode=self.max_mode, n_modes=self.n_modes, abs_prob=self.abs_prob, window_prob=0.0)

    def sample(self, key: jax.Array, grid, n_fields: int = 3) -> jax.Array:
        x = jnp.asarray(grid.coords(), jnp.float32)
        d = self.domains()
        fields = []
        for f in range(3):  # rho, u, p
            k_field = jax.random.fold_in(key, f)
            s = self._shape()._one(k_field, x, grid.length)
            k_win, k_l, k_r, k_scale, k_base = jax.random.split(jax.random.fold_in(k_field, 1), 5)
            x_l = grid.length * d["window_left"].sample(k_l)
            x_r = grid.length * d["window_right"].sample(k_r)
            w = self.window_width * grid.length
            window = 0.5 * (jnp.tanh((x - x_l) / w) - jnp.tanh((x - x_r) / w))
            s = jnp.where(jax.random.uniform(k_win) < self.window_prob, s * window, s)
            if f == 1:
                fields.append(self.u_scale * s)
                continue
            name = "rho" if f == 0 else "p"
            s = s - jnp.min(s)
            s = s / jnp.maximum(jnp.max(s), jnp.finfo(jnp.float32).tiny)
            fields.append(d[f"{name}_scale"].sample(k_scale) * s + d[f"{name}_base"].sample(k_base))
        return jnp.stack(fields).astype(jnp.float32)

    def check(self, grid) -> None:
        self._shape().check(type("_Open", (), {"ndim": 1, "n": grid.n, "bc": ("periodic",)})())
        d = self.domains()
        for name in ("window_left", "window_right"):
            lo, hi = d[name].bounds
            if not 0 <= lo <= hi <= 1:
                raise ValueError(f"ic.{name}={d[name]} not allowed: a fraction of the length, in [0, 1]")
        if not self.window_width > 0:
            raise ValueError(f"ic.window_width={self.window_width} not allowed: must be > 0 (a fraction of the length)")
        for name in ("rho_scale", "rho_base", "p_scale", "p_base"):
            if not min(d[name].bounds) > 0:
                raise ValueError(f"ic.{name}={d[name]} not allowed: density and pressure scales and bases must be > 0")
        if not (math.isfinite(self.u_scale) and self.u_scale >= 0):
            raise ValueError(f"ic.u_scale={self.u_scale} not allowed: must be a finite number >= 0")

    def bound(self, grid) -> float:
        d = self.domains()
        top = [max(d[f"{n}_scale"].bounds) + max(d[f"{n}_base"].bounds) for n in ("rho", "p")]
        return max(*top, self.u_scale * self.max_mode)

    def speed(self, gamma: float) -> float:
        """Largest |u| + c the distribution allows: |u| <= u_scale max_mode, c <= sqrt(gamma p_max / rho_min)."""
        d = self.domains()
        p_max = max(d["p_scale"].bounds) + max(d["p_base"].bounds)
        return self.u_scale * self.max_mode + math.sqrt(gamma * p_max / min(d["rho_base"].bounds))

    def __str__(self) -> str:
        return (f"PDEBench's random sines: modes 1..{self.max_mode} ({self.n_modes} drawn) per field, |.| p="
                f"{self.abs_prob:g}, window p={self.window_prob:g}; rho in [{self.rho_base}, + {self.rho_scale}], "
                f"p in [{self.p_base}, + {self.p_scale}], u x {self.u_scale:g}")


IC_KINDS: dict[str, type] = {c.kind: c for c in (Riemann, Sod, Lax, Toro123, Smooth, SineStates)}

_LAST = threading.local()  # the causes of this thread's last run_keys (failure_causes)


@dataclass(frozen=True, eq=False)  # hashed by identity: a static argument of the compiled programs
class Scheme:
    """One solver of the family as the problems use it: ``run(q, health, phys, dt, k, h, sides, limiter,
    cfl_limit)`` (a module's guarded stepping loop), ``to_state(w, phys)`` stored fields -> conserved state,
    ``to_output(q, phys)`` the reverse, ``causes`` {health code: words}; phys [P] holds the entry's physical
    parameters (``FiniteVolume.PHYS``, in that order)."""

    run: Callable
    to_state: Callable
    to_output: Callable
    causes: Mapping


def _on_first(run, to_state, to_output, causes) -> Scheme:
    """A Scheme of a module whose functions take one physical scalar (phys[0]) where the family passes phys [P]."""
    return Scheme(lambda q, hl, ph, *rest: run(q, hl, ph[0], *rest), lambda w, ph: to_state(w, ph[0]),
                  lambda q, ph: to_output(q, ph[0]), causes)


def _same(q, phys):
    return q


EULER_1D = _on_first(euler.run, euler.to_conserved, euler.to_primitive, euler.CAUSES)
EULER_2D = _on_first(euler.run_2d, euler.to_conserved_2d, euler.to_primitive_2d, euler.CAUSES)
SHALLOW_WATER = _on_first(shallow_water.run, _same, _same, shallow_water.CAUSES)
NAVIER_STOKES_1D = Scheme(navier_stokes.run, navier_stokes.to_conserved, navier_stokes.to_primitive,
                          navier_stokes.CAUSES)
NAVIER_STOKES_2D = Scheme(navier_stokes.run_2d, navier_stokes.to_conserved_2d, navier_stokes.to_primitive_2d,
                          navier_stokes.CAUSES)


class UniformFrames:
    """The family's uniform grid and frames from its settings n, length, t_end, n_frames: the cell size ``h``,
    ``times()`` (float32 [n_frames], 0 .. t_end) and ``frame_dt``."""

    @property
    def h(self) -> float:
        return self.length / self.n

    def times(self) -> np.ndarray:
        """Frame times, float32 [n_frames]."""
        return np.linspace(0.0, self.t_end, self.n_frames).astype(np.float32)

    @property
    def frame_dt(self) -> float:
        return self.t_end / (self.n_frames - 1)


def viscous_steps_per_frame(problem) -> int:
    """Steps of one frame interval of a viscous entry: dt (NDIM s0 / h + 2 nu / h^2) <= cfl, with s0 and nu =
    ``problem.nu_max()`` (the diffusion coefficients summed over the axes) at their largest."""
    h = problem.h
    bound = problem.frame_dt * (problem.NDIM * problem.speed_bound() / h + 2 * problem.nu_max() / h**2) / problem.cfl
    return max(1, math.ceil(bound * (1 - 1e-9)))


@dataclass(frozen=True)
class FiniteVolume(UniformFrames, ProblemBase):
    """What every entry of the family shares: the fixed step, the chunked batch-invariant rollout, the failure
    causes, the interactive oracle and its VJP. A subclass declares SCHEME, PHYS (its physical parameters' names),
    MAX_CFL and the settings n, length, ic, t_end, n_frames, bc, cfl, limiter; ``sides`` (the side kinds, 2 per
    axis), ``speed_bound`` and ``grid`` come from it too."""

    SCHEME: ClassVar[Scheme] = EULER_1D
    PHYS: ClassVar[tuple[str, ...]] = ("gamma",)  # the parameters the scheme reads, in its order (phys [P])
    MAX_CFL: ClassVar[float] = MAX_CFL
    FAILURE_WORDS: ClassVar[str] = "a non-positive density or pressure, a NaN/Inf"

    # --- settings ------------------------------------------------------------------------------------
    @property
    def steps_per_frame(self) -> int:
        """Steps of one frame interval: dt NDIM s0 / h <= cfl (in 2D the CFL number sums both axes' speeds)."""
        bound = self.frame_dt * self.NDIM * self.speed_bound() / (self.cfl * self.h)
        return max(1, math.ceil(bound * (1 - 1e-9)))

    @property
    def step_dt(self) -> float:
        return self.frame_dt / self.steps_per_frame

    def _validate_common(self, n_min: int) -> None:
        """The checks every entry makes (bc is the subclass's: its grammar differs by dimension)."""
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < n_min:
            raise ValueError(f"{self.NAME}: n={self.n!r} not allowed: cells must be an integer >= {n_min}")
        self._check_length()
        if not (self.t_end > 0 and math.isfinite(self.t_end)):
            raise ValueError(f"{self.NAME}: t_end={self.t_end} not allowed: must be a finite number > 0")
        if self.n_frames < 2:
            raise ValueError(f"{self.NAME}: n_frames={self.n_frames} not allowed: need an integer >= 2 (t=0 and t_end)")
        if not 0 < self.cfl <= self.MAX_CFL:
            raise ValueError(f"{self.NAME}: cfl={self.cfl:g} not allowed: must be in (0, {self.MAX_CFL:g}]")
        if self.limiter not in LIMITERS:
            raise ValueError(f"{self.NAME}: limiter={self.limiter!r} not allowed; allowed: {', '.join(LIMITERS)}")

    def _validate_size(self) -> None:
        if getattr(self.ic, "field_count", None) != len(self.FIELDS):
            raise ValueError(f"{self.NAME}: ic={self.ic.kind!r} not allowed; allowed: {', '.join(self.IC_KINDS)}")
        self._check_size()
        self._check_ic_on_grid()
        steps = (self.n_frames - 1) * self.steps_per_frame
        if not steps <= MAX_STEPS:
            raise ValueError(self._too_many_steps(steps))

    def _too_many_steps(self, steps: int) -> str:
        """The one line refusing a trajectory of ``steps`` > MAX_STEPS steps."""
        return (f"{self.NAME}: t_end={self.t_end:g} would take ~{steps:.3g} steps per trajectory; the limit is "
                f"{MAX_STEPS} (a shorter time window or a coarser grid)")

    def _step_words(self) -> str:
        return (f"t in [0, {self.t_end:g}], {self.n_frames} frames, step {self.step_dt:.4g} ({self.steps_per_frame}/"
                f"frame, CFL {self.cfl:g} at the initial speed bound {self.speed_bound():.3g})")

    def failure(self) -> tuple[str, str]:
        return (f"trajectories failed ({self.FAILURE_WORDS}, or a CFL number above {self.MAX_CFL:g} with step "
                f"{self.step_dt:.4g})", "a smaller cfl, a finer grid or a narrower ic domain avoids this")

    def failure_causes(self) -> list[str]:
        return list(getattr(_LAST, "causes", ()))

    # --- solving ---------------------------------------------------------------------------------------
    def consts(self, dtype=np.float32) -> tuple:
        """The stepping program's traced settings: (dt, h, sides int32 [2 NDIM], limiter int32)."""
        return (jnp.asarray(self.step_dt, dtype), jnp.asarray(self.h, dtype),
                jnp.asarray([SIDE_KINDS.index(s) for s in self.sides], jnp.int32),
                jnp.int32(LIMITERS.index(self.limiter)))

    def _causes(self, health: Health) -> list[str]:
        code, step, cfl = (np.asarray(a) for a in (health.code, health.step, health.cfl))
        return ["" if c == scheme.OK else f"{self.SCHEME.causes[int(c)]} at t = {s * self.step_dt:.4g}"
                + (f" (CFL {v:.3g})" if c == scheme.CFL_EXCEEDED else "") for c, s, v in zip(code, step, cfl)]

    def _rollout(self, q, hl, phys, count):
        """One chunk from its initial state: (u [K, T, C, *grid], health)."""
        consts, sch = self.consts(), self.SCHEME
        frames = [_frame(sch, q, phys)]
        per_step = CHUNK * self.n**self.NDIM * STEP_WORK_PER_CELL + dispatch.step_overhead()
        for _ in range(self.n_frames - 1):
            for k in dispatch.pieces(self.steps_per_frame, per_step):
                q, hl = _advance(sch, self.MAX_CFL, q, hl, phys, *consts, jnp.int32(k))
                dispatch.sync([(q,)])
                count[0] += k
                dispatch.report(count[0], count[1])
            frames.append(_frame(sch, q, phys))
        return jnp.stack(frames, axis=1), hl

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """keys [B], explicit float32 [B, P], given bool [B, P] -> (u [B, T, C, *grid], params {name: [B]}, ok
        bool [B], None); why a sample failed in ``failure_causes()``."""
        start = _start(self)
        parts = split([jnp.asarray(keys), jnp.asarray(explicit), jnp.asarray(given)], CHUNK)
        count = [0, len(parts) * (self.n_frames - 1) * self.steps_per_frame]
        results = []
        for part in parts:
            p, q, hl = start(*part)
            results.append((*self._rollout(q, hl, _phys(self, p), count), p))
        u, health, params = join(results, int(keys.shape[0]))
        _LAST.causes = self._causes(health)
        return u, params, health.code == scheme.OK, None

    def evolve(self, u0: jax.Array, p: Mapping[str, jax.Array]):
        """A caller's states u0 [B, C, *grid] (the stored fields), params {name: [B]} -> (u [B, T, C, *grid],
        ok [B])."""
        phys = jnp.broadcast_to(_phys(self, p, jnp.float32), (u0.shape[0], len(self.PHYS)))
        parts = split([jnp.asarray(u0, jnp.float32), phys], CHUNK)
        count = [0, len(parts) * (self.n_frames - 1) * self.steps_per_frame]
        results = []
        for w, g in parts:
            q, hl = _conserved(self.SCHEME, w, g)
            results.append(self._rollout(q, hl, g, count))
        u, health = join(results, u0.shape[0])
        _LAST.causes = self._causes(health)
        return u, health.code == scheme.OK

    def advance_frames(self, u: jax.Array, params: Mapping[str, jax.Array], frames: int):
        """Frames u [B, C, *grid] advanced ``frames`` frame intervals: (u_k, ok [B]) (generator.interactive): the
        sampler's step sequence, so frame i advanced once is frame i + 1 to the rounding of the conversion
        round trip (bit for bit where the stored fields are the conserved ones)."""
        phys = jnp.broadcast_to(_phys(self, params, u.dtype), (u.shape[0], len(self.PHYS)))
        consts = self.consts(u.dtype)
        k = jnp.int32(frames * self.steps_per_frame)
        return chunked_map(lambda w, g: _oracle(self.SCHEME, self.MAX_CFL, w, g, *consts, k), CHUNK, u, phys)

    def advance_frames_vjp(self, u: jax.Array, params: Mapping[str, jax.Array], frames: int, wrt_params: bool):
        """``advance_frames`` with its VJP: (u_k, ok, vjp); vjp(g) -> (g_u, g_params or None). A vmapped scan of
        the same steps, equal to ``advance_frames`` to rounding."""
        phys = jnp.broadcast_to(_phys(self, params, u.dtype), (u.shape[0], len(self.PHYS)))
        go = _oracle_vjp(self.SCHEME, self.MAX_CFL, frames * self.steps_per_frame, wrt_params)
        out, ok, vjp = go(u, phys, *self.consts(u.dtype))

        def back(g):
            got = _apply(vjp, jnp.asarray(g, out.dtype))
            return (got[0], {name: got[1][:, j] for j, name in enumerate(self.PHYS)}) if wrt_params else (got[0], None)

        return out, ok, back


@dataclass(frozen=True)
class Euler1D(FiniteVolume):
    """1D compressible Euler of an ideal gas; dimensionless (length, time and density units of the IC)."""

    NAME: ClassVar[str] = "euler1d"
    EQUATION: ClassVar[str] = ("rho_t + (rho u)_x = 0, (rho u)_t + (rho u^2 + p)_x = 0, E_t + ((E + p) u)_x = 0, "
                               "E = p / (gamma - 1) + rho u^2 / 2; stored: primitive rho, u, p")
    FIELDS: ClassVar[tuple] = ("rho", "u", "p")
    FIELD_UNITS: ClassVar[dict] = {"rho": "mass/length^3", "u": "length/time", "p": "mass/(length time^2)"}
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict] = {"gamma": Param("ratio of specific heats (ideal gas)", "1", positive=True)}
    IC_KINDS: ClassVar[Mapping[str, type]] = IC_KINDS
    BOUNDARIES: ClassVar[tuple] = SIDE_KINDS  # what `--set bc=` takes: one word, or two (left,right)

    n: int = 256  # cells
    length: float = 1.0
    ic: Any = Riemann()
    t_end: float = 0.2
    n_frames: int = 21
    bc: str = "outflow"  # one of SIDE_KINDS for both ends, or "left,right" (e.g. "wall,outflow")
    cfl: float = 0.4  # s0 dt / h at the initial condition's largest speed s0
    limiter: str = "minmod"  # MUSCL slope limiter: one of LIMITERS
    gamma: Any = Fixed(1.4)

    def replace(self, overrides: Mapping[str, Any] | None = None, **kwargs) -> "Euler1D":
        """``ProblemBase.replace``; ``bc.x`` is ``bc`` (the one axis)."""
        changes = {("bc" if k == "bc.x" else k): v for k, v in {**(overrides or {}), **kwargs}.items()}
        return super().replace(changes)

    @property
    def sides(self) -> tuple[str, str]:
        words = [w.strip().lower() for w in self.bc.split(",")]
        return (words[0], words[0]) if len(words) == 1 else tuple(words)

    @property
    def grid(self) -> FVGrid:
        return FVGrid(1, self.n, self.length, self.sides)

    def speed_bound(self) -> float:
        """Largest |u| + c of the initial states the IC distribution allows, at the largest gamma."""
        return self.ic.speed(max(self.gamma.bounds))

    def validate(self) -> None:
        self._validate_common(16)
        sides = [w.strip().lower() for w in self.bc.split(",")]
        if len(sides) > 2 or any(w not in SIDE_KINDS for w in sides):
            raise ValueError(f"{self.NAME}: bc={self.bc!r} not allowed; allowed: {', '.join(SIDE_KINDS)}, one for "
                             "both ends or two as left,right (e.g. wall,outflow)")
        if len(sides) == 2 and is_periodic(sides[0]) != is_periodic(sides[1]):
            raise ValueError(f"{self.NAME}: bc={self.bc!r} not allowed: periodic ends come in pairs")
        check_gamma(self.NAME, self.gamma)
        self._validate_size()

    def describe_setup(self) -> str:
        return (f"  fields: {', '.join(self.FIELDS)} (primitive)   grid: {self.grid.describe()}\n"
                f"  {self._step_words()}; finite volumes: MUSCL ({self.limiter}) on (rho, u, p), HLLC, SSP-RK3")


def _phys(problem: FiniteVolume, params: Mapping[str, jax.Array], dtype=None) -> jax.Array:
    """The scheme's physical parameters stacked last: [..., P] in ``problem.PHYS`` order (scalars and [B] arrays
    broadcast together)."""
    return jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(params[name], dtype) for name in problem.PHYS)), axis=-1)


# The compressible Navier-Stokes entries' parameters (1D and 2D)
VISCOUS_GAS_PARAMS: dict[str, Param] = {
    "gamma": Param("ratio of specific heats (ideal gas)", "1", positive=True),
    "eta": Param("shear viscosity, kinematic (the dynamic one is rho eta)", "length^2/time"),
    "zeta": Param("bulk viscosity, kinematic (the dynamic one is rho zeta)", "length^2/time")}


GAMMA_MAX = 3.0  # gamma = 1 + 2 / f for f >= 1 degrees of freedom: a monatomic gas 5/3, a 1D gas 3


def check_gamma(name: str, gamma) -> None:
    """Refuse a ratio of specific heats outside (1, 3] (an ideal gas with at least one degree of freedom), in one line."""
    lo, hi = min(gamma.bounds), max(gamma.bounds)
    if not (lo > 1 and hi <= GAMMA_MAX):
        raise ValueError(f"{name}: gamma={gamma} not allowed: the ratio of specific heats of an ideal gas lies in "
                         f"(1, {GAMMA_MAX:g}] (1 + 2 / degrees of freedom: air 1.4, a monatomic gas 5/3)")


def check_viscosities(problem) -> None:
    """Refuses, in one line, an eta or zeta domain that is not finite and >= 0."""
    for name in ("eta", "zeta"):
        lo, hi = getattr(problem, name).bounds
        if not (0 <= lo and math.isfinite(hi)):
            raise ValueError(f"{problem.NAME}: {name}={getattr(problem, name)} not allowed: a viscosity must be a "
                             "finite number >= 0")


@dataclass(frozen=True)
class ViscousGas:
    """What the compressible Navier-Stokes entries (1D, 2D) add to their Euler entry: the viscosities eta, zeta as
    parameters beside gamma (PDEBench's values as defaults: gamma 5/3, eta = zeta = 0.01), periodic sides and the mc
    limiter by default, the step's viscous limit and the viscosities' checks. Listed before the Euler class in the
    bases, so its defaults and ``validate`` come first; the entry states ``nu_max`` (its diffusion coefficients
    summed over the axes)."""

    PARAMS: ClassVar[dict] = VISCOUS_GAS_PARAMS
    PHYS: ClassVar[tuple[str, ...]] = ("gamma", "eta", "zeta")

    bc: str = "periodic"
    limiter: str = "mc"
    gamma: Any = Fixed(5.0 / 3.0)
    eta: Any = Fixed(0.01)
    zeta: Any = Fixed(0.01)

    @property
    def steps_per_frame(self) -> int:
        """Steps of one frame interval: dt (NDIM s0 / h + 2 nu_max / h^2) <= cfl, s0 and nu_max at their largest."""
        return viscous_steps_per_frame(self)

    def validate(self) -> None:
        check_viscosities(self)
        super().validate()

    def _too_many_steps(self, steps: int) -> str:
        """Names the viscosities when their limit sets the step (eta=1e6 was refused as t_end's alone)."""
        h, nu = self.h, self.nu_max()
        advective = self.NDIM * self.speed_bound() / h
        if 2 * nu / h**2 <= advective:
            return super()._too_many_steps(steps)
        most = (MAX_STEPS * self.cfl / self.t_end - advective) * h**2 / 2  # frames from t = 0
        return (f"{self.NAME}: eta={self.eta}, zeta={self.zeta} not allowed with n={self.n}, t_end={self.t_end:g}: "
                f"the viscous step limit (nu_l = {self.NU_L} up to {nu:.3g}) would take ~{steps:.3g} steps per "
                f"trajectory, the limit is {MAX_STEPS}; allowed: nu_l <= {max(most, 0):.3g} here (smaller "
                "viscosities, a coarser grid or a shorter time window)")


@dataclass(frozen=True)
class CompressibleNS1D(ViscousGas, Euler1D):
    """1D compressible Navier-Stokes of an ideal gas, PDEBench's 1D CFD model: euler1d's scheme plus the viscous
    stress tau = rho (4/3 eta + zeta) u_x with kinematic viscosities eta, zeta (``navier_stokes``); no heat
    conduction. Dimensionless."""

    NAME: ClassVar[str] = "compressible_ns1d"
    EQUATION: ClassVar[str] = ("rho_t + (rho u)_x = 0, (rho u)_t + (rho u^2 + p - tau)_x = 0, E_t + ((E + p) u - "
                               "tau u)_x = 0, tau = rho (4/3 eta + zeta) u_x, E = p / (gamma - 1) + rho u^2 / 2; "
                               "stored: primitive rho, u, p")
    SCHEME: ClassVar[Scheme] = NAVIER_STOKES_1D
    NU_L: ClassVar[str] = "4/3 eta + zeta"  # nu_max's words

    n: int = 256
    length: float = 2.0
    ic: Any = SineStates()
    t_end: float = 1.0
    n_frames: int = 21

    def nu_max(self) -> float:
        """The largest 4/3 eta + zeta the parameter domains allow (length^2 / time)."""
        return 4.0 / 3.0 * max(self.eta.bounds) + max(self.zeta.bounds)

    def describe_setup(self) -> str:
        return (f"  fields: {', '.join(self.FIELDS)} (primitive)   grid: {self.grid.describe()}\n"
                f"  {self._step_words()} with the viscous limit 2 nu_l / h^2 (nu_l = 4/3 eta + zeta <= "
                f"{self.nu_max():.3g}); finite volumes: MUSCL ({self.limiter}) on (rho, u, p), HLLC, central viscous "
                "fluxes, SSP-RK3")


# --- compiled programs: each row the unbatched solver, mapped over a fixed chunk (batch-invariant
# bits); the settings (dt, h, sides, limiter, steps) are traced, so one program serves every entry of a grid size
# and scheme (static: which equations)
@jit(static_argnums=(0, 1))
def _advance(sch, cfl_limit, q, hl, phys, dt, h, sides, limiter, k):
    """(q [K, C, *grid], Health [K], phys [K, P]) -> (q, health) k steps of dt later."""
    # vmap over the fixed chunk, not lax.map: 3.8x faster at 1024 cells (a step's arrays are K times wider) and the
    # same bits, because nothing in a step reduces across samples (each row's max speed is its own) and the chunk's
    # size never changes; tests/test_finite_volume*.py hold a sample alone to its bits in a batch
    return jax.vmap(lambda a, b, c: sch.run(a, b, c, dt, k, h, sides, limiter, cfl_limit))(q, hl, phys)


@jit(static_argnums=0)
def _frame(sch, q, phys):
    """Conserved q [K, C, *grid] -> the stored fields [K, C, *grid]."""
    return jax.lax.map(lambda t: sch.to_output(*t), (q, phys))


@jit(static_argnums=0)
def _conserved(sch, w, phys):
    """A caller's stored fields w [K, C, *grid] -> (conserved q, Health [K])."""
    return jax.lax.map(lambda t: (sch.to_state(*t), scheme.healthy(t[0].dtype)), (w, phys))


@functools.lru_cache(maxsize=16)
def _start(problem: FiniteVolume):
    """jit of (keys [K], explicit [K, P], given [K, P]) -> (params {name: [K]}, conserved q [K, C, *grid],
    Health)."""
    grid, sch = problem.grid, problem.SCHEME

    def one(key, explicit, given):
        k_param, k_ic = jax.random.split(key)
        p = resolve_params(problem, k_param, explicit, given)
        w = problem.ic.sample(k_ic, grid, len(problem.FIELDS))
        return p, sch.to_state(w, _phys(problem, p)), scheme.healthy()

    return jax.jit(lambda keys, ex, gv: jax.lax.map(lambda t: one(*t), (keys, ex, gv)))


def _oracle_one(sch, cfl_limit, w, phys, dt, h, sides, limiter, k):
    """A stored frame w [C, *grid] k steps later, and whether it stayed healthy."""
    q, hl = sch.run(sch.to_state(w, phys), scheme.healthy(w.dtype), phys, dt, k, h, sides, limiter, cfl_limit)
    return sch.to_output(q, phys), hl.code == scheme.OK


@jit(static_argnums=(0, 1))
def _oracle(sch, cfl_limit, u, phys, dt, h, sides, limiter, k):
    return jax.lax.map(lambda t: _oracle_one(sch, cfl_limit, t[0], t[1], dt, h, sides, limiter, k), (u, phys))


@functools.lru_cache(maxsize=32)
def _oracle_vjp(sch, cfl_limit: float, k: int, wrt_params: bool):
    """jit of (u [B, C, *grid], phys [B], dt, h, sides, limiter) -> (u_k, ok, vjp): k a Python int (a scan)."""
    def go(u, phys, dt, h, sides, limiter):
        many = jax.vmap(lambda w, g: _oracle_one(sch, cfl_limit, w, g, dt, h, sides, limiter, k))

        def fn(*args):  # the frames, with ok as an undifferentiated output
            return many(*args) if wrt_params else many(args[0], phys)

        out, vjp, ok = jax.vjp(fn, *((u, phys) if wrt_params else (u,)), has_aux=True)
        return out, ok, vjp

    return jax.jit(go)


@jit
def _apply(vjp, g):
    return vjp(g)


__all__ = ["CompressibleNS1D", "ViscousGas", "Euler1D", "FVGrid", "FiniteVolume", "IC_KINDS", "Lax", "MAX_CFL", "Riemann", "SineStates", "Smooth", "Sod", "Toro123"]
