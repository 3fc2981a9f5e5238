"""Dask generation benchmark: samples/s of ``write_cache_dask`` with 1 and 2 workers vs ``write_cache``.

    python -m benchmarks.dask_bench [--quick] [--pde burgers1d] [--set n=512 ...] [--n 192] [--block 16]

All runs write the same Zarr cache (samples 0..N-1, seed 0) to a temporary directory, in one process:
- local: ``datasets.write_cache`` (one process; XLA uses every core; writing overlaps solving);
- dask steady: a LocalCluster (spawned single-threaded workers) started and warmed (compiled) beforehand,
  then ``write_cache_dask(scheduler=address)`` timed: the throughput a long run approaches;
- dask end-to-end: ``write_cache_dask(workers=k)`` with its embedded cluster, as ``pdestream generate
  --executor dask`` runs it: cluster start, JAX import and compilation in every worker included.
Median of ``--repeats`` runs (alternating local and dask); ratio = dask samples/s / local samples/s. The dask
output is checked equal to the local one. Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import statistics
import sys
import tempfile
import time

import numpy as np

from pdestream import generator
from pdestream.datasets import open_cache, write_cache
from pdestream.datasets.distributed import _worker_env, write_cache_dask

DEFAULT = {"n": "512", "n_frames": "51", "t_end": "1.0"}


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def _same(a, b) -> bool:
    x, y = open_cache(a), open_cache(b)
    return all(np.array_equal(x[v].values, y[v].values, equal_nan=True) for v in y.variables)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.dask_bench", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small run (~1-2 min): N=48, one repeat")
    ap.add_argument("--pde", default="burgers1d")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="PDE override")
    ap.add_argument("--n", type=int, help="samples (default 192; quick 48)")
    ap.add_argument("--block", type=int, default=16, help="samples per block / Dask task")
    ap.add_argument("--repeats", type=int, help="timed runs per arm (default 3; quick 1)")
    ap.add_argument("--workers", default="1,2", help="worker counts to measure")
    args = ap.parse_args(argv)
    try:
        from distributed import LocalCluster
    except ImportError:
        print("dask benchmark not run: dask is not installed (pip install -e '.[dask]')")
        return 0

    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    n = args.n or (48 if args.quick else 192)
    repeats = args.repeats or (1 if args.quick else 3)
    pde = generator.get_pde(args.pde, {**DEFAULT, **dict(s.split("=", 1) for s in args.set)})
    block = min(args.block, n)
    print(f"{pde.NAME} n={pde.n} frames={pde.n_frames} | N={n} samples, block {block}, {repeats} repeat(s), "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} (other processes skew the figures)")
    tmp = tempfile.mkdtemp(prefix="dask_bench_")
    try:
        ref = os.path.join(tmp, "local.zarr")
        write_cache(pde, ref, block, seed=0, block=block, progress=False)  # compile once in this process
        local = []
        rows = []
        for k in [int(w) for w in args.workers.split(",")]:
            out = os.path.join(tmp, f"dask{k}.zarr")
            with LocalCluster(n_workers=k, threads_per_worker=1, processes=True, dashboard_address=":0",
                              silence_logs=logging.ERROR, env=_worker_env()) as cluster:
                addr = cluster.scheduler_address
                warm = os.path.join(tmp, "warm.zarr")  # compile in every worker: one block per worker
                write_cache_dask(pde, warm, block * k, scheduler=addr, block=block, progress=False, overwrite=True)
                steady = []
                for _ in range(repeats):
                    local.append(_timed(lambda: write_cache(pde, ref, n, block=block, progress=False,
                                                            overwrite=True)))
                    steady.append(_timed(lambda: write_cache_dask(pde, out, n, scheduler=addr, block=block,
                                                                  progress=False, overwrite=True)))
            same = _same(out, ref)
            e2e = _timed(lambda: write_cache_dask(pde, out, n, workers=k, block=block, progress=False,
                                                  overwrite=True))
            rows.append((k, statistics.median(steady), e2e, same))
        t_local = statistics.median(local)
        print(f"{'arm':<28}{'seconds':>9}{'samples/s':>11}{'vs local':>10}")
        print(f"{'local write_cache':<28}{t_local:9.2f}{n / t_local:11.1f}{1.0:10.2f}")
        for k, t_steady, t_e2e, same in rows:
            print(f"{f'dask {k} worker(s), steady':<28}{t_steady:9.2f}{n / t_steady:11.1f}{t_local / t_steady:10.2f}"
                  f"   identical to local: {same}")
            print(f"{f'dask {k} worker(s), end-to-end':<28}{t_e2e:9.2f}{n / t_e2e:11.1f}{t_local / t_e2e:10.2f}")
        if len(rows) > 1:
            print(f"dask scaling {rows[-1][0]} vs {rows[0][0]} worker(s), steady: {rows[0][1] / rows[-1][1]:.2f}x")
        print(f"load average at the end: {os.getloadavg()[0]:.1f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
