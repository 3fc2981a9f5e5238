"""Any solver as a producer: ``ExternalSolver``, a problem whose samples come from your own code.

Subclass it (a ``@dataclass(frozen=True)``), declare NAME, FIELDS, NDIM, PARAMS (each a domain setting), the
grid (``n``, ``length``, ``BC``), ``n_frames`` and ``t_end``, and either

* a method ``solve(self, params, seed) -> array [T, C, *space]`` (numpy, scipy, PhiFlow, JAX, anything), or
* ``COMMAND``: an argv list run once per sample, in which ``{params}`` is replaced by the path of a JSON file
  {"params": {...}, "seed": s, "settings": {...}} and ``{out}`` by the path the command must write (.npy, or .h5
  with a dataset "u"; ``OUTPUT`` picks the suffix).

pdestream draws the parameters (the same keys as every entry: sample i of seed s is key fold_in(key(s), i),
split into a parameter key and a solver-seed key), solves each sample in a worker process, checks the result
and hands it on as any entry's sample: the stream, the reservoir (loss-driven sampling too) and the caches read
it through ``generator.Problem``. Identity: (config with the class's origin, seed, index[, params]); the
solver gets ``seed`` (an int in [0, 2**32)) derived from (seed, index), so a deterministic solver gives the same
bits alone, batched, streamed or cached. A solver that is not (``DETERMINISTIC = False``) is stated as not
reproducible in ``describe()``.

Worker processes (``configure(workers=N, timeout=S)``, the CLI's ``--solver-workers`` / ``--solver-timeout``):
N plain subprocesses (not forked: JAX is not fork-safe; started with ``subprocess`` so that a Dask worker, a
daemon, may start them) solve the samples of one call in parallel; a solve past S seconds has its worker killed
(its process group: a COMMAND's children too). Each failure -- the solver raised, timed out, crashed, returned
the wrong shape or NaN/Inf, or its command exited non-zero -- is one line naming the cause
(``failure_causes``) and fails that sample only, under the usual policies (on_blowup raise / redraw / skip). A
worker that dies mid-solve (killed from outside, or the solver crashed it) is replaced and the sample solved
once more before it counts as a crash. ``workers=0`` solves in the calling process (no timeout; a crash of the
solver is a crash of the caller).
A worker gets its caller's environment, less the malloc setting a Dask nanny gives its worker process
(MALLOC_TRIM_THRESHOLD_): inherited, it more than doubled the CPU cost of a NumPy solver's every solve.
"""

from __future__ import annotations

import functools
import json
import math
import os
import pickle
import queue
import select
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import Future, wait
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ...boundaries import BOUNDARY_TYPES, Boundary, is_periodic
from ..dispatch import Cancelled, cancelled, report
from ..grids import GridBase
from ..problem import ProblemBase, resolve_params

WORKERS_ENV = "PDESTREAM_SOLVER_WORKERS"
TIMEOUT_ENV = "PDESTREAM_SOLVER_TIMEOUT"
DEFAULT_WORKERS = 1
STARTUP_S = 300.0  # the longest a worker may take to start and import the solver's module
CRASH_RETRIES = 1  # a worker that died mid-solve: the sample is solved again this many times in a fresh one


@dataclass(frozen=True)
class SolverIC:
    """The initial condition of an external solver: the solver's own, drawn from the ``seed`` it is given."""

    kind = "solver"
    field_count = None

    def __str__(self) -> str:
        return "the solver's own, from the seed it is given"

    def check(self, grid) -> None:
        """Nothing to check: the solver owns its initial condition."""

    def bound(self, grid) -> float:
        return math.inf

    def sample(self, key, grid, n_fields: int = 1):
        raise ValueError("an external solver draws its own initial condition from the seed it is given")


@dataclass(frozen=True)
class SolverGrid(GridBase):
    """``n`` points per axis on [0, length]^ndim with one boundary type on every axis: periodic (points i h,
    h = length / n) or dirichlet / neumann (nodes i h, h = length / (n - 1), both ends included)."""

    walls: str = Boundary.PERIODIC.value
    POINTS: ClassVar[str] = "the external solver's grid points"

    @property
    def bc(self) -> tuple[str, ...]:
        return (self.walls,) * self.ndim

    def coords(self, axis: int = 0) -> np.ndarray:
        """Point positions along ``axis``, float32 [n] (length units)."""
        if is_periodic(self.walls):
            return (np.arange(self.n) * (self.length / self.n)).astype(np.float32)
        return np.linspace(0.0, self.length, self.n).astype(np.float32)

    def describe(self) -> str:
        box = f"[0, {self.length:g})" if is_periodic(self.walls) else f"[0, {self.length:g}]"
        return f"{'x'.join(map(str, self.shape))} points on {box}^{self.ndim} ({self.walls})"


# --- worker settings: in the environment, so spawned producers and a local Dask cluster inherit them ----------
def configure(workers: int | None = None, timeout: float | None = None) -> None:
    """Worker processes per solving process (0: solve in the caller) and the seconds one solve may take (None:
    no limit), for this process and the processes it starts afterwards (producers, a LocalCluster's workers)."""
    if workers is not None:
        if isinstance(workers, bool) or not isinstance(workers, int) or not 0 <= workers <= 256:
            raise ValueError(f"--solver-workers={workers!r} not allowed; must be an integer in [0, 256]")
    if timeout is not None:
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not 0 < timeout < math.inf:
            raise ValueError(f"--solver-timeout={timeout!r} not allowed; must be a number of seconds > 0")
    now_workers, now_timeout = settings()
    if (now_workers if workers is None else workers) == 0 and (now_timeout if timeout is None else timeout):
        # a solve in the calling process cannot be stopped from outside: the timeout would be ignored
        raise ValueError(f"--solver-timeout={(now_timeout if timeout is None else timeout):g} not allowed with "
                         "--solver-workers 0 (a solve in the calling process cannot be stopped): use >= 1 worker")
    if workers is not None:
        os.environ[WORKERS_ENV] = str(workers)
    if timeout is not None:
        os.environ[TIMEOUT_ENV] = repr(float(timeout))


def settings() -> tuple[int, float | None]:
    """(workers, timeout in seconds or None) in force in this process."""
    workers = int(os.environ.get(WORKERS_ENV, DEFAULT_WORKERS))
    timeout = os.environ.get(TIMEOUT_ENV)
    return workers, (float(timeout) if timeout else None)


@dataclass(frozen=True)
class ExternalSolver(ProblemBase):
    """A problem solved by your code: subclass, set the class attributes and settings, give ``solve`` or COMMAND.

    A sample is u [n_frames, len(FIELDS), n, ...] (NDIM spatial axes) at ``times()`` = linspace(0, t_end,
    n_frames). ``solve(params, seed)`` gets {name: float} for every parameter and an int seed; the settings are
    the instance's fields (self.n, self.t_end, your own).
    """

    EQUATION: ClassVar[str] = "an external solver"
    IC_KINDS: ClassVar[dict] = {SolverIC.kind: SolverIC}
    IC_LABEL: ClassVar[str] = "initial condition"
    BC: ClassVar[str] = Boundary.PERIODIC.value  # the boundary type of every axis, one of generator.BOUNDARY_TYPES
    COMMAND: ClassVar[tuple] = ()  # argv with "{params}" and "{out}"; empty: the solve method
    OUTPUT: ClassVar[str] = ".npy"  # what the command writes: ".npy", or ".h5" (dataset "u")
    ADVANCES: ClassVar[bool] = False  # no solve from a given state: --mode oracle and the interactive modes refuse it
    DETERMINISTIC: ClassVar[bool] = True  # False: the same (seed, index) may give other bits (stated, not hidden)

    n: int = 64
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 11
    ic: Any = "solver"

    # --- the user's part -----------------------------------------------------------------------------
    def solve(self, params: dict, seed: int):
        """One trajectory [n_frames, C, *space] for parameters {name: float} and an integer seed; by default runs
        COMMAND (subclasses without COMMAND override this)."""
        return run_command(self, params, seed)

    # --- the problem protocol --------------------------------------------------------------------------
    @property
    def grid(self) -> SolverGrid:
        return SolverGrid(self.NDIM, self.n, self.length, self.BC)

    @property
    def shape(self) -> tuple[int, ...]:
        """What every solve must return: (n_frames, C, *space)."""
        return (self.n_frames, len(self.FIELDS), *self.grid.shape)

    def times(self) -> np.ndarray:
        return np.linspace(0.0, self.t_end, self.n_frames).astype(np.float32)

    def validate(self) -> None:
        name = type(self).__name__
        if type(self).solve is ExternalSolver.solve and not self.COMMAND:
            raise ValueError(f"{self.NAME or name}: class {name} lacks the required method solve(self, params, seed) "
                             "(or a COMMAND)")
        if self.COMMAND and (isinstance(self.COMMAND, str) or not all(isinstance(a, str) for a in self.COMMAND)):
            raise ValueError(f"{self.NAME}: COMMAND={self.COMMAND!r} not allowed: an argv list of strings, e.g. "
                             "['python', 'solve.py', '{params}', '{out}']")
        fields = self.FIELDS
        if not isinstance(fields, tuple) or not fields or not all(isinstance(f, str) and f for f in fields):
            raise ValueError(f"{self.NAME}: FIELDS={fields!r} not allowed: a tuple of one or more field names, "
                             "e.g. ('u',)")
        if len(set(fields)) != len(fields):
            raise ValueError(f"{self.NAME}: FIELDS={fields!r} not allowed: names must differ")
        if self.OUTPUT not in (".npy", ".h5"):
            raise ValueError(f"{self.NAME}: OUTPUT={self.OUTPUT!r} not allowed; allowed: '.npy', '.h5'")
        if self.BC not in BOUNDARY_TYPES:
            raise ValueError(f"{self.NAME}: BC={self.BC!r} not allowed; allowed: {', '.join(BOUNDARY_TYPES)}")
        if self.NDIM not in (1, 2, 3):
            raise ValueError(f"{self.NAME}: NDIM={self.NDIM!r} not allowed; allowed: 1, 2, 3")
        if self.n < 2:
            raise ValueError(f"{self.NAME}: n={self.n} not allowed: must be >= 2")
        if self.n_frames < 1:
            raise ValueError(f"{self.NAME}: n_frames={self.n_frames} not allowed: must be >= 1")
        if not (self.t_end > 0 and math.isfinite(self.t_end)):
            raise ValueError(f"{self.NAME}: t_end={self.t_end} not allowed: must be a finite number > 0")
        self._check_length()
        self._check_size()
        self.check_settings()

    def describe_setup(self) -> str:
        how = f"command {' '.join(self.COMMAND)}" if self.COMMAND else f"{type(self).__name__}.solve"
        repro = "" if self.DETERMINISTIC else "; NOT reproducible: the solver is not deterministic"
        return (f"  fields {', '.join(self.FIELDS)} on {self.grid.describe()}; {self.n_frames} frames on "
                f"[0, {self.t_end:g}]; solved by {how}{repro}")

    def failure(self) -> tuple[str, str]:
        return ("samples failed in the external solver",
                "fix the solver, give it more time (--solver-timeout), or on_blowup='redraw' / 'skip'")

    def failure_causes(self) -> list[str]:
        """Why each sample of this thread's last ``run_keys`` failed ('' where it did not): one line each."""
        return list(getattr(_LAST, "causes", ()))

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """keys [B], explicit float32 [B, P], given bool [B, P] -> (u [B, T, C, *space], params {name: [B]},
        ok bool [B], None); the causes of the failures in ``failure_causes()``."""
        drawn = [_draw(self, keys[b], jnp.asarray(explicit[b]), jnp.asarray(given[b])) for b in range(len(keys))]
        params = {name: np.array([float(p[name]) for p, _ in drawn], np.float32) for name in self.PARAMS}
        jobs = [({name: float(params[name][b]) for name in self.PARAMS}, int(seed)) for b, (_, seed) in enumerate(drawn)]
        # a padded batch (the stream's and the reservoir's fixed solve_batch) repeats samples: solve each once
        first = {}
        for b, (p, seed) in enumerate(jobs):
            first.setdefault((tuple(p.items()), seed), b)
        unique = sorted(set(first.values()))
        solved = dict(zip(unique, solve_all(self, [jobs[b] for b in unique])))
        results = [solved[first[(tuple(p.items()), seed)]] for p, seed in jobs]
        u = np.zeros((len(jobs), *self.shape), np.float32)
        causes = []
        for b, (out, cause) in enumerate(results):
            if not cause:
                out, cause = check_result(self, out)
            if cause:
                args = ", ".join(f"{k}={v:.6g}" for k, v in jobs[b][0].items())
                causes.append(f"{cause} (params {args or 'none'}, solver seed {jobs[b][1]})")
            else:
                u[b] = out
                causes.append("")
        _LAST.causes = causes
        ok = np.array([not c for c in causes])
        return jnp.asarray(u), {k: jnp.asarray(v) for k, v in params.items()}, ok, None


_LAST = threading.local()


@functools.lru_cache(maxsize=64)
def _draw_program(problem: ExternalSolver):
    def one(key, explicit, given):
        k_param, k_seed = jax.random.split(key)
        return resolve_params(problem, k_param, explicit, given), jax.random.bits(k_seed, (), jnp.uint32)

    return jax.jit(one)


def _draw(problem: ExternalSolver, key, explicit, given) -> tuple[dict, int]:
    """(parameters {name: float32 scalar}, solver seed int) of one sample: its key split into a parameter key and a
    seed key, as every family splits its keys; one compiled program per problem, one key per call (so a sample's
    parameters do not depend on its batch)."""
    params, seed = _draw_program(problem)(key, explicit, given)
    return params, int(seed)


def check_result(problem: ExternalSolver, out) -> tuple[np.ndarray | None, str]:
    """(float32 array, '') for a good solve result, else (None, the cause in words)."""
    try:
        arr = np.asarray(out)
    except Exception as err:  # the solver's object, whatever it is: say what it was
        return None, f"returned {type(out).__name__}, not an array ({type(err).__name__}: {err})"
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        return None, f"returned {type(out).__name__} of dtype {arr.dtype}, not numbers"
    if np.iscomplexobj(arr):  # a cast to float32 would keep the real part and drop the rest silently
        return None, (f"returned complex values (dtype {arr.dtype}); a sample holds real fields: return the real "
                      "and imaginary parts as two FIELDS")
    if arr.shape != problem.shape:
        return None, (f"returned shape {tuple(arr.shape)}; expected {problem.shape} = [T={problem.n_frames}, "
                      f"C={len(problem.FIELDS)}, *space={problem.grid.shape}]")
    arr = arr.astype(np.float32)
    finite = np.isfinite(arr)
    if not finite.all():
        frame = int(np.flatnonzero(~finite.reshape(len(arr), -1).all(1))[0])
        return None, f"returned NaN/Inf (first in frame {frame}, or beyond float32)"
    return arr, ""


# --- running solves ------------------------------------------------------------------------------------------
def solve_all(problem: ExternalSolver, jobs: list[tuple[dict, int]]) -> list[tuple[Any, str]]:
    """[(output or None, cause or '')] for jobs [(params, seed)], in order: in worker processes (settings())
    in parallel, or in this process with workers = 0."""
    workers, timeout = settings()
    if workers == 0:
        out = []
        for p, s in jobs:
            out.append(_solve_here(problem, p, s))
            report(len(out), len(jobs))  # progress: one report per finished sample
        return out
    where = (problem.config().get("origin") or {}).get("module")
    if where == "__main__":
        raise ValueError(f"{problem.NAME}: class {type(problem).__name__} is defined in the script being run "
                         "(module __main__), which solver worker processes cannot import; define it in a module "
                         "and import it from there, or solve in this process (--solver-workers 0)")
    pool = _pool(workers)
    config = problem.config()
    futures = [pool.submit(config, *job, timeout) for job in jobs]
    finished = 0
    while (waited := wait(futures, timeout=0.2)).not_done:
        if len(waited.done) > finished:  # progress: samples finished so far
            finished = len(waited.done)
            report(finished, len(jobs))
        if cancelled():  # the consumer has gone (a closed reservoir): stop waiting; the solves in flight end alone
            for f in futures:
                f.cancel()
            raise Cancelled("external solves cancelled: their consumer stopped")
    report(len(jobs), len(jobs))
    return [f.result() for f in futures]


def _solve_here(problem, params, seed):
    try:
        return problem.solve(dict(params), seed), ""
    except Exception as err:
        return None, _raised(err)


def _raised(err: BaseException) -> str:
    text = " ".join(str(err).split())  # one line, whatever the solver's message
    return f"raised {type(err).__name__}: {text[:300]}"


class _Pool:
    """``workers`` daemon threads, each talking to a worker process of its own. Daemon threads: an exit (a
    Ctrl-C) never waits for a solve in flight, which may run for hours or hang; the workers are killed at exit."""

    def __init__(self, workers: int):
        self.jobs: queue.Queue = queue.Queue()
        for i in range(workers):
            threading.Thread(target=self._serve, name=f"pdestream-external-{i}", daemon=True).start()

    def submit(self, *args) -> Future:
        future: Future = Future()
        self.jobs.put((future, args))
        return future

    def _serve(self) -> None:
        while True:
            future, args = self.jobs.get()
            if future is None:
                return
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(_solve_in_worker(*args))
                except BaseException as err:  # handed to the caller, who raises it
                    future.set_exception(err)

    def stop(self) -> None:
        while True:  # queued jobs are cancelled; each thread ends after its job in flight
            try:
                future, _args = self.jobs.get_nowait()
            except queue.Empty:
                break
            future.cancel()
        for _ in range(64):
            self.jobs.put((None, None))


_POOLS: dict[int, _Pool] = {}
_POOL_LOCK = threading.Lock()
_LOCAL = threading.local()  # the worker process of each pool thread
_PROCS: set = set()
_STOPPING = threading.Event()


def _pool(workers: int) -> _Pool:
    """The threads (one per worker process) that run solves; kept for the life of this process."""
    with _POOL_LOCK:
        pool = _POOLS.get(workers)
        if pool is None:
            pool = _POOLS[workers] = _Pool(workers)
        return pool


def _solve_in_worker(config: dict, params: dict, seed: int, timeout: float | None) -> tuple[Any, str]:
    """One solve in this thread's worker process: (output, '') or (None, cause). A worker that ends mid-solve is
    replaced and the job run again (CRASH_RETRIES times) before the sample counts as crashed."""
    payload = pickle.dumps((config, params, seed), protocol=5)
    for attempt in range(CRASH_RETRIES + 1):
        if _STOPPING.is_set():
            return None, "not solved: the solvers are being stopped (exit)"
        worker = getattr(_LOCAL, "worker", None)
        if worker is None or worker.poll() is not None:
            worker = _LOCAL.worker = _start_worker()
        status, value = _exchange(worker, payload, timeout)
        if status == "ok":
            return value, ""
        if status == "error":
            return None, value
        _LOCAL.worker = None
        _kill(worker)
        if status == "timeout":
            return None, f"timed out after {timeout:g} s (--solver-timeout); its worker was stopped"
        if attempt == CRASH_RETRIES:
            return None, f"crashed: {value} (solved {CRASH_RETRIES + 1} times)"
    raise AssertionError("unreachable")


def _dask_malloc_settings() -> dict[str, str]:
    """The glibc malloc variables a Dask nanny puts into its worker's environment (``distributed.nanny.pre-spawn-environ``:
    MALLOC_TRIM_THRESHOLD_=65536 by default), as strings; {} where Dask is not loaded (then it started nothing here)."""
    if "distributed" not in sys.modules:
        return {}
    try:
        import dask

        spawn_env = dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {}
    except Exception:  # a damaged Dask configuration is Dask's to report
        return {}
    return {k: str(v) for k, v in spawn_env.items() if k.startswith("MALLOC_")}


def _solver_env(base=None) -> dict:
    """The environment of a solver worker started from a process with environment ``base`` (default os.environ).

    As the caller's, except the malloc setting a Dask nanny gave its worker (MALLOC_TRIM_THRESHOLD_=65536, for the
    Dask worker's own memory reports): set at all, it fixes glibc's mmap threshold at 128 KiB, so a solver's every
    array of more than 128 KiB is mapped fresh from the kernel and zero-filled on first touch, and freed back at once.
    A NumPy solver working on 160 KB arrays spent 2.2x the CPU per solve (48,000 page faults per solve): two Dask
    workers solved no faster than one worker process. A value other than Dask's (set by the user) is kept."""
    env = dict(os.environ if base is None else base)
    for name, value in _dask_malloc_settings().items():
        if env.get(name) == value:
            del env[name]
    return env


def _start_worker() -> subprocess.Popen:
    env = _solver_env()
    # the worker finds the user's module where this process found it (a test's tmp_path, the script's folder)
    env["PYTHONPATH"] = os.pathsep.join(p or os.getcwd() for p in sys.path)
    env.setdefault("JAX_PLATFORMS", "cpu")  # a solver's JAX, if any, stays off a GPU the trainer uses
    env[WORKERS_ENV] = "0"
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.generator.external.worker"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, env=env, process_group=0)
    # its own process group (a timeout kills the group: a COMMAND's children too), not its own session: a new
    # session would be a new scheduling autogroup on Linux, and take a larger CPU share than its caller's
    _PROCS.add(proc)
    return proc


def _kill(proc: subprocess.Popen) -> None:
    """End a worker and everything it started (its process group: a COMMAND's solver too)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        pass
    for f in (proc.stdin, proc.stdout):
        try:
            f.close()
        except OSError:
            pass
    _PROCS.discard(proc)


def _exchange(proc: subprocess.Popen, payload: bytes, timeout: float | None) -> tuple[str, Any]:
    """Send one job, wait for its answer: ("ok", array), ("error", cause), ("timeout", None) or ("crash", why)."""
    try:
        proc.stdin.write(struct.pack("<Q", len(payload)) + payload)
        proc.stdin.flush()
    except (BrokenPipeError, OSError):
        return "crash", _ended(proc)
    fd = proc.stdout.fileno()
    try:
        # the worker says when the solve starts: its own start-up and the import of the solver's module (JAX,
        # PhiFlow: seconds) do not count against the timeout
        started = _frame(fd, None if timeout is None else time.monotonic() + max(STARTUP_S, timeout))
        if started[0] != "started":
            return started
        return _frame(fd, None if timeout is None else time.monotonic() + timeout)
    except TimeoutError:
        return "timeout", None
    except EOFError:
        return "crash", _ended(proc)


def _frame(fd: int, deadline: float | None):
    head = _read(fd, 8, deadline)
    return pickle.loads(_read(fd, struct.unpack("<Q", head)[0], deadline))


def _ended(proc: subprocess.Popen) -> str:
    try:
        code = proc.wait(5)
    except subprocess.TimeoutExpired:
        return "its worker process stopped answering"
    how = f"signal {-code} ({signal.Signals(-code).name})" if code < 0 else f"exit code {code}"
    return f"its worker process ended mid-solve ({how})"


def _read(fd: int, n: int, deadline: float | None) -> bytes:
    parts, got = [], 0
    while got < n:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise TimeoutError
        chunk = os.read(fd, min(n - got, 1 << 22))
        if not chunk:
            raise EOFError
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


def _stop_all(exiting: bool = True) -> None:
    """End every solver worker of this process and their threads (at exit; exiting=False: the next solve
    starts fresh ones)."""
    if exiting:
        _STOPPING.set()
    with _POOL_LOCK:
        pools = list(_POOLS.values())
        _POOLS.clear()
    for pool in pools:
        pool.stop()
    for proc in list(_PROCS):
        _kill(proc)


import atexit  # noqa: E402 (registered after the function it calls)

atexit.register(_stop_all)


# --- COMMAND solvers -----------------------------------------------------------------------------------------
def run_command(problem: ExternalSolver, params: dict, seed: int) -> np.ndarray:
    """Run ``problem.COMMAND`` for one sample: the parameters as JSON in a temporary file, the trajectory read
    from the file it writes; RuntimeError (one line) if it exits non-zero or writes nothing readable."""
    settings_ = {k: v for k, v in problem.config().items() if k not in ("pde", "origin", "ic", *problem.PARAMS)}
    with tempfile.TemporaryDirectory(prefix="pdestream-solve-") as tmp:
        spec, out = os.path.join(tmp, "params.json"), os.path.join(tmp, "u" + problem.OUTPUT)
        with open(spec, "w") as f:
            json.dump({"params": params, "seed": seed, "settings": settings_}, f)
        argv = [a.replace("{params}", spec).replace("{out}", out) for a in problem.COMMAND]
        try:
            done = subprocess.run(argv, capture_output=True, text=True)
        except OSError as err:
            raise RuntimeError(f"command {argv[0]!r} could not start: {err.strerror}") from None
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or [""])[-1][:200]
            raise RuntimeError(f"command exited with code {done.returncode}" + (f": {last}" if last else ""))
        if not os.path.exists(out):
            raise RuntimeError(f"command exited 0 but wrote no {problem.OUTPUT} file at {{out}}")
        if problem.OUTPUT == ".npy":
            return np.load(out, allow_pickle=False)
        import h5py

        with h5py.File(out, "r") as f:
            if "u" not in f:
                raise RuntimeError(f"command's .h5 output has no dataset 'u' (has {', '.join(f) or 'nothing'})")
            return f["u"][()]


# --- the worker process --------------------------------------------------------------------------------------
def _serve() -> None:
    """A worker: read jobs (config, params, seed) from stdin, answer ("ok", float32 array) or ("error", cause)."""
    proto_in = os.fdopen(os.dup(0), "rb", buffering=0)
    proto_out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # the solver's prints go to stderr, never into the answers
    problems: dict[str, Any] = {}
    from .. import from_config

    while True:
        head = proto_in.read(8)
        if len(head) < 8:
            return
        size = struct.unpack("<Q", head)[0]
        body = b""
        while len(body) < size:
            chunk = proto_in.read(size - len(body))
            if not chunk:
                return
            body += chunk
        config, params, seed = pickle.loads(body)
        key = json.dumps(config, sort_keys=True)
        try:
            problem = problems.get(key) or problems.setdefault(key, from_config(config))
        except Exception as err:  # the class could not be rebuilt here (its module, its code changed)
            problem, out, cause = None, None, _raised(err)
        try:
            _send(proto_out, ("started", None))
        except OSError:
            return
        if problem is not None:
            out, cause = _solve_here(problem, params, seed)
        if not cause:
            try:
                out = np.asarray(out)
                if out.dtype != object:
                    out = np.ascontiguousarray(out)
                answer = ("ok", out)
                data = pickle.dumps(answer, protocol=5)
            except Exception as err:
                data = pickle.dumps(("error", f"returned something that cannot be sent back ({_raised(err)})"))
        else:
            data = pickle.dumps(("error", cause), protocol=5)
        try:
            proto_out.write(struct.pack("<Q", len(data)) + data)
            proto_out.flush()
        except OSError:  # the caller has gone (killed, or it stopped this solve): nobody to answer
            return


def _send(f, message) -> None:
    data = pickle.dumps(message, protocol=5)
    f.write(struct.pack("<Q", len(data)) + data)
    f.flush()
