"""What does a batch cost the training loop, by data route? The host seconds between two training steps.

``python -m benchmarks.batch_cost [PDE] [--set n=128] [--batches 600] [--rounds 3] [--train] [--target-reuse R]
[--producers thread,process]``

In one process, rounds alternating: the precomputed route (a cache of ``--cache-size`` trajectories read through
``CachedTrajectories`` and the epoch sampler, as ``compare``'s precomputed arm reads it) and the stream's
(``ReservoirStream`` at compare's defaults, async, its pacer on), each handing out ``--batches`` batches of 32
(operator view) after 50 unmeasured ones, the reservoir given a loss per example after each (as training does).
No model is trained, so the figures are the routes' own cost per step: torch on one thread, as in the suites.
Printed per round: ms per batch, and the reservoir's ratio to the cache. With ``--train``, each route instead feeds
compare's FNO (32 / 12 / 3, Adam, lr 3e-3, relative L2), the reservoir twice (its solver a thread of this process,
as compare runs it, and ``producer='process'``), and the seconds inside the optimizer step are timed apart from
those waiting for a batch: whether a solve beside training slows the step itself. Short rounds, many
(``--rounds 40 --batches 50``), interleave the routes finely enough that a shared machine's drifting speed cancels;
``--target-reuse`` sets the reservoir's pace (auto, a number, off) to price its solves by the step time they cost.
Issue 30's step gap on fisher_kpp1d (docs/results/compare.md): figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time


def route_ms(batches, n: int, step=None, after_each=None, skip: int = 50) -> tuple[float, float]:
    """(ms the route takes: waiting for a batch and ``after_each(batch)``, a loss report; ms in ``step(batch)``)
    per step over ``n`` steps of the iterator ``batches``, after ``skip`` unmeasured ones."""
    route = work = 0.0
    for i in range(skip + n):
        t0 = time.perf_counter()
        batch = next(batches)
        t1 = time.perf_counter()
        if step is not None:
            step(batch)
        t2 = time.perf_counter()
        if after_each is not None:
            after_each(batch)
        if i >= skip:
            route, work = route + (t1 - t0) + (time.perf_counter() - t2), work + t2 - t1
    return route / n * 1e3, work / n * 1e3


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.batch_cost", description=__doc__.splitlines()[0])
    p.add_argument("pde", nargs="?", default="fisher_kpp1d", help="catalog entry (default fisher_kpp1d)")
    p.add_argument("--set", action="append", default=["n=128"], metavar="KEY=VALUE", help="entry setting")
    p.add_argument("--batches", type=int, default=600, help="measured batches per route and round")
    p.add_argument("--rounds", type=int, default=3, help="alternated rounds")
    p.add_argument("--cache-size", type=int, default=512, help="trajectories in the precomputed cache")
    p.add_argument("--train", action="store_true", help="train compare's FNO on each route; time the step apart")
    p.add_argument("--target-reuse", default="auto", help="the reservoir's pace: auto, a number or off (default auto)")
    p.add_argument("--producers", default="thread,process", help="--train: the reservoir's producers to time")
    a = p.parse_args(argv)
    import torch

    from pdestream import generator

    torch.set_num_threads(1)
    pde = generator.get_pde(a.pde).replace(dict(s.split("=", 1) for s in a.set))
    with tempfile.TemporaryDirectory(prefix="batch_cost_") as tmp:  # the cache is this run's alone: removed after
        _measure(pde, os.path.join(tmp, "cache.h5"), a)


def _measure(pde, path: str, a) -> None:
    """The rounds of ``main``'s arguments ``a`` on ``pde``, the precomputed route's cache written to ``path``."""
    import torch
    from torch.utils.data import DataLoader

    from pdestream import datasets
    from pdestream.surrogate.data import EpochBatchSampler

    datasets.write_cache(pde, path, a.cache_size, seed=0, progress=False)
    cached = datasets.CachedTrajectories(path, view="operator")

    def cache_batches():
        epoch = 0
        while True:
            sampler = EpochBatchSampler(len(cached), 32, epoch, drop_last=True)
            yield from DataLoader(cached, batch_sampler=sampler, collate_fn=datasets.collate)
            epoch += 1

    cache = cache_batches()
    if a.train:
        return _train_routes(pde, cache, a)
    stream = datasets.ReservoirStream(pde, seed=0, view="operator", batch_size=32, target_reuse=_pace(a.target_reuse))
    reservoir = iter(stream)
    report = lambda batch: stream.report_losses(batch, torch.rand(len(batch["index"])))  # noqa: E731
    rows = []
    for r in range(a.rounds):
        c = route_ms(cache, a.batches)[0]
        s = route_ms(reservoir, a.batches, after_each=report)[0]
        rows.append((c, s))
        print(f"round {r}: cache {c:.3f} ms/batch, reservoir {s:.3f} ms/batch, reservoir / cache x{s / c:.2f}")
    solved = stream.stats()["inserted"]
    stream.close()
    c, s = statistics.median(x for x, _ in rows), statistics.median(y for _, y in rows)
    print(f"median: cache {c:.3f} ms, reservoir {s:.3f} ms per batch (x{s / c:.2f}; +{s - c:.3f} ms); "
          f"the reservoir solved {solved} trajectories meanwhile")


def _pace(text: str):
    """--target-reuse as ReservoirStream takes it: "auto", None (off) or a number."""
    return text if text == "auto" else None if text == "off" else float(text)


def _train_routes(pde, cache, a) -> None:
    """Rounds of ``a.batches`` FNO steps on each route (the cache, the reservoir with each of ``a.producers``)."""
    import torch

    from pdestream import datasets
    from pdestream.surrogate.models import build_model

    pace = _pace(a.target_reuse)
    streams = {p: datasets.ReservoirStream(pde, seed=0, view="operator", batch_size=32, target_reuse=pace,
                                           producer=p) for p in a.producers.split(",")}
    routes = {"cache": (cache, None)}
    for p, st in streams.items():
        routes[f"reservoir ({p})"] = (iter(st), lambda b, st=st: st.report_losses(b, torch.rand(len(b["index"]))))
    torch.manual_seed(0)
    model = build_model("fno", pde.NDIM, 1, 1, len(pde.PARAMS), width=32, modes=12, layers=3)
    opt = torch.optim.Adam(model.parameters(), 3e-3)

    def step(batch):
        out = model(batch["x"], batch["params"])
        loss = ((out - batch["y"]).flatten(1).norm(dim=1) / batch["y"].flatten(1).norm(dim=1)).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    n, got = a.batches, {k: [] for k in routes}
    for r in range(a.rounds):
        for name, (batches, after) in routes.items():
            wait, work = route_ms(batches, n, step, after, skip=50 if r == 0 else 0)  # (warm-up: once)
            got[name].append((wait, work))
            if a.rounds <= 10:
                print(f"round {r}: {name}: waiting {wait:.2f} ms, step {work:.2f} ms per step", flush=True)
    base = statistics.median(w for _, w in got["cache"])
    for name, rows in got.items():
        wait, work = statistics.median(x for x, _ in rows), statistics.median(y for _, y in rows)
        print(f"median {name}: waiting {wait:.2f} ms, step {work:.2f} ms (x{work / base:.2f} the cache's step)")
    for p, st in streams.items():
        stats, steps = st.stats(), a.rounds * n
        solved = stats["inserted"]
        extra = (statistics.mean(w for _, w in got[f"reservoir ({p})"]) - statistics.mean(w for _, w in got["cache"]))
        print(f"reservoir ({p}): {solved} trajectories solved beside {steps} measured steps (mean reuse "
              f"{stats['reuse_mean']:.1f}); the mean step {extra:+.2f} ms against the cache's, "
              f"{extra * steps / max(solved, 1):+.3f} ms of training per trajectory solved, pacer k {st.pacer.slowdown:.2f}")
        st.close()


if __name__ == "__main__":
    main()
