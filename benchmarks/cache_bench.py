"""Cache benchmark: what writing costs generation, and how fast a cache feeds a DataLoader.

    python -m benchmarks.cache_bench [--quick] [--repeats R]

Per case and format (HDF5, Zarr), in one process:
- write: samples/s of ``write_cache`` (generate block k+1 while writing block k) against pure generation
  of the same blocks (``generator.sample`` with the same block size, results pulled to host memory);
  the ratio write/generate is the figure (target >= 0.9): the median over ``repeats`` back-to-back
  pairs (rates are medians too).
- read: samples/s of ``CachedTrajectories`` (view "whole") through a DataLoader (batch 32, shuffled;
  0 and 2 spawn workers, second epoch so worker start-up is excluded; warm page cache), against the
  ``TrajectoryStream`` of the same samples (generation on demand, num_workers=0).
Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from pdestream import datasets, generator

CASES = {  # name: (overrides, n_samples, block)
    "burgers1d": ({"n": "256", "n_frames": "51"}, 512, 64),
    "ns2d": ({"n": "64", "n_frames": "21", "t_end": "5"}, 64, 16),
}
QUICK = {
    "burgers1d": ({"n": "128", "n_frames": "26"}, 128, 32),
    "ns2d": ({"n": "32", "n_frames": "11", "t_end": "2"}, 32, 8),
}


def generate_only(pde, n: int, block: int, seed: int = 0) -> float:
    """Seconds to solve samples 0..n-1 in blocks of ``block`` (padded like the writer) into host memory."""
    start = time.perf_counter()
    for lo in range(0, n, block):
        idx = np.minimum(np.arange(lo, lo + block), n - 1)
        traj = generator.sample(pde, idx, seed)
        np.asarray(traj.u)
    return time.perf_counter() - start


def write(pde, path: Path, n: int, block: int) -> float:
    start = time.perf_counter()
    datasets.write_cache(pde, path, n, seed=0, block=block, overwrite=True, progress=False)
    return time.perf_counter() - start


def read_rate(dataset, workers: int, epochs: int = 2) -> float:
    """Samples/s of the last of ``epochs`` passes through a shuffled DataLoader."""
    kw = dict(num_workers=workers, persistent_workers=True, multiprocessing_context="spawn") if workers else {}
    loader = torch.utils.data.DataLoader(dataset, batch_size=32, shuffle=True, **kw)
    for _ in range(epochs):
        start, count = time.perf_counter(), 0
        for batch in loader:
            count += len(batch["index"])
        seconds = time.perf_counter() - start
    return count / seconds


def stream_rate(pde, n: int, block: int) -> float:
    stream = datasets.TrajectoryStream(pde, seed=0, view="whole", batch_size=32, n_samples=n, solve_batch=block,
                                       resample=False)
    loader = datasets.stream_loader(stream)
    for _ in range(2):  # the first pass compiles for this solve_batch
        start, count = time.perf_counter(), 0
        for batch in loader:
            count += len(batch["index"])
        seconds = time.perf_counter() - start
    return count / seconds


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a minute on 2 cores)")
    ap.add_argument("--repeats", type=int, default=None, help="alternating write/generate runs (default 3, quick 2)")
    args = ap.parse_args(argv)
    cases = QUICK if args.quick else CASES
    repeats = args.repeats or (2 if args.quick else 3)
    tmp = Path(tempfile.mkdtemp(prefix="cache_bench_"))
    try:
        print(f"{'case':<10} {'fmt':<5} {'N':>5} {'blk':>4} {'gen s/s':>9} {'write s/s':>9} {'ratio':>6} "
              f"{'MiB':>7} {'read w0':>9} {'read w2':>9} {'stream':>8}")
        for name, (overrides, n, block) in cases.items():
            pde = generator.get_pde(name, overrides)
            generate_only(pde, block, block)  # compile once, outside every timing
            stream = stream_rate(pde, n, block)
            for fmt in ("h5", "zarr"):
                path = tmp / f"{name}.{fmt}"
                gen_t, write_t = [], []
                for _ in range(repeats):  # back-to-back pairs: load from other processes hits both alike
                    gen_t.append(generate_only(pde, n, block))
                    write_t.append(write(pde, path, n, block))
                gen, wr = n / statistics.median(gen_t), n / statistics.median(write_t)
                ratio = statistics.median(g / w for g, w in zip(gen_t, write_t))
                mib = datasets.cache.schema.disk_bytes(path) / 2**20
                loader = datasets.CachedTrajectories(path, view="whole")
                r0, r2 = read_rate(loader, 0), read_rate(loader, 2)
                print(f"{name:<10} {fmt:<5} {n:>5} {block:>4} {gen:>9.1f} {wr:>9.1f} {ratio:>6.3f} "
                      f"{mib:>7.1f} {r0:>9.0f} {r2:>9.0f} {stream:>8.1f}", flush=True)
        print("samples/s; ratio = write / generate, median of pairs (target >= 0.9); read w0/w2: CachedTrajectories through a "
              "DataLoader with 0 / 2 spawn workers; stream: TrajectoryStream, num_workers=0")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
