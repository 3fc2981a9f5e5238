"""(PDE config, seed, index) -> trajectory: keys, parameters, initial condition, jit(vmap(scan)) rollout.

Sample i uses the key ``fold_in(key(seed), i)``, split into a parameter key and an IC key, so it does not
depend on which other samples share its batch. A redrawn sample (after a blow-up) uses
``fold_in(fold_in(key(seed), i), attempt)``.
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass, field
from typing import Literal, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .catalog import get_pde
from .pdes import PDE
from .spectral import advance_frames, etdrk4_coefficients, etdrk4_step, rollout

OnBlowup = Literal["raise", "redraw"]
MAX_INDEX = 2**32 - 1


class BlowUpError(ValueError):
    """A solve produced NaN or Inf; names the sample indices and their parameters."""


@dataclass
class Trajectory:
    """A batch of solutions.

    u: float32 [B, T, C, *space] (jax array), or [B, C, *space] for a steady PDE (``pde.STEADY``: no time
    axis, t is empty); t: float32 [T]; params: {name: float32 [B]}; indices: int64 [B] global sample indices
    (None for ``solve``); redraws: int [B] blow-up redraws used; inputs: float32 [B, C_in, *space], the
    random input fields ``pde.INPUTS`` of a steady PDE (darcy2d's coefficient a), else None.
    """

    u: jax.Array
    t: np.ndarray
    params: dict[str, jax.Array]
    pde: PDE
    indices: np.ndarray | None = None
    redraws: np.ndarray | None = field(default=None)
    inputs: jax.Array | None = None

    def __len__(self) -> int:
        return int(self.u.shape[0])


def _coefficients(pde: PDE, p: Mapping[str, jax.Array]):
    return etdrk4_coefficients(pde.linear(pde.grid, p), pde.step_dt)


def _stepping(pde: PDE, p: Mapping[str, jax.Array]):
    """(u0 [C, *space] -> initial state, masked nonlinear part or None, state -> fields [C, *space]) of a rollout."""
    grid = pde.grid
    mask = grid.dealias_mask()
    nonlinear = pde.nonlinear(grid, p)
    masked = None if nonlinear is None else (lambda v: mask * nonlinear(v))

    def dealiased(u0):  # float32 data; float64 stays (generator.interactive's gradient checks under x64)
        return mask * grid.rfft(u0 if u0.dtype == jnp.float64 else u0.astype(jnp.float32))

    basis = pde.state_basis(grid, p)  # a linear system diagonal in other variables than its fields (wave)
    if basis is None:
        return dealiased, masked, grid.irfft
    to_state, from_state = basis
    return (lambda u0: to_state(dealiased(u0))), masked, (lambda v: grid.irfft(from_state(v)))


def _evolve(pde: PDE, u0: jax.Array, p: Mapping[str, jax.Array], coeffs) -> jax.Array:
    """One trajectory [T, C, *space] from u0 [C, *space]; frame 0 is the dealiased u0 the solver evolves."""
    to_state, masked, to_physical = _stepping(pde, p)
    return rollout(to_state(u0), coeffs, masked, pde.n_frames, pde.steps_per_frame, to_physical)


def draw_params(pde: PDE, key: jax.Array) -> dict[str, jax.Array]:
    """One draw of every parameter from its domain: {name: float32 scalar}."""
    return {name: dom.sample(jax.random.fold_in(key, j)) for j, (name, dom) in enumerate(pde.param_domains.items())}


def _draw(pde: PDE, key: jax.Array, explicit: jax.Array, given: jax.Array):
    """(parameters, initial condition, ETDRK4 coefficients) of one sample from its key.

    explicit: float32 [P] caller's parameter values, used where ``given`` [P] (bool) is set; the other
    parameters are drawn from the key as usual. The IC always comes from the key.
    """
    k_param, k_ic = jax.random.split(key)
    drawn = draw_params(pde, k_param)
    p = {name: jnp.where(given[j], explicit[j], drawn[name]) for j, name in enumerate(pde.PARAMS)}
    return p, pde.sample_ic(k_ic), _coefficients(pde, p)


# Per-sample set-up (parameters, initial condition, ETDRK4 coefficients) runs as its own compiled
# program over fixed-size chunks of keys, one key per loop iteration. XLA's CPU code for transcendental
# and complex operations rounds differently when vectorised over, or fused across, a batch of another
# size; a fixed program per chunk makes sample i independent of its batch. The time stepping is a
# separate vmapped program: FFTs and real arithmetic only (see spectral.cmul), batch-invariant.
SETUP_CHUNK = 8


@functools.lru_cache(maxsize=64)
def compiled_setup(pde: PDE):
    """jit of (keys [K], explicit [K, P], given [K, P]) -> (params {name: [K]}, u0 [K, C, *space],
    coefficients [K, ...]), K = SETUP_CHUNK. Drawn and explicit parameters go through this one program,
    so a sample given its drawn values explicitly is bit-identical to the drawn sample."""
    return jax.jit(lambda keys, explicit, given: jax.lax.map(lambda a: _draw(pde, *a), (keys, explicit, given)))


def _evolve_checked(pde: PDE, u0, p, coeffs):
    u = _evolve(pde, u0, p, coeffs)
    return u, jnp.all(jnp.isfinite(u))


@functools.lru_cache(maxsize=64)
def compiled_evolve(pde: PDE):
    """jit(vmap) of (u0, params, coefficients) -> (u [B, T, C, *space], finite [B])."""
    return jax.jit(jax.vmap(functools.partial(_evolve_checked, pde)))


# The rollout runs over chunks of samples whose per-stage fields take about EVOLVE_BYTES (half a core's
# L2 cache here), dispatched asynchronously: 2D fields then stay in cache (-10% time at 128^2 compared
# with one batch of 16). 1D batches stay whole (splitting them gained nothing: chunks ran one after another).
# A chunk holds at least MIN_CHUNK samples: a 3D sample (256 KB per field at 32^3) never fits that cache, and
# chunks of 1-2 cost time in 3D (process CPU of a batch of 8, on a loaded 2-core CPU: grayscott3d 4 per call
# -8% against 2, burgers3d -15% against 1; 8 per call -2% and -11%). Bits do not depend on the chunk.
EVOLVE_BYTES = 2**21
MIN_CHUNK = 4


def evolve_chunk(pde: PDE) -> int:
    """Samples per rollout call: EVOLVE_BYTES over ~4 float32 fields per PDE field per sample, at least MIN_CHUNK."""
    return max(MIN_CHUNK, EVOLVE_BYTES // (16 * len(pde.FIELDS) * pde.n**pde.NDIM))


# A rollout runs as a series of compiled calls, each advancing the batch by at most about DISPATCH_WORK
# grid-point steps (0.05-0.3 s per call on an idle 2-core CPU here, 0.5-2% slower in all than one call:
# benchmarks/dispatch_bench.py; 2**22 cost 2-20%), with a host sync between them: a Ctrl-C in the thread that
# waits, or a consumer that has gone (``cancel_on``), then stops a solve within one call instead of after the
# whole rollout (41 s with a long t_end). Every call runs the loop body of the one-call rollout: same bits.
# A step also costs a fixed ~25 us whatever its size, counted as STEP_OVERHEAD points (small grids).
DISPATCH_WORK = 2**24
STEP_OVERHEAD = 2**13
_CANCEL = threading.local()


class Cancelled(Exception):
    """A solve stopped between two calls because its thread's cancel event was set (see ``cancel_on``)."""


def cancel_on(event: threading.Event | None) -> None:
    """Solves in the calling thread stop at their next call boundary, raising Cancelled, once ``event`` is set
    (None: never). A producer thread sets it to its stop flag so that closing its consumer stops a solve."""
    _CANCEL.event = event


def _sync(states) -> None:
    """Wait for the calls in flight (a Ctrl-C is seen here), then stop if this thread's solve was cancelled."""
    jax.block_until_ready([s[0] for s in states])
    event = getattr(_CANCEL, "event", None)
    if event is not None and event.is_set():
        raise Cancelled("solve cancelled: its consumer stopped")


def _steps(pde: PDE, v, p, coeffs, k):
    """The state v advanced k ETDRK4 steps (k static or traced)."""
    masked = _stepping(pde, p)[1]
    return jax.lax.fori_loop(0, k, lambda _, w: etdrk4_step(w, coeffs, masked), v)


@functools.lru_cache(maxsize=64)
def compiled_stages(pde: PDE):
    """The jit(vmap) programs of a rollout in bounded calls (``frames`` buffers are donated: updated in place):
    start (u0 [B, C, *space], params) -> (state, frames float32 [B, T, C, *space]);
    frames (state, frames, params, coefficients, lo, hi) -> (state at frame hi, frames lo..hi-1 written);
    record (state, frames, params, i) -> frames with frame i written;
    steps (state, params, coefficients, k) -> state k steps later;
    finish (state, frames, params) -> (u [B, T, C, *space], finite [B]) with the last frame written."""
    spf, last = pde.steps_per_frame, pde.n_frames - 1

    def start(u0, p):
        v0 = _stepping(pde, p)[0](u0)
        return v0, jnp.zeros((pde.n_frames, *u0.shape), jnp.float32)

    def frames(v, buf, p, coeffs, lo, hi):
        _, masked, to_physical = _stepping(pde, p)
        return advance_frames(v, buf, lo, hi, coeffs, masked, spf, to_physical)

    def record(v, buf, p, i):
        return jax.lax.dynamic_update_index_in_dim(buf, _stepping(pde, p)[2](v), i, 0)

    def steps(v, p, coeffs, k):
        return _steps(pde, v, p, coeffs, k)

    def finish(v, buf, p):
        u = jax.lax.dynamic_update_index_in_dim(buf, _stepping(pde, p)[2](v), last, 0)
        return u, jnp.all(jnp.isfinite(u))

    return (jax.jit(jax.vmap(start)),
            jax.jit(jax.vmap(frames, in_axes=(0, 0, 0, 0, None, None)), donate_argnums=1),
            jax.jit(jax.vmap(record, in_axes=(0, 0, 0, None)), donate_argnums=1),
            jax.jit(jax.vmap(steps, in_axes=(0, 0, 0, None))),
            jax.jit(jax.vmap(finish), donate_argnums=1))


def _evolve_bounded(pde: PDE, parts):
    """``compiled_evolve`` of each (u0, params, coefficients) part, in calls of at most ~DISPATCH_WORK
    point-steps for all parts together: [(u [b, T, C, *space], finite [b])] per part, bit-identical."""
    start, frames, record, steps, finish = compiled_stages(pde)
    states = [(*start(u0, p), p, c) for u0, p, c in parts]
    batch = sum(int(u0.shape[0]) for u0, _, _ in parts)
    spf, last = pde.steps_per_frame, pde.n_frames - 1
    per_step = batch * len(pde.FIELDS) * pde.n**pde.NDIM + len(parts) * STEP_OVERHEAD
    if per_step * spf <= DISPATCH_WORK:  # whole frames per call
        k = DISPATCH_WORK // (per_step * spf)
        for lo in range(0, last, k):
            states = [(*frames(v, buf, p, c, lo, min(lo + k, last)), p, c) for v, buf, p, c in states]
            _sync(states)
    else:  # a frame takes longer than one call: record it, then its steps in pieces
        for i in range(last):
            states = [(v, record(v, buf, p, i), p, c) for v, buf, p, c in states]
            for k in _pieces(spf, per_step):
                states = [(steps(v, p, c, k), buf, p, c) for v, buf, p, c in states]
                _sync(states)
    return [finish(v, buf, p) for v, buf, p, _ in states]


def _pieces(n_steps: int, per_step: int) -> list[int]:
    """Steps per call for ``n_steps`` steps of ``per_step`` point-steps each: at most ~DISPATCH_WORK per call."""
    k = max(1, DISPATCH_WORK // per_step)
    return [min(k, n_steps - done) for done in range(0, n_steps, k)]


@functools.lru_cache(maxsize=64)
def compiled_state(pde: PDE):
    """The jit(vmap) programs of steps that record no frames (``advance_bounded``):
    enter (u [B, C, *space], params) -> state; leave (state, params) -> (u [B, C, *space], finite [B]);
    whole (u, params, coefficients, k) -> leave of the state k steps after enter, in one call.
    float64 stays float64 (generator.interactive's gradient checks under x64)."""

    def enter(u, p):
        return _stepping(pde, p)[0](u)

    def leave(v, p):
        u = _stepping(pde, p)[2](v)
        return u, jnp.all(jnp.isfinite(u))

    def whole(u, p, coeffs, k):
        return leave(_steps(pde, enter(u, p), p, coeffs, k), p)

    # whole's k is static (a loop of known length, as in the one-call rollout: a traced k cost ~20%)
    return (jax.jit(jax.vmap(enter)), jax.jit(jax.vmap(leave)),
            jax.jit(lambda u, p, coeffs, k: jax.vmap(lambda *a: whole(*a, k))(u, p, coeffs), static_argnums=3))


def advance_bounded(pde: PDE, u: jax.Array, p: Mapping[str, jax.Array], coeffs, n_steps: int):
    """States u [B, C, *space] (params {name: [B]}, coefficients [B, ...]) advanced ``n_steps`` ETDRK4 steps,
    recording no frames, in calls of at most ~DISPATCH_WORK point-steps like a rollout (a Ctrl-C or
    ``cancel_on`` stops between two): (u_k [B, C, *space], finite [B]), the bits of the steps in one call."""
    enter, leave, whole = compiled_state(pde)
    pieces = _pieces(n_steps, int(u.shape[0]) * len(pde.FIELDS) * pde.n**pde.NDIM + STEP_OVERHEAD)
    if len(pieces) == 1:  # one program (three dispatches and a sync made a one-frame advance 20-40% slower)
        return whole(u, p, coeffs, n_steps)
    steps = compiled_stages(pde)[3]
    v = enter(u, p)
    for k in pieces:
        v = steps(v, p, coeffs, k)
        _sync([(v,)])
    return leave(v, p)


@functools.partial(jax.jit, static_argnums=1)
def _join(parts, batch: int):
    """Set-up chunks -> one batch of ``batch`` samples, in one dispatch (copies only: bits unchanged)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs)[:batch], *parts)


def _run_keys(pde: PDE, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
    """keys [B], explicit float32 [B, P], given bool [B, P] -> (u [B, T, C, *space], params {name: [B]}, finite [B]).
    The time-dependent PDEs' ``PDE.run_keys``."""
    batch = keys.shape[0]
    pad = (-batch) % SETUP_CHUNK
    padded = jnp.concatenate([keys, jnp.repeat(keys[:1], pad, axis=0)])
    explicit = np.concatenate([explicit, np.repeat(explicit[:1], pad, axis=0)])
    given = np.concatenate([given, np.repeat(given[:1], pad, axis=0)])
    setup = compiled_setup(pde)
    parts = [setup(padded[i : i + SETUP_CHUNK], explicit[i : i + SETUP_CHUNK], given[i : i + SETUP_CHUNK])
             for i in range(0, padded.shape[0], SETUP_CHUNK)]
    params, u0, coeffs = _join(parts, batch)
    size = evolve_chunk(pde)
    chunks = _evolve_bounded(pde, [(u0, params, coeffs)] if batch <= size else [
        jax.tree_util.tree_map(lambda x: x[i : i + size], (u0, params, coeffs)) for i in range(0, batch, size)])
    u, finite = chunks[0] if len(chunks) == 1 else jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *chunks)
    return u, params, finite


@functools.lru_cache(maxsize=64)
def compiled_coefficients(pde: PDE):
    """jit of params {name: [B]} -> ETDRK4 coefficients [B, ...], one sample per loop step (``solve``);
    params are traced: new values never recompile."""
    return jax.jit(lambda params: jax.lax.map(functools.partial(_coefficients, pde), params))


@functools.partial(jax.jit, static_argnums=2)
def _fold_keys(base: jax.Array, idx: jax.Array, attempt: int) -> jax.Array:
    # jitted: traced eagerly, these two vmaps cost ~3 ms per sample() call (integer hashing: same bits)
    keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(idx)
    if attempt:
        keys = jax.vmap(lambda k: jax.random.fold_in(k, attempt))(keys)
    return keys


def sample_keys(seed: int, indices: np.ndarray, attempt: int = 0) -> jax.Array:
    """Keys fold_in(key(seed), i) (and fold_in(., attempt) for attempt > 0), one per index: [B]."""
    return _fold_keys(jax.random.key(seed), jnp.asarray(indices, jnp.uint32), attempt)


def _check_indices(indices: Sequence[int] | np.ndarray | int) -> np.ndarray:
    idx = np.atleast_1d(np.asarray(indices))
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"indices must be a non-empty 1D sequence of integers, got {indices!r}")
    if idx.min() < 0 or idx.max() > MAX_INDEX:
        raise ValueError(f"sample indices must be in [0, {MAX_INDEX}], got min {idx.min()} max {idx.max()}")
    return idx.astype(np.int64)


def explicit_params(pde: PDE, params: Mapping[str, Sequence[float] | float] | None, batch: int):
    """Caller's parameter values -> (explicit float32 [B, P], given bool [B, P]) in PDE.PARAMS order.

    ``params`` maps some or all of the PDE's parameters to a scalar or [B] values; each value must lie in its
    domain (ValueError naming the parameter, the value and the domain otherwise). Parameters left out are drawn.
    """
    names = list(pde.PARAMS)
    explicit = np.zeros((batch, len(names)), np.float32)
    given = np.zeros((batch, len(names)), bool)
    if not params:
        return explicit, given
    unknown = sorted(set(params) - set(names))
    if unknown:
        raise ValueError(f"{pde.NAME}: unknown parameter(s) {unknown}; allowed: {names}")
    for name, values in params.items():
        j = names.index(name)
        v = np.asarray(values, np.float64)
        if v.ndim > 1 or (v.ndim == 1 and v.shape[0] != batch):
            raise ValueError(f"{pde.NAME}: params[{name!r}] has shape {v.shape}; expected a scalar or [{batch}]")
        v = np.broadcast_to(v, (batch,))
        domain = pde.param_domains[name]
        bad = [x for x in v if not (np.isfinite(x) and domain.contains(x))]
        if bad:
            raise ValueError(f"{pde.NAME}: {name}={bad[0]:.6g} not allowed: outside its domain {domain}")
        explicit[:, j], given[:, j] = v.astype(np.float32), True
    return explicit, given


def sample(
    pde: PDE | str,
    indices: Sequence[int] | np.ndarray | int,
    seed: int = 0,
    on_blowup: OnBlowup = "raise",
    max_redraws: int = 3,
    params: Mapping[str, Sequence[float] | float] | None = None,
) -> Trajectory:
    """Solve samples ``indices`` of ``pde`` under ``seed``: a Trajectory with u [B, T, C, *space].

    params: optional explicit values {name: scalar or [B]} for some or all parameters (each inside its
    domain); the initial condition still comes from the key of (seed, index), so sample identity is
    (config, seed, index, params), and a sample given its drawn values is bit-identical to the drawn one.
    on_blowup="raise": a NaN/Inf trajectory raises BlowUpError naming the indices and parameters.
    on_blowup="redraw": such a sample is redrawn with attempt keys 1..max_redraws (deterministic per
    index; explicit parameters are kept, only the drawn ones and the IC change); ``Trajectory.redraws``
    counts them; still failing after max_redraws raises.
    """
    pde = get_pde(pde) if isinstance(pde, str) else pde
    if on_blowup not in ("raise", "redraw"):
        raise ValueError(f"on_blowup={on_blowup!r} not allowed; allowed: 'raise', 'redraw'")
    if not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    idx = _check_indices(indices)
    explicit, given = explicit_params(pde, params, len(idx))
    # each kind of PDE solves its samples its own way (time-dependent: ETDRK4 rollouts; steady: PCG)
    u, params, finite, inputs = pde.run_keys(sample_keys(int(seed), idx), explicit, given)
    redraws = np.zeros(len(idx), np.int64)
    attempt = 0
    bad = np.flatnonzero(~np.asarray(finite))
    while bad.size and on_blowup == "redraw" and attempt < max_redraws:
        attempt += 1
        # rerun the full batch shape (failed keys padded by repetition) so no new compile is needed
        retry = np.resize(bad, len(idx))
        u2, p2, f2, in2 = pde.run_keys(sample_keys(int(seed), idx[retry], attempt), explicit[retry], given[retry])
        sel = jnp.asarray(bad)
        u = u.at[sel].set(u2[: bad.size])
        inputs = None if inputs is None else inputs.at[sel].set(in2[: bad.size])
        params = {k: v.at[sel].set(p2[k][: bad.size]) for k, v in params.items()}
        redraws[bad] = attempt
        bad = bad[~np.asarray(f2[: bad.size])]
    if bad.size:
        detail = "; ".join(
            f"index {idx[b]}: " + ", ".join(f"{k}={float(v[b]):.4g}" for k, v in params.items()) for b in bad[:5]
        )
        hint = "" if on_blowup == "redraw" else " (on_blowup='redraw' draws replacements)"
        what, remedy = pde.failure()
        raise BlowUpError(f"{pde.NAME}: {bad.size} of {len(idx)} {what}: {detail}{hint}; {remedy}")
    return Trajectory(u=u, t=pde.times(), params=params, pde=pde, indices=idx, redraws=redraws, inputs=inputs)


def solve(pde: PDE | str, u0, params: Mapping[str, float | Sequence[float]]) -> Trajectory:
    """Solve from a caller's initial condition.

    u0: [C, *space] or [B, C, *space] (C may be omitted for one-field PDEs when unbatched 1D/2D arrays
    match the grid); params: {name: scalar or [B]} for every parameter of the PDE. Returns u [B, T, C, *space].
    """
    pde = get_pde(pde) if isinstance(pde, str) else pde
    if pde.STEADY:
        raise ValueError(f"{pde.NAME} is steady: it has no initial condition to evolve; use sample(pde, indices, seed, "
                         "params=...) (its input field comes from the key of each index)")
    grid, n_fields = pde.grid, len(pde.FIELDS)
    u0 = jnp.asarray(u0, jnp.float32)
    if u0.shape == grid.shape:
        u0 = u0[None]
    if u0.shape == (n_fields, *grid.shape):
        u0 = u0[None]
    if u0.ndim != 2 + grid.ndim or u0.shape[1:] != (n_fields, *grid.shape):
        raise ValueError(
            f"{pde.NAME}: u0 has shape {tuple(u0.shape)}; expected [B, {n_fields}, {', '.join(map(str, grid.shape))}]"
        )
    missing = set(pde.PARAMS) - set(params)
    extra = set(params) - set(pde.PARAMS)
    if missing or extra:
        raise ValueError(f"{pde.NAME}: params must be exactly {sorted(pde.PARAMS)}; missing {sorted(missing)}, unknown {sorted(extra)}")
    batch = u0.shape[0]
    p = {k: jnp.broadcast_to(jnp.asarray(v, jnp.float32), (batch,)) for k, v in params.items()}
    for name, spec in pde.PARAMS.items():
        if spec.positive and not bool(jnp.all(p[name] > 0)):
            raise ValueError(f"{pde.NAME}: {name}={np.asarray(p[name])} not allowed: {spec.description} must be > 0")
    # the sampler's rollout in bounded calls (a Ctrl-C stops it within one), from coefficients of their own program
    [(u, finite)] = _evolve_bounded(pde, [(u0, p, compiled_coefficients(pde)(p))])
    bad = np.flatnonzero(~np.asarray(finite))
    if bad.size:
        raise BlowUpError(f"{pde.NAME}: solve blew up (NaN/Inf) for batch entries {bad[:10].tolist()} with step {pde.step_dt:.4g}")
    return Trajectory(u=u, t=pde.times(), params=p, pde=pde)
