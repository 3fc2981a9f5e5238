"""One training run end to end: data source -> model -> train -> held-out test errors (used by the CLI)."""

from __future__ import annotations

import json
from pathlib import Path

import torch

import datasets

from .data import test_set, train_loader
from .evaluate import evaluate, rollout_error
from .models import build_model
from .train import train


def model_channels(pde, view) -> tuple[int, int]:
    """(in_channels, out_channels): frames stacked into channels for next-step views."""
    c = len(pde.FIELDS)
    if isinstance(view, datasets.NextStep):
        return view.k_in * c, view.k_out * c
    if isinstance(view, datasets.Operator):
        return c, c
    raise ValueError(f"cannot train on the {view.name!r} view; allowed: next_step, operator")


def test_errors(model, normalizer, view, test: list[dict]) -> dict:
    """{"rel_l2", "nrmse"} on every pair of the test trajectories, plus "rollout" (per frame) for next-step."""
    out = evaluate(model, normalizer, test, view)
    if isinstance(view, datasets.NextStep):
        curve = rollout_error(model, normalizer, test, view.k_in)
        out["rollout"], out["rollout_final"] = curve, curve[-1]
    return out


def train_run(pde, source: str, out_dir, *, model: str = "fno", model_cfg: dict | None = None, view="next_step",
              steps: int = 1000, batch_size: int = 32, lr: float = 1e-3, schedule: str = "cosine", seed: int = 0,
              data_seed: int | None = None,
              tests: dict[str, list[dict]] | None = None, n_test: int = 32, explicit: dict | None = None,
              label: str = "train") -> dict:
    """Train ``model`` on ``source`` ("stream" or a cache path) for ``steps`` optimizer steps; evaluate.

    seed: model initialization and cache shuffling; data_seed: the stream's sample seed (default: seed).
    tests: named held-out sets (whole trajectories); default {"test": n_test trajectories of a held-out seed}.
    Writes metrics.csv, metrics.json (with the test errors) and model.pt to out_dir; returns the summary.
    """
    view = datasets.make_view(view)
    data_seed = seed if data_seed is None else data_seed
    loader, data_pde = train_loader(pde, source, view, batch_size, seed=seed, data_seed=data_seed, explicit=explicit)
    view.check(data_pde.n_frames)
    c_in, c_out = model_channels(data_pde, view)
    torch.manual_seed(seed)  # same initial weights for every source with the same seed
    net = build_model(model, data_pde.NDIM, c_in, c_out, len(data_pde.PARAMS), **(model_cfg or {}))
    meta = {"pde": data_pde.config(), "source": str(source), "view": view.name,
            "view_args": {k: v for k, v in vars(view).items()}, "seed": seed, "data_seed": data_seed, "batch_size": batch_size}
    summary = train(net, loader, steps, out_dir, lr=lr, schedule=schedule, meta=meta, label=label)
    if tests is None:
        tests = {"test": test_set(data_pde, data_seed, n_test)}
    summary["test"] = {name: test_errors(net, summary["normalizer"], view, t) for name, t in tests.items()}
    path = Path(out_dir) / "metrics.json"
    saved = json.loads(path.read_text())
    saved["test"] = summary["test"]
    path.write_text(json.dumps(saved, indent=2))
    return summary
