"""Walled entries against their periodic twins: the same equation, grid, batch, time window and step count
(the walled entry's dt is set to the twin's step), solved in one process, alternating, median of --reps runs.
A sine / cosine transform costs about a real FFT of the same length plus O(n) twiddles, so the target is a walled
entry within 1.5x of its twin's time.

    python -m benchmarks.bounded_bench --reps 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax

from pdestream import generator

# (entry, its settings, the walls, batch)
CASES = [
    ("burgers1d", {"n": 1024, "n_frames": 11, "t_end": 0.2}, "dirichlet", 64),
    ("ks1d", {"n": 256, "n_frames": 11, "t_end": 20.0}, "dirichlet", 64),
    ("allen_cahn1d", {"n": 512, "n_frames": 11}, "neumann", 64),
    ("diffusion2d", {"n": 128, "n_frames": 11}, "dirichlet", 16),
    ("allen_cahn2d", {"n": 128, "n_frames": 11, "t_end": 2.0}, "neumann", 16),
    ("burgers2d", {"n": 128, "n_frames": 11, "t_end": 0.1}, "x=dirichlet,y=periodic", 16),
    ("fisher_kpp2d", {"n": 128, "n_frames": 11}, "neumann", 16),
]


def once(pde, batch: int, seed: int) -> float:
    """Seconds to solve samples 0..batch-1 of ``pde`` under ``seed``."""
    t0 = time.perf_counter()
    jax.block_until_ready(generator.sample(pde, range(batch), seed=seed).u)
    return time.perf_counter() - t0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--only", help="comma-separated entry names")
    args = ap.parse_args(argv)
    print("| case | batch | walls | periodic traj/s | walled traj/s | walled / periodic time |")
    print("| --- | ---: | --- | ---: | ---: | ---: |")
    for name, settings, bc, batch in CASES:
        if args.only and name not in args.only.split(","):
            continue
        twin = generator.get_pde(name, settings)
        walled = generator.get_pde(name, {**settings, "bc": bc, "dt": twin.step_dt})
        assert walled.steps_per_frame == twin.steps_per_frame
        once(twin, batch, 0), once(walled, batch, 0)  # compile both
        a, b = [], []
        for rep in range(1, args.reps + 1):  # alternating, so both see the same machine load
            a.append(once(twin, batch, rep))
            b.append(once(walled, batch, rep))
        ta, tb = statistics.median(a), statistics.median(b)
        n = "x".join(map(str, twin.grid.shape))
        print(f"| {name} {n}, {twin.steps_per_frame * (twin.n_frames - 1)} steps | {batch} | {bc} | {batch / ta:.1f} | "
              f"{batch / tb:.1f} | {tb / ta:.2f} |", flush=True)


if __name__ == "__main__":
    main()
