"""Active sampling against uniform and loss-driven sampling: where it cuts the tail, and why it does not more.

``python -m benchmarks.active_bench DIR [DIR ...]`` summarizes ``pdestream compare ... --sim-budget N --arms
reservoir,reservoir_loss,reservoir_active`` (or ``--budget S``) outputs: for each DIR, every steered arm's mean,
p95 and max over seeds against the uniform reservoir's (ratio uniform / arm: > 1 is better), each with its
verdict against the seed spread (the two arms' standard deviations added), and two figures for the "why":

- ``explained``: the share of the variance of log(per-trajectory error) of the uniform arm that the parameters
  explain (test trajectories binned in the unit box, about 8 cells: 8 bins for one parameter, 3 x 3 for two; the rest
  comes from the initial condition, which a proposal over parameters cannot steer);
- ``in/out``: the steered arm's error ratio (uniform / arm, mean over seeds of per-trajectory errors) in the
  unit-box bin with the highest uniform error, and in all the others;
- ``target norm``: how much of that variance the norm of each test trajectory's last frame explains (relative
  L2 divides by it: a trajectory that decayed to almost nothing has a large relative error for a small
  absolute one, and an MSE-trained network spends nothing on it), and that norm for the worst 5% against the
  median.

Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

METRICS = ("test_mean", "test_p95", "test_max")


def _arm(result: dict, name: str) -> dict | None:
    return next((a for a in result["arms"] if a["arm"] == name), None)


def _seed_errors(out: Path, arm: str, seeds: int) -> np.ndarray:
    """Per-trajectory test errors [seeds, N] from each seed's arm.json."""
    runs = [json.loads((out / (arm if seeds == 1 else f"{arm}_seed{s}") / "arm.json").read_text()) for s in range(seeds)]
    return np.array([r["errors"]["test"] for r in runs])


def _bins(result: dict) -> np.ndarray:
    """Bin id [N] of each test trajectory: its random parameters in the unit box, about 8 cells in all (8 bins
    for one parameter, 3 x 3 for two), so that each cell holds enough trajectories for its mean to mean something."""
    from pdestream.datasets.proposal import ParamProposal

    domains = {k: tuple(v) if not isinstance(v, (list, tuple)) else (v[0], v[1], v[2], tuple(v[3]))
               for k, v in result["domains"].items()}
    z = ParamProposal(domains, mode="uniform").to_unit(np.asarray(result["test_params"]["test"]))
    bins = max(2, round(8 ** (1 / max(z.shape[1], 1))))
    cell = np.minimum((z * bins).astype(int), bins - 1)
    return (cell * bins ** np.arange(z.shape[1])).sum(1) if z.shape[1] else np.zeros(len(z), int)


def summarize(out: Path) -> list[str]:
    result = json.loads((out / "compare.json").read_text())
    seeds = result["config"]["seeds"]
    uniform = _arm(result, "reservoir")
    if uniform is None:
        raise SystemExit(f"{out}: no uniform reservoir arm to compare with; run compare with --arms reservoir,...")
    budget = (f"{result['config']['sim_budget']} solves, {result['config']['steps']} steps" if result["config"]["sim_budget"]
              else f"{result['config']['budget_s']} s wall clock")
    lines = [f"{out.name}: {result['pde']['pde']} (n={result['pde'].get('n')}), {budget}, {seeds} seeds"]
    from pdestream import datasets, generator

    pde = generator.get_pde(result["pde"]["pde"], **{k: v for k, v in result["pde"].items() if k != "pde"})
    result["domains"] = datasets.param_domains(pde)
    bins = _bins(result)
    base = _seed_errors(out, "reservoir", seeds)
    y = np.log(base.mean(0))
    fitted = np.array([y[bins == b].mean() for b in bins])
    explained = 1 - ((y - fitted) ** 2).sum() / ((y - y.mean()) ** 2).sum()
    worst = max(set(bins.tolist()), key=lambda b: base.mean(0)[bins == b].mean())
    for name in ("reservoir_loss", "reservoir_active", "reservoir_priority", "reservoir_generative"):
        arm = _arm(result, name)
        if arm is None or uniform is None:
            continue
        cells = []
        for m in METRICS:
            ratio = uniform[m] / arm[m]
            spread = uniform[m + "_std"] + arm[m + "_std"]
            verdict = "outside" if abs(uniform[m] - arm[m]) > spread else "within"
            cells.append(f"{m[5:]} {arm[m]:.4f} ± {arm[m + '_std']:.4f} vs {uniform[m]:.4f} ± {uniform[m + '_std']:.4f} "
                         f"(x{ratio:.2f}, {verdict} the spread)")
        errs = _seed_errors(out, name, seeds).mean(0)
        inside = base.mean(0)[bins == worst].mean() / errs[bins == worst].mean()
        outside = base.mean(0)[bins != worst].mean() / errs[bins != worst].mean()
        lines.append(f"  {name}: " + "; ".join(cells) + f"; worst bin x{inside:.2f}, elsewhere x{outside:.2f}")
    lines.append(f"  parameters explain {100 * explained:.0f}% of the variance of log error (uniform arm); the worst "
                 f"bin holds {int((bins == worst).sum())} of {len(bins)} test trajectories and "
                 f"{int((bins[np.argsort(base.mean(0))[-max(1, len(bins) // 20):]] == worst).sum())} of the top 5%")
    from pdestream.experiments.budget import stratified_test_set

    last = np.concatenate([b["u"][:, -1].flatten(1).norm(dim=1).numpy() for b in
                           stratified_test_set(pde, result["config"]["n_test"], 0)])
    x = np.log(np.maximum(last, 1e-30))
    by_norm = np.corrcoef(x, y)[0, 1] ** 2
    top = np.argsort(base.mean(0))[-max(1, len(y) // 20):]
    lines.append(f"  the norm of the last frame explains {100 * by_norm:.0f}% of it (log-log, linear); the worst 5% end at "
                 f"{np.median(last[top]) / np.median(last):.3g}x the median norm (median of their norms)")
    return lines


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.active_bench", description=__doc__.splitlines()[0])
    p.add_argument("dirs", nargs="+", type=Path, help="pdestream compare outputs (compare.json and the arms' runs)")
    for out in p.parse_args(argv).dirs:
        print("\n".join(summarize(out)), flush=True)


if __name__ == "__main__":
    main()
