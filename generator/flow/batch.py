"""Batch-invariant flow runs: a sample's bits do not depend on the batch it is computed in.

``jax.vmap`` of the solver changes XLA's CPU code for the per-sample reductions and elementwise multiply-adds
(CG dot products, smoother sweeps): measured, sample 1 of a vmapped batch of 3 differed from the same run alone
by about one ulp. Here each sample runs the same unbatched program, one after another inside ``jax.lax.map``
over a fixed chunk, and any batch is padded to whole chunks (``generator.chunked``), so the compiled
per-sample program never sees the batch size.
"""

from __future__ import annotations

import functools

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ..chunked import chunked_map
from .grid import Geometry, Params
from .step import State, initial_state, run


def _leaves(params: Params, dt, batch: int, dtype):
    """Params (scalars or [B] leaves) and dt -> 8 arrays [B] in a fixed order."""
    vals = [params.nu, params.lid, params.inflow, *params.circle, params.buoyancy, dt]
    return [jnp.broadcast_to(jnp.asarray(a, dtype), (batch,)) for a in vals]


@functools.lru_cache(maxsize=32)
def _program(geom: Geometry, n_steps: int, chunk: int, advection: str = "semi_lagrangian"):
    def one(row):
        nu, lid, inflow, cx, cy, r, buoy, dt = row
        p = Params(nu=nu, lid=lid, inflow=inflow, circle=(cx, cy, r), buoyancy=buoy)
        return run(geom, initial_state(geom, p, dt.dtype), p, dt, n_steps, advection=advection)

    return jax.jit(lambda *cols: jax.lax.map(one, cols))


def run_batch(geom: Geometry, params: Params, dt, n_steps: int, chunk: int = 4, dtype=np.float32,
              advection: str = "semi_lagrangian") -> State:
    """n_steps steps of dt (s) from rest (initial_state) for a batch of parameter sets.

    params: Params whose leaves are scalars or arrays [B] (circle: three of them); dt scalar or [B].
    Returns a State with a leading batch axis B (u [B, ny, nx+1], v [B, ny+1, nx], p/smoke [B, ny, nx]).
    Sample i's bits are identical alone (B = 1) and in any batch. advection: a key of step.ADVECTION.
    """
    if chunk < 1:
        raise ValueError(f"chunk={chunk} must be a positive integer")
    sizes = {jnp.shape(a)[0] for a in [params.nu, params.lid, params.inflow, *params.circle, params.buoyancy, dt]
             if jnp.ndim(a) == 1}
    if len(sizes) > 1:
        raise ValueError(f"params/dt batch sizes {sorted(sizes)} differ; allowed: one common size B or scalars")
    batch = sizes.pop() if sizes else 1
    return chunked_map(_program(geom, n_steps, chunk, advection), chunk, *_leaves(params, dt, batch, dtype))
