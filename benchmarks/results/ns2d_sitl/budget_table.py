"""Tables for the training-budget ablation (docs/results/interactive.md, "Training budget: 1500 steps"): every arm
of two `pdestream compare` runs that differ only in --steps, side by side.

    python benchmarks/results/ns2d_sitl/budget_table.py benchmarks/results/ns2d_sitl/u8_fourier \
        benchmarks/results/ns2d_sitl/u8_fourier_1500

Reads each run's compare.json (per-seed records and the seed-mean error curve, relative L2, one value per
frame of 0.2 time units). The longer run's seeds decide the comparison: with one seed, the shorter run's seed 0
alone; with more, the same seeds of both (mean +- std, ddof 1). Prints markdown: per arm rollout mean, rollout p95,
end mean; the ratios other arm / solver-in-the-loop with each ratio's per-seed std; the per-frame ratio
pairs / solver-in-the-loop at t - t_start = 0.2, 1, ..., 6 (seed means of the curves)."""
import json
import sys
from pathlib import Path

import numpy as np

METRICS = ("rollout_mean", "rollout_p95", "end_mean")
SITL = "solver-in-the-loop (unroll 8)"
OTHERS = ("pairs (unroll 1)", "pairs + noise (unroll 1)")
TIMES = (0.2, 1, 2, 3, 4, 5, 6)


def load(run: Path) -> dict:
    """{set: {arm: record}} for the sets "inside" and "beyond" of ``run``/compare.json."""
    d = json.loads((run / "compare.json").read_text())
    sets = {"inside": d["arms"], "beyond": d.get("beyond", {}).get("arms", [])}
    return {name: {a["arm"]: a for a in arms} for name, arms in sets.items()}


def per_seed(arm: dict, metric: str, seeds: list) -> np.ndarray:
    """``metric`` of ``arm`` for each seed in ``seeds``; shape (len(seeds),). The coarse solver: its one value."""
    if not arm.get("per_seed"):
        return np.full(len(seeds), arm[metric])
    by = {p["seed"]: p for p in arm["per_seed"]}
    return np.array([by[s][metric] for s in seeds])


def fmt(x: np.ndarray) -> str:
    """mean +- std (ddof 1) with more than one value, else the value; 4 digits."""
    return f"{x.mean():.4f}" if len(x) < 2 or np.all(x == x[0]) else f"{x.mean():.4f} +- {x.std(ddof=1):.4f}"


def ratio(o: np.ndarray, s: np.ndarray) -> str:
    """The ratio of the seed means, and the std of the per-seed ratios where there are several seeds."""
    r = o.mean() / s.mean()
    return f"{r:.3f}x" if len(o) < 2 else f"{r:.3f}x (per-seed std {np.std(o / s, ddof=1):.3f})"


def verdict(short: dict, long: dict, other: str, metric: str, seeds: list) -> str:
    """The rule's reading of one ratio's change: "widened" / "narrowed" when it exceeds the per-seed ratio's std at
    500 steps over all the short run's seeds (one seed at 1500) or the two runs' stds over ``seeds`` added."""
    def ratios(run, which):
        return per_seed(run[other], metric, which) / per_seed(run[SITL], metric, which)
    r_short, r_long = ratios(short, seeds), ratios(long, seeds)
    change = (per_seed(long[other], metric, seeds).mean() / per_seed(long[SITL], metric, seeds).mean()
              - per_seed(short[other], metric, seeds).mean() / per_seed(short[SITL], metric, seeds).mean())
    if len(seeds) < 2:
        every = [p["seed"] for p in short[SITL]["per_seed"]]
        limit = np.std(ratios(short, every), ddof=1)
    else:
        limit = np.std(r_short, ddof=1) + np.std(r_long, ddof=1)
    word = "unchanged" if abs(change) <= limit else ("widened" if change > 0 else "narrowed")
    return f"{metric} {word} ({change:+.3f}, limit {limit:.3f})"


def tables(short: Path, long: Path) -> None:
    """Print the arm table, the ratio table and the per-frame table of the two runs."""
    a, b = load(short), load(long)
    seeds = [p["seed"] for p in b["inside"][SITL]["per_seed"]]
    print(f"seeds compared: {seeds}\n")
    print("| set | arm | steps | " + " | ".join(METRICS) + " |\n| --- | --- | --- | " + "--- | " * len(METRICS))
    for name in ("inside", "beyond"):
        for arm in b[name]:
            for label, run in (("500", a), ("1500", b)):
                vals = [fmt(per_seed(run[name][arm], m, seeds)) for m in METRICS]
                print(f"| {name} | {arm} | {label} | " + " | ".join(vals) + " |")
    print("\n| set | against | steps | " + " | ".join(METRICS) + " |\n| --- | --- | --- | " + "--- | " * len(METRICS))
    for name in ("inside", "beyond"):
        for other in OTHERS:
            for label, run in (("500", a), ("1500", b)):
                vals = [ratio(per_seed(run[name][other], m, seeds), per_seed(run[name][SITL], m, seeds))
                        for m in METRICS]
                print(f"| {name} | {other} | {label} | " + " | ".join(vals) + " |")
    print("\nchange of each ratio, 500 -> 1500, against the rule's threshold")
    for name in ("inside", "beyond"):
        for other in OTHERS:
            print(f"- {name}, {other}: " + "; ".join(verdict(a[name], b[name], other, m, seeds) for m in METRICS))
    print("\nper-frame pairs / solver-in-the-loop (seed means of the curves; the 500-step run: all its seeds)")
    print("| set | steps | " + " | ".join(f"t-10={t}" for t in TIMES) + " |\n| --- | --- | " + "--- | " * len(TIMES))
    for name in ("inside", "beyond"):
        for label, run in (("500", a), ("1500", b)):
            p, s = np.array(run[name][OTHERS[0]]["curve"]), np.array(run[name][SITL]["curve"])
            idx = [round(t / 0.2) - 1 for t in TIMES]  # curve[i] is frame i + 1
            print(f"| {name} | {label} | " + " | ".join(f"{p[i] / s[i]:.2f}" for i in idx) + " |")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: budget_table.py SHORT_RUN LONG_RUN (two compare --out directories)")
    tables(Path(sys.argv[1]), Path(sys.argv[2]))
