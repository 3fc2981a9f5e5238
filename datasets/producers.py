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
import signal
import threading
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
        stop = threading.Event()  # set on close: the job in flight stops at its next bounded call
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pdestream-solver",
                                  initializer=_bridge.cancel_solves_on, initargs=(stop,))
        closer.callback(pool.shutdown, wait=True, cancel_futures=True)
        closer.callback(stop.set)  # (callbacks run last-in first-out: this one first)
        return pool, closer, 1
    if kind == "process":
        from .stream import check_main_guard

        check_main_guard(f"producer='process' with {workers} worker(s)")
        pool = _QuietProcessPool(max_workers=workers, mp_context=mp.get_context("spawn"),
                                 initializer=_process_worker_init)
        closer.callback(_stop_processes, pool)
        return pool, closer, workers
    from .distributed import dask_client  # (a Dask cluster's workers are stopped by closing the client)

    client = closer.enter_context(dask_client(scheduler, workers))
    slots = sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()) or workers
    return client.get_executor(pure=False), closer, slots


class _QuietProcessPool(ProcessPoolExecutor):
    """A process pool whose workers never see SIGINT: a terminal's Ctrl-C reaches the whole process group, and
    each idle worker printed a KeyboardInterrupt traceback; the producer's owner handles it and stops them. They
    are started (on a submit) with SIGINT blocked, a mask they inherit, and then ignore it."""

    def submit(self, *args, **kwargs):
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # this thread only; a Ctrl-C meanwhile
        try:  # is handled by the main thread, or delivered when the block ends
            return super().submit(*args, **kwargs)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _process_worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _bridge.configure_worker()


def _stop_processes(pool: ProcessPoolExecutor) -> None:
    """Close a process producer at once: drop the queued jobs and end the workers, whose job in flight may be a
    long solve whose result nobody will read (waiting for it held a Ctrl-C up for the whole solve)."""
    workers = list((getattr(pool, "_processes", None) or {}).values())  # no public handle to them
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in workers:
        proc.terminate()
    for proc in workers:
        proc.join(5)
