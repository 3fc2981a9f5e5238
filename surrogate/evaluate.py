"""Held-out evaluation: one-step errors under a training view, and autoregressive rollouts.

A test set is a list of whole-trajectory batches {"u": [B, T, C, *space], "params": [B, P], "index": [B]}
(the "whole" view), so the same test set serves operator and next-step models alike.
"""

from __future__ import annotations

import torch
from torch import nn

from datasets.normalize import Normalization
from datasets.views import collate, examples

from .data import model_device, to_device
from .metrics import nrmse, rel_l2, summarize
from .train import predict


def pairs(view, batch: dict) -> dict:
    """Whole trajectories -> the view's (x, y) pairs, every window for next-step views."""
    view = view.evaluation()  # a next-step view: every window, not a random few; ValueError for "whole"
    u, params, index = batch["u"], batch["params"], batch["index"]
    t = torch.zeros(u.shape[1])  # times are not model inputs
    out = []
    for i in range(len(u)):
        out += examples(view, u[i], t, params[i], int(index[i]))
    return collate(out)


@torch.no_grad()
def evaluate(model: nn.Module, norm: Normalization, test: list[dict], view, chunk: int = 256) -> dict:
    """Mean relative L2 and nRMSE (PDEBench) over every pair of the test trajectories, physical units."""
    model.train(False)  # evaluation mode
    errors = {"rel_l2": [], "nrmse": []}
    for batch in test:
        p = to_device(pairs(view, batch), model_device(model))
        for s in range(0, len(p["x"]), chunk):
            x, y, params = p["x"][s:s + chunk], p["y"][s:s + chunk], p["params"][s:s + chunk]
            pred = predict(model, norm, x, params, model.ndim, y.shape)  # [b, (k_out,) C, *space]
            errors["rel_l2"].append(rel_l2(pred, y))
            errors["nrmse"].append(nrmse(pred, y, model.ndim))
    model.train()
    return summarize(errors)


@torch.no_grad()
def rollout(model: nn.Module, u0: torch.Tensor, params: torch.Tensor, n_frames: int) -> torch.Tensor:
    """Feed predictions back, in normalized units (the caller normalizes u0 and params, and denormalizes the
    result): u0 [B, k_in, C, *space], params [B, P] -> [B, n_frames, C, *space]."""
    k_in, frames, done = u0.shape[1], [], 0
    window = u0
    while done < n_frames:
        out = model(window.flatten(1, 2), params)  # [B, k_out*C, *space]
        nxt = out.reshape(u0.shape[0], -1, *u0.shape[2:])  # [B, k_out, C, *space]
        frames.append(nxt)
        done += nxt.shape[1]
        window = torch.cat([window, nxt], dim=1)[:, -k_in:]  # [B, k_in, C, *space]
    return torch.cat(frames, dim=1)[:, :n_frames]


@torch.no_grad()
def rollout_error(model: nn.Module, norm: Normalization, test: list[dict], k_in: int, horizon: int | None = None) -> list[float]:
    """Relative L2 per predicted frame (mean over test trajectories), rolling out from the first k_in frames.

    horizon: frames to predict (default: the rest of the trajectory).
    """
    model.train(False)  # evaluation mode
    per_frame = []
    for batch in test:
        batch = to_device(batch, model_device(model))
        u = batch["u"]  # [B, T, C, *space]
        h = u.shape[1] - k_in if horizon is None else horizon
        if not 1 <= h <= u.shape[1] - k_in:
            raise ValueError(f"rollout horizon={h} not allowed; must be in 1..{u.shape[1] - k_in} for {u.shape[1]} frames")
        pred = rollout(model, norm.normalize(u[:, :k_in]), norm.normalize_params(batch["params"]), h)
        pred = norm.denormalize(pred)  # [B, h, C, *space]
        truth = u[:, k_in:k_in + h]
        per_frame.append(torch.stack([rel_l2(pred[:, j], truth[:, j]) for j in range(h)], dim=1).cpu())  # [B, h]
    model.train()
    return torch.cat(per_frame).mean(0).tolist()
