"""The training reservoir's store: a storage, a sampler and a writer composed, with no threads and no solver.

``Reservoir`` holds up to ``capacity`` trajectories in its ``storage`` (``reservoir_storage``), draws examples
through its ``sampler`` (``reservoir_sampler``: the reuse bound and the draw rule) and inserts through its
``writer`` (``reservoir_writer``: occupancy and eviction). The bookkeeping stays on the host, so drawing never
waits for the storage's device. One seeded generator, ``rng``, serves the sampler and the writer (their calls
interleave in a fixed order: the sequence is a function of the seed). Its saved state is the composition of
the parts' states: {"slots", "storage", "writer", "sampler", "rng"}; ``from_flat`` reads the flat layout that
ReservoirStream saved before the parts existed.
"""

from __future__ import annotations

import numpy as np
import torch

from .proposal_fit import _plain
from .reservoir_sampler import SAMPLERS, Sampler
from .reservoir_storage import Storage, TensorStorage
from .reservoir_writer import WRITERS, Writer


class Reservoir:
    """The store: up to ``capacity`` trajectories with use counts.

    eviction: a ``WRITERS`` name or a Writer; draw: a ``SAMPLERS`` name or a Sampler; storage: a Storage (None:
    ``TensorStorage`` on ``device``); rng: the generator of every random choice. A trajectory is drawable while
    its uses < cap_uses, and evictable once its uses >= 1.
    """

    def __init__(self, capacity: int, cap_uses: int, n_windows: int, eviction: str | Writer, draw: str | Sampler,
                 rng: np.random.Generator, device: torch.device | str = "cpu", priority_power: float = 1.0,
                 priority_floor: float = 0.25, storage: Storage | None = None):
        self.capacity, self.cap_uses, self.n_windows, self.rng = capacity, cap_uses, n_windows, rng
        self.storage = TensorStorage(capacity, device) if storage is None else storage
        self.writer = WRITERS[eviction](capacity, cap_uses) if isinstance(eviction, str) else eviction
        if isinstance(draw, str):
            extra = dict(power=priority_power, floor=priority_floor) if draw == "priority" else {}
            draw = SAMPLERS[draw](capacity, cap_uses, n_windows, **extra)
        self.sampler = draw
        # the IC latents a joint proposal gave the held samples, float32 [capacity, L] on the host (None: none given,
        # every sample's IC from its key): what reports steer by and a saved state re-solves them from
        self.latent_host: np.ndarray | None = None

    # the parts' bookkeeping, under the names the store has always had
    index = property(lambda self: self.storage.index)
    params_host = property(lambda self: self.storage.params_host)
    device = property(lambda self: self.storage.device)
    serial = property(lambda self: self.writer.serial)
    inserted = property(lambda self: self.writer.inserted)
    evicted = property(lambda self: self.writer.evicted)
    uses = property(lambda self: self.sampler.uses)
    window_uses = property(lambda self: self.sampler.window_uses)
    priority = property(lambda self: self.sampler.priority)  # (a PrioritySampler's)

    @property
    def drawn(self) -> int:
        return self.sampler.drawn

    @drawn.setter
    def drawn(self, value: int) -> None:
        self.sampler.drawn = value

    def live(self) -> np.ndarray:
        """The occupied slots, int64 [n]."""
        return np.flatnonzero(self.writer.held())

    def room(self) -> int:
        """Trajectories that can be inserted now: empty slots plus evictable ones."""
        return self.writer.room(self.sampler.uses)

    def eligible(self) -> np.ndarray:
        """The slots that may be drawn now, int64 [m]."""
        return self.sampler.drawable(self.writer.held())

    def to(self, device: torch.device | str) -> None:
        """Move the storage to ``device``; the bookkeeping stays on the host."""
        self.storage.to(device)

    def insert(self, u: torch.Tensor, params: torch.Tensor, index: np.ndarray, latent: np.ndarray | None = None) -> int:
        """Insert trajectories u [B, T, C, *space] (params [B, P], index [B]; any device; latent: their IC latents
        [B, L] where a joint proposal gave them); returns how many were evicted. The caller checks ``room() >= B``
        first."""
        b = len(index)
        held = self.writer.held()
        slots, out = self.writer.write(b, self.sampler.uses, self.rng)
        self.sampler.inserted(slots, out, held)
        self.writer.occupy(slots)
        self.storage.put(slots, u[:b], params[:b], index[:b])
        self.set_latent(slots, latent)
        return len(out)

    def set_latent(self, slots: np.ndarray, latent: np.ndarray | None) -> None:
        """Record the IC latents [m, L] of the samples in ``slots`` [m] (None: none given; a NaN row: the key's)."""
        if latent is None:
            if self.latent_host is not None:
                self.latent_host[slots] = np.nan
            return
        latent = np.asarray(latent, np.float32).reshape(len(slots), -1)
        if self.latent_host is None:
            self.latent_host = np.full((self.capacity, latent.shape[1]), np.nan, np.float32)
        self.latent_host[slots] = latent

    def latent_of(self, slots: np.ndarray) -> np.ndarray | None:
        """The IC latents [m, L] of ``slots`` (a copy), or None when no sample was given one."""
        return None if self.latent_host is None else self.latent_host[slots].copy()

    def draw(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to k examples, each trajectory at most once: (slots [m], window starts [m]), m <= k; m = 0 when
        every held trajectory is at its bound."""
        return self.sampler.draw(self.writer.held(), k, self.rng)

    def set_priority(self, slots: np.ndarray, losses: np.ndarray) -> None:
        """The training losses [m] of examples from ``slots`` [m], for the sampler (prioritized replay)."""
        self.sampler.report(slots, losses)

    def use_counts(self) -> np.ndarray:
        """Trajectories inserted so far (evicted and held) by use count: int64 [cap_uses + 1]."""
        return self.writer.evicted_counts + np.bincount(self.sampler.uses[self.live()], minlength=self.cap_uses + 1)

    def reuse(self, per_trajectory: int) -> np.ndarray:
        """Uses / per_trajectory of every trajectory inserted so far (evicted and held), float64 [inserted]."""
        counts = self.use_counts()
        return np.repeat(np.arange(len(counts), dtype=np.float64), counts) / per_trajectory

    # --- state -----------------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """{"slots": the held slots, "storage", "writer", "sampler": each part's state for them, "rng"}."""
        live = self.live()
        storage = self.storage.state_dict(live)
        if self.latent_host is not None:  # (None where none was given: a state as before the latent)
            storage["latent"] = self.latent_host[live].tolist()
        return {"slots": live.tolist(), "storage": storage, "writer": self.writer.state_dict(live),
                "sampler": self.sampler.state_dict(live), "rng": _plain(self.rng.bit_generator.state)}

    def check_state(self, state: dict, max_index: int) -> None:
        """ValueError (one line, "reservoir state: ...") for a state with integers out of range or lists that
        disagree in length (a hand-edited or corrupted checkpoint), before anything changes."""
        try:
            n = len(ints("slots", state["slots"], 0, self.capacity - 1))
            if len(set(state["slots"])) != n:
                raise ValueError("reservoir state: slots repeat a slot")
            if len(ints("storage.index", state["storage"]["index"], 0, max_index)) != n:
                raise ValueError(f"reservoir state: storage.index has {len(state['storage']['index'])} entries for "
                                 f"{n} slots")
            latent = state["storage"].get("latent")
            if latent is not None and (not isinstance(latent, list) or len(latent) != n):
                raise ValueError(f"reservoir state: storage.latent has {len(latent) if isinstance(latent, list) else latent!r}"
                                 f" entries for {n} slots")
            self.writer.check_state(state["writer"], n, ints)
            self.sampler.check_state(state["sampler"], n, ints)
        except (KeyError, TypeError) as err:
            raise ValueError(f"reservoir state is incomplete or malformed ({type(err).__name__}: {err})") from None

    def load_state_dict(self, state: dict, refill) -> None:
        """Resume from ``state_dict()`` (checked with ``check_state``). The held trajectories are not in a state:
        ``refill(slots [n], index [n], params [n, P], latent [n, L] or None)`` solves them again and puts them in
        the storage (and their latents here)."""
        slots = np.asarray(state["slots"], np.int64)
        if len(slots):
            latent = state["storage"].get("latent")
            refill(slots, np.asarray(state["storage"]["index"], np.int64), state["storage"]["params"],
                   None if latent is None else np.asarray(latent, np.float32).reshape(len(slots), -1))
        self.writer.load_state_dict(slots, state["writer"])
        self.sampler.load_state_dict(slots, state["sampler"])
        self.rng.bit_generator.state = state["rng"]


def ints(name: str, values, low: int, high: int) -> np.ndarray:
    """``values`` (an integer or a list of them) as int64, or one line naming ``name`` and the first value out of
    [low, high] (JSON and torch give Python ints of any size)."""
    values = list(values) if isinstance(values, (list, tuple)) else [values]
    bad = [v for v in values if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not low <= v <= high]
    if bad:
        raise ValueError(f"reservoir state: {name} holds {_plain(bad[0])!r}; allowed: integers in [{low}, {high}]")
    return np.asarray(values, np.int64)


def from_flat(state: dict) -> dict:
    """A ReservoirStream state in the flat layout saved before the parts (every list and counter at the top
    level) in the composed layout that ``ReservoirStream.load_state_dict`` reads; the missing keys of a damaged
    one raise KeyError."""
    c = state["counters"]
    n = len(state["slots"])
    res = {"slots": state["slots"], "rng": state["rng"],
           "storage": {"index": state["index"], "params": state["params"]},
           "writer": {"serial": state["serial"], "evicted_counts": state["evicted_counts"],
                      **{k: c[k] for k in ("next_serial", "inserted", "evicted")}},
           # (states saved before draw "priority" existed have no priorities: every one 1)
           "sampler": {"uses": state["uses"], "window_uses": state["window_uses"], "drawn": c["drawn"],
                       "priority": state.get("priority", [1.0] * n)}}
    keep = ("kind", "seed", "config_hash", "mode", "capacity", "max_reuse", "view", "n_windows", "rank", "world_size")
    return {**{k: state[k] for k in keep if k in state}, "layout": 2, "reservoir": res,
            "producer": {"next_index": c["next_index"], "jobs": state["jobs"]},
            "schedule": {"drawn_since_insert": c["drawn_since_insert"], "batches": c["batches"]},
            "proposal": state["proposal"]}
