"""The steered share over each generative unit, stop 52's suite against the veto at 8: the step the probes ended (the
first logged step whose steered share fell below the probe share), the share and the lift's lower bound at the end.

``python benchmarks/results/generative_suite_veto8/gate_table.py`` prints a markdown table (docs/results/active.md,
"The veto at 8 draws")."""

from __future__ import annotations

import csv
import math
from pathlib import Path

HERE = Path(__file__).parent
BEFORE = HERE.parent / "generative_suite"
PROBE = 0.25  # the suite's probe share


def gate(unit: Path) -> tuple[str, str, str] | None:
    """(probe end step, steered share at the end, lift's lower bound at the end) of one unit's metrics.csv."""
    f = unit / "metrics.csv"
    if not f.is_file():
        return None
    rows = list(csv.DictReader(f.open()))
    steer = [(int(r["step"]), float(r["proposal_steer"])) for r in rows]
    probing = [s for s, w in steer if w >= PROBE]
    ended = next((s for s, w in steer if probing and s > probing[0] and w < PROBE), None)
    lift = float(rows[-1]["proposal_lift"])
    return (str(ended) if ended is not None else "never", f"{steer[-1][1]:.2f}",
            "-" if math.isnan(lift) else f"{lift:+.2f}")


def main() -> None:
    print("| problem | seed | probes ended at step (stop 52 / veto 8) | steered share at the end | lift's lower bound at the end |")
    print("| --- | --- | --- | --- | --- |")
    for problem in ("burgers1d", "kdv1d", "burgers2d", "fisher_kpp1d", "grayscott2d"):
        for seed in range(3):
            a, b = (gate(d / problem / f"reservoir_generative_seed{seed}") for d in (BEFORE, HERE))
            if a is None or b is None:
                continue
            print(f"| {problem} | {seed} | {a[0]} / {b[0]} | {a[1]} / {b[1]} | {a[2]} / {b[2]} |")


if __name__ == "__main__":
    main()
