"""The spectral family's solver: parameters, initial condition and ETDRK4 coefficients of each sample in fixed
chunks, then jit(vmap) rollouts in bounded calls (generator.dispatch), and the frame-free advances of
``generator.interactive``. Reads a PDE (``generator.pdes.base.PDE``) through its linear and nonlinear parts,
its grid and its time window; imports nothing above it.

A sample's key is split into a parameter key and an IC key (``_draw``), so its parameters and IC do not depend
on which other samples share its batch; the set-up runs through ``generator.chunked`` (fixed-shape programs)
and the stepping is vmapped FFTs and real arithmetic (see spectral.cmul): batch-invariant bits.
"""

from __future__ import annotations

import functools
from typing import Mapping

from pdestream.generator.lazy_jax import jax, jit, jnp

from .. import dispatch
from ..chunked import chunked_map
from ..domains import Fixed
from ..problem import Problem, resolve_params
from .fourier import advance_frames, etdrk4_coefficients, etdrk4_step, rollout

PDE = Problem  # a spectral PDE (generator.pdes.base.PDE: linear, nonlinear, state_basis, time window): its
# family imports this module, so the annotations name the protocol rather than import the family back


def _coefficients(pde: PDE, p: Mapping[str, jax.Array], dt: float | None = None):
    return etdrk4_coefficients(pde.linear(pde.grid, p), pde.step_dt if dt is None else dt)


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


def _draw(pde: PDE, key: jax.Array, explicit: jax.Array, given: jax.Array):
    """(parameters, initial condition, ETDRK4 coefficients) of one sample from its key (coefficients None where
    all samples share them: ``fixed_coefficients``).

    explicit: float32 [P] caller's parameter values, used where ``given`` [P] (bool) is set; the other
    parameters are drawn from the key as usual. The IC always comes from the key.
    """
    k_param, k_ic = jax.random.split(key)
    p = resolve_params(pde, k_param, explicit, given)
    return p, pde.sample_ic(k_ic, p), None if shared_coefficients(pde) else _coefficients(pde, p)


def _draw_latent(pde: PDE, key: jax.Array, explicit: jax.Array, given: jax.Array, latent: jax.Array, has: jax.Array):
    """``_draw`` with the IC's latent coordinates the caller's ``latent`` [L] where ``has`` (bool), the key's own
    elsewhere (drawn either way, so a sample given its key's latent is the drawn sample bit for bit)."""
    k_param, k_ic = jax.random.split(key)
    p = resolve_params(pde, k_param, explicit, given)
    z = jnp.where(has, latent, pde.latent_from_key(k_ic))
    return p, pde.sample_ic(k_ic, p, z), None if shared_coefficients(pde) else _coefficients(pde, p)


# Per-sample set-up (parameters, initial condition, ETDRK4 coefficients) runs as its own compiled program over
# fixed-size chunks of keys, one key per loop iteration (generator.chunked says why). The time stepping is a
# separate vmapped program: FFTs and real arithmetic only (see spectral.cmul), batch-invariant.
SETUP_CHUNK = 8


@functools.lru_cache(maxsize=64)
def compiled_setup(pde: PDE):
    """jit of (keys [K], explicit [K, P], given [K, P]) -> (params {name: [K]}, u0 [K, C, *space],
    coefficients [K, ...] or None where ``shared_coefficients``), K = SETUP_CHUNK. Drawn and explicit parameters
    go through this one program, so a sample given its drawn values explicitly is bit-identical to the drawn sample."""
    return jax.jit(lambda keys, explicit, given: jax.lax.map(lambda a: _draw(pde, *a), (keys, explicit, given)))


@functools.lru_cache(maxsize=64)
def compiled_latent_setup(pde: PDE):
    """``compiled_setup`` with the IC latent: (keys, explicit, given, latent [K, L], has [K]) -> the same outputs."""
    return jax.jit(lambda *args: jax.lax.map(lambda a: _draw_latent(pde, *a), args))


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
# On an accelerator there is no such cache to fit and every call is a launch: the whole batch goes in one chunk
# (up to this many bytes: 256K burgers1d n=1024 samples)
ACCELERATOR_EVOLVE_BYTES = 2**32


def evolve_chunk(pde: PDE) -> int:
    """Samples per rollout call: EVOLVE_BYTES (ACCELERATOR_EVOLVE_BYTES on a GPU) over ~4 float32 fields per PDE
    field per sample, at least MIN_CHUNK."""
    budget = ACCELERATOR_EVOLVE_BYTES if dispatch.accelerated() else EVOLVE_BYTES
    return max(MIN_CHUNK, budget // (16 * len(pde.FIELDS) * pde.n**pde.NDIM))


def _steps(pde: PDE, v, p, coeffs, k):
    """The state v advanced k ETDRK4 steps (k static or traced)."""
    masked = _stepping(pde, p)[1]
    return jax.lax.fori_loop(0, k, lambda _, w: etdrk4_step(w, coeffs, masked), v)


def shared_coefficients(pde: PDE) -> bool:
    """Whether every sample of ``pde`` has the same ETDRK4 coefficients: all its parameters are fixed (a sample's
    explicit values must lie in their domain, so they are the fixed values too). A PDE without parameters keeps
    the per-sample path (``compiled_coefficients`` maps over the parameters: it has none to map over)."""
    domains = pde.param_domains.values()
    # Not on a grid of 2+ dimensions with walls on every axis (a real state): there one set of coefficients for the
    # batch gave a sample other bits alone and in a batch of 3 (allen_cahn2d on Neumann or Dirichlet walls with nu
    # fixed: 1 ulp by t = 0.2), the per-sample coefficients do not; one periodic axis, or 1D, kept them equal.
    grid = pde.grid
    all_walls = getattr(grid, "periodic_axes", None) == () and grid.ndim >= 2
    return bool(domains) and all(isinstance(d, Fixed) for d in domains) and not all_walls


@functools.lru_cache(maxsize=64)
def fixed_coefficients(pde: PDE):
    """The coefficients [1, ...] every sample of a ``shared_coefficients`` PDE has, computed once (by the program
    of ``solve``, ``compiled_coefficients``: the bits of a sample's own; a sample's set-up then draws only its
    IC, ks1d at B=64 -5% time)."""
    return compiled_coefficients(pde)({k: jnp.full((1,), d.value, jnp.float32) for k, d in pde.param_domains.items()})


@functools.lru_cache(maxsize=64)
def compiled_stages(pde: PDE, shared: bool = False):
    """The jit(vmap) programs of a rollout in bounded calls (``frames`` buffers are donated: updated in place);
    ``shared``: frames and steps take one sample's coefficients [...] for the whole batch (``shared_coefficients``:
    the same bits, and the stages stop streaming [B, ...] copies of them: ks1d at B=64 ~15% less time):
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

    c = None if shared else 0
    return (jax.jit(jax.vmap(start)),
            jax.jit(jax.vmap(frames, in_axes=(0, 0, 0, c, None, None)), donate_argnums=1),
            jax.jit(jax.vmap(record, in_axes=(0, 0, 0, None)), donate_argnums=1),
            jax.jit(jax.vmap(steps, in_axes=(0, 0, c, None))),
            jax.jit(jax.vmap(finish), donate_argnums=1))


def evolve_bounded(pde: PDE, parts, shared: bool = False):
    """``compiled_evolve`` of each (u0, params, coefficients) part, in calls of at most ~DISPATCH_WORK
    point-steps for all parts together: [(u [b, T, C, *space], finite [b])] per part, bit-identical.
    shared: every sample has the first sample's coefficients (``shared_coefficients``); only those are used."""
    start, frames, record, steps, finish = compiled_stages(pde, shared)
    first = _first_row if shared else _same
    states = [(*start(u0, p), p, first(c)) for u0, p, c in parts]
    batch = sum(int(u0.shape[0]) for u0, _, _ in parts)
    spf, last = pde.steps_per_frame, pde.n_frames - 1
    per_step = batch * len(pde.FIELDS) * pde.n**pde.NDIM + len(parts) * dispatch.step_overhead()
    done, total = 0, last * spf  # steps, for dispatch.report
    if per_step * spf <= dispatch.work():  # whole frames per call
        k = dispatch.work() // (per_step * spf)
        for lo in range(0, last, k):
            states = [(*frames(v, buf, p, c, lo, min(lo + k, last)), p, c) for v, buf, p, c in states]
            dispatch.sync(states)
            done += (min(lo + k, last) - lo) * spf
            dispatch.report(done, total)
    else:  # a frame takes longer than one call: record it, then its steps in pieces
        for i in range(last):
            states = [(v, record(v, buf, p, i), p, c) for v, buf, p, c in states]
            for k in dispatch.pieces(spf, per_step):
                states = [(steps(v, p, c, k), buf, p, c) for v, buf, p, c in states]
                dispatch.sync(states)
                done += k
                dispatch.report(done, total)
    return [finish(v, buf, p) for v, buf, p, _ in states]


@jit
def _first_row(tree):
    return jax.tree_util.tree_map(lambda x: x[0], tree)


def _same(tree):
    return tree


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
    pieces = dispatch.pieces(n_steps, int(u.shape[0]) * len(pde.FIELDS) * pde.n**pde.NDIM + dispatch.step_overhead())
    if len(pieces) == 1:  # one program (three dispatches and a sync made a one-frame advance 20-40% slower)
        return whole(u, p, coeffs, n_steps)
    steps = compiled_stages(pde)[3]
    v = enter(u, p)
    done = 0
    for k in pieces:
        v = steps(v, p, coeffs, k)
        dispatch.sync([(v,)])
        done += k
        dispatch.report(done, n_steps)
    return leave(v, p)


def run_keys(pde: PDE, keys: jax.Array, explicit, given, latent=None):
    """keys [B], explicit float32 [B, P], given bool [B, P], latent None or (float32 [B, L], given bool [B]) ->
    (u [B, T, C, *space], params {name: [B]}, finite [B]): the set-up in fixed chunks, then the rollout in bounded
    calls over chunks of ``evolve_chunk`` samples."""
    batch = keys.shape[0]
    if latent is None:
        params, u0, coeffs = chunked_map(compiled_setup(pde), SETUP_CHUNK, keys, explicit, given)
    else:
        params, u0, coeffs = chunked_map(compiled_latent_setup(pde), SETUP_CHUNK, keys, explicit, given, *latent)
    shared = coeffs is None
    if pde.burn_in_steps:  # the IC at t = 0 advanced to the first frame's time, t_start
        u0 = burn_in(pde, u0, params)
    size = evolve_chunk(pde)
    parts = [(u0, params)] if batch <= size else [
        jax.tree_util.tree_map(lambda x: x[i : i + size], (u0, params)) for i in range(0, batch, size)]
    if shared:
        coeffs = [fixed_coefficients(pde)] * len(parts)
    else:
        coeffs = [coeffs] if batch <= size else [jax.tree_util.tree_map(lambda x: x[i : i + size], coeffs)
                                                  for i in range(0, batch, size)]
    chunks = evolve_bounded(pde, [(u, p, c) for (u, p), c in zip(parts, coeffs)], shared=shared)
    u, finite = chunks[0] if len(chunks) == 1 else jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *chunks)
    return u, params, finite


@functools.lru_cache(maxsize=64)
def compiled_coefficients(pde: PDE, dt: float | None = None):
    """jit of params {name: [B]} -> ETDRK4 coefficients [B, ...] for a step dt (None: ``pde.step_dt``), one sample
    per loop step (``solve``); params are traced: new values never recompile."""
    return jax.jit(lambda params: jax.lax.map(functools.partial(_coefficients, pde, dt=dt), params))


def evolve_from(pde: PDE, u0: jax.Array, p: Mapping[str, jax.Array]):
    """A caller's initial conditions u0 [B, C, *space] with params {name: [B]} -> (u [B, T, C, *space],
    finite [B]): the rollout in bounded calls, from coefficients of their own program."""
    if pde.burn_in_steps:
        u0 = burn_in(pde, u0, p)
    [(u, finite)] = evolve_bounded(pde, [(u0, p, compiled_coefficients(pde)(p))])
    return u, finite



def burn_in(pde: PDE, u0: jax.Array, p: Mapping[str, jax.Array]) -> jax.Array:
    """The states u0 [B, C, *space] at t = 0 advanced ``pde.t_start`` (``burn_in_steps`` ETDRK4 steps of
    ``burn_in_dt``, in bounded calls, per-sample coefficients: batch-invariant bits) -> float32 [B, C, *space],
    the rollout's initial condition (a sample that blew up is NaN here and fails its rollout's finite check)."""
    u, _ = advance_bounded(pde, u0, p, compiled_coefficients(pde, pde.burn_in_dt)(p), pde.burn_in_steps)
    return u
