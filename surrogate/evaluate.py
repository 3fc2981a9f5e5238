"""Held-out evaluation, one evaluator: per-trajectory, per-frame errors, and the figures derived from them.

A test set is a list of whole-trajectory batches {"u": [B, T, C, *space], "params": [B, P], "index": [B]}
(the "whole" view), so the same test set serves operator and next-step models, and every training mode.

- ``rollout_errors`` is the one definition of a rollout's error: per test trajectory and predicted frame, the
  L2 norm of the error and of the truth ([N, T] each). A next-step model is rolled out autoregressively from
  the first k_in frames (by its mode: a network, or a corrected coarse solver); an operator model's one output
  counts as one frame (T = 1). Per-frame relative errors, whole-trajectory relative errors, curves and the mean,
  p95, p99, CVaR and max over trajectories all derive from it.
- ``test_errors``: one-step errors (relative L2 and PDEBench nRMSE) over every pair of the test trajectories,
  plus the rollout curve for next-step views: what a training run reports.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from pdestream.datasets.normalize import Normalization

from .data import model_device, to_device
from .metrics import EPS, nrmse, rel_l2
from .modes import Mode, OneStep
from .predict import pairs, predict
from .tails import tail_metrics


@dataclass(frozen=True)
class RolloutErrors:
    """diff, ref: float64 CPU [N, T]: per test trajectory and predicted frame, ||pred - truth||_2 and ||truth||_2
    over all channels and grid points of the frame (physical units)."""

    diff: torch.Tensor
    ref: torch.Tensor

    def relative(self) -> np.ndarray:
        """Relative L2 error per trajectory and frame, [N, T] (``metrics.rel_l2`` of each frame)."""
        return (self.diff / (self.ref + EPS)).numpy()

    def trajectory(self) -> np.ndarray:
        """Relative L2 error of each whole predicted trajectory (all its frames together), [N]."""
        return (self.diff.pow(2).sum(1).sqrt() / (self.ref.pow(2).sum(1).sqrt() + EPS)).numpy()

    def curve(self) -> list[float]:
        """Relative L2 error per frame, mean over trajectories, [T]."""
        return self.relative().mean(0).tolist()


def error_stats(errors: np.ndarray) -> dict:
    """mean, p95, p99, CVaR_0.95 ("cvar95": the mean of the worst ceil(0.05 N)) and max over trajectories of
    per-trajectory errors [N] (``surrogate.tails``)."""
    return tail_metrics(errors)


def _rolled_out(mode: Mode, model, norm: Normalization, batch: dict, view) -> tuple[torch.Tensor, torch.Tensor]:
    """(prediction, truth) [B, T', ...] of one batch of whole trajectories, physical units."""
    if view.rollout_k_in is None:  # an operator view: its one output is the whole prediction
        p = pairs(view, batch)
        return predict(model, norm, p["x"], p["params"], model.ndim, p["y"].shape)[:, None], p["y"][:, None]
    return mode.rollout(model, norm, batch["u"], batch["params"], view.rollout_k_in)


@torch.no_grad()
def rollout_errors(model: nn.Module | None, norm: Normalization, test: list[dict], view,
                   mode: Mode | None = None) -> RolloutErrors:
    """Per test trajectory and predicted frame, the L2 error norm and the truth's norm ([N, T] each, see
    ``RolloutErrors``). view: the model's view (its rollout_k_in frames start a rollout; an operator view makes
    one frame); mode: who predicts a step (default one-step: the network; model None: the mode's solver alone)."""
    mode = OneStep() if mode is None else mode
    device = model_device(model) if model is not None else torch.device("cpu")
    if model is not None:
        model.train(False)
    diff, ref = [], []
    for batch in test:
        pred, truth = _rolled_out(mode, model, norm, to_device(batch, device), view)
        e, t = (pred - truth).double().flatten(2), truth.double().flatten(2)  # [B, T', C * points]
        diff.append(e.norm(dim=2).cpu())
        ref.append(t.norm(dim=2).cpu())
    if model is not None:
        model.train()
    return RolloutErrors(torch.cat(diff), torch.cat(ref))


@torch.no_grad()
def test_errors(model: nn.Module, norm: Normalization, view, test: list[dict], mode: Mode | None = None) -> dict:
    """{"rel_l2", "nrmse"}: mean over every one-step pair of the test trajectories (physical units; a next-step
    mode's pairs are (frame, next frame)), plus "rollout" (relative L2 per frame, mean over trajectories) and
    "rollout_final" for a next-step view."""
    mode = OneStep() if mode is None else mode
    model.train(False)
    rel, nr = [], []
    for batch in test:
        pred, truth = mode.one_step(model, norm, to_device(batch, model_device(model)), view)
        rel.append(rel_l2(pred, truth).cpu())
        nr.append(nrmse(pred, truth, model.ndim).cpu())
    model.train()
    out = {"rel_l2": float(torch.cat(rel).mean()), "nrmse": float(torch.cat(nr).mean())}
    if view.rollout_k_in:  # a next-step view: the model is also rolled out
        curve = rollout_errors(model, norm, test, view, mode).curve()
        out["rollout"], out["rollout_final"] = curve, curve[-1]
    return out
