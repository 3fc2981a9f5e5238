"""Bounded calls: a long solve runs as a series of compiled calls with a host sync between them, so that a
Ctrl-C in the waiting thread, or a consumer that has gone (``cancel_on``), stops it within one call.

Each call advances a batch by at most about DISPATCH_WORK grid-point steps (0.05-0.3 s per call on an idle
2-core CPU here, 0.5-2% slower in all than one call: benchmarks/dispatch_bench.py; 2**22 cost 2-20%). A step
also costs a fixed ~25 us whatever its size, counted as STEP_OVERHEAD points (small grids). Every family that
solves in steps (the spectral rollouts, interactive advances) splits its work with ``pieces`` and waits with
``sync``. DISPATCH_WORK and STEP_OVERHEAD are the defaults; ``call_size(work, overhead)`` sets other sizes for
the solves of one thread inside a ``with`` block (tests, benchmarks), read with ``work()`` / ``step_overhead()``.
On an accelerator (the default device is a GPU) a call does ACCELERATOR_WORK: a GPU runs 2**24 point-steps in
about a millisecond, so the host sync after each call, not the steps, set the pace (benchmarks/device_reservoir_bench.py).
Progress: after each sync a solving loop calls ``report(done, total)`` (steps, or samples of an external solver),
read by the callback of ``progress_to(callback)`` in force in the calling thread (``pdestream.meter``, no JAX);
a report only reads counters, so a solve's calls and bits do not depend on it.
"""

from __future__ import annotations

import contextlib
import threading

from pdestream.generator.lazy_jax import jax
from pdestream.meter import progress_to, report  # noqa: F401  (the progress hook: see the docstring)

DISPATCH_WORK = 2**24
ACCELERATOR_WORK = 2**28  # ~0.1 s per call for a full batch on an H100, a Ctrl-C still seen within that
STEP_OVERHEAD = 2**13
_CANCEL = threading.local()
_SIZE = threading.local()


@contextlib.contextmanager
def call_size(work: int = DISPATCH_WORK, overhead: int = STEP_OVERHEAD):
    """Inside the block, solves in the calling thread run in calls of at most ~``work`` point-steps, a step
    counting ``overhead`` points more (ints >= 1 and >= 0); the sizes before it come back after it."""
    if isinstance(work, bool) or not isinstance(work, int) or work < 1:
        raise ValueError(f"work={work!r} not allowed; must be an integer >= 1 (point-steps per call)")
    if isinstance(overhead, bool) or not isinstance(overhead, int) or overhead < 0:
        raise ValueError(f"overhead={overhead!r} not allowed; must be an integer >= 0 (points per step)")
    before = getattr(_SIZE, "value", None)
    _SIZE.value = (work, overhead)
    try:
        yield
    finally:
        _SIZE.value = before


def accelerated() -> bool:
    """Whether this thread's solves run on an accelerator: the device of a ``jax.default_device`` block in force,
    else JAX's default backend, is not the CPU."""
    device = jax.config.jax_default_device
    if device is None:
        return jax.default_backend() != "cpu"
    return (device if isinstance(device, str) else device.platform) != "cpu"


def work() -> int:
    """Point-steps per call for this thread's solves (DISPATCH_WORK, ACCELERATOR_WORK on a GPU, unless inside
    ``call_size``)."""
    size = getattr(_SIZE, "value", None)
    if size is not None:
        return size[0]
    return ACCELERATOR_WORK if accelerated() else DISPATCH_WORK


def step_overhead() -> int:
    """The fixed cost of a step in points for this thread's solves (STEP_OVERHEAD unless inside ``call_size``)."""
    return (getattr(_SIZE, "value", None) or (DISPATCH_WORK, STEP_OVERHEAD))[1]


class Cancelled(Exception):
    """A solve stopped between two calls because its thread's cancel event was set (see ``cancel_on``)."""


def cancel_on(event: threading.Event | None) -> None:
    """Solves in the calling thread stop at their next call boundary, raising Cancelled, once ``event`` is set
    (None: never). A producer thread sets it to its stop flag so that closing its consumer stops a solve."""
    _CANCEL.event = event


def cancelled() -> bool:
    """Whether the calling thread's solves have been cancelled (``cancel_on``'s event is set)."""
    event = getattr(_CANCEL, "event", None)
    return event is not None and event.is_set()


def sync(states) -> None:
    """Wait for the calls in flight (a Ctrl-C is seen here), then stop if this thread's solve was cancelled.
    states: a list of tuples whose first item is an array of the call."""
    jax.block_until_ready([s[0] for s in states])
    event = getattr(_CANCEL, "event", None)
    if event is not None and event.is_set():
        raise Cancelled("solve cancelled: its consumer stopped")


def pieces(n_steps: int, per_step: int) -> list[int]:
    """Steps per call for ``n_steps`` steps of ``per_step`` point-steps each: at most ~DISPATCH_WORK per call."""
    k = max(1, work() // per_step)
    return [min(k, n_steps - done) for done in range(0, n_steps, k)]
