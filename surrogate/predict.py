"""The network's side of every loop and evaluation: frames into channels, one prediction, a rollout, errors.

Known here once: how frames are stacked into a model's channels (``stack_frames``), how a batch becomes a
physical-unit prediction (``predict``), how whole trajectories become a view's pairs (``pairs``), how a
next-step network is fed its own output (``rollout``) and the per-example relative error a loop reports
(``relative_errors``). Nothing here trains, evaluates a test set or touches a file.
"""

from __future__ import annotations

import torch
from torch import nn

from pdestream.datasets.normalize import Normalization
from pdestream.datasets.views import collate, examples


def stack_frames(u: torch.Tensor, ndim: int) -> torch.Tensor:
    """[B, k, C, *space] -> [B, k*C, *space]; [B, C, *space] unchanged."""
    return u.flatten(1, u.ndim - ndim - 1)


def model_channels(pde, view) -> tuple[int, int]:
    """(in_channels, out_channels) of a model trained on ``view`` (the view says: frames stacked into channels for
    next-step views); ValueError for a view that makes no input/target pairs."""
    return view.channels(len(pde.FIELDS))


def predict(model: nn.Module, norm: Normalization, x: torch.Tensor, params: torch.Tensor, ndim: int,
            y_shape: torch.Size) -> torch.Tensor:
    """Physical-unit prediction in the target's layout y_shape ([B, k_out, C, *space] or [B, C, *space])."""
    out = model(stack_frames(norm.of_x.normalize(x), ndim), norm.normalize_params(params))  # [B, k_out*C, *space]
    return norm.of_y.denormalize(out.reshape(y_shape))


def net_step(model: nn.Module, window: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """One network step in normalized units: window [B, k_in, C, *space] -> next frame [B, 1, C, *space]."""
    out = model(stack_frames(window, window.ndim - 3), p)  # [B, C, *space]
    return out.reshape(window.shape[0], 1, *window.shape[2:])


@torch.no_grad()
def rollout(model: nn.Module, u0: torch.Tensor, params: torch.Tensor, n_frames: int) -> torch.Tensor:
    """Feed predictions back, in normalized units (the caller normalizes u0 and params, and denormalizes the
    result): u0 [B, k_in, C, *space], params [B, P] -> [B, n_frames, C, *space]."""
    k_in, frames, done = u0.shape[1], [], 0
    window = u0
    while done < n_frames:
        out = model(stack_frames(window, window.ndim - 3), params)  # [B, k_out*C, *space]
        nxt = out.reshape(u0.shape[0], -1, *u0.shape[2:])  # [B, k_out, C, *space]
        frames.append(nxt)
        done += nxt.shape[1]
        window = torch.cat([window, nxt], dim=1)[:, -k_in:]  # [B, k_in, C, *space]
    return torch.cat(frames, dim=1)[:, :n_frames]


def pairs(view, batch: dict) -> dict:
    """Whole trajectories {"u": [B, T, C, *space], "params", "index"} -> the view's (x, y) pairs, every window
    for next-step views."""
    view = view.evaluation()  # a next-step view: every window, not a random few; ValueError for "whole"
    u, params, index = batch["u"], batch["params"], batch["index"]
    t = torch.zeros(u.shape[1])  # times are not model inputs
    out = []
    for i in range(len(u)):
        out += examples(view, u[i], t, params[i], int(index[i]))
    return collate(out)


def relative_errors(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-example ||pred - target|| / ||target|| over all non-batch dims: [B, ...] x 2 -> float64 CPU [B]."""
    pred, target = pred.detach().flatten(1).double().cpu(), target.detach().flatten(1).double().cpu()
    return (pred - target).norm(dim=1) / target.norm(dim=1).clamp_min(torch.finfo(torch.float64).tiny)
