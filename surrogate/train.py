"""One training loop for any DataLoader of batch dicts, streamed or cached, with identical code.

A batch is {"x": [B, k_in, C, *space] or [B, C, *space], "y": same layout with k_out frames, "params": [B, P],
"index": [B], ...}. Frames are stacked into channels for the model ([B, k*C, *space]); fields and
parameters are normalized by a ``datasets.Normalization`` (per-field / per-parameter mean and std) taken from the
data source when it offers one (a stream's calibration draw, a cache's stored samples), else from the first
training batch. The loss is the mode's (``surrogate.modes``: MSE in normalized units, or the mean relative L2).

The run directory gets ``metrics.csv`` (one row per log step), ``metrics.json`` (summary, written once at the
end: its presence marks a finished run), ``model.pt`` and ``checkpoint.pt`` (the whole training state every
``checkpoint_every`` steps and at the end, see ``train_state``; ``train(..., resume=ckpt)`` continues it). All
``.pt`` files hold state dicts and plain containers only: ``torch.load(path, weights_only=True)`` works.

Three optional hooks of the data source (``loader.dataset``) are called when it has them: ``place(device)``
once before the first batch (the model's device: a training reservoir keeps its trajectories and gathers its
batches there), ``report_losses(batch, per_example)`` after each optimizer step (per_example: float64 CPU [B],
each example's relative L2 error in normalized units), and ``stats()`` (a flat dict of numbers) at each logged
row.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn
from torch.utils.data import DataLoader

from pdestream.datasets.normalize import Normalization

from . import ddp
from .checkpoint import (
    TrainProgress,
    atomic_write,
    check_belongs,
    restore,
    save_checkpoint,
    save_train_state,
    train_state,
)
from .checks import check_count, check_number
from .data import model_device, to_device
from .models import model_spec
from .modes import OneStep
from .phases import RunProgress


def source_normalization(loader) -> Normalization | None:
    """The data source's own statistics over its data (TrajectoryStream / CachedTrajectories
    ``.normalization()``), or None if it has none."""
    source = getattr(loader, "dataset", loader)
    return source.normalization() if hasattr(source, "normalization") else None


@dataclass(frozen=True)
class Stop:
    """When a run ends: after ``steps`` optimizer steps, or once ``seconds`` of wall clock have passed since the
    run's clock started (``train(..., started=)``); ``once``: also when a single pass over the loader ends (a
    simulation budget's stream: every solve used once), else a finite loader is iterated again (epochs)."""

    steps: int | None = None
    seconds: float | None = None
    once: bool = False

    def check(self) -> None:
        """ValueError (one line) naming the bad value."""
        if (self.steps is None) == (self.seconds is None):
            raise ValueError(f"a run stops after steps or after seconds, exactly one (got steps={self.steps}, "
                             f"seconds={self.seconds})")
        if self.steps is not None:
            check_count("steps", self.steps)
        else:
            check_number("seconds", self.seconds, 0)

    def fraction(self, step: int, elapsed: float) -> float:
        """How much of the run is done after ``step`` steps and ``elapsed`` seconds: 0 at the start, >= 1 at the end."""
        return step / self.steps if self.steps is not None else elapsed / self.seconds


def cosine_factor(fraction: float) -> float:
    """The cosine schedule's lr / peak lr at ``fraction`` of the run: 1 down to 0.01."""
    return 0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * min(fraction, 1.0)))


def make_schedule(opt: torch.optim.Optimizer, name: str, stop: Stop | int, lr: float, fraction=None):
    """"cosine" (decay to 1% of lr) or "onecycle" (warm-up then anneal) over the run, or "constant" (lr
    throughout: a run extended by ``train --resume RUN --steps N`` equals one of N steps). A run of known steps
    uses torch's schedulers; a run of ``seconds`` follows ``fraction()`` (the share of its clock spent)."""
    stop = Stop(steps=stop) if isinstance(stop, int) else stop
    if name not in SCHEDULES:
        raise ValueError(f"unknown schedule {name!r}; allowed: {', '.join(SCHEDULES)}")
    if name == "constant":
        return torch.optim.lr_scheduler.LambdaLR(opt, lambda _: 1.0)
    if stop.steps is None:
        if name != "cosine":
            raise ValueError(f"schedule {name!r} needs a number of steps; a run of seconds allows: cosine, constant")
        return torch.optim.lr_scheduler.LambdaLR(opt, lambda _: cosine_factor(fraction()))
    if name == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=stop.steps, eta_min=lr * 0.01)
    return torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=stop.steps)


def once(loader):
    """Batches of one pass over ``loader``."""
    yield from loader


def forever(loader):
    """Batches from ``loader``, iterating it again whenever a finite loader runs out.

    The loader owns its epochs: a finite TrajectoryStream / StreamLoader starts the next epoch itself when one
    ends, and a shuffling DataLoader reshuffles on each new iteration, so nothing is advanced here. A resumed
    source may start with an empty pass (it stopped right at an epoch's end), so only two empty passes in a
    row mean there is no data.
    """
    empty_passes = 0
    while empty_passes < 2:
        empty_passes += 1
        for batch in loader:
            empty_passes = 0
            yield batch
    raise ValueError("the data loader yielded no batches (empty dataset?)")


POSTFIX_STATS = ("wait_share", "reuse_mean")  # data-source stats shown in the progress bar when offered
# the only values a resume may change: the loop's timers and the data source's rates
# (and a reservoir's pacing rates, datasets/reservoir_pacer.py: deterministic mode's batches read none of them)
TIMINGS = ("t_data", "t_compute", "elapsed", "wall", "data_share", "wait_share", "solver_traj_per_s", "examples_per_s",
           "pace_slowdown", "pace_fit_k", "pace_probe_k", "pace_probes", "pace_probe_cost", "solve_s_per_traj", "step_s",
           "producer_idle_s", "producer_idle_share")


SCHEDULES = ("cosine", "onecycle", "constant")


def check_train_settings(steps, lr: float, schedule: str, checkpoint_every: int = 0) -> None:
    """ValueError naming the value and what is allowed (called before a run touches its directory); steps: an
    int or a ``Stop``."""
    stop = Stop(steps=steps) if not isinstance(steps, Stop) else steps
    stop.check()
    check_number("lr", lr, 0)
    if schedule not in SCHEDULES:
        raise ValueError(f"unknown schedule {schedule!r}; allowed: {', '.join(SCHEDULES)}")
    if stop.steps is None and schedule not in ("cosine", "constant"):
        raise ValueError(f"schedule {schedule!r} needs a number of steps; a run of seconds allows: cosine, constant")
    check_count("checkpoint_every", checkpoint_every, 0, " (0: only at the end)")


def _postfix(loss: float, stats: dict | None) -> dict:
    """Progress-bar items: the loss and a few of the data source's stats (POSTFIX_STATS, else its first two)."""
    shown = {"loss": f"{loss:.3g}"}
    if stats:
        keys = [k for k in POSTFIX_STATS if k in stats] or list(stats)[:2]
        shown.update({k: format(stats[k], ".3g") if isinstance(stats[k], (int, float)) else str(stats[k])
                      for k in keys})
    return shown


def _plain(stats: dict) -> dict:
    """stats() values as Python numbers (numpy / 0-d tensor scalars would not load with weights_only=True)."""
    return {str(k): (v.item() if hasattr(v, "item") else v) for k, v in stats.items()}


def train(model: nn.Module, loader, steps: int | Stop, out_dir, *, lr: float = 1e-3, schedule: str = "cosine",
          normalizer: Normalization | None = None, log_every: int = 10, meta: dict | None = None,
          label: str = "train", checkpoint_every: int = 0, resume: dict | None = None, finish=None,
          mode=None, started: float | None = None, after_step=None, on_normalization=None) -> dict:
    """Train ``model`` on batches from ``loader`` until ``steps`` (an int: optimizer steps; or a ``Stop``: steps
    or seconds, optionally one pass over the data) says stop; returns the summary dict.

    Works the same for an IterableDataset stream (DataLoader(stream, batch_size=None)) and a map-style cache
    (DataLoader(cached, batch_sampler=EpochBatchSampler(...))). Times are wall-clock seconds: "t_data" is time
    spent waiting for the next batch, "t_compute" forward + backward + optimizer step.
    checkpoint_every: write checkpoint.pt every that many steps (0: only at the end). resume: a checkpoint.pt
    dict (``load_train_state``) to continue from, with the same model architecture, loader and steps; the
    result is the uninterrupted run's, bit for bit on the CPU. finish: ``finish(model, normalizer) -> dict``,
    merged into the summary before metrics.json is written (e.g. test errors). mode: how a batch becomes a
    loss (``surrogate.modes``: one-step, pushforward, oracle, solver-in-the-loop, noise; None: one-step).
    started: ``time.perf_counter()`` when the run's clock started (default: now), for a ``Stop(seconds=)``
    that counts what the caller did before (solving a cache). after_step: ``after_step(step, fraction,
    elapsed)`` after every optimizer step (fraction: of the run done, ``Stop.fraction``), e.g. to snapshot the
    model. on_normalization: ``on_normalization(normalizer)`` once a fresh run has its statistics (every rank's,
    rank 0's), e.g. to record them in run.json. The summary's "stop" says what ended the run: "steps", "seconds" or "data" (a ``once`` pass ran out).
    Under torch.distributed (``surrogate.ddp``) every rank calls this with its own loader: gradients are averaged
    each step, the logged loss and example counts are the ranks' mean and sum, and rank 0 alone writes files.
    """
    stop = Stop(steps=steps) if not isinstance(steps, Stop) else steps
    check_train_settings(stop, lr, schedule, checkpoint_every)
    rank, ranks = ddp.world()
    writes = rank == 0  # rank 0 writes the run's files
    if ranks > 1 and (stop.steps is None or stop.once):  # the ranks would stop at different steps and wait forever
        raise ValueError(f"training on {ranks} ranks stops after a number of steps (not seconds, nor when a pass of "
                         "the data ends)")
    mode = OneStep() if mode is None else mode
    out = Path(out_dir)
    if writes:
        out.mkdir(parents=True, exist_ok=True)
    ndim, device = model.ndim, model_device(model)
    opt = torch.optim.Adam(model.parameters(), lr=lr)  # the first one imports torch's compiler: seconds
    start = time.perf_counter() if started is None else started
    sched = make_schedule(opt, schedule, stop, lr, fraction=lambda: (time.perf_counter() - start) / stop.seconds)
    if resume is not None:
        check_belongs(resume, meta or {})
        normalizer, progress = restore(resume, model, opt, sched, loader, stop.steps)
    else:
        progress = TrainProgress()
        if normalizer is None:
            t0 = time.perf_counter()
            normalizer = source_normalization(loader)
            progress.t_data += time.perf_counter() - t0  # a calibration draw (or reading a cache) is data time
    ddp.broadcast_model(model)  # several ranks: one start (after a resume they all loaded the same weights)
    normalizer = ddp.agree(normalizer)
    if on_normalization is not None and resume is None and normalizer is not None:
        on_normalization(normalizer)
    if isinstance(loader, DataLoader) and loader.generator is None:
        # Each pass over a DataLoader draws its workers' base seed from its generator, else from the global torch
        # RNG. A resumed run starts a pass where the uninterrupted one did not, so that draw would shift the RNG
        # that the data source (random windows) and the model may use; a generator of its own keeps it out.
        loader.generator = torch.Generator().manual_seed(torch.initial_seed())
    dataset = getattr(loader, "dataset", None)
    report_losses, stats = getattr(dataset, "report_losses", None), getattr(dataset, "stats", None)
    if hasattr(dataset, "place"):
        dataset.place(device)
    batches = once(loader) if stop.once else forever(loader)
    if resume is not None:  # last, so that nothing above draws from it; the data source may (random windows)
        torch.set_rng_state(resume["torch_rng"])
    bar = RunProgress(label, stop.steps, progress.step) if writes else None
    model.train()
    clip = getattr(mode, "clip", None)  # solver-in-the-loop's gradient clipping norm (None: off)
    step, loss_value, ended = progress.step, math.nan, "steps" if stop.steps is not None else "seconds"
    on_device = None if normalizer is None else normalizer.to(device)  # the statistics where the batches are
    while stop.fraction(step, progress.wall + time.perf_counter() - start) < 1:
        step += 1
        t0 = time.perf_counter()
        batch = next(batches, None)
        if batch is None:  # one pass over the data was asked for, and it ran out
            step, ended = step - 1, "data"
            break
        batch = to_device(batch, device)  # a copy to the GPU counts as waiting for data
        t1 = time.perf_counter()
        if normalizer is None:  # the data source offers none: calibrate on the first batch
            normalizer = Normalization.from_batch(batch, ndim)
            on_device = normalizer.to(device)
        loss, per_example = mode.step_loss(model, batch, on_device, step)  # per_example: float64 CPU [B]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        loss_value, examples = ddp.average_gradients(model, loss, len(batch["x"]))  # one process: loss, batch size
        if clip is not None and float(torch.nn.utils.clip_grad_norm_(model.parameters(), clip)) > clip:
            progress.clipped += 1  # (the norm before clipping; every rank has the averaged gradients: the same)
        opt.step()
        sched.step()
        t2 = time.perf_counter()
        if not math.isfinite(loss_value):
            raise ValueError(f"{label}: training diverged at step {step} (loss={loss_value}); lower --lr")
        if report_losses is not None:  # from this step's forward pass: no extra model evaluation
            report_losses(batch, per_example)
        progress.step = step
        progress.t_data, progress.t_compute = progress.t_data + t1 - t0, progress.t_compute + t2 - t1
        progress.examples += examples
        progress.trajectories.update(batch["index"].tolist())
        elapsed = progress.wall + time.perf_counter() - start
        last = stop.fraction(step, elapsed) >= 1
        if step % log_every == 0 or last:
            row = {"step": step, "loss": loss_value, "lr": sched.get_last_lr()[0], "examples": progress.examples,
                   "trajectories": len(progress.trajectories), "t_data": progress.t_data,
                   "t_compute": progress.t_compute, "elapsed": elapsed}
            if stats is not None:
                progress.data_stats = _plain(stats())
                row.update({k: v for k, v in progress.data_stats.items() if k not in row})  # the loop's own win
            progress.rows.append(row)
            if bar is not None:
                bar.show(step, _postfix(loss_value, progress.data_stats))
        if after_step is not None:
            after_step(step, stop.fraction(step, elapsed), elapsed)
        if checkpoint_every and step % checkpoint_every == 0 and not last:
            progress.trajectories = ddp.union(progress.trajectories)
            state = train_state(model, opt, sched, normalizer, loader, progress, stop.steps, start, meta)  # all ranks
            if writes:
                save_train_state(out, state)
                write_metrics_csv(out / "metrics.csv", progress.rows)
    if bar is not None:
        bar.close()
    if normalizer is None:
        raise ValueError(f"{label}: the data ran out before the first step")
    if progress.rows and progress.rows[-1]["step"] != progress.step:  # a run of seconds or one pass ends anywhere
        progress.rows.append({**progress.rows[-1], "step": progress.step, "loss": loss_value})
    progress.trajectories = ddp.union(progress.trajectories)
    state = train_state(model, opt, sched, normalizer, loader, progress, stop.steps, start, meta)  # all ranks
    if writes:
        write_metrics_csv(out / "metrics.csv", progress.rows)
        save_train_state(out, state)
    wall = progress.wall + time.perf_counter() - start
    summary = {"label": label, "steps": progress.step, "stop": ended,
               "final_loss": progress.rows[-1]["loss"] if progress.rows else math.nan,
               "examples_seen": progress.examples, "trajectories_seen": len(progress.trajectories),
               "t_data": progress.t_data, "t_compute": progress.t_compute, "wall": wall,
               "data_share": progress.t_data / max(progress.t_data + progress.t_compute, 1e-12),
               "normalization_samples": normalizer.samples, "model": model_spec(model), "lr": lr, "schedule": schedule,
               **(meta or {})}
    if progress.data_stats is not None:
        summary["data_stats"] = progress.data_stats
    if ranks > 1:
        summary["ranks"] = ranks
    summary["mode"] = mode.settings()
    if clip is not None:
        summary["clipped_steps"] = progress.clipped
    if hasattr(mode, "stats"):  # e.g. the oracle's examples dropped for a non-finite solver answer
        summary["mode_stats"] = mode.stats()
    if not writes:  # the other ranks: the summary without test errors, and no file
        return {**summary, "normalizer": normalizer, "curve": progress.rows}
    if finish is not None:
        summary.update(finish(model, normalizer))
    save_checkpoint(out / "model.pt", model, normalizer, step=progress.step, meta=meta)
    atomic_write(out / "metrics.json", json.dumps(summary, indent=2).encode())  # last: marks the run finished
    summary["normalizer"] = normalizer
    summary["curve"] = progress.rows
    return summary


def write_metrics_csv(path: Path, rows: list[dict]) -> None:
    """One row per log step; columns: the union of the rows' keys in first-seen order (data stats may vary)."""
    columns = list(dict.fromkeys(k for row in rows for k in row))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(rows)
