"""The training reservoir's samplers: which held examples a batch draws, under the reuse bound (torchrl's
"sampler").

``Sampler`` is the declared interface and owns the use counts (the reuse bound is a rule of drawing):
uses [capacity] and window_uses [capacity, n_windows] per slot, and ``drawn`` (examples drawn in all). A slot is
drawable while it holds a trajectory and its uses < ``cap_uses``. Implementations (``SAMPLERS``, by the
``draw`` setting's name): ``UniformSampler``, ``LeastUsedSampler``, ``PrioritySampler`` (prioritized replay,
Schaul et al. 2016). Every random choice comes from the generator the reservoir passes in, so one seeded
generator fixes the whole draw sequence.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from .reservoir_config import DRAWS

_EMPTY = (np.zeros(0, np.int64), np.zeros(0, np.int64))


class Sampler(ABC):
    """Draws (slot, window start) pairs from the held trajectories below the reuse bound; owns the use counts.

    capacity: slots; cap_uses: the bound on draws per trajectory; n_windows: window starts per trajectory.
    """

    name: str

    def __init__(self, capacity: int, cap_uses: int, n_windows: int):
        self.capacity, self.cap_uses, self.n_windows = capacity, cap_uses, n_windows
        self.uses = np.zeros(capacity, np.int64)
        self.window_uses = np.zeros((capacity, n_windows), np.int64)
        self.drawn = 0

    def drawable(self, held: np.ndarray) -> np.ndarray:
        """Slots [m] whose trajectory may still be drawn (``held``: bool [capacity], the occupied slots)."""
        return np.flatnonzero(held & (self.uses < self.cap_uses))

    def draw(self, held: np.ndarray, k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Up to k examples, each trajectory at most once: (slots [m], window starts [m]), m <= k; m = 0 when
        every held trajectory is at its bound. Counts the uses."""
        ok = self.drawable(held)
        m = min(k, len(ok))
        if m == 0:
            return _EMPTY
        slots, starts = self.pick(ok, m, rng)
        self.uses[slots] += 1  # slots are distinct: one increment each
        self.window_uses[slots, starts] += 1
        self.drawn += m
        return slots, starts

    @abstractmethod
    def pick(self, ok: np.ndarray, m: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """m distinct slots of ``ok`` (drawable, int64 [n >= m]) and a window start for each: int64 [m] both."""

    def inserted(self, slots: np.ndarray, evicted: np.ndarray, held: np.ndarray) -> None:
        """New trajectories in ``slots`` [b] (``evicted`` [k]: the slots among them whose trajectory made way;
        ``held``: the occupied slots before): their counts start at zero."""
        self.uses[slots], self.window_uses[slots] = 0, 0

    def report(self, slots: np.ndarray, losses: np.ndarray) -> None:
        """The training losses [m] of examples drawn from ``slots`` [m] (only a prioritized sampler uses them)."""
        return None

    def state_dict(self, slots: np.ndarray) -> dict:
        """Plain values resuming the held ``slots`` [n]: their counts, and the draw total."""
        return {"draw": self.name, "uses": self.uses[slots].tolist(), "window_uses": self.window_uses[slots].tolist(),
                "drawn": self.drawn}

    def load_state_dict(self, slots: np.ndarray, state: dict) -> None:
        self.uses[slots] = state["uses"]
        self.window_uses[slots] = np.asarray(state["window_uses"], np.int64).reshape(len(slots), -1)
        self.drawn = state["drawn"]

    def check_state(self, state: dict, n: int, ints) -> None:
        """ValueError (one line) for a state of n slots whose counts are out of range or of the wrong length;
        ``ints(name, values, low, high)`` checks integers."""
        if len(ints("sampler.uses", state["uses"], 0, 2**62)) != n:
            raise ValueError(f"reservoir state: sampler.uses has {len(state['uses'])} entries for {n} slots")
        if len(ints("sampler.window_uses", np.ravel(state["window_uses"]).tolist(), 0, 2**62)) != n * self.n_windows:
            raise ValueError(f"reservoir state: sampler.window_uses has {np.size(state['window_uses'])} entries for "
                             f"{n} slots of {self.n_windows} windows")
        ints("sampler.drawn", state["drawn"], 0, 2**62)


class UniformSampler(Sampler):
    """A random subset of the drawable trajectories and a random window each."""

    name = "uniform"

    def pick(self, ok, m, rng):
        return rng.choice(ok, size=m, replace=False), rng.integers(self.n_windows, size=m)


class LeastUsedSampler(Sampler):
    """The least-drawn trajectories and, in each, its least-drawn window (ties broken at random): Melissa's
    pairing of rarely used samples and windows."""

    name = "least_used"

    def pick(self, ok, m, rng):
        order = np.lexsort((rng.random(len(ok)), self.uses[ok]))  # by uses, ties at random
        slots = ok[order[:m]]
        return slots, (self.window_uses[slots] + rng.random((m, self.n_windows))).argmin(1)


class PrioritySampler(Sampler):
    """Prioritized replay: a trajectory is drawn with probability proportional to its priority (its last
    reported loss) ** ``power``, mixed with a uniform share ``floor``; a random window each. A new trajectory
    starts at the highest priority among those still drawable, so it is drawn soon and its loss measured.
    Owns priority: float64 [capacity] (> 0)."""

    name = "priority"

    def __init__(self, capacity: int, cap_uses: int, n_windows: int, power: float = 1.0, floor: float = 0.25):
        super().__init__(capacity, cap_uses, n_windows)
        self.power, self.floor = power, floor
        self.priority = np.ones(capacity)

    def pick(self, ok, m, rng):
        w = self.priority[ok] ** self.power
        p = (1.0 - self.floor) * w / w.sum() + self.floor / len(ok)
        return rng.choice(ok, size=m, replace=False, p=p / p.sum()), rng.integers(self.n_windows, size=m)

    def inserted(self, slots, evicted, held):
        # the highest priority among those still drawable (not the evicted, not those at their bound, whose
        # priority no longer updates)
        keep = held & (self.uses < self.cap_uses)
        keep[evicted] = False
        self.priority[slots] = self.priority[keep].max() if keep.any() else 1.0
        super().inserted(slots, evicted, held)

    def report(self, slots, losses):
        """``slots`` [m] get their examples' losses [m] as priorities (clipped to [1e-30, 1e30], so a power up
        to 8 stays finite; a slot twice in a batch keeps its last); a non-finite loss (a diverged step) leaves
        its slot's priority as it was."""
        ok = np.isfinite(losses)
        self.priority[slots[ok]] = np.clip(losses[ok], 1e-30, 1e30)

    def state_dict(self, slots):
        return {**super().state_dict(slots), "priority": self.priority[slots].tolist()}

    def load_state_dict(self, slots, state):
        """(A state saved by another sampler has no priorities: every one 1.)"""
        super().load_state_dict(slots, state)
        self.priority[slots] = np.asarray(state.get("priority", np.ones(len(slots))), np.float64)

    def check_state(self, state, n, ints):
        super().check_state(state, n, ints)
        priority = np.asarray(state.get("priority", np.ones(n)), np.float64)
        if priority.shape != (n,) or not ((priority >= 1e-30) & (priority <= 1e30)).all():
            raise ValueError(f"reservoir state: priority must be {n} numbers in [1e-30, 1e30], one per slot")


SAMPLERS = {cls.name: cls for cls in (UniformSampler, LeastUsedSampler, PrioritySampler)}
if tuple(SAMPLERS) != DRAWS:
    raise ImportError(f"reservoir_config.DRAWS {DRAWS} and the samplers {tuple(SAMPLERS)} disagree")
