"""Streaming throughput and data-wait share: ``python -m benchmarks.stream_bench [--quick]``.

1. Trajectories/s from ``generator.sample`` alone (the baseline), and delivered through
   ``stream_loader`` with 0 and 2 workers (view "whole", one batch per solve batch); ratio to the baseline.
2. A small FNO trained on burgers1d next-step windows straight from the stream: the share of training
   wall time spent waiting for the next batch (``next(loader)``), for 0 and 2 workers.
Figures, not pass/fail; all rates are measured in this process after a warm-up (compilation excluded).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from pdestream import generator
from pdestream.datasets import TrajectoryStream, stream_loader
from pdestream.surrogate.fno import FNO, FNOConfig

SEED = 0


def timed(fn, n_batches: int) -> float:
    """Trajectories/s of ``n_batches`` calls of fn (each returns a batch size)."""
    start = time.perf_counter()
    count = sum(fn() for _ in range(n_batches))
    return count / (time.perf_counter() - start)


def throughput(pde, solve_batch: int, n_batches: int, rounds: int) -> dict:
    """Median over ``rounds`` of trajectories/s: generator.sample alone (fixed-size batches) and a DataLoader
    over an endless whole-trajectory stream with 0 and 2 workers, measured in alternation."""
    counter = iter(range(1, 10**9))

    def raw() -> int:
        b = next(counter)
        generator.sample(pde, np.arange(b * solve_batch, (b + 1) * solve_batch), SEED).u.block_until_ready()
        return solve_batch

    rates: dict = {"raw": [], 0: [], 2: []}
    raw()
    # One loader at a time: idle persistent workers refill their queues in the background, which would
    # steal the cores from the other arms' measurements.
    for workers in (0, 2):
        stream = TrajectoryStream(pde, SEED, view="whole", batch_size=solve_batch, solve_batch=solve_batch)
        loader = stream_loader(stream, num_workers=workers)
        it = iter(loader)
        for _ in range(2 + 2 * workers):  # warm-up: worker start, compilation, full prefetch queues
            next(it)
        for _ in range(rounds):
            rates["raw"].append(timed(raw, n_batches))
            for _ in range(3 + 4 * workers):  # drain what was buffered while idle: time steady production
                next(it)
            rates[workers].append(timed(lambda: len(next(it)["index"]), n_batches))  # noqa: F821 (`it` is bound: the del below confuses ruff)
        del it, loader  # shuts persistent workers down
    # medians of alternating rounds: single rounds vary by +-15% on a 2-core machine, and a best-of
    # would reward whichever arm got the luckiest round
    return {k: float(np.median(v)) for k, v in rates.items()}


def wait_share(pde, steps: int, num_workers: int, windows, batch_size: int = 32) -> tuple[float, float]:
    """(share of wall time waiting for data, ms per training step) for a small FNO on next-step pairs."""
    torch.manual_seed(0)
    stream = TrajectoryStream(pde, SEED, view="next_step", windows=windows, batch_size=batch_size, solve_batch=16)
    model = FNO(ndim=1, in_channels=1, out_channels=1, n_params=len(pde.PARAMS), config=FNOConfig(32, 12, 4))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    it = iter(stream_loader(stream, num_workers=num_workers))
    waited = total = 0.0
    for step in range(steps + 5):  # the first 5 steps warm up (compilation, worker start)
        t0 = time.perf_counter()
        batch = next(it)
        t1 = time.perf_counter()
        pred = model(batch["x"][:, 0], batch["params"])  # [B, 1, n]
        loss = torch.nn.functional.mse_loss(pred, batch["y"][:, 0])
        opt.zero_grad()
        loss.backward()
        opt.step()
        t2 = time.perf_counter()
        if step >= 5:
            waited, total = waited + (t1 - t0), total + (t2 - t0)
    del it
    return waited / total, 1e3 * total / steps


def rss_mb() -> float:
    """Resident memory of this process now (MB), from /proc (Linux)."""
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def memory_growth(pde, n_samples: int, batch: int = 16) -> tuple[float, float]:
    """(RSS after 10% of the stream, RSS growth over the remaining 90%) in MB, streaming n_samples whole
    trajectories through a 0-worker loader: a leak shows as growth, warm-up allocations do not."""
    stream = TrajectoryStream(pde, SEED, view="whole", batch_size=batch, solve_batch=batch, n_samples=n_samples)
    it = iter(stream_loader(stream, num_workers=0))
    n_batches = -(-n_samples // batch)
    warm = max(1, n_batches // 10)
    for _ in range(warm):
        next(it)
    start = rss_mb()
    for _ in range(n_batches - warm):
        next(it)
    return start, rss_mb() - start


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer batches and steps (a smoke run)")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch threads of the training loop (default 1: the other core generates)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.torch_threads)
    n_batches, steps, rounds = (10, 20, 3) if args.quick else (30, 150, 5)
    pde = generator.get_pde("burgers1d")  # n=256, 51 frames
    print(f"stream benchmark: {pde.NAME} n={pde.n} frames={pde.n_frames}, {os.cpu_count()} CPU cores, "
          f"torch threads {torch.get_num_threads()}, load average {os.getloadavg()[0]:.1f}")

    solve_batch = 16
    rate = throughput(pde, solve_batch, n_batches, rounds)
    print(f"\n| source (whole trajectories, batches of {solve_batch}, median of {rounds} rounds) | trajectories/s | ratio |")
    print("| --- | ---: | ---: |")
    print(f"| generator.sample | {rate['raw']:.1f} | 1.00 |")
    for workers in (0, 2):
        print(f"| DataLoader, {workers} workers | {rate[workers]:.1f} | {rate[workers] / rate['raw']:.2f} |")

    print("\n| FNO (width 32, 12 modes, 4 layers) on next-step pairs, batch 32 | workers | ms/step | waiting for data |")
    print("| --- | ---: | ---: | ---: |")
    for windows in ("all", 4):
        for workers in (0, 2):
            share, ms = wait_share(pde, steps, workers, windows)
            print(f"| windows={windows} | {workers} | {ms:.1f} | {100 * share:.1f}% |")

    n_mem = 2_000 if args.quick else 10_000
    start, growth = memory_growth(pde, n_mem)
    print(f"\nmemory: streaming {n_mem} trajectories (0 workers), RSS {start:.0f} MB after the first 10%, "
          f"then {growth:+.1f} MB over the rest (target < 50 MB)")


if __name__ == "__main__":
    main()
