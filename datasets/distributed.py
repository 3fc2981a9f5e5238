"""Write a cache on a Dask cluster: ``write_cache_dask`` (the ``--executor dask`` of ``pdestream generate``).

The client creates the store exactly as ``write_cache`` does (``cache.writing``: checks, lock, a
replacement built beside the old cache and swapped in at the end), then submits one task per
block that is not yet complete. A task is a pure function of (PDE config, seed, block): it solves the block
(``cache.solve_block``) and writes that block's chunks and then its ``complete`` flags (``cache.write_block``).
Zarr chunks along ``sample`` never straddle two blocks, so concurrent tasks never write the same chunk, and a
block whose worker died is simply computed again by Dask (writing the same bytes twice is harmless). The
client sets the cache's completion flag last. Result: bit-identical to ``write_cache``; resume redoes only
missing blocks.

HDF5 allows one writer per file, so the Dask executor writes Zarr only.

Running on a real cluster: start workers however the site does it (``dask-jobqueue``'s ``SLURMCluster``,
``dask scheduler`` + ``dask worker``, Kubernetes) with pdestream installed and the output directory on a
shared filesystem, then pass the scheduler's address (``--scheduler tcp://host:8786``); the recipe for
``dask scheduler`` + ``dask worker`` on machines of your own: docs/guides/dask.md, "A cluster of machines".
"""

from __future__ import annotations

import importlib.util
import logging
import os
import re
import signal
import socket
import struct
import sys
import threading
import time
from contextlib import ExitStack, contextmanager
from pathlib import Path

from . import cache, schema
from .store import format_of

# Embedded workers: JAX on the CPU, one XLA thread each (processes, not threads, give the parallelism).
SINGLE_THREAD_XLA = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
CONNECT_TIMEOUT = "20s"  # how long the client tries to reach a --scheduler
PROBE_TIMEOUT = 5.0  # seconds a plain TCP connect to the scheduler may take before the address is refused
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")  # transports a remote scheduler listens on
_ADDRESS = re.compile(r"^(?:(?P<scheme>[A-Za-z][A-Za-z0-9+.-]*)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                      r":(?P<port>[0-9]{1,5})/?$")


def check_scheduler(address) -> tuple[str, str, int]:
    """(scheme, host, port) of a Dask scheduler address such as tcp://host:8786 (bare host:port means tcp);
    a one-line ValueError naming the address and the expected form otherwise."""
    if isinstance(address, str) and address.startswith("inproc://"):
        return "inproc", address, 0  # LocalCluster(processes=False) in this very process
    form = "expected SCHEME://HOST:PORT, e.g. tcp://10.0.0.5:8786 (schemes: " + ", ".join(SCHEDULER_SCHEMES) + ")"
    match = _ADDRESS.match(address) if isinstance(address, str) else None
    if match is None:
        raise ValueError(f"bad --scheduler {address!r}: {form}")
    scheme = (match["scheme"] or "tcp").lower()
    port = int(match["port"])
    if scheme not in SCHEDULER_SCHEMES:
        raise ValueError(f"bad --scheduler {address!r}: unknown scheme {scheme!r}; {form}")
    if not 1 <= port <= 65535:
        raise ValueError(f"bad --scheduler {address!r}: port {port} not in 1..65535; {form}")
    return scheme, match["host"].strip("[]"), port


def probe_scheduler(address: str) -> None:
    """Check the address format, then that a Dask scheduler answers there within PROBE_TIMEOUT seconds: a
    malformed, unreachable or wrong address fails in seconds with one line (Dask's client may hang for minutes)."""
    scheme, host, port = check_scheduler(address)
    if scheme in ("ucx", "inproc"):
        return  # not a TCP socket (inproc: a scheduler in this process): the client's own connect decides
    try:
        sock = socket.create_connection((host, port), timeout=PROBE_TIMEOUT)
    except socket.gaierror:
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: unknown host {host!r}") from None
    except OSError as err:
        why = "timed out" if isinstance(err, TimeoutError) else (err.strerror or str(err)).lower()
        raise ValueError(f"cannot reach the Dask scheduler at {address!r}: {why} (is a scheduler running "
                         f"there? start one with `dask scheduler --port {port}`)") from None
    with sock:
        if scheme == "tcp" and not _greets_like_dask(sock):
            raise ValueError(f"{address!r} accepts connections but does not answer like a Dask scheduler "
                             f"within {PROBE_TIMEOUT:g} s (wrong port, or a proxy in the way?)")


def _greets_like_dask(sock: socket.socket) -> bool:
    """Whether the peer sends a Dask TCP handshake: a scheduler writes its handshake as soon as it accepts, and
    a frame starts with its length (uint64, little-endian), small for a handshake. Anything else (silence, an
    HTTP proxy's reply read as a length of exabytes) is not a scheduler, and Dask's own client would hang on it."""
    head = b""
    try:
        while len(head) < 8:
            chunk = sock.recv(8 - len(head))
            if not chunk:
                return False
            head += chunk
    except OSError:
        return False
    return 0 < struct.unpack("<Q", head)[0] < 2**20


def _worker_env() -> dict:
    xla = os.environ.get("XLA_FLAGS", "")
    return {"JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu"),
            "XLA_FLAGS": f"{xla} {SINGLE_THREAD_XLA}".strip(), "OMP_NUM_THREADS": "1"}


def _distributed():
    """The dask.distributed module, or a clear error naming the optional extra."""
    try:
        import distributed
    except ImportError:
        raise ValueError("the dask executor needs dask.distributed: pip install 'pdestream[dask]'") from None
    return distributed


@contextmanager
def dask_client(scheduler: str | None = None, workers: int = 2):
    """A ``distributed.Client``: to ``scheduler`` (an address such as tcp://host:8786) when given, else to
    an embedded ``LocalCluster`` of ``workers`` spawned single-threaded processes (closed on exit)."""
    dist = _distributed()
    if scheduler:
        probe_scheduler(scheduler)
        try:
            client = dist.Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except Exception as err:  # a failed handshake raises what it likes (even MemoryError): one line
            raise ValueError(f"cannot reach the Dask scheduler at {scheduler!r}: {err}") from None
        with client:
            yield client
        return
    # set_as_default=False: leave the caller's dask scheduler (e.g. for xarray's .compute()) untouched
    with ExitStack() as stack:
        restore = _nanny_environ_undone()
        stack.callback(restore)  # (a nanny that restarts a dead worker writes them again: undone at the end too)
        with _sigint_blocked():
            try:
                cluster = stack.enter_context(dist.LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                    silence_logs=logging.CRITICAL, env=_worker_env()))  # a task's error reaches us as an exception
                # (our one line); at ERROR the workers also printed their own 8-line "Compute Failed" report first
            finally:
                restore()
        yield stack.enter_context(dist.Client(cluster, set_as_default=False))


def _nanny_environ_undone():
    """A function that puts back this process's values of the variables a Dask nanny sets before it spawns its
    worker (``distributed.nanny.pre-spawn-environ``: MALLOC_TRIM_THRESHOLD_=65536, OMP_NUM_THREADS=1, ...). The
    nanny writes them into its own process's os.environ, here the caller's, and leaves them there: every process the
    caller started afterwards inherited them (a solver worker with MALLOC_TRIM_THRESHOLD_ spent 2.2x the CPU per
    NumPy solve; a DataLoader or producer process got OMP_NUM_THREADS=1)."""
    import dask

    names = [str(k) for k in dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {}]
    saved = {k: os.environ.get(k) for k in names}

    def restore():
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

    return restore


@contextmanager
def _sigint_blocked():
    """SIGINT blocked in this thread while the cluster starts: its processes (and the thread that spawns them)
    inherit the mask, so a terminal's Ctrl-C, which reaches the whole process group, is handled here alone (the
    cluster is closed in order) instead of printing a KeyboardInterrupt traceback from every worker. A Ctrl-C
    meanwhile is delivered when the block ends."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


PROGRESS_EVERY = 1.0  # seconds between a task's progress events (and its last one)


def _progress_events(topic: str | None, lo: int, hi: int, clock=time.monotonic):
    """A ``meter.progress_to`` callback for a task: its block's fraction done as a Dask event (topic, (lo, hi,
    fraction)) to the client, at most every PROGRESS_EVERY s and at the end; None without a topic or a worker."""
    if topic is None:
        return None
    try:
        worker = _distributed().get_worker()
    except ValueError:  # not on a worker (a task run in the client)
        return None
    last = [None]

    def send(done: int, total: int) -> None:
        now = clock()
        if done == total or last[0] is None or now - last[0] >= PROGRESS_EVERY:
            last[0] = now
            worker.log_event(topic, (lo, hi, done / total))

    return send


def _block_task(config: dict, seed: int, path: str, lo: int, hi: int, block: int, on_blowup: str,
                topic: str | None = None):
    """Runs on a worker: solve samples lo..hi-1 and write them (data, then flags) into the Zarr store; the
    solve's progress goes to the client as events of ``topic`` (``_progress_events``)."""
    from pdestream.meter import progress_to

    from ._bridge import configure_jax, pde_from_config

    configure_jax()  # persistent compilation cache: a (re)started worker does not recompile from scratch
    pde = pde_from_config(config)
    with progress_to(_progress_events(topic, lo, hi)):
        data = cache.solve_block(pde, seed, lo, hi, block, on_blowup)
    store = format_of(path).open(Path(path), writable=True)
    try:
        cache.write_block(store, pde, lo, hi, *data)
    finally:
        store.close()
    return lo, hi


def _run_blocks(client, name: str, settings, path: str, todo, block: int, bar) -> None:
    """One task per (lo, hi) block, counted on ``bar`` (a Meter; disabled: no progress); raises the first task
    error after cancelling the rest."""
    progress = bar.enabled
    if progress and "dashboard" in client.scheduler_info().get("services", {}):
        hint = "" if importlib.util.find_spec("bokeh") else " (install bokeh to see its plots)"
        print(f"dask dashboard: {client.dashboard_link}{hint}", file=sys.stderr)
    seed, on_blowup = settings.seed, settings.on_blowup
    config = settings.config  # tasks rebuild the PDE from it: plain data travels
    tag = f"pdestream-{settings.config_hash}-s{seed}"  # readable task names on the dashboard
    # samples of finished blocks plus the fractions that running tasks report (Dask events)
    count = BlockCount(bar)
    topic = f"{tag}-progress" if progress else None
    if topic:
        client.subscribe_topic(topic, count.event)
    futures = [client.submit(_block_task, config, seed, path, lo, hi, block, on_blowup, topic, key=f"{tag}-{lo}-{hi}",
                             pure=False) for lo, hi in todo]
    try:
        for future in _distributed().as_completed(futures, loop=client.loop):
            lo, hi = future.result()  # a task's error (e.g. generator.BlowUpError) is raised here
            count.finished(lo, hi)
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        if topic:
            client.unsubscribe_topic(topic)


@contextmanager
def _meter(name: str, settings, todo, cluster: str, progress: bool):
    """The Meter of a Dask run, started before its cluster (a line within FIRST s, the estimate from the last run
    of the same ``cluster`` (its workers or scheduler) and set-up); its times recorded at the end."""
    from pdestream.meter import Meter

    from . import timings

    n = settings.n_samples
    key = f"dask {cluster} {name} {settings.config_hash}"
    bar = Meter(f"{name} (dask)", n, "samples", initial=n - sum(hi - lo for lo, hi in todo), enabled=progress,
                last=timings.recall(key) if progress else None, starting="starting the workers and compiling the solver")
    try:
        yield bar
    finally:
        bar.close()
        if progress:
            timings.remember(key, bar.measured())


class BlockCount:
    """Moves a Meter by the blocks of a Dask run: the finished ones (``finished(lo, hi)``) plus the fractions
    that running tasks report (``event``: the handler of ``client.subscribe_topic``, called with a Dask event
    (time, (lo, hi, fraction))). A block's late event after it finished is ignored."""

    def __init__(self, bar):
        self.bar, self.done, self.running, self.ended = bar, bar.initial, {}, set()
        self._lock = threading.Lock()

    def event(self, event) -> None:
        lo, hi, fraction = event[1]
        with self._lock:
            if lo not in self.ended:
                self.running[lo] = max(self.running.get(lo, 0.0), (hi - lo) * min(max(fraction, 0.0), 1.0))
                self.bar.set(self.done + sum(self.running.values()))

    def finished(self, lo: int, hi: int) -> None:
        with self._lock:
            self.running.pop(lo, None)
            self.ended.add(lo)
            self.done += hi - lo
            self.bar.set(self.done + sum(self.running.values()))


def write_cache_dask(pde, path, n_samples: int, seed: int = 0, scheduler: str | None = None, workers: int = 2,
                     resume: bool = False, overwrite: bool = False, block: int | None = None,
                     on_blowup: str = "raise", progress: bool = True) -> cache.WriteSummary:
    """``write_cache`` with blocks solved and written in parallel by Dask workers (Zarr output only).

    Same arguments and result as ``datasets.write_cache`` (bit-identical cache), plus ``scheduler`` (address
    of a running Dask scheduler; None: an embedded LocalCluster) and ``workers`` (its process count).
    ``progress``: a tqdm bar over finished blocks (on a terminal) and the dashboard address on stderr.
    """
    if not format_of(path).parallel_writers:
        raise ValueError(f"the dask executor writes Zarr only (got {str(path)!r}): HDF5 allows one writer per file; "
                         "use a .zarr path, or --executor local for HDF5")
    _distributed()  # before anything is created on disk
    if scheduler:
        check_scheduler(scheduler)  # a malformed address: one line, nothing created (reachability: dask_client)
    if not scheduler and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers={workers!r} not allowed: need an integer >= 1")
    from ._bridge import resolve_pde

    pde = resolve_pde(pde)  # a catalog name or a generator PDE, like write_cache
    start = time.perf_counter()
    with cache.writing(pde, path, n_samples, seed, resume, overwrite, block, on_blowup) as job:
        lay, block, work = job.lay, job.block, job.work  # work: a hidden sibling when replacing an old cache
        store = job.fmt.open(work, writable=True)
        for name in (*lay.fields, *lay.per_sample):  # blocks cover whole chunks: no two tasks share a chunk
            if block % store[name].chunks[0]:
                raise ValueError(f"{path}: {name} chunks {store[name].chunks} along sample do not tile block={block}")
        todo = cache.pending_blocks(store, block)
        try:
            if todo:  # a finished cache needs no cluster
                cluster = f"scheduler={scheduler}" if scheduler else f"workers={workers}"
                with _meter(pde.NAME, job.settings, todo, cluster, progress) as bar, \
                        dask_client(scheduler, workers) as client:
                    # an absolute path: remote workers run in another directory (of a shared filesystem)
                    _run_blocks(client, pde.NAME, job.settings, str(work.resolve()), todo, block, bar)
            if not (store["complete"][:] == 1).all():
                raise RuntimeError(f"{path}: blocks missing after the Dask run (a bug)")
            job.fmt.mark_complete(store)
        except OSError as err:  # a task's write or the last flag failed (a full disk): one line, as write_cache
            raise cache.CacheWriteError(f"cannot write {path}: {cache.os_error_cause(err)}") from None
    written, seconds = sum(hi - lo for lo, hi in todo), time.perf_counter() - start
    return cache.WriteSummary(str(job.path), job.settings.n_samples, written, seconds, schema.disk_bytes(job.path),
                              job.repaired)
