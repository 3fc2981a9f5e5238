"""What does a batch cost the training loop, by data route? The host seconds between two training steps.

``python -m benchmarks.batch_cost [PDE] [--set n=128] [--batches 600] [--rounds 3]``

In one process, rounds alternating: the precomputed route (a cache of ``--cache-size`` trajectories read through
``CachedTrajectories`` and the epoch sampler, as ``compare``'s precomputed arm reads it) and the stream's
(``ReservoirStream`` at compare's defaults, async, its pacer on), each handing out ``--batches`` batches of 32
(operator view) after 50 unmeasured ones, the reservoir given a loss per example after each (as training does).
No model is trained, so the figures are the routes' own cost per step: torch on one thread, as in the suites.
Printed per round: ms per batch, and the reservoir's ratio to the cache. Explains issue 30's step gap on
fisher_kpp1d (docs/results/compare.md): figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time


def per_batch_ms(batches, n: int, after_each=None, skip: int = 50) -> float:
    """Milliseconds per batch over ``n`` batches of the iterator ``batches``, after ``skip`` unmeasured ones;
    ``after_each(batch)`` runs after each (a loss report)."""
    t0 = None
    for i in range(skip + n):
        if i == skip:
            t0 = time.perf_counter()
        batch = next(batches)
        if after_each is not None:
            after_each(batch)
    return (time.perf_counter() - t0) / n * 1e3


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.batch_cost", description=__doc__.splitlines()[0])
    p.add_argument("pde", nargs="?", default="fisher_kpp1d", help="catalog entry (default fisher_kpp1d)")
    p.add_argument("--set", action="append", default=["n=128"], metavar="KEY=VALUE", help="entry setting")
    p.add_argument("--batches", type=int, default=600, help="measured batches per route and round")
    p.add_argument("--rounds", type=int, default=3, help="alternated rounds")
    p.add_argument("--cache-size", type=int, default=512, help="trajectories in the precomputed cache")
    a = p.parse_args(argv)
    import torch
    from torch.utils.data import DataLoader

    from pdestream import datasets, generator
    from pdestream.surrogate.data import EpochBatchSampler

    torch.set_num_threads(1)
    pde = generator.get_pde(a.pde).replace(dict(s.split("=", 1) for s in a.set))
    path = os.path.join(tempfile.mkdtemp(prefix="batch_cost_"), "cache.h5")
    datasets.write_cache(pde, path, a.cache_size, seed=0, progress=False)
    cached = datasets.CachedTrajectories(path, view="operator")

    def cache_batches():
        epoch = 0
        while True:
            sampler = EpochBatchSampler(len(cached), 32, epoch, drop_last=True)
            yield from DataLoader(cached, batch_sampler=sampler, collate_fn=datasets.collate)
            epoch += 1

    stream = datasets.ReservoirStream(pde, seed=0, view="operator", batch_size=32, target_reuse="auto")
    reservoir = iter(stream)
    report = lambda batch: stream.report_losses(batch, torch.rand(len(batch["index"])))  # noqa: E731
    cache = cache_batches()
    rows = []
    for r in range(a.rounds):
        c = per_batch_ms(cache, a.batches)
        s = per_batch_ms(reservoir, a.batches, report)
        rows.append((c, s))
        print(f"round {r}: cache {c:.3f} ms/batch, reservoir {s:.3f} ms/batch, reservoir / cache x{s / c:.2f}")
    solved = stream.stats()["inserted"]
    stream.close()
    c, s = statistics.median(x for x, _ in rows), statistics.median(y for _, y in rows)
    print(f"median: cache {c:.3f} ms, reservoir {s:.3f} ms per batch (x{s / c:.2f}; +{s - c:.3f} ms); "
          f"the reservoir solved {solved} trajectories meanwhile")


if __name__ == "__main__":
    main()
