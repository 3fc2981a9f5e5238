"""Outside the seed spread, as stop 48 computed it: per test set and metric, solver-in-the-loop against pairs and
pairs + noise: the margin of the means over seeds (other - solver-in-the-loop) against the two arms' sample
standard deviations over seeds (ddof 1) added; and the per-seed ratios.

    python benchmarks/results/karman_sitl_developed/spread.py [DIR]   # DIR: a karman_sitl --out (default: this one)
"""
import json
import sys
from pathlib import Path

import numpy as np

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent
runs = [json.loads(f.read_text()) for f in sorted(out.glob("seed*/summary.json"))]
print(f"{out}: {len(runs)} seeds")
for where in ("inside", "beyond"):
    loop_key = next(k for k in runs[0] if k.startswith(f"{where}|solver-in-the-loop"))
    for other in ("pairs (unroll 1)", "pairs + noise (unroll 1)"):
        for j, what in ((0, "mean"), (1, "p95")):
            loop = np.array([r[loop_key][j] for r in runs])
            base = np.array([r[f"{where}|{other}"][j] for r in runs])
            margin = base.mean() - loop.mean()
            sd = base.std(ddof=1) + loop.std(ddof=1) if len(runs) > 1 else float("nan")
            print(f"{where} {what} vs {other}: ratio {np.mean(base / loop):.2f}x (per seed "
                  f"{', '.join(f'{x:.2f}' for x in base / loop)}; ratio of the means {base.mean() / loop.mean():.2f}x), "
                  f"margin {margin:.4f} vs sd sum {sd:.4f}: {'outside' if margin > sd else 'NOT outside'} the spread")
