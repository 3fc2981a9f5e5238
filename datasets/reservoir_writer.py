"""The training reservoir's writers: which slots new trajectories take, and which held one makes way (torchrl's
"writer"; here the eviction policy).

``Writer`` is the declared interface and owns occupancy: serial [capacity] (insertion order; -1: an empty slot),
next_serial, the inserted and evicted totals, and evicted_counts (evicted trajectories by use count, a fixed-size
histogram: neither memory nor a saved state grows with the length of a run). New trajectories take the empty
slots in order, then evictable ones (drawn at least once: a solve is never thrown away unused), chosen by
``evict``. Implementations (``WRITERS``, by the ``eviction`` setting's name): ``FifoWriter`` (oldest first),
``RandomWriter`` (one random draw each).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from .reservoir_config import EVICTIONS


class Writer(ABC):
    """Where inserted trajectories go. capacity: slots; cap_uses: the reuse bound (the histogram's last bin)."""

    name: str

    def __init__(self, capacity: int, cap_uses: int):
        self.capacity = capacity
        self.serial = np.full(capacity, -1, np.int64)
        self.next_serial = self.inserted = self.evicted = 0
        self.evicted_counts = np.zeros(cap_uses + 1, np.int64)

    def held(self) -> np.ndarray:
        """bool [capacity]: the slots that hold a trajectory."""
        return self.serial >= 0

    def room(self, uses: np.ndarray) -> int:
        """Trajectories that can be inserted now (uses: int64 [capacity]): empty slots plus evictable ones."""
        return int(((self.serial < 0) | (uses >= 1)).sum())

    def write(self, b: int, uses: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Slots for b new trajectories: (slots [b], the evicted ones among them [k]); records the evictions
        (by their ``uses``) and the insertions. The caller checks ``room(uses) >= b`` first."""
        empty = np.flatnonzero(self.serial < 0)[:b]
        used = np.flatnonzero(uses >= 1)  # (a slot just filled has uses 0: never chosen twice)
        k = b - len(empty)
        if k > len(used):
            raise RuntimeError("reservoir full of unused trajectories (insert without room(): a bug)")
        out = self.evict(used, k, rng)
        slots = np.concatenate([empty, out]).astype(np.int64)
        np.add.at(self.evicted_counts, uses[out], 1)
        self.evicted += k
        return slots, out

    def occupy(self, slots: np.ndarray) -> None:
        """``slots`` [b] now hold the newest trajectories, in this order."""
        self.serial[slots] = self.next_serial + np.arange(len(slots))
        self.next_serial += len(slots)
        self.inserted += len(slots)

    @abstractmethod
    def evict(self, used: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
        """k distinct slots of ``used`` (evictable, int64 [n >= k]) whose trajectories make way: int64 [k]."""

    def state_dict(self, slots: np.ndarray) -> dict:
        """Plain values resuming the held ``slots`` [n]: their serials, the totals and the histogram."""
        return {"eviction": self.name, "serial": self.serial[slots].tolist(), "next_serial": self.next_serial,
                "inserted": self.inserted, "evicted": self.evicted, "evicted_counts": self.evicted_counts.tolist()}

    def load_state_dict(self, slots: np.ndarray, state: dict) -> None:
        self.serial[slots] = state["serial"]
        self.next_serial, self.inserted, self.evicted = state["next_serial"], state["inserted"], state["evicted"]
        self.evicted_counts = np.asarray(state["evicted_counts"], np.int64)

    def check_state(self, state: dict, n: int, ints) -> None:
        """ValueError (one line) for a state of n slots with integers out of range or lists of the wrong length;
        ``ints(name, values, low, high)`` checks integers."""
        if len(ints("writer.serial", state["serial"], 0, 2**62)) != n:
            raise ValueError(f"reservoir state: writer.serial has {len(state['serial'])} entries for {n} slots")
        for name in ("next_serial", "inserted", "evicted"):
            ints(f"writer.{name}", state[name], 0, 2**62)
        ints("writer.evicted_counts", list(state["evicted_counts"]), 0, 2**62)


class FifoWriter(Writer):
    """The oldest used trajectory makes way first."""

    name = "fifo"

    def evict(self, used, k, rng):
        return used[np.argsort(self.serial[used], kind="stable")[:k]]


class RandomWriter(Writer):
    """A random used trajectory makes way: one generator call per trajectory, from what is left."""

    name = "random"

    def evict(self, used, k, rng):
        out = np.empty(k, np.int64)
        for j in range(k):
            pick = rng.choice(len(used))
            out[j], used = used[pick], np.delete(used, pick)
        return out


WRITERS = {cls.name: cls for cls in (FifoWriter, RandomWriter)}
if tuple(WRITERS) != EVICTIONS:
    raise ImportError(f"reservoir_config.EVICTIONS {EVICTIONS} and the writers {tuple(WRITERS)} disagree")
