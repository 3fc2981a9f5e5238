"""Training views of a trajectory, shared by the stream and the cache loader.

A view turns one trajectory ``u: [T, C, *space]`` (torch float32) with its parameters ``params: [P]``
into training examples (dicts of tensors):

- ``Whole()``: {"u": [T, C, *space], "t": [T]}
- ``NextStep(k_in, k_out, windows)``: {"x": [k_in, C, *space], "y": [k_out, C, *space], "t0": []} from
  windows starting at frame s; ``windows="all"`` gives every start, an int gives that many random starts
  per trajectory (so one solve feeds many pairs)
- ``Operator(t_in, t_out)``: {"x": [C, *space] at frame t_in, "y": [C, *space] at frame t_out}

A steady PDE's sample (no time axis) is one tensor [C_in + C, *space] over its input fields then its solution
fields (``datasets._bridge.sample_channels``); ``for_sample`` fits a view to it: ``operator`` becomes
``SteadyOperator`` (input fields -> solution), ``whole`` gives the sample, ``next_step`` is refused.

Every example also carries "params": [P] (conditioning) and "index": [] (global sample index).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Union

import torch


class ViewProtocol(Protocol):
    """What every view declares, so that the loaders, training and evaluation never switch on its class."""

    name: str  # its name in VIEWS (run.json, checkpoints)
    rollout_k_in: int | None  # frames an autoregressive rollout starts from (next_step: k_in); None: no rollout
    frames_out: int  # target frames per example (next_step: k_out; a single map: 1)

    def check(self, n_frames: int) -> None:
        """ValueError when trajectories of ``n_frames`` frames cannot give this view's examples."""

    def starts(self, n_frames: int, generator: torch.Generator | None = None) -> list[int]:
        """The frames where this trajectory's examples start."""

    def example(self, u: torch.Tensor, t: torch.Tensor, start: int) -> dict:
        """One example of u [T, C, *space] at ``start``."""

    def gather(self, u: torch.Tensor, t: torch.Tensor, traj: torch.Tensor, start: torch.Tensor) -> dict:
        """A batch of examples of u [B, T, C, *space] in one indexing pass."""

    def channels(self, c: int) -> tuple[int, int]:
        """(in, out) channels of a model trained on this view, for a PDE of ``c`` fields; ValueError if none."""

    def evaluation(self) -> "ViewProtocol":
        """The view held-out errors are computed under; ValueError when a model cannot be evaluated on this one."""

    def ahead(self, k_out: int) -> "ViewProtocol":
        """This view with ``k_out`` target frames per example (for training modes that unroll); ValueError (one
        line) when the view has no frames ahead of its input (rollout_k_in is None)."""

    def per_trajectory(self, n_frames: int) -> int:
        """Examples a map-style reader (``CachedTrajectories``) makes of one stored trajectory."""

    def cut(self, n_frames: int, sub: int) -> tuple[int, int, "ViewProtocol"]:
        """(lo, hi, view) for a map-style reader's example ``sub`` of a trajectory: it reads frames lo:hi only and
        takes the first example ``view`` makes of them."""


class _OneExample:
    """Views that make one example of a whole trajectory (or steady sample), starting at frame 0."""

    frames_out = 1

    def ahead(self, k_out: int) -> "ViewProtocol":
        raise ValueError(f"the {self.name!r} view has no frames ahead of its input; allowed: next_step")

    def per_trajectory(self, n_frames: int) -> int:
        return 1

    def cut(self, n_frames: int, sub: int) -> tuple[int, int, "ViewProtocol"]:
        return 0, n_frames, self

    def starts(self, n_frames: int, generator: torch.Generator | None = None) -> list[int]:
        return [0]


class _OneMap(_OneExample):
    """A single input -> target map (no rollout), evaluated as it is trained."""

    rollout_k_in = None  # one map, no rollout

    def evaluation(self) -> "ViewProtocol":
        return self


@dataclass(frozen=True)
class Whole(_OneExample):
    """The whole trajectory as one example."""

    name = "whole"
    rollout_k_in = None  # not a next-step view: no autoregressive rollout

    def check(self, n_frames: int) -> None:
        pass

    def channels(self, c: int) -> tuple[int, int]:
        raise ValueError(f"cannot train on the {self.name!r} view (it makes no input/target pairs); allowed: "
                         "next_step, operator")

    def evaluation(self):
        raise ValueError(f"cannot evaluate a model on the {self.name!r} view; use next_step or operator")

    def example(self, u: torch.Tensor, t: torch.Tensor, start: int) -> dict:
        return {"u": u, "t": t}

    def steady(self, n_inputs: int) -> "Whole":
        return self

    def gather(self, u: torch.Tensor, t: torch.Tensor, traj: torch.Tensor, start: torch.Tensor) -> dict:
        return {"u": u[traj], "t": t.repeat(len(traj), 1)}


@dataclass(frozen=True)
class NextStep:
    """k_in input frames -> the k_out frames that follow; windows: "all" or a number of random starts."""

    k_in: int = 1
    k_out: int = 1
    windows: Union[int, str] = "all"
    name = "next_step"

    def __post_init__(self):
        if self.k_in < 1 or self.k_out < 1:
            raise ValueError(f"next_step: k_in={self.k_in} and k_out={self.k_out} must both be >= 1")
        if not (self.windows == "all" or (isinstance(self.windows, int) and self.windows >= 1)):
            raise ValueError(f"next_step: windows={self.windows!r} not allowed; use 'all' or an integer >= 1")

    def check(self, n_frames: int) -> None:
        if self.k_in + self.k_out > n_frames:
            raise ValueError(
                f"next_step window k_in + k_out = {self.k_in} + {self.k_out} is longer than the trajectory "
                f"({n_frames} frames); allowed: k_in + k_out <= {n_frames}"
            )

    def n_starts(self, n_frames: int) -> int:
        return n_frames - self.k_in - self.k_out + 1

    def steady(self, n_inputs: int):
        raise ValueError("next_step needs a time axis and the samples of a steady PDE have none; allowed: "
                         "operator (input field -> solution) or whole")

    def starts(self, n_frames: int, generator: torch.Generator | None = None) -> list[int]:
        """Window starts: all of them, or ``windows`` drawn uniformly (with replacement) by ``generator``."""
        count = self.n_starts(n_frames)
        if self.windows == "all":
            return list(range(count))
        return torch.randint(count, (int(self.windows),), generator=generator).tolist()

    def example(self, u: torch.Tensor, t: torch.Tensor, start: int) -> dict:
        mid = start + self.k_in
        return {"x": u[start:mid], "y": u[mid : mid + self.k_out], "t0": t[start]}

    def gather(self, u: torch.Tensor, t: torch.Tensor, traj: torch.Tensor, start: torch.Tensor) -> dict:
        x_frames = start[:, None] + torch.arange(self.k_in, device=start.device)  # [N, k_in]
        y_frames = start[:, None] + self.k_in + torch.arange(self.k_out, device=start.device)  # [N, k_out]
        return {"x": u[traj[:, None], x_frames], "y": u[traj[:, None], y_frames], "t0": t[start]}

    @property
    def rollout_k_in(self) -> int:
        """Frames an autoregressive rollout of a model trained on this view starts from."""
        return self.k_in

    @property
    def frames_out(self) -> int:
        """Target frames per example."""
        return self.k_out

    def ahead(self, k_out: int) -> "NextStep":
        """The same windows with ``k_out`` target frames each."""
        return NextStep(self.k_in, k_out, self.windows)

    def channels(self, c: int) -> tuple[int, int]:
        """(in, out) model channels for c fields: k_in (k_out) frames stacked into channels."""
        return self.k_in * c, self.k_out * c

    def evaluation(self) -> "NextStep":
        """The view held-out errors use: every window, not a random few."""
        return NextStep(self.k_in, self.k_out, "all")

    def per_trajectory(self, n_frames: int) -> int:
        """Every window, or ``windows`` random ones."""
        return self.n_starts(n_frames) if self.windows == "all" else int(self.windows)

    def cut(self, n_frames: int, sub: int) -> tuple[int, int, "NextStep"]:
        """Window ``sub``, or one drawn by torch's RNG (random windows): only its k_in + k_out frames are read."""
        start = sub if self.windows == "all" else int(torch.randint(self.n_starts(n_frames), ()))
        return start, start + self.k_in + self.k_out, NextStep(self.k_in, self.k_out, "all")


@dataclass(frozen=True)
class Operator(_OneMap):
    """Frame t_in -> frame t_out (negative indices count from the end; default u(0) -> u(t_end))."""

    t_in: int = 0
    t_out: int = -1
    name = "operator"

    def check(self, n_frames: int) -> None:
        for label, value in (("t_in", self.t_in), ("t_out", self.t_out)):
            if not -n_frames <= value < n_frames:
                raise ValueError(f"operator: {label}={value} outside a trajectory of {n_frames} frames")
        if self.t_in % n_frames >= self.t_out % n_frames:
            raise ValueError(f"operator: t_in={self.t_in} must come before t_out={self.t_out}")

    def channels(self, c: int) -> tuple[int, int]:
        """(in, out) model channels for c fields: one frame in, one frame out."""
        return c, c

    def example(self, u: torch.Tensor, t: torch.Tensor, start: int) -> dict:
        return {"x": u[self.t_in], "y": u[self.t_out]}

    def gather(self, u: torch.Tensor, t: torch.Tensor, traj: torch.Tensor, start: torch.Tensor) -> dict:
        return {"x": u[traj, self.t_in], "y": u[traj, self.t_out]}

    def steady(self, n_inputs: int) -> "SteadyOperator":
        if (self.t_in, self.t_out) != (0, -1):
            raise ValueError(f"operator: t_in={self.t_in}, t_out={self.t_out} not allowed: a steady PDE's samples have "
                             "no frames; its operator maps the input field to the solution (leave t_in, t_out unset)")
        return SteadyOperator(n_inputs)


@dataclass(frozen=True)
class SteadyOperator(_OneMap):
    """A steady sample's input fields -> its solution: s [C_in + C, *space] -> {"x": s[:C_in], "y": s[C_in:]}."""

    n_inputs: int
    name = "operator"

    def check(self, n_frames: int) -> None:
        pass

    def steady(self, n_inputs: int) -> "SteadyOperator":
        return self

    def channels(self, c: int) -> tuple[int, int]:
        """(in, out) model channels: the input fields -> the c solution fields."""
        return self.n_inputs, c

    def example(self, u: torch.Tensor, t: torch.Tensor, start: int) -> dict:
        return {"x": u[: self.n_inputs], "y": u[self.n_inputs :]}

    def gather(self, u: torch.Tensor, t: torch.Tensor, traj: torch.Tensor, start: torch.Tensor) -> dict:
        return {"x": u[traj, : self.n_inputs], "y": u[traj, self.n_inputs :]}


View = Union[Whole, NextStep, Operator, SteadyOperator]
VIEWS = {"whole": Whole, "next_step": NextStep, "operator": Operator}


def make_view(view: View | str, **kwargs) -> View:
    """A view from an object or a name ("whole", "next_step", "operator") plus its keyword arguments."""
    if not isinstance(view, str):  # a view object (see ViewProtocol) passes through
        return view
    if view not in VIEWS:
        raise ValueError(f"unknown view {view!r}; allowed: {', '.join(VIEWS)}")
    try:
        return VIEWS[view](**kwargs)
    except TypeError as err:
        raise ValueError(f"view {view!r}: {err}") from None


def for_sample(view: View, n_frames: int, n_inputs: int = 0) -> View:
    """``view`` fitted to the samples it will cut, and checked: trajectories of ``n_frames`` frames or, with
    ``n_inputs`` > 0, a steady PDE's samples [n_inputs + C, *space] (no time axis; see the module docstring)."""
    if n_inputs:
        return view.steady(n_inputs)
    view.check(n_frames)
    return view


def examples(view: View, u: torch.Tensor, t: torch.Tensor, params: torch.Tensor, index: int,
             generator: torch.Generator | None = None) -> list[dict]:
    """All examples of one trajectory u [T, C, *space] (params [P], t [T]) under ``view``."""
    out = []
    for start in view.starts(u.shape[0], generator):
        ex = view.example(u, t, start)
        ex["params"] = params
        ex["index"] = torch.tensor(index, dtype=torch.int64)
        out.append(ex)
    return out


def gather(view: View, u: torch.Tensor, t: torch.Tensor, params: torch.Tensor, index: torch.Tensor,
           traj: torch.Tensor, start: torch.Tensor) -> dict:
    """A collated batch in one indexing pass: example k is trajectory ``traj[k]`` of u [B, T, C, *space]
    (params [B, P], index [B]) at window start ``start[k]``. Equals ``collate`` of the same ``examples``.
    Runs where the tensors are (all on one device, CPU or GPU)."""
    out = view.gather(u, t, traj, start)
    out["params"] = params[traj]
    out["index"] = index[traj]
    return out


def collate(batch: list[dict]) -> dict:
    """Stack a list of examples into a batch dict: each tensor gets a leading batch dimension."""
    return {key: torch.stack([ex[key] for ex in batch]) for key in batch[0]}
