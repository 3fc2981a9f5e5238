"""Error against training compute at ns2d 64 -> 32 (docs/results/interactive.md, "Error against compute"): each arm's
rollout error (inside the training range, seed 0) at every budget run so far, against its training cost in
pairs-step units (one pairs optimizer step = 1; a solver-in-the-loop step at unroll 8 = the measured wall ratio, 5.0:
942 s against 188 s per 500 steps over 3 seeds, 1706 s against 348 s at 1500, seed 0). Wall seconds themselves are
not the axis: the runs ran at loads from 0.5 to 8, and one arm's seeds took 621-1273 s for the same work.

    python benchmarks/results/ns2d_sitl/wall_frontier.py [--out docs/ns2d_sitl_frontier.png]

Reads the compare.json of c32_u8_fourier (500 steps), c32_u8_fourier_1500 (1500), c32_u8_eqwall (pairs 2500) and
c32_u8_eqwall1500 (pairs 7500), c32_u8_cost11000 (solver-in-the-loop 2200, pairs 11,000), where they exist; prints a markdown table and draws the figure."""
import argparse
import json
from pathlib import Path

HERE = Path(__file__).parent
SITL, PAIRS, NOISE = "solver-in-the-loop (unroll 8)", "pairs (unroll 1)", "pairs + noise (unroll 1)"
COST = {SITL: 5.0, PAIRS: 1.0, NOISE: 1.0}  # pairs-step units per optimizer step
RUNS = {"c32_u8_fourier": (SITL, PAIRS, NOISE), "c32_u8_fourier_1500": (SITL, PAIRS, NOISE),
        "c32_u8_eqwall": (PAIRS, NOISE), "c32_u8_eqwall1500": (PAIRS, NOISE), "c32_u8_cost11000": (SITL, PAIRS, NOISE)}
STEPS = {"c32_u8_fourier": {SITL: 500, PAIRS: 500, NOISE: 500}, "c32_u8_fourier_1500": {SITL: 1500, PAIRS: 1500, NOISE: 1500},
         "c32_u8_eqwall": {PAIRS: 2500, NOISE: 2500}, "c32_u8_eqwall1500": {PAIRS: 7500, NOISE: 7500},
         "c32_u8_cost11000": {SITL: 2200, PAIRS: 11000, NOISE: 11000}}


def points() -> dict:
    """{arm: [(steps, cost, rollout mean, rollout p95, beyond rollout mean)]} of seed 0, sorted by cost."""
    out = {SITL: [], PAIRS: [], NOISE: []}
    for run, arms in RUNS.items():
        path = HERE / run / "compare.json"
        if not path.is_file():
            continue
        d = json.loads(path.read_text())
        inside = {a["arm"]: a for a in d["arms"]}
        beyond = {a["arm"]: a for a in d.get("beyond", {}).get("arms", [])}
        for arm in arms:
            seed0 = lambda rec: next(p for p in rec["per_seed"] if p["seed"] == 0)  # noqa: E731
            a, b = seed0(inside[arm]), seed0(beyond[arm]) if arm in beyond else None
            steps = STEPS[run][arm]
            out[arm].append((steps, steps * COST[arm], a["rollout_mean"], a["rollout_p95"],
                             None if b is None else b["rollout_mean"]))
    return {arm: sorted(set(v), key=lambda r: r[1]) for arm, v in out.items()}


def table(pts: dict) -> str:
    lines = ["| arm | steps | cost (pairs steps) | inside rollout mean | inside rollout p95 | beyond rollout mean |",
             "| --- | ---: | ---: | --- | --- | --- |"]
    for arm, rows in pts.items():
        for steps, cost, mean, p95, beyond in rows:
            lines.append(f"| {arm} | {steps} | {cost:.0f} | {mean:.4f} | {p95:.4f} | "
                         f"{'-' if beyond is None else f'{beyond:.4f}'} |")
    return "\n".join(lines)


def draw(pts: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    style = {SITL: ("tab:purple", "o"), PAIRS: ("tab:blue", "s"), NOISE: ("tab:green", "^")}
    for ax, col, title in ((axes[0], 2, "inside: rollout mean"), (axes[1], 3, "inside: rollout p95")):
        for arm, rows in pts.items():
            color, marker = style[arm]
            ax.loglog([r[1] for r in rows], [r[col] for r in rows], marker=marker, color=color, label=arm)
            for r in rows:
                ax.annotate(f"{r[0]}", (r[1], r[col]), textcoords="offset points", xytext=(4, 4), fontsize=7)
        ax.set_xticks([500, 1000, 2500, 7500, 11000], ["500", "1000", "2500", "7500", "11000"])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("training cost, pairs steps (a solver-in-the-loop step = 5)")
        ax.set_ylabel("relative L2")
        ax.set_title(f"ns2d 64 -> 32, {title} (seed 0)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=120)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=HERE.parents[2] / "docs" / "ns2d_sitl_frontier.png")
    a = p.parse_args()
    pts = points()
    print(table(pts))
    draw(pts, a.out)
    print(f"figure: {a.out}")


if __name__ == "__main__":
    main()
