"""A training run's files: the resumable state (checkpoint.pt), the finished model (model.pt), atomic writes.

``train_state`` / ``restore`` turn the loop's objects into checkpoint.pt's dict and back; ``check_belongs``
refuses a checkpoint of another run; ``save_checkpoint`` / ``load_checkpoint`` write and read the model a
finished run leaves. All ``.pt`` files hold state dicts and plain containers only:
``torch.load(path, weights_only=True)`` works.
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import nn

from pdestream.datasets.normalize import Normalization
from pdestream.datasets.ranks import check_world, keyed, placement
from pdestream.datasets.schema import atomic_write  # the one atomic write (fsyncs the file and its directory)

from .models import build_model, model_spec

CHECKPOINT = "checkpoint.pt"
CHECKPOINT_FORMAT = 1


@dataclass
class TrainProgress:
    """What a run has done so far; saved in checkpoint.pt so that a resumed run's metrics continue it.

    wall: wall-clock seconds of earlier sessions (a resumed session adds its own); rows: metrics.csv rows;
    trajectories: global sample indices seen; data_stats: the data source's last ``stats()``.
    """

    step: int = 0
    examples: int = 0
    t_data: float = 0.0
    t_compute: float = 0.0
    wall: float = 0.0
    rows: list = field(default_factory=list)
    trajectories: set = field(default_factory=set)
    data_stats: dict | None = None
    clipped: int = 0  # optimizer steps whose gradient norm was clipped (a mode's ``clip``)

    def counters(self, wall: float) -> dict:
        """Plain values for checkpoint.pt; ``trajectories`` as a sorted int64 tensor [N]."""
        return {"examples": self.examples, "t_data": self.t_data, "t_compute": self.t_compute, "wall": wall,
                "trajectories": torch.tensor(sorted(self.trajectories), dtype=torch.int64),
                "data_stats": self.data_stats, "clipped": self.clipped}

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> "TrainProgress":
        c = ckpt["counters"]
        return cls(step=int(ckpt["step"]), examples=int(c["examples"]), t_data=float(c["t_data"]),
                   t_compute=float(c["t_compute"]), wall=float(c["wall"]), rows=[dict(r) for r in ckpt["rows"]],
                   trajectories=set(c["trajectories"].tolist()), data_stats=c["data_stats"],
                   clipped=int(c.get("clipped", 0)))  # (absent from checkpoints before clipping)


def data_state_owner(loader) -> tuple[str | None, object]:
    """("dataset" | "batch_sampler", the object) holding the data source's resumable state, or (None, None).

    A stream (or the reservoir) keeps its own ``state_dict()``; a cache source keeps it in its batch sampler
    (surrogate.data.EpochBatchSampler). Under several torch.distributed ranks the object is a
    ``datasets.ranks.RankStates`` around it: every rank's state, rank-keyed, in the one checkpoint.
    """
    for name in ("dataset", "batch_sampler"):
        owner = getattr(loader, name, None)
        if callable(getattr(owner, "state_dict", None)) and callable(getattr(owner, "load_state_dict", None)):
            return name, keyed(owner)
    return None, None


def train_state(model: nn.Module, opt, sched, normalizer: Normalization, loader, progress: TrainProgress, steps: int,
                start: float, meta: dict | None) -> dict:
    """The checkpoint.pt dict: everything a resumed run needs to continue as if never stopped.

    {"format": 1, "step": done, "steps": total, "model": state dict, "spec": model_spec, "optimizer": state
    dict, "scheduler": state dict, "torch_rng": uint8 tensor (torch.get_rng_state()), "normalization":
    Normalization.to_dict(), "rows": metrics rows so far, "counters": TrainProgress.counters, "data": {"owner":
    "dataset" | "batch_sampler", "state": its state_dict()} or None, "meta": run metadata}.
    """
    owner_name, owner = data_state_owner(loader)
    return {"format": CHECKPOINT_FORMAT, "step": progress.step, "steps": steps, "model": model.state_dict(),
            "spec": model_spec(model), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
            "torch_rng": torch.get_rng_state(), "normalization": normalizer.to_dict(),
            "rows": [dict(r) for r in progress.rows], "counters": progress.counters(progress.wall + time.perf_counter() - start),
            "data": None if owner is None else {"owner": owner_name, "state": owner.state_dict()}, "meta": meta or {}}


def restore(ckpt: dict, model: nn.Module, opt, sched, loader, steps: int) -> tuple[Normalization, TrainProgress]:
    """Load a ``train_state`` dict into the model, optimizer, schedule and data source (not the torch RNG:
    ``train`` sets that right before the first batch). ValueError when it belongs to another set-up."""
    if ckpt.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"checkpoint format {ckpt.get('format')!r} not supported; allowed: {CHECKPOINT_FORMAT}")
    if not 0 < ckpt["step"] <= steps:
        raise ValueError(f"checkpoint at step {ckpt['step']} of {ckpt['steps']} does not fit a run of {steps} steps")
    if ckpt["spec"] != model_spec(model):
        raise ValueError(f"checkpoint model {ckpt['spec']} differs from this run's {model_spec(model)}")
    owner_name, owner = data_state_owner(loader)
    saved = ckpt["data"]
    if (saved is None) != (owner is None) or (saved is not None and saved["owner"] != owner_name):
        raise ValueError(f"checkpoint data state ({saved and saved['owner']}) does not fit this data source "
                         f"({owner_name})")
    if saved is not None:
        check_world(saved["state"], placement()[1])  # a state of other ranks: refused before anything is loaded
    fresh = sched.state_dict()  # the schedule of this run's own length, at step 0
    model.load_state_dict(ckpt["model"])
    opt.load_state_dict(ckpt["optimizer"])
    if ckpt["steps"] == steps:
        sched.load_state_dict(ckpt["scheduler"])
    else:  # a run extended to more steps (train --resume RUN --steps N)
        replan_schedule(sched, opt, fresh, ckpt["step"])
    if owner is not None:
        owner.load_state_dict(saved["state"])
    return Normalization.from_dict(ckpt["normalization"]), TrainProgress.from_checkpoint(ckpt)


def replan_schedule(sched, opt, fresh: dict, step: int) -> None:
    """Put ``sched`` (built for the run's new length; ``fresh`` its state at step 0) where it is after ``step``
    steps of that length: from here on the learning rate (and onecycle's momentum) follows a run planned for the
    new length from the start. Only "constant" makes the result equal to such a run; cosine and onecycle change
    their curve at ``step`` (a finished cosine run warms up again from 1% of its peak)."""
    import warnings

    for group in opt.param_groups:
        group["lr"] = group["initial_lr"]  # what the fresh schedule started from
    sched.load_state_dict(fresh)
    with warnings.catch_warnings():  # stepping a schedule without optimizer steps is what is wanted here
        warnings.simplefilter("ignore")
        for _ in range(step):
            sched.step()


# What a checkpoint belongs to (train's ``meta``): a resume with a checkpoint of another PDE, grid, view or mode
# would train on with foreign weights and normalization, so each is compared before anything is loaded.
BELONGS = {"pde": "PDE configuration", "view": "view", "view_args": "view settings", "mode": "training mode"}
CHECKPOINT_KEYS = ("format", "step", "steps", "model", "spec", "optimizer", "scheduler", "torch_rng",
                   "normalization", "rows", "counters", "data", "meta")


def check_belongs(ckpt: dict, meta: dict) -> None:
    """ValueError naming the first difference when checkpoint ``ckpt`` was saved by a run with other ``meta``
    (PDE config, view, view settings, mode); a key missing on either side is not compared."""
    saved = ckpt.get("meta") or {}
    for key, what in BELONGS.items():
        if key in saved and key in meta and saved[key] != meta[key]:
            a, b = saved[key], meta[key]
            if isinstance(a, dict) and isinstance(b, dict):  # name the settings that differ, not two whole dicts
                diff = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
                a, b = {k: a.get(k) for k in diff}, {k: b.get(k) for k in diff}
            raise ValueError(f"the checkpoint belongs to another run: its {what} is {a}, this run's is {b}; "
                             "resume it with its own run directory, or start this one afresh (--overwrite)")


def save_train_state(out: Path, state: dict) -> None:
    """Write ``train_state``'s dict to out/checkpoint.pt atomically."""
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write(out / CHECKPOINT, buf.getvalue())


def load_train_state(path) -> dict:
    """checkpoint.pt as a dict (weights_only: plain containers and tensors); ValueError when unreadable."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # truncated or foreign file: torch raises several kinds (its words for a file that is
        # no pickle advise weights_only=False: not for a damaged file)
        from .config import damaged_checkpoint

        raise ValueError(damaged_checkpoint(path, f"torch cannot read it: {type(err).__name__}")) from None
    if not isinstance(ckpt, dict):
        raise ValueError(f"{path} is not a pdestream checkpoint: it holds a {type(ckpt).__name__}, not a dict")
    missing = [key for key in CHECKPOINT_KEYS if key not in ckpt]
    if missing:
        raise ValueError(f"{path} is not a complete pdestream checkpoint: it lacks {', '.join(missing)}")
    return ckpt


def save_checkpoint(path, model: nn.Module, normalizer: Normalization, step: int, meta: dict | None = None) -> None:
    """State dict + plain dicts only, so ``torch.load(path, weights_only=True)`` loads it."""
    torch.save({"model": model.state_dict(), "spec": model_spec(model), "normalization": normalizer.to_dict(),
                "step": step, "meta": meta or {}}, path)


def load_checkpoint(path) -> tuple[nn.Module, Normalization, dict]:
    """(model in eval mode, its normalization, the checkpoint dict) from ``save_checkpoint``'s file; ValueError (one
    line) for a file torch cannot read (it was torch's UnpicklingError, a traceback)."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # truncated or foreign file: torch raises several kinds
        from .config import damaged_checkpoint

        raise ValueError(damaged_checkpoint(path, f"torch cannot read it: {type(err).__name__}")) from None
    if "normalization" not in ckpt:
        raise ValueError(f"{path} is a checkpoint of an older pdestream (no 'normalization' entry); train it again")
    spec = dict(ckpt["spec"])
    model = build_model(spec.pop("name"), spec.pop("ndim"), spec.pop("in_channels"), spec.pop("out_channels"),
                        spec.pop("n_params"), **spec)
    model.load_state_dict(ckpt["model"])
    return model.train(False), Normalization.from_dict(ckpt["normalization"]), ckpt
