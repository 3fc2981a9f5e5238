"""The flow solver as a function of a caller's frames: advance frames by k frame intervals, and its VJP
(``generator.interactive`` hands flow problems here: the oracle and the differentiable solver step).

A frame is u [C, nx, ny] over the problem's FIELDS (``FlowProblem.frame_fields``: staggered velocities, pressure,
and the solid mask or smoke), parameters are {name: [B]}. The frame is turned back into the solver's state
(``FlowProblem.state_of``: the faces not stored rebuilt from walls or continuity), its obstacles taken from its
own ``solid`` field (a channel2d body is random geometry, not a parameter), advanced ``frames * steps_per_frame``
steps of ``step_dt`` and recorded again; so advancing frame i of a sampled trajectory gives frame i+1 to the
pressure solve's tolerance (the right-most faces are rebuilt, not stored). The advanced frame's ``solid`` channel is
the given frame's, bit for bit: the geometry is the caller's, not the solver's to predict. (A coarse solver's frame
restricted from a finer one, ``surrogate.modes.subsample``, marks a coarse cell solid when any of its fine cells is;
recomputed on the coarse grid it would differ from the truth in a few cells per frame that no correction may touch:
docs/results/flows.md.)

Batch invariance: each sample runs the same unbatched program inside ``jax.lax.map`` over chunks of CHUNK rows
(``generator.chunked``). Derivatives: reverse mode through the semi-Lagrangian interpolation weights, the
explicit viscosity and the projection (the pressure solve is a ``custom_linear_solve``: its cotangent is another
solve with the same symmetric operator), w.r.t. the frame and every parameter (viscosity, inflow and so on; karman2d's
radius and centre too where its body is sharp: the open fractions and ghost weights are smooth in them). A mask is
a set of cells and is not differentiated: the solid channel passes through (its derivative the identity).
"""

from __future__ import annotations

import functools

from pdestream.generator.lazy_jax import jax, jit, jnp

from ..chunked import chunked_map

CHUNK = 4


def _one(problem, frames: int):
    """(frame [C, *space], params [P]) -> the frame ``frames`` frame intervals later (dtype of the frame)."""
    geom = problem.geometry()
    steps = frames * problem.steps_per_frame

    def one(u, p_row):
        p = {name: p_row[j] for j, name in enumerate(problem.PARAMS)}
        fp = problem.oracle_params(p, u)
        s = problem.rollout(geom, problem.state_of(u, fp), fp, jnp.asarray(problem.step_dt, u.dtype), steps)
        out = problem.frame_fields(geom, s, fp)
        if "solid" in problem.FIELDS:
            k = problem.FIELDS.index("solid")
            out = out.at[k].set(u[k])
        return out

    return one


@functools.lru_cache(maxsize=32)
def _program(problem, frames: int):
    one = _one(problem, frames)
    return jax.jit(lambda u, p: jax.lax.map(lambda t: one(*t), (u, p)))


@functools.lru_cache(maxsize=32)
def _program_vjp(problem, frames: int, wrt_params: bool):
    many = jax.vmap(_one(problem, frames))

    def go(u, p):
        if wrt_params:
            out, vjp = jax.vjp(many, u, p)
        else:
            out, vjp = jax.vjp(lambda x: many(x, p), u)
        return out, _finite(out), vjp

    return jax.jit(go)


@jit
def _apply(vjp, g):
    return vjp(g)


def _finite(u):
    return jnp.all(jnp.isfinite(u.reshape(u.shape[0], -1)), axis=1)


def _rows(problem, params, batch: int, dtype):
    return jnp.stack([jnp.asarray(params[k], dtype) for k in problem.PARAMS], axis=1) if problem.PARAMS else \
        jnp.zeros((batch, 0), dtype)


def advance(problem, u, params, frames: int = 1):
    """Frames u [B, C, *space], params {name: [B]} -> (u_k [B, C, *space], finite bool [B]); an element's bits
    are the same alone or in any batch."""
    out = chunked_map(_program(problem, frames), CHUNK, u, _rows(problem, params, u.shape[0], u.dtype))
    return out, _finite(out)


def advance_vjp(problem, u, params, frames: int = 1, wrt_params: bool = True):
    """``advance`` and its VJP: (u_k, finite, vjp); vjp(g [B, C, *space]) -> (g_u, g_params {name: [B]} or None).
    A different (vmapped) program from ``advance``: equal to it to float32 rounding, not bit for bit."""
    out, finite, vjp = _program_vjp(problem, frames, wrt_params)(u, _rows(problem, params, u.shape[0], u.dtype))

    def back(g):
        got = _apply(vjp, jnp.asarray(g, out.dtype))
        if not wrt_params:
            return got[0], None
        g_u, g_rows = got
        return g_u, {k: g_rows[:, j] for j, k in enumerate(problem.PARAMS)}

    return out, finite, back
