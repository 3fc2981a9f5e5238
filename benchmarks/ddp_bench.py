"""Training throughput on 1 rank vs N gloo ranks on this machine's CPU, each rank with its own training reservoir.

``python -m benchmarks.ddp_bench [--ranks 2] [--steps 60] [--quick]``

Each arm spawns its ranks (torch.multiprocessing, gloo, one torch thread and one solver thread per rank), trains
an FNO (width 32, 12 modes, 3 layers, batch 16 per rank) through ``surrogate.train.train`` on burgers1d n=256
with an async reservoir per rank (capacity 256, max_reuse 16), and times the steps after a warm-up of 10 (the
compile and the normalization draw left out). Printed per arm: global examples/s (all ranks) and the ratio to
one rank, measured in the same process. On a machine with fewer cores than 2 x ranks (the project's 2-core
machine) the ranks share cores, so this shows the cost of the collectives, not a speed-up. Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import torch

WARMUP = 10


def _rank(rank: int, world: int, work: str, n: int, steps: int, model_cfg: dict) -> None:
    """One rank: train ``steps`` steps; rank 0 writes the times of the steps after the warm-up."""
    torch.set_num_threads(1)
    torch.distributed.init_process_group("gloo", init_method=f"file://{work}/rendezvous", rank=rank, world_size=world)
    from pdestream import generator
    from pdestream.surrogate import build_model
    from pdestream.surrogate.data import train_loader
    from pdestream.surrogate.train import train

    try:
        pde = generator.get_pde("burgers1d", n=n, nu=0.1, t_end=1.0, n_frames=2)
        cfg = {"kind": "reservoir", "capacity": 256, "max_reuse": 16.0, "solve_batch": 16, "mode": "async"}
        loader, _ = train_loader(pde, "stream", "operator", 16, data_seed=0, data_cfg=cfg)
        torch.manual_seed(0)
        model = build_model("fno", 1, 1, 1, 1, **model_cfg)
        times = []
        summary = train(model, loader, steps, Path(work) / "run", log_every=steps, schedule="constant",
                        after_step=lambda step, _f, _e: times.append(time.perf_counter()))
        loader.dataset.close()
        if rank == 0:
            per_step = summary["examples_seen"] / steps
            (Path(work) / "result").write_text(f"{per_step * (steps - WARMUP) / (times[-1] - times[WARMUP - 1])}")
    finally:
        torch.distributed.destroy_process_group()


def examples_per_s(world: int, n: int, steps: int, model_cfg: dict) -> float:
    """Global training examples/s of ``world`` gloo ranks after the warm-up."""
    with tempfile.TemporaryDirectory() as work:
        torch.multiprocessing.start_processes(_rank, args=(world, work, n, steps, model_cfg), nprocs=world,
                                              start_method="spawn")
        return float((Path(work) / "result").read_text())


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.ddp_bench", description=__doc__.splitlines()[0])
    p.add_argument("--ranks", type=int, default=2, help="ranks of the second arm")
    p.add_argument("--steps", type=int, default=60, help="steps per arm (the first 10 are not timed)")
    p.add_argument("--quick", action="store_true", help="n=128, a smaller FNO, 30 steps")
    args = p.parse_args(argv)
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    n, steps, model_cfg = 256, args.steps, {"width": 32, "modes": 12, "layers": 3}
    if args.quick:
        n, steps, model_cfg = 128, 30, {"width": 16, "modes": 8, "layers": 2}
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"DDP throughput, burgers1d n={n}, FNO {model_cfg}, batch 16 per rank, {steps - WARMUP} timed steps, "
          f"{cores} cores")
    base = examples_per_s(1, n, steps, model_cfg)
    print(f"  1 rank : {base:8.1f} examples/s")
    many = examples_per_s(args.ranks, n, steps, model_cfg)
    print(f"  {args.ranks} ranks: {many:8.1f} examples/s  ({many / base:.2f}x one rank)")


if __name__ == "__main__":
    main()
