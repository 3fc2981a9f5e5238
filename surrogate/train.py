"""One training loop for any DataLoader of batch dicts, streamed or cached, with identical code.

A batch is {"x": [B, k_in, C, *space] or [B, C, *space], "y": same layout with k_out frames, "params": [B, P],
"index": [B], ...}. Frames are stacked into channels for the model ([B, k*C, *space]); fields and
parameters are normalized by a ``datasets.Normalization`` (per-field / per-parameter mean and std) taken from the
data source when it offers one (a stream's calibration draw, a cache's stored samples), else from the first
training batch. The loss is the MSE in normalized units.

The run directory gets ``metrics.csv`` (one row per log step), ``metrics.json`` (summary) and ``model.pt``
(state dicts and plain dicts only: ``torch.load(path, weights_only=True)`` works).
"""

from __future__ import annotations

import csv
import json
import math
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm

from datasets.normalize import Normalization

from .models import build_model, model_spec


def source_normalization(loader) -> Normalization | None:
    """The data source's own statistics over its data (TrajectoryStream / CachedTrajectories
    ``.normalization()``), or None if it has none."""
    source = getattr(loader, "dataset", loader)
    return source.normalization() if hasattr(source, "normalization") else None


def stack_frames(u: torch.Tensor, ndim: int) -> torch.Tensor:
    """[B, k, C, *space] -> [B, k*C, *space]; [B, C, *space] unchanged."""
    return u.flatten(1, u.ndim - ndim - 1)


def predict(model: nn.Module, norm: Normalization, x: torch.Tensor, params: torch.Tensor, ndim: int,
            y_shape: torch.Size) -> torch.Tensor:
    """Physical-unit prediction in the target's layout y_shape ([B, k_out, C, *space] or [B, C, *space])."""
    out = model(stack_frames(norm.normalize(x), ndim), norm.normalize_params(params))  # [B, k_out*C, *space]
    return norm.denormalize(out.reshape(y_shape))


def make_schedule(opt: torch.optim.Optimizer, name: str, steps: int, lr: float):
    """"cosine" (decay to 1% of lr) or "onecycle" (warm-up then anneal) over ``steps`` optimizer steps."""
    if name == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=steps, eta_min=lr * 0.01)
    if name == "onecycle":
        return torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps)
    raise ValueError(f"unknown schedule {name!r}; allowed: cosine, onecycle")


def forever(loader):
    """Batches from ``loader``, iterating it again whenever a finite loader runs out.

    The loader owns its epochs: a finite TrajectoryStream / StreamLoader starts the next epoch itself when one
    ends, and a shuffling DataLoader reshuffles on each new iteration, so nothing is advanced here.
    """
    while True:
        empty = True
        for batch in loader:
            empty = False
            yield batch
        if empty:
            raise ValueError("the data loader yielded no batches (empty dataset?)")


def train(model: nn.Module, loader, steps: int, out_dir, *, lr: float = 1e-3, schedule: str = "cosine",
          normalizer: Normalization | None = None, log_every: int = 10, meta: dict | None = None,
          label: str = "train") -> dict:
    """Train ``model`` for ``steps`` optimizer steps on batches from ``loader``; returns the summary dict.

    Works the same for an IterableDataset stream (DataLoader(stream, batch_size=None)) and a map-style cache
    (DataLoader(cached, batch_size=B, shuffle=True)). Times are wall-clock seconds: "t_data" is time spent
    waiting for the next batch, "t_compute" forward + backward + optimizer step.
    """
    if steps < 1:
        raise ValueError(f"steps={steps} not allowed; must be >= 1")
    if lr <= 0:
        raise ValueError(f"lr={lr} not allowed; must be > 0")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ndim = model.ndim
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = make_schedule(opt, schedule, steps, lr)
    batches = forever(loader)
    t_data = t_compute = 0.0
    examples, trajectories, rows = 0, set(), []
    bar = tqdm(total=steps, desc=label, disable=not sys.stderr.isatty(), leave=False)
    start = time.perf_counter()
    if normalizer is None:
        normalizer = source_normalization(loader)
        t_data += time.perf_counter() - start  # a calibration draw (or reading a cache for it) is data time
    model.train()
    for step in range(1, steps + 1):
        t0 = time.perf_counter()
        batch = next(batches)
        t1 = time.perf_counter()
        if normalizer is None:  # the data source offers none: calibrate on the first batch
            normalizer = Normalization.from_batch(batch, ndim)
        x, y = batch["x"], batch["y"]  # [B, (k,) C, *space]
        target = stack_frames(normalizer.normalize(y), ndim)  # [B, k_out*C, *space]
        pred = model(stack_frames(normalizer.normalize(x), ndim), normalizer.normalize_params(batch["params"]))
        loss = F.mse_loss(pred, target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        loss_value = loss.item()
        t2 = time.perf_counter()
        if not math.isfinite(loss_value):
            raise ValueError(f"{label}: training diverged at step {step} (loss={loss_value}); lower --lr")
        t_data, t_compute = t_data + t1 - t0, t_compute + t2 - t1
        examples += len(x)
        trajectories.update(batch["index"].tolist())
        bar.update(1)
        if step % log_every == 0 or step == steps:
            rows.append({"step": step, "loss": loss_value, "lr": sched.get_last_lr()[0], "examples": examples,
                         "trajectories": len(trajectories), "t_data": t_data, "t_compute": t_compute,
                         "elapsed": time.perf_counter() - start})
            bar.set_postfix(loss=f"{loss_value:.3g}")
    bar.close()
    summary = {"label": label, "steps": steps, "final_loss": rows[-1]["loss"], "examples_seen": examples,
               "trajectories_seen": len(trajectories), "t_data": t_data, "t_compute": t_compute,
               "wall": time.perf_counter() - start, "data_share": t_data / max(t_data + t_compute, 1e-12),
               "normalization_samples": normalizer.samples, "model": model_spec(model), "lr": lr, "schedule": schedule, **(meta or {})}
    with open(out / "metrics.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (out / "metrics.json").write_text(json.dumps(summary, indent=2))
    save_checkpoint(out / "model.pt", model, normalizer, step=steps, meta=meta)
    summary["normalizer"] = normalizer
    summary["curve"] = rows
    return summary


def save_checkpoint(path, model: nn.Module, normalizer: Normalization, step: int, meta: dict | None = None) -> None:
    """State dict + plain dicts only, so ``torch.load(path, weights_only=True)`` loads it."""
    torch.save({"model": model.state_dict(), "spec": model_spec(model), "normalization": normalizer.to_dict(),
                "step": step, "meta": meta or {}}, path)


def load_checkpoint(path) -> tuple[nn.Module, Normalization, dict]:
    """(model in eval mode, its normalization, the checkpoint dict) from ``save_checkpoint``'s file."""
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    if "normalization" not in ckpt:
        raise ValueError(f"{path} is a checkpoint of an older pdestream (no 'normalization' entry); train it again")
    spec = dict(ckpt["spec"])
    model = build_model(spec.pop("name"), spec.pop("ndim"), spec.pop("in_channels"), spec.pop("out_channels"),
                        spec.pop("n_params"), **spec)
    model.load_state_dict(ckpt["model"])
    return model.train(False), Normalization.from_dict(ckpt["normalization"]), ckpt
