"""pdebench_diffusion_sorption1d against PDEBench's generator: ``python -m benchmarks.diffusion_sorption1d_validation
--pdebench DIR [--only pdebench_stats,same_ic,stats,report] [--samples 256] [--minutes 10]``.

pdebench_stats: PDEBench's own Simulator (src/sim_diff_sorp.py of the pdebench 0.1.0 wheel: np.random.seed(seed),
u0 = U(0, 0.2) in every cell, scipy's RK45 at its default tolerances) for seeds 0, 1, ...; per seed its draw and the
spatial mean / std of u at every REPORT_EVERY-th frame, one JSON line each in RESULTS/pdebench_seeds.jsonl (resumable:
seeds already there are skipped; ``--minutes`` bounds one call). same_ic: PDEBench's seed-0 IC given to both
solvers at n and 2n cells (each measured against its own finer run), RESULTS/same_ic.json. stats: the recipe's
samples (seed 0) summarised the same way, RESULTS/ours_seeds.jsonl. report: the two sets' per-frame mean and std
across samples with their sampling errors, RESULTS/stats.json. Figures, not pass/fail (docs/results/recipes.md).

--pdebench DIR: a directory holding PDEBench's ``pdebench`` package (e.g. the pdebench 0.1.0 wheel unpacked; this
module needs numpy and scipy only). PDEBench is not part of pdestream and is not imported otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

# PDEBench's diff-sorp.yaml (sim:) and the published set's time sampling (101 frames: config_diff-sorp.yaml t_train)
CONSTS = {"D": 5e-4, "por": 0.29, "rho_s": 2880.0, "k_f": 3.5e-4, "n_f": 0.874, "sol": 1.0}
T_END, N_FRAMES, N = 500.0, 101, 1024
REPORT_EVERY = 5  # frames kept in the per-seed summaries: t = 0, 25, ..., 500
RESULTS = Path(__file__).parent / "results" / "diffusion_sorption1d"


def pdebench_solve(root: str, seed: int, n: int = N, u0: float | None = None) -> np.ndarray:
    """PDEBench's own Simulator for ``seed`` on n cells: frames [T, n] float64 at linspace(0, 500, 101). ``u0``:
    its constant initial value instead of the seed's draw (the draw is replaced after the Simulator makes it)."""
    if root not in sys.path:
        sys.path.insert(0, root)
    from pdebench.data_gen.src.sim_diff_sorp import Simulator

    sim = Simulator(**CONSTS, t=T_END, tdim=N_FRAMES, x_left=0.0, x_right=1.0, xdim=n, seed=seed)
    if u0 is None:
        return sim.generate_sample()[..., 0]
    real = np.random.uniform  # its draw is np.random.uniform(0, 0.2) after np.random.seed(seed)
    try:
        np.random.uniform = lambda *a, **k: u0
        return sim.generate_sample()[..., 0]
    finally:
        np.random.uniform = real


def pdebench_draw(seed: int) -> float:
    """The published set's u0 value for ``seed`` (pdebench 0.1.0: np.random.seed(seed); np.random.uniform(0, 0.2))."""
    return float(np.random.RandomState(seed).uniform(0, 0.2))


def summary(u: np.ndarray) -> dict:
    """Frames [T, n] -> {"mean": [T'], "std": [T']} over x at every REPORT_EVERY-th frame (6 significant digits)."""
    keep = u[::REPORT_EVERY]
    return {"mean": [float(f"{v:.6g}") for v in keep.mean(-1)], "std": [float(f"{v:.6g}") for v in keep.std(-1)]}


def _done(path: Path) -> dict[int, dict]:
    if not path.exists():
        return {}
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return {r["seed"]: r for r in rows}


def pdebench_stats(root: str, samples: int, minutes: float) -> None:
    path = RESULTS / "pdebench_seeds.jsonl"
    done = _done(path)
    stop = time.monotonic() + 60 * minutes
    for seed in range(samples):
        if seed in done:
            continue
        if time.monotonic() > stop:
            print(f"pdebench_stats: stopped at --minutes {minutes:g}; {len(done)} of {samples} seeds done (rerun to go on)")
            return
        t0 = time.perf_counter()
        u = pdebench_solve(root, seed)
        row = {"seed": seed, "u0": pdebench_draw(seed), "seconds": round(time.perf_counter() - t0, 2),
               "finite": bool(np.isfinite(u).all()), **summary(u)}
        with path.open("a") as f:
            f.write(json.dumps(row) + "\n")
        done[seed] = row
        print(f"pdebench seed {seed}: u0 {row['u0']:.4f}, {row['seconds']:.1f} s", flush=True)
    print(f"pdebench_stats: {samples} seeds done")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--minutes", type=float, default=10.0, help="wall-clock bound of one call's PDEBench runs")
    parser.add_argument("--pdebench", default=None, help="a directory holding PDEBench's pdebench package")
    parser.add_argument("--only", default="pdebench_stats,same_ic,stats,report")
    args = parser.parse_args(argv)
    parts = args.only.split(",")
    RESULTS.mkdir(parents=True, exist_ok=True)
    if "pdebench_stats" in parts:
        if not args.pdebench:
            raise SystemExit("pdebench_stats needs --pdebench DIR (a directory holding PDEBench's pdebench package)")
        pdebench_stats(args.pdebench, args.samples, args.minutes)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
