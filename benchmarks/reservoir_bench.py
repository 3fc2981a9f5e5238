"""Reservoir vs FIFO stream at the FNO paper's Burgers set-up: how long does training wait for the solver?

``python -m benchmarks.reservoir_bench [--seconds 120] [--max-reuse 50] [--quick]``

Both arms train the same FNO (width 64, 16 modes, 4 layers, batch 20, lr 1e-3, torch on 1 thread so the
solver keeps the other core) on burgers1d n=1024, nu=0.1, u0 -> u(1), for the same wall-clock time, through
``surrogate.budget.run_arm``. Printed per arm: the training loop's wait share (time in ``next(batch)`` over
the loop's time), start-up (compile + normalization draw), steps, trajectories solved, solver trajectories/s,
examples/s, mean and max reuse, and the test error on 64 held-out trajectories. Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reservoir_bench", description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=120.0, help="wall-clock budget per arm")
    p.add_argument("--max-reuse", type=float, default=50.0, help="the reservoir's bound on uses per trajectory")
    p.add_argument("--capacity", type=int, default=1000, help="trajectories the reservoir holds")
    p.add_argument("--quick", action="store_true", help="n=256, a small FNO, 20 s per arm")
    args = p.parse_args(argv)
    from pdestream import generator
    from pdestream.experiments.budget import BudgetConfig, run_arm, stratified_test_set

    torch.set_num_threads(1)
    n, model_cfg, seconds = 1024, {"width": 64, "modes": 16, "layers": 4}, args.seconds
    if args.quick:
        n, model_cfg, seconds = 256, {"width": 32, "modes": 12, "layers": 3}, min(seconds, 20.0)
    pde = generator.get_pde("burgers1d", n=n, nu=0.1, t_end=1.0, n_frames=2)
    cfg = BudgetConfig(budget_s=seconds, model_cfg=model_cfg, batch_size=20, lr=1e-3, capacity=args.capacity,
                       max_reuse=args.max_reuse, n_test=64, snapshots=1)
    tests = {"test": stratified_test_set(pde, cfg.n_test, 0)}
    from pdestream import datasets

    datasets.sample_tensors(pde, list(range(cfg.solve_batch)), 0)  # compile first: neither arm pays for it

    view = datasets.make_view("operator")
    print(f"burgers1d n={n}, nu=0.1, u0 -> u(1); FNO {model_cfg}, batch 20; {seconds:g} s per arm; "
          f"reservoir capacity {args.capacity}, max_reuse {args.max_reuse:g}, async, thread producer")
    print("| arm | wait share | start-up s | steps | trajectories solved | solver traj/s | examples/s | "
          "mean reuse | max reuse | test rel L2 |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        for arm in ("fifo", "reservoir"):
            r = run_arm(arm, pde, view, cfg, Path(tmp) / arm, tests, log=lambda *_: None)
            st = r["stats"] or {}
            loop = r["data_wait_s"] + r["compute_s"]
            solved = r["trajectories_solved"]
            print(f"| {arm} | {100 * r['wait_share']:.1f}% | {r['startup_s']:.1f} | {r['steps']} | {solved} | "
                  f"{solved / r['wall_s']:.1f} | {r['examples'] / max(loop, 1e-9):.1f} | "
                  f"{st.get('reuse_mean', 1.0):.2f} | {st.get('reuse_max', 1.0):.2f} | {r['test_mean']:.4f} |", flush=True)


if __name__ == "__main__":
    main()
