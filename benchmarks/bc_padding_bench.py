"""Walls in the model or not: the same FNO / U-Net trained on a walled entry with padding that follows its
boundary conditions, against the same network forced to circular padding (the periodic model), on the same
cached data, steps and seeds. Prints test relative L2 (one-step pairs) mean and p95 per arm, mean +- std over
seeds, and the ratio circular / walls.

    python -m benchmarks.bc_padding_bench --pde burgers1d --set n=128 --set bc=dirichlet \
        --set "bc_lo=uniform(-1, 1)" --set "bc_hi=uniform(-1, 1)" --steps 600 --seeds 3
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from pdestream import datasets, generator
from pdestream.surrogate.data import test_set, train_loader
from pdestream.surrogate.metrics import rel_l2
from pdestream.surrogate.models import build_model
from pdestream.surrogate.predict import model_channels, pairs, predict
from pdestream.surrogate.train import train


@torch.no_grad()
def pair_errors(model, norm, test, view) -> np.ndarray:
    """Relative L2 of every (input, next frame) pair of the test trajectories: float64 [pairs]."""
    model.train(False)
    out = []
    for batch in test:
        p = pairs(view, batch)
        pred = predict(model, norm, p["x"], p["params"], model.ndim, p["y"].shape)
        out.append(rel_l2(pred, p["y"]).double().numpy())
    return np.concatenate(out)


def run(pde, cache: Path, model: str, walls: bool, steps: int, seed: int, test, cfg: dict) -> np.ndarray:
    view = datasets.make_view("next_step")
    loader, data_pde = train_loader(pde, str(cache), view, batch_size=32, seed=seed)
    view = datasets.for_sample(view, data_pde.n_frames, len(data_pde.INPUTS))
    c_in, c_out = model_channels(data_pde, view)
    torch.manual_seed(seed)
    net = build_model(model, data_pde.NDIM, c_in, c_out, len(data_pde.PARAMS),
                      bc=data_pde.grid.bc if walls else None, **cfg)
    with tempfile.TemporaryDirectory() as out:
        summary = train(net, loader, steps, out, lr=1e-3, log_every=max(1, steps // 4))
    return pair_errors(net, summary["normalizer"], test, view)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pde", default="burgers1d")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--model", default="fno", choices=("fno", "unet"))
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--samples", type=int, default=256, help="trajectories in the training cache")
    ap.add_argument("--test", type=int, default=64, help="held-out test trajectories")
    args = ap.parse_args(argv)
    torch.set_num_threads(2)
    pde = generator.get_pde(args.pde, dict(s.split("=", 1) for s in args.set))
    cfg = {"width": 32, "modes": 12, "layers": 3} if args.model == "fno" else {"channels": 16, "depth": 2}
    print(f"{pde.NAME}: bc {' '.join(pde.grid.bc)}, n={pde.n}, {args.samples} training trajectories, {args.model} {cfg}, "
          f"{args.steps} steps, {args.seeds} seeds")
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "train.h5"
        datasets.write_cache(pde, cache, args.samples, seed=0)
        test = test_set(pde, 0, args.test)
        table = {True: [], False: []}
        for seed in range(args.seeds):
            for walls in (True, False):
                t0 = time.perf_counter()
                err = run(pde, cache, args.model, walls, args.steps, seed, test, cfg)
                table[walls].append((err.mean(), np.percentile(err, 95)))
                print(f"  seed {seed} {'walls   ' if walls else 'circular'}: mean {err.mean():.4f}  p95 "
                      f"{np.percentile(err, 95):.4f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    print("| padding | test rel L2 mean | test rel L2 p95 |\n| --- | --- | --- |")
    for walls in (True, False):
        a = np.asarray(table[walls])
        print(f"| {'bc-aware' if walls else 'circular'} | {a[:, 0].mean():.4f} +- {a[:, 0].std():.4f} | "
              f"{a[:, 1].mean():.4f} +- {a[:, 1].std():.4f} |")
    w, c = np.asarray(table[True]), np.asarray(table[False])
    print(f"circular / bc-aware: mean {c[:, 0].mean() / w[:, 0].mean():.2f}x, p95 {c[:, 1].mean() / w[:, 1].mean():.2f}x")


if __name__ == "__main__":
    main()
