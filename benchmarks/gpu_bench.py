"""JAX solving on the GPU while torch trains there: ``python -m benchmarks.gpu_bench [--quick] [--seconds S]``.

Needs JAX's CUDA build and torch's CUDA build in one environment (prints what it sees and stops otherwise).

1. Solver throughput: trajectories/s of ``generator.sample`` on the GPU against the CPU, both in this process
   (the CPU arm through ``jax.default_device``), per PDE and batch size, after a warm-up (compilation excluded).
2. Zero-copy hand-over: a stream batch solved on the GPU reaches torch as a CUDA tensor sharing JAX's buffer
   (DLPack), with no host copy: the pointers are compared.
3. The FNO Burgers set-up (n=1024, nu=0.1, u0 -> u(1), FNO 64/16/4, batch 20) trained on the GPU for the same
   wall-clock time through the FIFO stream and through the reservoir (``surrogate.budget.run_arm``, solver on
   the same GPU): the training loop's wait share, steps, solver trajectories/s, reuse, test error.
Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

# before JAX starts: JAX's default 75% preallocation of the GPU would starve torch, which trains there too
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

CASES = (  # (catalog name, overrides, batch sizes)
    ("burgers1d", {"n": 1024, "nu": 0.1, "t_end": 1.0, "n_frames": 2}, (16, 256)),
    ("ks1d", {}, (16, 256)),
    ("ns2d", {}, (4, 32)),
)


def rate(pde, batch: int, device, reps: int) -> float:
    """Median trajectories/s of ``reps`` solves of ``batch`` samples on ``device`` (after one warm-up)."""
    import jax

    from pdestream import generator

    times = []
    with jax.default_device(device):
        for r in range(reps + 1):
            t0 = time.perf_counter()
            generator.sample(pde, np.arange(r * batch, (r + 1) * batch), 0).u.block_until_ready()
            times.append(time.perf_counter() - t0)
    return batch / float(np.median(times[1:]))


def solver_table(quick: bool) -> None:
    import jax

    from pdestream import generator

    gpu, cpu = jax.devices("gpu")[0], jax.devices("cpu")[0]
    print("| pde | grid | batch | GPU traj/s | CPU traj/s | GPU / CPU |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for name, overrides, batches in CASES:
        pde = generator.get_pde(name, **overrides)
        for b in batches[:1] if quick else batches:
            g, c = rate(pde, b, gpu, 3), rate(pde, b, cpu, 2)
            print(f"| {name} | {pde.n}^{pde.NDIM} x {pde.n_frames} frames | {b} | {g:.1f} | {c:.1f} | {g / c:.1f}x |",
                  flush=True)


def zero_copy() -> None:
    import jax

    from pdestream import datasets, generator
    from pdestream.datasets._bridge import to_torch

    traj = generator.sample("burgers1d", np.arange(8), 0)
    u = to_torch(traj.u)
    same = u.data_ptr() == traj.u.unsafe_buffer_pointer()
    batch = next(iter(datasets.TrajectoryStream("burgers1d", 0, view="whole", batch_size=8, solve_batch=8)))
    print(f"JAX default backend: {jax.default_backend()}; stream batch on {batch['u'].device}; a solved batch as a "
          f"torch tensor on {u.device} {'shares' if same else 'does NOT share'} JAX's buffer (DLPack, no copy)")


def training(seconds: float, quick: bool, solve_batch: int) -> None:
    from pdestream import datasets, generator
    from pdestream.experiments.budget import BudgetConfig, run_arm, stratified_test_set

    n, model_cfg = (256, {"width": 32, "modes": 12, "layers": 3}) if quick else (1024, {"width": 64, "modes": 16, "layers": 4})
    pde = generator.get_pde("burgers1d", n=n, nu=0.1, t_end=1.0, n_frames=2)
    cfg = BudgetConfig(budget_s=seconds, model_cfg=model_cfg, batch_size=20, lr=1e-3, capacity=1000, max_reuse=50,
                       n_test=64, snapshots=1, device="cuda", solve_batch=solve_batch)
    tests = {"test": stratified_test_set(pde, cfg.n_test, 0)}
    datasets.sample_tensors(pde, list(range(cfg.solve_batch)), 0)  # compile first: neither arm pays for it
    view = datasets.make_view("operator")
    print(f"\nburgers1d n={n}, nu=0.1, u0 -> u(1); FNO {model_cfg}, batch 20, trained on {torch.cuda.get_device_name()}"
          f"; {seconds:g} s per arm; solver on the same GPU, {solve_batch} trajectories per solve")
    print("| arm | wait share | steps | steps/s | trajectories solved | solver traj/s | mean reuse | test rel L2 |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        for arm in ("fifo", "reservoir"):
            r = run_arm(arm, pde, view, cfg, Path(tmp) / arm, tests, log=lambda *_: None)
            st = r["stats"] or {}
            loop = r["data_wait_s"] + r["compute_s"]
            print(f"| {arm} | {100 * r['wait_share']:.1f}% | {r['steps']} | {r['steps'] / max(loop, 1e-9):.1f} | "
                  f"{r['trajectories_solved']} | {r['trajectories_solved'] / r['wall_s']:.1f} | "
                  f"{st.get('reuse_mean', 1.0):.2f} | {r['test_mean']:.4f} |", flush=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.gpu_bench", description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=60.0, help="wall-clock budget per training arm")
    p.add_argument("--quick", action="store_true", help="one batch size per PDE, a small FNO, 15 s per arm")
    p.add_argument("--solve-batch", type=int, default=16, help="trajectories per solve in the training arms")
    p.add_argument("--skip", default="", help="comma list of parts to skip: solver, zero_copy, training")
    args = p.parse_args(argv)
    import jax

    if not torch.cuda.is_available() or not any(d.platform == "gpu" for d in jax.devices()):
        print(f"no GPU for both frameworks here (torch cuda: {torch.cuda.is_available()}, JAX devices: "
              f"{jax.devices()}); nothing to measure")
        return
    skip = set(args.skip.split(","))
    print(f"JAX {jax.__version__} on {jax.devices()[0].device_kind}; torch {torch.__version__}")
    if "solver" not in skip:
        solver_table(args.quick)
    if "zero_copy" not in skip:
        zero_copy()
    if "training" not in skip:
        training(min(args.seconds, 15.0) if args.quick else args.seconds, args.quick, args.solve_batch)


if __name__ == "__main__":
    main()
