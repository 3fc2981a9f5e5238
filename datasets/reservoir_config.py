"""The training reservoir's settings and their defaults, once: ``ReservoirConfig``.

``ReservoirStream`` takes one (or the same names as keyword arguments), experiments' ``BudgetConfig`` and the
CLI read their defaults from it. ``checked(batch_size)`` refuses a bad setting in one line (the stream's own
checks that need the PDE and the view, e.g. target_reuse against the view's examples, stay in the stream).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields, replace
from typing import Callable

MODES = ("async", "deterministic")
# the names of the samplers (reservoir_sampler.SAMPLERS) and writers (reservoir_writer.WRITERS), here without their
# classes so that the CLI's parser reads them without numpy; those modules check their registries against these
DRAWS = ("uniform", "least_used", "priority")
EVICTIONS = ("fifo", "random")
# the proposals (datasets.proposal.MODES, checked against these there): the key's own draws, then the steered ones
PROPOSALS = ("uniform", "loss", "active", "generative")
# what a steered proposal steers (proposal_kwargs["space"]): the parameters alone, or jointly with the
# IC's latent coordinates (generator.ics.LatentIC)
PROPOSAL_SPACES = ("params", "params+ic")


def _real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def _integer(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


# a steered proposal's settings (datasets.proposal.ParamProposal): what each accepts and the words that say so. One
# table: the CLI checks its numbers with it before torch, the proposal (a torch module) when it is built.
PROPOSAL_RANGES: dict[str, tuple[Callable, str]] = {
    "floor": (lambda v: _real(v) and 0 < v <= 1, "must be in (0, 1] (uniform share)"),
    "bandwidth": (lambda v: _real(v) and 0 < v <= 1, "must be in (0, 1] (unit-box units)"),
    "power": (lambda v: _real(v) and 0 <= v <= 8, "must be in [0, 8]"),
    "window": (lambda v: _integer(v) and v >= 1, "must be an integer >= 1"),
    "ensemble": (lambda v: _integer(v) and 2 <= v <= 100, "must be an integer >= 2 (the uncertainty signal is the "
                 "disagreement of its members) and <= 100 (each member is a loss model refitted at every refit)"),
    "kappa": (lambda v: _real(v) and 0 <= v <= 100, "must be in [0, 100] (weight of the ensemble spread)"),
    "top": (lambda v: _real(v) and 0 < v < 1, "must be in (0, 1) (the share of fresh solves that counts as high "
            "difficulty)"),
    "step": (lambda v: _real(v) and 0 < v <= 1, "must be in (0, 1] (the generative proposal's move, in prior "
             "standard deviations)"),
    "gate": (lambda v: isinstance(v, bool), "must be True or False"),
    "skill_full": (lambda v: _real(v) and 0 < v <= 1, "must be in (0, 1] (a rank correlation)"),
    "skill_min": (lambda v: _integer(v) and v >= 3, "must be an integer >= 3"),
    "refit": (lambda v: _integer(v) and v >= 1, "must be an integer >= 1"),
    "candidates": (lambda v: _integer(v) and v >= 1, "must be an integer >= 1"),
    "skill_window": (lambda v: _integer(v) and v >= 1, "must be an integer >= 1"),
    "probe": (lambda v: _real(v) and 0 <= v < 1, "must be in [0, 1) (the generative proposal's steered share until its "
              "lift is measured)"),
}


# which settings each proposal reads (window: every mode keeps its recent losses, the loss-over-domain plot's)
_STEERED = {"window", "floor", "gate", "skill_window", "skill_min", "skill_full"}
PROPOSAL_USES = {"uniform": {"window"}, "loss": _STEERED | {"bandwidth", "power"},
                 "active": _STEERED | {"power", "ensemble", "kappa", "refit", "candidates"},
                 "generative": _STEERED | {"refit", "top", "step", "probe"}}


def check_proposal_uses(mode: str, changed: dict) -> None:
    """Refuse a setting given away from its default (``changed``: by name) to a proposal ``mode`` that does not read
    it (PROPOSAL_USES): one line naming the proposals that do (it was silently ignored)."""
    for name in changed:
        if name not in PROPOSAL_USES[mode]:
            users = " / ".join(m for m in PROPOSALS if name in PROPOSAL_USES[m])
            raise ValueError(f"proposal {name}={changed[name]!r} goes with proposal {users} (not {mode}); nothing here "
                             "uses it: drop it")


def check_proposal_settings(mode: str | None = None, **values) -> None:
    """Refuse a steered proposal's setting outside PROPOSAL_RANGES (``values``: those given, by name; ``mode``: one
    of PROPOSALS, None: not given): ValueError, one line naming it and what is allowed."""
    if mode is not None and mode not in PROPOSALS:
        raise ValueError(f"proposal={mode!r} not allowed; allowed: {', '.join(PROPOSALS)}")
    for name, value in values.items():
        accepts, allowed = PROPOSAL_RANGES[name]  # (KeyError: a setting the table lacks, a programming error)
        if not accepts(value):
            raise ValueError(f"proposal {name}={value!r} not allowed; {allowed}")


def check_proposal_kwargs(mode, kwargs) -> None:
    """A reservoir's ``proposal`` and ``proposal_kwargs`` (ParamProposal's settings by name, plus "space"), one line
    for an unknown proposal, a kwargs that is not a dict, an unknown key, or a value outside PROPOSAL_RANGES."""
    if kwargs is not None and not isinstance(kwargs, dict):
        raise ValueError(f"proposal_kwargs={kwargs!r} not allowed; a dict of the proposal's settings "
                         "(datasets.proposal.ParamProposal) or None")
    kwargs = dict(kwargs or {})
    space = kwargs.pop("space", "params")
    unknown = [k for k in kwargs if k not in PROPOSAL_RANGES]
    if unknown:
        raise ValueError(f"proposal_kwargs key {unknown[0]!r} not allowed; allowed: {', '.join(PROPOSAL_RANGES)}, space")
    check_proposal_settings(mode, **kwargs)
    if space not in PROPOSAL_SPACES:
        raise ValueError(f"proposal space={space!r} not allowed; allowed: {', '.join(PROPOSAL_SPACES)}")


def _check_int(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise ValueError(f"{name}={value!r} not allowed; must be an integer >= {low}")
    return int(value)


def _check_choice(name: str, value, allowed: tuple) -> str:
    if value not in allowed:
        raise ValueError(f"{name}={value!r} not allowed; allowed: {', '.join(allowed)}")
    return value


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float))


@dataclass(frozen=True)
class ReservoirConfig:
    """A training reservoir's settings (``datasets/reservoir.py``'s docstring says what each does).

    capacity: trajectories held (>= batch_size and >= solve_batch); max_reuse (>= 1): the bound on uses per
    trajectory, in FIFO passes; warmup: trajectories held before the first batch (None: max(solve_batch,
    capacity // 4)); eviction: "fifo" | "random"; draw: "uniform" | "least_used" | "priority" (+ priority_power
    in [0, 8], priority_floor in (0, 1]); solve_batch: trajectories per solve job; mode: "async" |
    "deterministic"; producer: "thread" | "process" | "dask" (+ workers, scheduler); inflight: jobs submitted
    ahead (None: 2 per producer slot); target_reuse: the solver's pace in async mode (``reservoir_pacer``):
    "auto" (the default: a reuse target chosen from rates re-measured as the run goes, so that solving costs
    training at most 5% of its steps), a number in [1, max_reuse] (fixed; also the deterministic schedule's
    reuse per solve, else max_reuse's), or None / "off" (flat out); sim_budget: trajectories solved in all (None: endless); proposal:
    one of PROPOSALS, "uniform" | "loss" | "active" | "generative" (+ proposal_kwargs for ParamProposal); on_blowup: "raise" | "redraw" |
    "skip"; device: where trajectories are kept ("cpu", "cuda", "cuda:N"; None: the training device); storage:
    a factory (capacity, device) -> ``reservoir_storage.Storage`` (None: ``TensorStorage``).
    """

    capacity: int = 512
    max_reuse: float = 16.0
    warmup: int | None = None
    eviction: str = "fifo"
    draw: str = "uniform"
    priority_power: float = 1.0
    priority_floor: float = 0.25
    solve_batch: int = 16
    mode: str = "async"
    producer: str = "thread"
    workers: int = 1
    scheduler: str | None = None
    inflight: int | None = None
    target_reuse: float | str | None = "auto"
    sim_budget: int | None = None
    proposal: str = "uniform"
    proposal_kwargs: dict | None = None
    on_blowup: str = "raise"
    device: object = None
    storage: Callable | None = None

    @classmethod
    def names(cls) -> tuple:
        """The settings' names."""
        return tuple(f.name for f in fields(cls))

    def checked(self, batch_size: int) -> ReservoirConfig:
        """This config with its numbers normalized (max_reuse float, ...), or ValueError (one line) naming the
        first bad setting; ``batch_size``: the stream's examples per batch (capacity must hold one batch)."""
        solve_batch = _check_int("solve_batch", self.solve_batch, 1)
        capacity = _check_int("capacity", self.capacity, 1)
        if capacity < batch_size:
            raise ValueError(f"capacity={self.capacity} not allowed: must be >= batch_size ({batch_size})")
        if capacity < solve_batch:
            raise ValueError(f"capacity={self.capacity} not allowed: must be >= solve_batch ({solve_batch})")
        if not _is_number(self.max_reuse) or not self.max_reuse >= 1 or not math.isfinite(self.max_reuse):
            raise ValueError(f"max_reuse={self.max_reuse!r} not allowed; must be a finite number >= 1")
        warmup = self.warmup
        if warmup is not None:
            warmup = _check_int("warmup", warmup, 1)
            if warmup > capacity:
                raise ValueError(f"warmup={self.warmup} not allowed: must be <= capacity ({self.capacity})")
        _check_choice("eviction", self.eviction, EVICTIONS)
        _check_choice("draw", self.draw, DRAWS)
        if not _is_number(self.priority_power) or not 0 <= self.priority_power <= 8:
            raise ValueError(f"priority_power={self.priority_power!r} not allowed; must be in [0, 8] (0: uniform draws)")
        if not _is_number(self.priority_floor) or not 0 < self.priority_floor <= 1:
            raise ValueError(f"priority_floor={self.priority_floor!r} not allowed; must be in (0, 1] (the uniform "
                             "share of draws)")
        _check_choice("mode", self.mode, MODES)
        check_proposal_kwargs(self.proposal, self.proposal_kwargs)  # (the stream's ParamProposal refused them later)
        sim_budget = None if self.sim_budget is None else _check_int("sim_budget", self.sim_budget, 1)
        inflight = None if self.inflight is None else _check_int("inflight", self.inflight, 1)
        target = None if self.target_reuse == "off" else self.target_reuse
        if target is not None and target != "auto" and (not _is_number(target) or not 1 <= target <= self.max_reuse):
            raise ValueError(f"target_reuse={target!r} not allowed; must be a number in [1, max_reuse={self.max_reuse}], "
                             "'auto' (paced by measured rates) or 'off' / None (flat out)")
        return replace(self, capacity=capacity, solve_batch=solve_batch, max_reuse=float(self.max_reuse),
                       warmup=warmup, priority_power=float(self.priority_power),
                       priority_floor=float(self.priority_floor), sim_budget=sim_budget, inflight=inflight,
                       target_reuse=target if target in (None, "auto") else float(target))

    def warmup_for(self) -> int:
        """Trajectories held before the first batch: ``warmup``, else max(solve_batch, capacity // 4)."""
        return min(max(self.solve_batch, self.capacity // 4), self.capacity) if self.warmup is None else self.warmup


DEFAULTS = ReservoirConfig()
