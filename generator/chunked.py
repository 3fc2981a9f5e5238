"""The one bit-invariant batch map: a batch runs as fixed-size chunks, one compiled program per chunk shape.

XLA's CPU code for transcendental and complex operations rounds differently when vectorised over, or fused
across, batches of other sizes, so a sample computed in a batch of 5 could differ in its last bits from the same
sample alone. Padding every batch to whole chunks of a fixed size (repeating its first row) and running one
fixed-shape program per chunk makes a sample's bits independent of what else is in its batch. Every per-sample
set-up or solve whose bits a sample's identity depends on goes through here (the spectral family's parameters,
initial conditions and ETDRK4 coefficients; the elliptic family's input fields and solves; the coefficients of
``generator.interactive``).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from pdestream.generator.lazy_jax import jax, jit, jnp

from . import dispatch


def pad_rows(x, chunk: int):
    """x [B, ...] (numpy or jax) -> [ceil(B / chunk) * chunk, ...], padded by repeating row 0."""
    pad = (-x.shape[0]) % chunk
    if not pad:
        return x
    xp = jnp if isinstance(x, jax.Array) else np
    return xp.concatenate([x, xp.repeat(x[:1], pad, axis=0)])


def split(arrays: Sequence, chunk: int) -> list[tuple]:
    """Arrays with a common leading batch axis -> a list of chunk tuples of ``chunk`` rows each (padded)."""
    padded = [pad_rows(a, chunk) for a in arrays]
    return [tuple(a[i : i + chunk] for a in padded) for i in range(0, padded[0].shape[0], chunk)]


@jit(static_argnums=1)
def join(parts, batch: int):
    """Chunk results (pytrees with a leading chunk axis) -> one batch of ``batch`` rows, in one dispatch (copies
    only: bits unchanged)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs)[:batch], *parts)


def chunked_map(program: Callable, chunk: int, *arrays, report: bool = False):
    """``program`` (a compiled function of ``chunk``-row arrays) over a batch of any size B: the batch padded to
    whole chunks, one call per chunk (dispatched asynchronously), results joined and trimmed to B rows.
    ``report``: a whole solve (a steady family's), reporting its chunks as each finishes (``dispatch.report``:
    progress within a block; the calls and bits are the same)."""
    batch = arrays[0].shape[0]
    parts = [program(*part) for part in split(arrays, chunk)]
    if report:
        for i, part in enumerate(parts):  # all dispatched already: waiting on one lets the next run
            dispatch.sync([(leaf,) for leaf in jax.tree_util.tree_leaves(part)])
            dispatch.report(i + 1, len(parts))
    return join(parts, batch)
