"""How much of a coarse solver's error is the fine -> coarse restriction? (issue 29's ``--restrict``)

``python -m benchmarks.restrict_gap PDE --coarse-n 16 [--test-samples 32] [--shift X] [--set n=64 ...]``

The held-out set ``compare --modes solver-in-the-loop`` rolls out on (``experiments.budget.stratified_test_set``,
seed 0, the PDE with ``--set`` applied; ``--shift``: the set beyond the training range, as compare's ``--shift``)
is rolled out by the coarse solver alone (``surrogate.modes.SolverInTheLoop`` at n = ``--coarse-n``), once per
restriction ("points": every factor-th fine point, the runs before the option; "fourier": the Fourier truncation).
Each restricts both the coarse start state and the fine reference. Printed per frame: the relative L2 error (mean
over trajectories, as compare.md's curves), and the size of the restriction's own disagreement: the relative L2
distance between the two restrictions of the fine reference (what point sampling aliases in).
"""

from __future__ import annotations

import argparse
import sys

from benchmarks.coarse_gap import entry_settings


def restrict_gap(name: str, coarse_n: int, n_test: int = 32, settings: dict | None = None,
                 shift: float | None = None) -> dict:
    """{"t": [T] frame times after the first, "points" / "fourier": [T] mean relative L2 errors of the coarse
    solver, "alias": [T] mean relative L2 distance points vs fourier of the reference, "pde": the config}."""
    import torch

    from pdestream.experiments.budget import stratified_test_set
    from pdestream.experiments.shift import shifted_pde
    from pdestream.settings import build_pde
    from pdestream.surrogate.mode_table import mode_settings
    from pdestream.surrogate.modes import make_mode

    pde = build_pde(name, dict(settings or {}))
    if shift is not None:
        pde = shifted_pde(pde, shift, {})
    test = stratified_test_set(pde, n_test, 0)
    out, refs = {}, {}
    for how in ("points", "fourier"):
        mode = make_mode(mode_settings("solver-in-the-loop", unroll=1, coarse_n=coarse_n, restrict=how)).bind(pde)
        diff, ref, truths = [], [], []
        for batch in test:
            pred, truth = mode.rollout(None, None, batch["u"], batch["params"])  # [B, T-1, C, *coarse]
            diff.append((pred - truth).double().flatten(2).norm(dim=2))
            ref.append(truth.double().flatten(2).norm(dim=2))
            truths.append(truth.double())
        out[how] = (torch.cat(diff) / torch.cat(ref).clamp_min(1e-30)).mean(0).tolist()
        refs[how] = torch.cat(truths)
    alias = ((refs["points"] - refs["fourier"]).flatten(2).norm(dim=2)
             / refs["fourier"].flatten(2).norm(dim=2).clamp_min(1e-30)).mean(0).tolist()
    return {"t": [float(t) for t in pde.times()[1:]], **out, "alias": alias, "pde": pde.config()}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.restrict_gap", description=__doc__.splitlines()[0])
    p.add_argument("pde", help="a catalog entry, e.g. ns2d")
    p.add_argument("--coarse-n", type=int, required=True, help="coarse grid, a proper divisor of n")
    p.add_argument("--test-samples", type=int, default=32, help="held-out trajectories (default 32)")
    p.add_argument("--shift", type=float, help="the set beyond the training range (compare's --shift)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a setting of the entry")
    a = p.parse_args(argv)
    settings = entry_settings(a.set)
    if a.test_samples < 1:
        sys.exit(f"--test-samples {a.test_samples}: need >= 1")
    try:
        g = restrict_gap(a.pde, a.coarse_n, a.test_samples, settings, a.shift)
    except (ValueError, KeyError) as err:
        sys.exit(str(err).splitlines()[0])
    print(f"{a.pde} -> coarse n={a.coarse_n}, {a.test_samples} held-out trajectories"
          + (f", shift {a.shift:g}" if a.shift is not None else ""))
    print("| frame | t | coarse error, points | coarse error, fourier | points vs fourier reference |\n"
          "| --- | --- | --- | --- | --- |")
    for k, t in enumerate(g["t"]):
        print(f"| {k + 1} | {t:g} | {g['points'][k]:.4f} | {g['fourier'][k]:.4f} | {g['alias'][k]:.4f} |")
    print(f"| mean | | {sum(g['points']) / len(g['t']):.4f} | {sum(g['fourier']) / len(g['t']):.4f} | "
          f"{sum(g['alias']) / len(g['t']):.4f} |")


if __name__ == "__main__":
    main()
