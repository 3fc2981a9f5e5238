"""``diffusion_sorption1d``: PDEBench's 1D diffusion-sorption equation as a ``generator.problem.Problem`` (the
scheme is ``generator.finite_volume.sorption``'s: conservative finite volumes, TR-BDF2, Newton per stage).

A sample is u [T, 1, n] float32 at ``times()``: the dissolved concentration at the n cell centres of [0, length],
from u = u_left held at x = 0 and the outflow condition u = -D u_x at x = length. Its IC is one value in every
cell (``ConstantIC``: PDEBench's u0 ~ U(0, 0.2)). The five constants D, por, rho_s, k_f, n_f are parameters (fixed
at PDEBench's values by default; any may take a domain, drawn per sample).

Time: one fixed step per configuration, dt = frame_dt / steps_per_frame <= the ``dt`` setting (the scheme is
implicit: dt is set by accuracy, not stability). A sample fails (``ok`` False, the sampler's on_blowup decides)
if a value turns non-finite, a Newton stage does not converge, or u leaves its maximum-principle range by more
than 5%; ``failure_causes`` says which and when; its state is held at the last good step (no NaN written).

Identity: the key of (seed, index) splits into a parameter key and an IC key; every sample runs the same
unbatched program inside ``jax.lax.map`` over a fixed chunk of CHUNK rows (padded, ``generator.chunked``), so its
bits are the same alone and in any batch; the steps run in bounded calls (``generator.dispatch``).
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import numpy as np

from pdestream.generator.lazy_jax import jax, jit, jnp

from ...boundaries import NEUMANN
from .. import dispatch
from ..chunked import chunked_map, join, split
from ..domains import Fixed
from ..problem import MAX_STEPS, Param, ProblemBase, resolve_params
from . import sorption
from .problem import FVGrid, UniformFrames

CHUNK = 4  # samples per compiled call (a fixed program shape: a sample's bits never depend on its batch)
STEP_WORK_PER_CELL = 64  # one step's work per cell in point-steps (generator.dispatch): 2 stages x NEWTON solves

_LAST = threading.local()  # the causes of this thread's last run_keys (failure_causes)


@dataclass(frozen=True)
class SorptionGrid(FVGrid):
    """n cells of h = length / n on [0, length], values at the centres; u = u_left at x = 0, u = -D u_x at x =
    length. Per axis 'neumann' (open): a model pads by repeating the edge value (the left wall's value is u_left,
    not the zero a Dirichlet padding would put there)."""

    @property
    def bc(self) -> tuple[str, ...]:
        return (NEUMANN.value,)

    def describe(self) -> str:
        return f"{self.n} cells on [0, {self.length:g}] (left: u = u_left, right: u = -D u_x)"


@dataclass(frozen=True)
class ConstantIC:
    """u0 = one value in every cell, drawn per sample ~ U(low, high) (PDEBench's diffusion-sorption IC: U(0, 0.2));
    low = high gives that value."""

    low: float = 0.0
    high: float = 0.2
    kind = "constant"
    field_count = 1

    def sample(self, key: jax.Array, grid, n_fields: int = 1) -> jax.Array:
        value = jax.random.uniform(key, (), jnp.float32, self.low, self.high)
        return jnp.full((n_fields, *grid.shape), value, jnp.float32)

    def check(self, grid) -> None:
        if not 0 <= self.low <= self.high:
            raise ValueError(f"ic.low={self.low:g}, ic.high={self.high:g} not allowed: need 0 <= low <= high (a "
                             "concentration)")

    def bound(self, grid) -> float:
        return max(abs(self.low), abs(self.high))

    def __str__(self) -> str:
        return f"u0 = a constant ~ U({self.low:g}, {self.high:g}) in every cell"


IC_KINDS: dict[str, type] = {"constant": ConstantIC}


@dataclass(frozen=True)
class DiffusionSorption1D(UniformFrames, ProblemBase):
    """PDEBench's 1D diffusion-sorption equation (a contaminant diffusing into a soil column with Freundlich
    sorption); SI units as PDEBench states them (m, s, kg)."""

    NAME: ClassVar[str] = "diffusion_sorption1d"
    EQUATION: ClassVar[str] = ("R(u) u_t = D u_xx, R(u) = 1 + (1 - por) / por rho_s k_f n_f u^(n_f - 1) (u -> u + eps "
                               "in R); u(0, t) = u_left, u(L, t) = -D u_x(L, t)")
    FIELDS: ClassVar[tuple] = ("u",)
    FIELD_UNITS: ClassVar[dict] = {"u": "mass/length^3"}
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict] = {
        "D": Param("effective diffusion coefficient", "length^2/time", positive=True),
        "por": Param("porosity, in (0, 1)", "1", positive=True),
        "rho_s": Param("bulk density of the solid", "mass/length^3", positive=True),
        "k_f": Param("Freundlich sorption coefficient, >= 0 (0: no sorption)", "(length^3/mass)^n_f"),
        "n_f": Param("Freundlich exponent", "1", positive=True),
    }
    IC_KINDS: ClassVar[Mapping[str, type]] = IC_KINDS
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 5.0, "unit_s": 0.45}  # defaults, 2 cores at load ~4 (measured)

    n: int = 256  # cells
    length: float = 1.0  # m
    ic: Any = ConstantIC()
    t_end: float = 500.0  # s
    n_frames: int = 101
    dt: float = 0.25  # s: the largest time step, set by accuracy (implicit: no stability limit)
    u_left: float = 1.0  # the concentration held at x = 0 (PDEBench's sol)
    eps: float = 1e-6  # R's regularisation: (u + eps)^(n_f - 1) (PDEBench's)
    D: Any = Fixed(5e-4)
    por: Any = Fixed(0.29)
    rho_s: Any = Fixed(2880.0)
    k_f: Any = Fixed(3.5e-4)
    n_f: Any = Fixed(0.874)

    # --- settings ----------------------------------------------------------------------------------
    @property
    def grid(self) -> SorptionGrid:
        return SorptionGrid(1, self.n, self.length, ("dirichlet", "robin"))

    @property
    def steps_per_frame(self) -> int:
        return max(1, math.ceil(self.frame_dt / self.dt * (1 - 1e-9)))

    @property
    def step_dt(self) -> float:
        return self.frame_dt / self.steps_per_frame

    def validate(self) -> None:
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 8:
            raise ValueError(f"{self.NAME}: n={self.n!r} not allowed: cells must be an integer >= 8")
        self._check_length()
        for name in ("t_end", "dt", "eps"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{self.NAME}: {name}={value} not allowed: must be a finite number > 0")
        if self.n_frames < 2:
            raise ValueError(f"{self.NAME}: n_frames={self.n_frames} not allowed: need an integer >= 2 (t=0 and t_end)")
        if not self.eps < 1:
            raise ValueError(f"{self.NAME}: eps={self.eps:g} not allowed: R's regularisation must be in (0, 1)")
        if not self.u_left >= 0:
            raise ValueError(f"{self.NAME}: u_left={self.u_left:g} not allowed: a concentration must be >= 0")
        if not max(self.por.bounds) < 1:
            raise ValueError(f"{self.NAME}: por={self.por} not allowed: the porosity must be in (0, 1)")
        if not min(self.k_f.bounds) >= 0:
            raise ValueError(f"{self.NAME}: k_f={self.k_f} not allowed: the Freundlich coefficient must be >= 0")
        if getattr(self.ic, "field_count", None) != 1:
            raise ValueError(f"{self.NAME}: ic={self.ic.kind!r} not allowed; allowed: {', '.join(self.IC_KINDS)}")
        self._check_size()
        self._check_ic_on_grid()
        steps = (self.n_frames - 1) * self.steps_per_frame
        if not steps <= MAX_STEPS:
            raise ValueError(f"{self.NAME}: dt={self.dt:g} with t_end={self.t_end:g} would take {steps} steps per "
                             f"trajectory; the limit is {MAX_STEPS} (a larger dt or a shorter time window)")

    def describe_setup(self) -> str:
        return (f"  fields: u   grid: {self.grid.describe()}, u_left = {self.u_left:g}, eps = {self.eps:g}\n"
                f"  t in [0, {self.t_end:g}], {self.n_frames} frames, step {self.step_dt:.4g} ({self.steps_per_frame}"
                "/frame); finite volumes (conservative in S(u) = u + K u^n_f), TR-BDF2 with Newton per stage")

    def failure(self) -> tuple[str, str]:
        return (f"trajectories failed (a NaN/Inf, a Newton stage that did not converge, or u outside its "
                f"maximum-principle range, with step {self.step_dt:.4g})", "a smaller dt avoids this")

    def failure_causes(self) -> list[str]:
        return list(getattr(_LAST, "causes", ()))

    # --- solving -------------------------------------------------------------------------------------
    def coefficients(self, p: Mapping[str, jax.Array], dtype=np.float32) -> sorption.Coefficients:
        """One sample's (or a batch's, [K]) traced constants from its parameters {name: scalar or [K]}."""
        f = {k: jnp.asarray(v, dtype) for k, v in p.items()}
        K = (1 - f["por"]) / f["por"] * f["rho_s"] * f["k_f"]
        like = jnp.zeros_like(K)
        return sorption.Coefficients(f["D"], K, f["n_f"], like + jnp.asarray(self.u_left, dtype),
                                     like + jnp.asarray(self.eps, dtype), like + jnp.asarray(self.h, dtype))

    def _causes(self, health: sorption.Health) -> list[str]:
        code, step = np.asarray(health.code), np.asarray(health.step)
        return ["" if c == sorption.OK else f"{sorption.CAUSES[int(c)]} at t = {s * self.step_dt:.4g}"
                for c, s in zip(code, step)]

    def _rollout(self, u, hl, coeffs, lo, hi, count):
        """One chunk from u [K, n]: (frames [K, T, 1, n], health)."""
        dt = jnp.float32(self.step_dt)
        frames = [u]
        per_step = CHUNK * self.n * STEP_WORK_PER_CELL + dispatch.step_overhead()
        for _ in range(self.n_frames - 1):
            for k in dispatch.pieces(self.steps_per_frame, per_step):
                u, hl = _advance(u, hl, coeffs, lo, hi, dt, jnp.int32(k))
                dispatch.sync([(u,)])
                count[0] += k
                dispatch.report(count[0], count[1])
            frames.append(u)
        return jnp.stack(frames, axis=1)[:, :, None], hl

    def _bounds(self, u0: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The maximum-principle range of samples u0 [K, n]: lo, hi [K] (their IC, u_left and 0)."""
        return (jnp.minimum(jnp.minimum(u0.min(-1), 0.0), self.u_left),
                jnp.maximum(u0.max(-1), self.u_left))

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """keys [B], explicit float32 [B, P], given bool [B, P] -> (u [B, T, 1, n], params {name: [B]}, ok bool [B],
        None); why a sample failed in ``failure_causes()``."""
        start = _start(self)
        parts = split([jnp.asarray(keys), jnp.asarray(explicit), jnp.asarray(given)], CHUNK)
        count = [0, len(parts) * (self.n_frames - 1) * self.steps_per_frame]
        results = []
        for part in parts:
            p, u0 = start(*part)
            lo, hi = self._bounds(u0)
            results.append((*self._rollout(u0, sorption.healthy_batch(CHUNK), self.coefficients(p), lo, hi, count), p))
        u, health, params = join(results, int(keys.shape[0]))
        _LAST.causes = self._causes(health)
        return u, params, health.code == sorption.OK, None

    def evolve(self, u0: jax.Array, p: Mapping[str, jax.Array]):
        """A caller's states u0 [B, 1, n], params {name: [B]} -> (u [B, T, 1, n], ok [B])."""
        batch = u0.shape[0]
        names = list(self.PARAMS)
        pa = jnp.stack([jnp.broadcast_to(jnp.asarray(p[k], jnp.float32), (batch,)) for k in names], -1)
        parts = split([jnp.asarray(u0, jnp.float32)[:, 0], pa], CHUNK)
        count = [0, len(parts) * (self.n_frames - 1) * self.steps_per_frame]
        results = []
        for w, q in parts:
            lo, hi = self._bounds(w)
            coeffs = self.coefficients({k: q[:, j] for j, k in enumerate(names)})
            results.append(self._rollout(w, sorption.healthy_batch(CHUNK), coeffs, lo, hi, count))
        u, health = join(results, batch)
        _LAST.causes = self._causes(health)
        return u, health.code == sorption.OK

    def advance_frames(self, u: jax.Array, params: Mapping[str, jax.Array], frames: int):
        """Frames u [B, 1, n] advanced ``frames`` frame intervals: (u_k, ok [B]) (generator.interactive): the
        sampler's steps (one step of state), so frame i advanced once is frame i + 1 bit for bit (the
        maximum-principle range that decides a failure is taken from u here, from the IC in a rollout)."""
        names = list(self.PARAMS)
        pa = jnp.stack([jnp.broadcast_to(jnp.asarray(params[k], u.dtype), (u.shape[0],)) for k in names], -1)
        k = jnp.int32(frames * self.steps_per_frame)
        dt = jnp.asarray(self.step_dt, u.dtype)
        return chunked_map(lambda w, q: _oracle(self, w, q, dt, k), CHUNK, u, pa)

    def advance_frames_vjp(self, u: jax.Array, params: Mapping[str, jax.Array], frames: int, wrt_params: bool):
        """``advance_frames`` with its VJP: (u_k, ok, vjp); vjp(g) -> (g_u, g_params {name: [B]} or None). A
        vmapped scan of the same steps, equal to ``advance_frames`` to rounding."""
        names = list(self.PARAMS)
        pa = jnp.stack([jnp.broadcast_to(jnp.asarray(params[k], u.dtype), (u.shape[0],)) for k in names], -1)
        go = _oracle_vjp(self, frames * self.steps_per_frame, wrt_params)
        out, ok, vjp = go(u, pa, jnp.asarray(self.step_dt, u.dtype))

        def back(g):
            got = _apply(vjp, jnp.asarray(g, out.dtype))
            if not wrt_params:
                return got[0], None
            return got[0], {k: got[1][:, j] for j, k in enumerate(names)}

        return out, ok, back


# --- compiled programs: each row the unbatched solver inside jax.lax.map over a fixed chunk (batch-invariant bits);
# the settings (dt, h, u_left, eps, steps) are traced, so one program serves every configuration of a grid size
@jit
def _advance(u, hl, coeffs, lo, hi, dt, k):
    """(u [K, n], Health [K], Coefficients [K], lo, hi [K]) -> (u, health) k steps of dt later."""
    return jax.lax.map(lambda t: sorption.run(t[0], t[1], t[2], dt, k, t[3], t[4]), (u, hl, coeffs, lo, hi))


@functools.lru_cache(maxsize=16)
def _start(problem: DiffusionSorption1D):
    """jit of (keys [K], explicit [K, P], given [K, P]) -> (params {name: [K]}, u0 [K, n])."""
    grid = problem.grid

    def one(key, explicit, given):
        k_param, k_ic = jax.random.split(key)
        return resolve_params(problem, k_param, explicit, given), problem.ic.sample(k_ic, grid, 1)[0]

    return jax.jit(lambda keys, ex, gv: jax.lax.map(lambda t: one(*t), (keys, ex, gv)))


def _oracle_one(problem, w, pa, dt, k):
    """A stored frame w [1, n] with parameters pa [P] k steps later, and whether it stayed healthy."""
    c = problem.coefficients(dict(zip(problem.PARAMS, pa)), w.dtype)
    lo, hi = problem._bounds(w)
    u, hl = sorption.run(w[0], sorption.healthy(w.dtype), c, dt, k, lo[0], hi[0])
    return u[None], hl.code == sorption.OK


@jit(static_argnums=0)
def _oracle(problem, u, pa, dt, k):
    return jax.lax.map(lambda t: _oracle_one(problem, t[0], t[1], dt, k), (u, pa))


@functools.lru_cache(maxsize=32)
def _oracle_vjp(problem, k: int, wrt_params: bool):
    """jit of (u [B, 1, n], pa [B, P], dt) -> (u_k, ok, vjp): k a Python int (a scan)."""
    def go(u, pa, dt):
        many = jax.vmap(lambda w, q: _oracle_one(problem, w, q, dt, k))

        def fn(*args):  # the frames, with ok as an undifferentiated output
            return many(*args) if wrt_params else many(args[0], pa)

        out, vjp, ok = jax.vjp(fn, *((u, pa) if wrt_params else (u,)), has_aux=True)
        return out, ok, vjp

    return jax.jit(go)


@jit
def _apply(vjp, g):
    return vjp(g)


__all__ = ["ConstantIC", "DiffusionSorption1D", "IC_KINDS", "SorptionGrid"]
