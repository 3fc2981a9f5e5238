"""The solver as a function of a caller's state: advance states by k frames, and the VJP of that map.

JAX only. A state is u [B, C, *space] (the PDE's fields on its grid), parameters are {name: [B]}. One frame is
the PDE's ``frame_dt``, taken as its own ``steps_per_frame`` ETDRK4 steps of ``step_dt`` with the PDE's linear
and nonlinear parts, through the rollout's stepping loop (``advance`` in its bounded calls, so a Ctrl-C stops a
long one; ``advance_vjp`` in one call), so advancing frame i of a sampled trajectory by one frame gives frame i+1
up to float32 rounding (the state re-enters Fourier space).

    advance(pde, u, params, frames)             -> (u_k [B, C, *space], finite bool [B])
    advance_vjp(pde, u, params, frames, wrt)    -> (u_k, finite, vjp); vjp(g) -> (g_u, g_params {name: [B]} | None)

Batch invariance: the ETDRK4 coefficients are computed in fixed chunks of ``rollout.SETUP_CHUNK`` samples (generator.chunked), one
compiled program per chunk, and the stepping is vmapped FFTs and real arithmetic, as in the rollouts; so
``advance`` gives an element the same bits alone or in any batch (tested on CPU). ``advance_vjp`` is a
different program: its output equals ``advance`` to float32 rounding, not bit for bit.

Differentiability: every parameter is differentiable, through the ETDRK4 coefficients (the contour-integral
phi functions) and through the nonlinear term; the step size is not a function of the parameters (it comes
from the parameter *domain*). Under ``jax_enable_x64`` with float64 inputs the whole map runs in float64,
except constants a PDE file builds in complex64 (e.g. kdv1d's dispersion operator, whose beta derivative
then has float32 accuracy). Programs are compiled once per (PDE config, frames, batch shape, dtype).
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict
from typing import Mapping

import numpy as np

from pdestream.generator.lazy_jax import jax, jit, jnp

from ..chunked import join as _join
from ..chunked import split
from .base import PDE
from .fourier import rollout
from .rollout import SETUP_CHUNK, _coefficients, _stepping, advance_bounded


def _advance_one(pde: PDE, frames: int, u: jax.Array, p: Mapping[str, jax.Array], coeffs) -> jax.Array:
    """One state u [C, *space] advanced ``frames`` frames -> [C, *space] (dtype of u): the sampler's rollout
    of frames + 1 frames from u (the recorded buffer costs one inverse FFT per frame), its last frame."""
    to_state, masked, to_physical = _stepping(pde, p)
    return rollout(to_state(u), coeffs, masked, frames + 1, pde.steps_per_frame, to_physical)[-1]


def _finite(u: jax.Array) -> jax.Array:
    return jnp.all(jnp.isfinite(u.reshape(u.shape[0], -1)), axis=1)


def _chunk_coefficients(pde: PDE, chunk):
    """(params {name: [K]}, index [K]) -> coefficients [K, ...]: one sample per loop step (the index makes a
    PDE without parameters loop too)."""
    return jax.lax.map(lambda a: _coefficients(pde, a[0]), chunk)


@functools.lru_cache(maxsize=64)
def _setup(pde: PDE):
    """jit of a chunk of K = SETUP_CHUNK samples -> their ETDRK4 coefficients [K, ...]."""
    return jax.jit(functools.partial(_chunk_coefficients, pde))


@functools.lru_cache(maxsize=64)
def _setup_vjp(pde: PDE):
    """jit of a chunk -> (coefficients, VJP closure over the chunk's residuals)."""
    return jax.jit(lambda chunk: jax.vjp(functools.partial(_chunk_coefficients, pde), chunk))


# The coefficients cost more than a frame of stepping (ns2d 64^2: ~4 ms per sample for the contour integrals
# on a CPU core, against ~1 ms of stepping), and a loop that unrolls k steps asks for the same parameters k
# times: chunks are kept by their exact parameter values, up to COEFFICIENT_CACHE_BYTES. Same bits either way.
COEFFICIENT_CACHE_BYTES = 2**26
_cache: OrderedDict = OrderedDict()
_cache_lock = threading.Lock()


def _host_chunks(params: Mapping[str, jax.Array], batch: int) -> list[dict[str, np.ndarray]]:
    """params {name: [B]} -> host chunks of SETUP_CHUNK samples (the last padded by repeating sample 0)."""
    names = list(params)
    return [dict(zip(names, part)) for part in split([np.asarray(params[k]) for k in names], SETUP_CHUNK)]


def _on(device, chunk: dict[str, np.ndarray]):
    return jax.device_put((chunk, np.arange(SETUP_CHUNK, dtype=np.int32)), device)


def _coefficients_for(pde: PDE, params: Mapping[str, jax.Array], batch: int, device):
    """ETDRK4 coefficients [B, ...] for params {name: [B]} on ``device``, chunk by chunk (memoised)."""
    parts = []
    for chunk in _host_chunks(params, batch):
        key = (pde, str(device), tuple((k, v.dtype.str, v.tobytes()) for k, v in sorted(chunk.items())))
        with _cache_lock:
            hit = _cache.get(key)
            if hit is not None:
                _cache.move_to_end(key)
        if hit is None:
            hit = _setup(pde)(_on(device, chunk))
            _remember(key, hit)
        parts.append(hit)
    return _join(parts, batch)


def _nbytes(tree) -> int:
    return sum(x.nbytes for x in jax.tree_util.tree_leaves(tree))


_cache_bytes = [0]  # bytes held by _cache, kept as entries come and go (summing them per insert grew with the cache)


def _remember(key, coeffs) -> None:
    with _cache_lock:
        if not _cache:
            _cache_bytes[0] = 0  # emptied from outside (tests clear it)
        old = _cache.pop(key, None)  # two threads may have solved the same chunk
        _cache_bytes[0] += _nbytes(coeffs) - (0 if old is None else _nbytes(old))
        _cache[key] = coeffs
        while len(_cache) > 1 and _cache_bytes[0] > COEFFICIENT_CACHE_BYTES:
            _cache_bytes[0] -= _nbytes(_cache.popitem(last=False)[1])


@functools.lru_cache(maxsize=128)
def _evolve_vjp(pde: PDE, frames: int, wrt_params: bool):
    """jit of (u, params, coefficients) -> (u_k, finite, VJP closure) w.r.t. u (and params, coefficients)."""
    step = jax.vmap(functools.partial(_advance_one, pde, frames))

    def run(u, p, c):
        if wrt_params:
            out, vjp = jax.vjp(step, u, p, c)
        else:
            out, vjp = jax.vjp(lambda x: step(x, p, c), u)
        return out, _finite(out), vjp

    return jax.jit(run)


@jit
def _apply(vjp, g):
    """A VJP closure returned by a compiled program, applied to the cotangent g (compiled once per closure)."""
    return vjp(g)


def refuse_refined(pde) -> None:
    """One-line ValueError for a problem with ``refine`` above 1: its samples come from a finer grid than the
    states a caller holds, which these functions step on their own grid (the oracle and solver-in-the-loop modes
    ask before a run starts)."""
    if getattr(pde, "refine", 1) > 1:
        raise ValueError(f"{pde.NAME}: refine={pde.refine} not allowed here: the interactive modes step the states "
                         f"they are given on their own grid, and this problem's samples come from a grid {pde.refine} "
                         f"times finer; allowed: refine=1 (n={pde.n * pde.refine} steps the fine grid itself)")


def _check(pde: PDE, u: jax.Array, params: Mapping[str, jax.Array], frames: int) -> None:
    grid, n_fields = pde.grid, len(pde.FIELDS)
    if getattr(pde, "STEADY", False):
        raise ValueError(f"{pde.NAME}: a steady PDE has no frames to advance; allowed: time-dependent PDEs")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"{pde.NAME}: frames={frames!r} not allowed: need an integer >= 1")
    refuse_refined(pde)
    if u.ndim != 2 + grid.ndim or u.shape[1:] != (n_fields, *grid.shape):
        raise ValueError(f"{pde.NAME}: state has shape {tuple(u.shape)}; expected [B, {n_fields}, "
                         f"{', '.join(map(str, grid.shape))}]")
    if set(params) != set(pde.PARAMS):
        raise ValueError(f"{pde.NAME}: params must be exactly {list(pde.PARAMS)}, got {sorted(params)}")
    for name, v in params.items():
        if v.shape != (u.shape[0],):
            raise ValueError(f"{pde.NAME}: params[{name!r}] has shape {tuple(v.shape)}; expected [{u.shape[0]}]")


def _inputs(pde: PDE, u, params: Mapping, frames: int):
    """u and params as arrays of u's float dtype (float32 unless float64 under jax_enable_x64), checked."""
    u = jnp.asarray(u)
    if u.dtype not in (jnp.float32, jnp.float64):
        u = u.astype(jnp.float32)
    params = {k: jnp.asarray(v, u.dtype) for k, v in params.items()}
    _check(pde, u, params, frames)
    return u, params


def advance(pde: PDE, u, params: Mapping[str, jax.Array], frames: int = 1):
    """States u [B, C, *space] with parameters {name: [B]} advanced ``frames`` frames of ``pde.frame_dt``.

    Returns (u_k [B, C, *space] of u's dtype, finite bool [B]); the caller decides what a non-finite row means.
    An element gets the same bits alone or in any batch (see the module docstring). The steps run in the
    rollout's bounded calls (``rollout.advance_bounded``: a Ctrl-C stops a long advance between two), with the
    bits of ``_advance_one`` in one call.
    """
    u, params = _inputs(pde, u, params, frames)
    own = getattr(pde, "advance_frames", None)  # a family with its own stepping (the flows) advances itself
    if own is not None:
        return own(u, params, frames)
    coeffs = _coefficients_for(pde, params, u.shape[0], _device(u))
    return advance_bounded(pde, u, params, coeffs, frames * _steps_per_frame(pde))


@functools.lru_cache(maxsize=64)
def _steps_per_frame(pde: PDE) -> int:
    return pde.steps_per_frame  # derived from the stable step each time (~30 us, a tenth of a small advance)


def advance_vjp(pde: PDE, u, params: Mapping[str, jax.Array], frames: int = 1, wrt_params: bool = True):
    """``advance`` with its vector-Jacobian product: (u_k [B, C, *space], finite [B], vjp).

    vjp(g [B, C, *space]) -> (g_u [B, C, *space], g_params {name: [B]} or None when wrt_params is False):
    the gradient of sum(g * u_k) w.r.t. u and the parameters (through the ETDRK4 coefficients and the
    nonlinear term). Between the call and vjp only the residuals jax.vjp needs are kept (in the closure).
    """
    u, params = _inputs(pde, u, params, frames)
    own = getattr(pde, "advance_frames_vjp", None)
    if own is not None:
        return own(u, params, frames, wrt_params)
    batch, device, shape = u.shape[0], _device(u), u.shape
    if not wrt_params:
        coeffs = _coefficients_for(pde, params, batch, device)
        out, finite, evolve_vjp = _evolve_vjp(pde, frames, False)(u, params, coeffs)
        return out, finite, lambda g: (_apply(evolve_vjp, _cotangent(g, shape, out.dtype))[0], None)
    parts = [_setup_vjp(pde)(_on(device, c)) for c in _host_chunks(params, batch)]
    coeffs = _join([c for c, _ in parts], batch)
    out, finite, evolve_vjp = _evolve_vjp(pde, frames, True)(u, params, coeffs)

    def vjp(g):
        g_u, g_p, g_c = _apply(evolve_vjp, _cotangent(g, shape, out.dtype))
        # the coefficients' cotangent goes back through each chunk's own VJP (params part of its input)
        through = [_apply(fn, c)[0][0] for (_, fn), c in zip(parts, _split(g_c, len(parts)))]
        through = _join(through, batch)
        return g_u, {k: g_p[k] + through[k] for k in pde.PARAMS}

    return out, finite, vjp


def _device(x: jax.Array):
    (device,) = x.devices()
    return device


@jit(static_argnums=1)
def _split(tree, n_chunks: int):
    """[B, ...] leaves -> n_chunks trees of SETUP_CHUNK rows (zero rows after B), in one dispatch."""
    def pad(x):
        return jnp.concatenate([x, jnp.zeros((n_chunks * SETUP_CHUNK - x.shape[0], *x.shape[1:]), x.dtype)])
    padded = jax.tree_util.tree_map(pad, tree)
    return [jax.tree_util.tree_map(lambda x: x[i * SETUP_CHUNK : (i + 1) * SETUP_CHUNK], padded) for i in range(n_chunks)]


def _cotangent(g, shape: tuple, dtype) -> jax.Array:
    g = jnp.asarray(g, dtype)
    if g.shape != tuple(shape):
        raise ValueError(f"cotangent has shape {tuple(g.shape)}; expected {tuple(shape)}")
    return g

