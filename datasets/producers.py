"""Solver producers for the training reservoir: one interface, three kinds of executor.

A producer is a ``concurrent.futures.Executor`` running solve jobs (``_bridge.solve_job``: (PDE config, seed,
indices, explicit params) -> numpy arrays), so the reservoir submits work and collects futures the same way
whatever runs them:

- ``"thread"``: one background thread in this process (XLA releases the GIL while it computes); the default.
- ``"process"``: N spawned worker processes (JAX is not fork-safe), JAX on the CPU in each, sharing the
  persistent compilation cache; the same processes a spawn DataLoader would start, driven by job instead.
- ``"dask"``: the workers of a Dask cluster (an embedded LocalCluster, or ``scheduler="tcp://host:8786"``
  for one started elsewhere, e.g. with dask-jobqueue on Slurm): many solver processes feeding one trainer.

Jobs carry plain data only (the PDE's config dict, numpy indices and parameters), so they pickle to any of
them. A job's result is a pure function of its arguments: which executor ran it changes nothing.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor

from . import _bridge

KINDS = ("thread", "process", "dask")


def open_producer(kind: str = "thread", workers: int = 1, scheduler: str | None = None) -> tuple[Executor, contextlib.ExitStack, int]:
    """(executor, its closer, how many jobs it runs at once). Close with ``closer.close()``.

    kind: "thread" | "process" | "dask"; workers: processes for "process" and for an embedded Dask cluster;
    scheduler: address of a running Dask scheduler (kind "dask" only).
    """
    if kind not in KINDS:
        raise ValueError(f"producer={kind!r} not allowed; allowed: {', '.join(KINDS)}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers={workers!r} not allowed; must be an integer >= 1")
    if scheduler and kind != "dask":
        raise ValueError(f"a scheduler address goes with producer='dask' (got producer={kind!r})")
    closer = contextlib.ExitStack()
    if kind == "thread":
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pdestream-solver")
        closer.callback(pool.shutdown, wait=True, cancel_futures=True)
        return pool, closer, 1
    if kind == "process":
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                   initializer=_bridge.configure_worker)
        closer.callback(pool.shutdown, wait=True, cancel_futures=True)
        return pool, closer, workers
    from .distributed import dask_client

    client = closer.enter_context(dask_client(scheduler, workers))
    slots = sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()) or workers
    return client.get_executor(pure=False), closer, slots
