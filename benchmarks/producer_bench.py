"""External solvers as producers: overhead against a plain loop, and scaling with worker processes and Dask.

    python -m benchmarks.producer_bench [--quick] [--solve-ms 50] [--n 40] [--repeats 3] [--dask-only]

The solver (``Busy`` below) does ~``--solve-ms`` of single-threaded NumPy work per sample. Timed, in one process,
median of ``--repeats`` (the arms alternate, so the shared machine's load hits them alike):
- plain loop: ``pde.solve(params, seed)`` called N times in this process (the parameters and seeds the sampler
  draws, computed beforehand): what the user would write without pdestream;
- producer, 0 workers: ``generator.sample(pde, range(N))`` solving in this process (draws, checks, conversion);
- producer, 1 / 2 workers: the same through 1 or 2 solver worker processes (--solver-workers);
- Dask: a warm 2-worker LocalCluster, each worker running ``solve_job`` on half the samples with one solver
  worker of its own, alternated with the 1- and 2-worker producers in the same window (speedups are ratios of
  medians measured under the same load; CPU per solve, from /proc, does not depend on the load);
- kill: a solver worker killed (SIGKILL) mid-solve, and a Dask worker killed mid-job: does the run finish, with
  the undisturbed bits, and how much later.
Overhead = producer time / plain time - 1; speedup = 1-worker time / k-worker time. Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import threading
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream import generator
from pdestream.generator import ExternalSolver, Param
from pdestream.generator.external import solver as external


@dataclass(frozen=True)
class Busy(ExternalSolver):
    """u = exp(-k t) u0 after ``reps`` rounds of elementwise NumPy work (single-threaded) on 20,000 numbers."""

    NAME: ClassVar[str] = "busy_ext1d"
    FIELDS: ClassVar[tuple] = ("u",)
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict] = {"k": Param("decay rate", "1/time", positive=True)}

    n: int = 64
    n_frames: int = 11
    k: Any = "uniform(0.5, 2.0)"
    reps: int = 100
    sleep: float = 0.0  # > 0: wait this many seconds instead of working (a solver waiting on I/O or a licence)

    def solve(self, params, seed):
        x = np.random.default_rng(seed).standard_normal(20_000)
        if self.sleep:
            time.sleep(self.sleep)
        for _ in range(0 if self.sleep else self.reps):
            x = np.sin(x) * 0.9 + 0.1
        return np.exp(-params["k"] * self.times())[:, None, None] * x[None, None, : self.n]


def calibrate(solve_ms: float) -> Busy:
    """A Busy whose solve takes about ``solve_ms`` of CPU here (CPU time, not wall: on the shared cores a wall-time
    calibration gave 21 ms solves for 50 asked)."""
    probe = Busy(reps=50)
    probe.solve({"k": 1.0}, 0)
    t = min(_cpu_timed(lambda: probe.solve({"k": 1.0}, 0)) for _ in range(5))
    return Busy(reps=max(1, round(50 * solve_ms / 1e3 / t)))


def _cpu_timed(fn) -> float:
    start = time.process_time()
    fn()
    return time.process_time() - start


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def _cpu() -> float:
    """CPU seconds used so far by this process and its live solver workers (Linux /proc; load-independent,
    unlike wall time on a shared machine)."""
    total = time.process_time()
    tick = os.sysconf("SC_CLK_TCK")
    for proc in list(external._PROCS):
        try:
            fields = open(f"/proc/{proc.pid}/stat").read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
        except (OSError, IndexError, ValueError):
            pass
    return total


def _cpu_used(fn) -> float:
    start = _cpu()
    fn()
    return _cpu() - start


def drawn_jobs(pde: Busy, n: int, seed: int = 0) -> list[tuple[dict, int]]:
    keys = generator.sample_keys(seed, np.arange(n))
    out = []
    for i in range(n):
        params, s = external._draw(pde, keys[i], np.zeros(1, np.float32), np.zeros(1, bool))
        out.append(({"k": float(params["k"])}, s))
    return out


def plain(pde: Busy, jobs) -> np.ndarray:
    return np.stack([np.asarray(pde.solve(p, s), np.float32) for p, s in jobs])


def producer(pde: Busy, n: int, workers: int) -> np.ndarray:
    external.configure(workers=workers)
    return np.asarray(generator.sample(pde, np.arange(n)).u)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.producer_bench", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer solves and repeats (a smoke run)")
    ap.add_argument("--solve-ms", type=float, default=50.0, help="work per solve, milliseconds")
    ap.add_argument("--n", type=int, default=40, help="solves per timed run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--dask-only", action="store_true", help="only the Dask arms (with their own 1- and 2-worker "
                    "producer runs alternated in the same window)")
    args = ap.parse_args(argv)
    n, repeats = (8, 1) if args.quick else (args.n, args.repeats)
    from benchmarks.producer_bench import calibrate  # Busy by its module's name, not __main__: workers import it

    pde = calibrate(args.solve_ms)
    print(f"{os.cpu_count()} cores, shared with other sessions (load average {os.getloadavg()[0]:.1f}); {n} solves "
          f"per run, median of {repeats}")
    if not args.dask_only:
        for label, solver in (("CPU-bound", pde), ("waiting", type(pde)(sleep=args.solve_ms / 1e3))):
            measure(label, solver, n, repeats)
        kill_solver_worker(pde)
    if not args.no_dask:
        for label, solver in (("CPU-bound", pde), ("waiting", type(pde)(sleep=args.solve_ms / 1e3))):
            dask_arm(label, solver, n, repeats, kill=label == "CPU-bound")
    return 0


def measure(label: str, pde: Busy, n: int, repeats: int) -> float:
    """Times of the plain loop and the producer with 0, 1, 2 workers; returns the 1-worker time."""
    jobs = drawn_jobs(pde, n)
    per_solve = statistics.median(_timed(lambda j=j: pde.solve(*j)) for j in jobs[:5])
    print(f"{label} solver (Busy reps={pde.reps}, sleep={pde.sleep:g} s): one solve {per_solve * 1e3:.1f} ms")
    want = plain(pde, jobs)
    arms = {"plain loop": lambda: plain(pde, jobs), "producer, 0 workers": lambda: producer(pde, n, 0),
            "producer, 1 worker": lambda: producer(pde, n, 1), "producer, 2 workers": lambda: producer(pde, n, 2)}
    for name in list(arms)[1:]:  # warm: worker processes started, the draw program compiled; the same bits
        got = producer(pde, min(n, 4), int(name.split()[1]))
        assert np.array_equal(got, want[: len(got)]), name
    times = {name: [] for name in arms}
    cpus = {name: [] for name in arms}
    for _ in range(repeats):
        for name, fn in arms.items():
            cpu = _cpu()
            times[name].append(_timed(fn))
            cpus[name].append(_cpu() - cpu)
    med = {name: statistics.median(t) for name, t in times.items()}
    cpu = {name: statistics.median(t) for name, t in cpus.items()}
    base, base_cpu = med["plain loop"], cpu["plain loop"]
    print(f"  {'':22s} {'wall':>7s}  {'':13s}    {'wall overhead':>13s}   CPU s (this process + its solver workers)")
    for name, t in med.items():
        extra = "" if name == "plain loop" else f"{100 * (t / base - 1):+12.1f}%"
        extra_cpu = "" if name == "plain loop" else (f"  {1e3 * (cpu[name] - base_cpu) / n:+.2f} ms per solve "
                                                      f"({100 * (cpu[name] - base_cpu) / n / per_solve:+.1f}% of a solve)")
        print(f"  {name:22s} {t:7.3f} s  {n / t:6.2f} solves/s {extra:>13s}   {cpu[name]:6.3f}{extra_cpu}")
    print(f"  speedup 2 workers vs 1: {med['producer, 1 worker'] / med['producer, 2 workers']:.2f}x")
    return med["producer, 1 worker"]


def kill_solver_worker(pde: Busy) -> None:
    """SIGKILL one of 2 solver workers while it solves: the run finishes with the undisturbed bits."""
    slow = type(pde)(reps=pde.reps * 10)  # ~0.5 s per solve: time to aim
    external._stop_all(exiting=False)  # only the two workers of this run: the victim is one of them
    external.configure(workers=2)
    want = np.asarray(generator.sample(slow, [0, 1, 2, 3]).u)
    t_clean = _timed(lambda: generator.sample(slow, [0, 1, 2, 3]))
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("u", np.asarray(generator.sample(slow, [0, 1, 2, 3]).u)))
    start = time.perf_counter()
    thread.start()
    time.sleep(0.2)
    victim = min(p.pid for p in external._PROCS)
    os.kill(victim, signal.SIGKILL)
    thread.join(120)
    t = time.perf_counter() - start
    same = "u" in result and np.array_equal(result["u"], want)
    print(f"  kill -9 of a solver worker mid-solve: finished={'u' in result}, bits as undisturbed={same}, "
          f"{t:.2f} s vs {t_clean:.2f} s undisturbed (the job re-run in a fresh worker)")


def _tree_cpu(pids) -> float:
    """CPU seconds (utime + stime) used so far by processes ``pids`` and all their descendants (Linux /proc)."""
    tick, total, todo = os.sysconf("SC_CLK_TCK"), 0.0, list(pids)
    while todo:
        pid = todo.pop()
        try:
            fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
            for tid in os.listdir(f"/proc/{pid}/task"):
                todo += [int(c) for c in open(f"/proc/{pid}/task/{tid}/children").read().split()]
        except (OSError, IndexError, ValueError):
            pass
    return total


def dask_arm(label: str, pde: Busy, n: int, repeats: int, kill: bool) -> None:
    """A warm 2-worker LocalCluster, each worker solving half the samples (solve_job) with its own solver
    worker, alternated ``repeats`` times with the 1- and 2-worker producers in the same window (the shared
    machine's load hits the three alike); with ``kill``, one Dask worker is killed mid-job."""
    from pdestream.datasets import _bridge
    from pdestream.datasets.distributed import dask_client

    external.configure(workers=1)
    config = pde.config()
    want = producer(pde, n, 1)
    halves = [np.arange(n)[: n // 2], np.arange(n)[n // 2:]]
    with dask_client(None, 2) as client:
        dask_pids = list(client.run(os.getpid).values())

        def run():
            futures = [client.submit(_bridge.solve_job, config, 0, h, pure=False) for h in halves]
            return np.concatenate([f.result()["u"] for f in futures])

        assert np.array_equal(run(), want)  # warm: each worker imports, starts its solver worker
        producer(pde, min(n, 4), 2)
        arms = {"producer, 1 worker": (lambda: producer(pde, n, 1), _cpu), "producer, 2 workers":
                (lambda: producer(pde, n, 2), _cpu), "dask, 2 workers": (run, lambda: _tree_cpu(dask_pids))}
        times, cpus, loads = {a: [] for a in arms}, {a: [] for a in arms}, []
        for _ in range(repeats):
            for name, (fn, cpu_of) in arms.items():
                cpu = cpu_of()
                times[name].append(_timed(fn))
                cpus[name].append(cpu_of() - cpu)
            loads.append(os.getloadavg()[0])
        one = statistics.median(times["producer, 1 worker"])
        print(f"  {label}, alternated {repeats}x in one window (load average {min(loads):.1f}-{max(loads):.1f}):")
        for name in arms:
            t = statistics.median(times[name])
            ratios = " ".join(f"{a / b:.2f}" for a, b in zip(times["producer, 1 worker"], times[name]))
            print(f"    {name:20s} {t:7.3f} s  {n / t:6.2f} solves/s  speedup vs 1 worker {one / t:.2f}x (each "
                  f"round: {ratios})  CPU {1e3 * statistics.median(cpus[name]) / n:.1f} ms per solve")
        if not kill:
            return
        pids = client.run(os.getpid)
        futures = [client.submit(_bridge.solve_job, config, 0, h, pure=False) for h in halves]
        time.sleep(min(1.0, 0.3 * statistics.median(times["dask, 2 workers"])))
        os.kill(next(iter(pids.values())), signal.SIGKILL)
        start = time.perf_counter()
        try:
            got = np.concatenate([f.result(timeout=300)["u"] for f in futures])
            print(f"  kill -9 of a dask worker mid-job: finished, bits as undisturbed={np.array_equal(got, want)}, "
                  f"{time.perf_counter() - start:.2f} s after the kill (dask re-ran its job)")
        except Exception as err:
            print(f"  kill -9 of a dask worker mid-job: stopped with {type(err).__name__}: {str(err).splitlines()[0]}")


if __name__ == "__main__":
    raise SystemExit(main())
