"""How wrong is a coarse solver? Its error against the fine solver, frame by frame: the gap a corrector can close.

``python -m benchmarks.coarse_gap PDE --fine-n 64 --coarse-n 16 [--n 8] [--set t_start=10 ...]``

``--n`` samples of the entry's defaults (``--set`` applied, n = ``--fine-n``) are solved on the fine grid; the
coarse solver (the same settings at n = ``--coarse-n``, its own stable step: ``surrogate.modes.SolverInTheLoop``,
as ``compare --modes solver-in-the-loop`` builds it) is rolled out from the first frame restricted to the coarse
grid (``--restrict``: fourier, the default of new runs, or points, every factor-th point as the figures before
the option). Printed per frame: the relative L2 error of the coarse rollout against the fine trajectory restricted to the
coarse grid (mean, median and max over samples) and the solve times. Used to pick issue 29's spectral case
(docs/results/interactive.md): a corrector can pay only where this error is large and grows.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def coarse_gap(name: str, fine_n: int, coarse_n: int, n: int = 8, settings: dict | None = None, seed: int = 0,
               restrict: str = "fourier") -> dict:
    """{"t": [T] frame times after the first, "mean" / "median" / "max": [T] relative L2 errors over the ``n``
    samples, "fine_s", "coarse_s": wall seconds} for entry ``name`` (settings as --set strings)."""
    import torch

    from pdestream import datasets, generator
    from pdestream.surrogate.modes import SolverInTheLoop

    pde = generator.get_pde(name).replace({**(settings or {}), "n": str(fine_n)})
    t0 = time.perf_counter()
    data = datasets.sample_tensors(pde, np.arange(n), seed)
    t1 = time.perf_counter()
    pred, truth = SolverInTheLoop(unroll=1, coarse_n=coarse_n, restrict=restrict).bind(pde).rollout(None, None, data["u"], data["params"])
    t2 = time.perf_counter()
    err = (pred - truth).flatten(2).norm(dim=2) / truth.flatten(2).norm(dim=2).clamp_min(1e-12)  # [n, T]
    return {"t": [float(t) for t in pde.times()[1:]], "mean": err.mean(0).tolist(),
            "median": err.median(0).values.tolist(), "max": err.max(0).values.tolist(),
            "fine_s": t1 - t0, "coarse_s": t2 - t1, "finite": bool(torch.isfinite(pred).all())}


def entry_settings(items: list[str]) -> dict:
    """``--set KEY=VALUE`` items as {KEY: VALUE} (strings, as the catalog parses them); exits with one line naming
    a malformed item."""
    bad = [kv for kv in items if "=" not in kv or not kv.split("=", 1)[0]]
    if bad:
        sys.exit(f"--set {bad[0]!r}: need KEY=VALUE")
    return dict(kv.split("=", 1) for kv in items)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.coarse_gap", description=__doc__.splitlines()[0])
    p.add_argument("pde", help="a catalog entry, e.g. ns2d")
    p.add_argument("--fine-n", type=int, required=True, help="fine grid")
    p.add_argument("--coarse-n", type=int, required=True, help="coarse grid, a proper divisor of --fine-n")
    p.add_argument("--n", type=int, default=8, help="samples (default 8)")
    p.add_argument("--restrict", choices=("fourier", "points"), default="fourier",
                   help="fine -> coarse on periodic axes (default fourier)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a setting of the entry")
    a = p.parse_args(argv)
    settings = entry_settings(a.set)
    if a.n < 1:
        sys.exit(f"--n {a.n}: need >= 1")
    try:
        g = coarse_gap(a.pde, a.fine_n, a.coarse_n, a.n, settings,
                       restrict=a.restrict)
    except (ValueError, KeyError) as err:
        sys.exit(str(err).splitlines()[0])
    print(f"{a.pde} fine n={a.fine_n} -> coarse n={a.coarse_n}, {a.n} samples: fine solve {g['fine_s']:.1f} s, "
          f"coarse rollout {g['coarse_s']:.1f} s{'' if g['finite'] else ', NOT FINITE (the coarse solver blew up)'}")
    print("| frame | t | mean | median | max |\n| --- | --- | --- | --- | --- |")
    for k, t in enumerate(g["t"]):
        print(f"| {k + 1} | {t:g} | {g['mean'][k]:.4f} | {g['median'][k]:.4f} | {g['max'][k]:.4f} |")


if __name__ == "__main__":
    main()
