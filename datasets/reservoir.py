"""A training reservoir between solver producers and the training loop (Melissa's idea, with pip install).

Producers (``datasets.producers``: a background thread, spawned processes or a Dask cluster) solve batches of
``solve_batch`` trajectories; the reservoir holds up to ``capacity`` of them and the loop draws training
examples (through the usual views) from what it holds, so a solve is reused instead of used once:

- **reuse bound**: a trajectory is drawn at most ``max_reuse`` times its example count under the view (one
  "use" = as many examples as the FIFO stream takes from it: every window for ``next_step`` windows="all",
  one for ``operator``); the loop waits for fresh solves rather than exceed it. Mean reuse is reported.
- **eviction** when full: ``"fifo"`` (oldest first) or ``"random"``, among trajectories drawn at least once
  (a solve is never thrown away unused: a producer that is faster than training waits instead).
- **draw**: ``"uniform"`` over the trajectories below the bound, ``"least_used"`` (the trajectory drawn
  least, then its least-drawn window: Melissa's pairing of rarely used samples and windows), or ``"priority"``
  (prioritized replay, Schaul et al. 2016: a trajectory is drawn with probability proportional to its last
  reported per-example loss (the training loop reports the relative L2 error, whatever the training loss) to the
  power ``priority_power``, mixed with a uniform share ``priority_floor``; a new trajectory starts at the
  highest priority among those still drawable, so it is drawn soon and its loss measured). At a fixed
  simulation budget this is the lever that reaches the initial conditions too: a proposal steers the
  parameters of the next solves, the priorities steer training toward the hard trajectories already solved,
  whatever made them hard. The reuse bound still holds.
- **warmup**: no batch before ``warmup`` trajectories are in.
- **mode** ``"deterministic"``: solves are inserted in submission order at fixed points of the draw sequence
  (after the warm-up, one solve batch of B trajectories each time B x max_reuse uses have been drawn, or
  earlier when nothing can be drawn), and draws come from a seeded generator, so the batch sequence is a pure
  function of (PDE config, seed, settings) whatever the producer, and ``state_dict`` resumes it exactly
  (the held trajectories are re-solved from their (index, params): sample identity). The solver still
  works ahead in the background; the loop waits only when the scheduled solve is not done.
  ``"async"`` (the fast one; **not reproducible**): results are inserted the moment they arrive, in any
  order, so what a batch holds depends on timing.
- **loss-driven sampling** (``proposal="loss"``): the next solves' parameters come from a
  ``datasets.proposal.ParamProposal`` fed by the per-sample losses the training loop reports
  (``report_losses``); ``proposal="active"`` adds an uncertainty signal (the disagreement of a small bootstrap
  ensemble of loss models over the parameter box, fitted in a background thread) and a proposal that can hold a
  sharp mode, over a uniform floor; ``"uniform"`` leaves the parameters to the solver's own draws.

- **device**: the trajectories live on the training device (``device=``; None: the model's, through the
  training loop's ``place`` hook), a thread producer's solves are copied in from JAX's buffer there (DLPack) and
  batches are gathered there; the bookkeeping above stays on the host, so drawing never waits for the GPU.

``max_reuse=1``, ``capacity=solve_batch``, ``draw="least_used"`` and deterministic mode is the plain FIFO
stream. Sample identity is (PDE config, seed, index, params): samples are numbered 0, 1, 2, ... in
submission order, and batches carry "index" and "params" as every other source does.
"""

from __future__ import annotations

import atexit
import collections
import copy
import math
import os
import time
import weakref
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, wait

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from . import _bridge
from .producers import open_producer
from .progress import StreamPosition
from .proposal import ParamProposal, _plain
from .views import for_sample, gather, make_view

MODES = ("async", "deterministic")
DRAWS = ("uniform", "least_used", "priority")
EVICTIONS = ("fifo", "random")
_OPEN: "weakref.WeakSet[ReservoirStream]" = weakref.WeakSet()


@atexit.register
def _close_all() -> None:
    # a script may leave a stream open: let producers finish their job in flight instead of dying in JAX
    for stream in list(_OPEN):
        stream.close()


def _solved(future, indices: np.ndarray) -> dict:
    """A solve job's result; a producer process that died under it (killed, out of memory) is one line naming the
    samples, not concurrent.futures' BrokenProcessPool traceback (the pool cannot run anything after that)."""
    try:
        return future.result()
    except BrokenExecutor:
        raise ValueError(f"a solver process of the reservoir's producer died (killed, or out of memory) while "
                         f"solving samples {int(indices[0])}..{int(indices[-1])}; the stream stops (a run goes "
                         "on with --resume from its last checkpoint)") from None


def _physical_memory() -> int:
    """Bytes of RAM (0 where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 0


def _check_int(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name}={value!r} not allowed; must be an integer >= {low}")
    return int(value)


def _check_choice(name: str, value, allowed: tuple) -> str:
    if value not in allowed:
        raise ValueError(f"{name}={value!r} not allowed; allowed: {', '.join(allowed)}")
    return value


def storage_device(device) -> torch.device:
    """torch.device for a reservoir's ``device``: "cpu", "cuda", "cuda:N" or a torch.device ("cuda" becomes the
    current GPU's index, so that it compares equal to a model's device); one line when it cannot be used."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        dev = None
    if dev is None or dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device={device!r} not allowed; allowed: cpu, cuda, cuda:N (None: the training device)")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device={device!r} not allowed: torch sees no GPU here; allowed: cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"device={device!r} not allowed: torch sees {torch.cuda.device_count()} GPU(s)")
        if dev.index is None:
            dev = torch.device("cuda", torch.cuda.current_device())
    return dev


def free_bytes(device: torch.device) -> tuple[int, int]:
    """(bytes free, bytes in all) on a CUDA device: the driver's free memory plus what torch's caching allocator
    holds unused (it hands that out first)."""
    free, total = torch.cuda.mem_get_info(device)
    return free + torch.cuda.memory_reserved(device) - torch.cuda.memory_allocated(device), total


def no_room_line(device: torch.device, need: int, what: str) -> str:
    """The one line for a device that cannot hold ``need`` bytes."""
    free, total = free_bytes(device)
    return (f"device={str(device)!r} cannot hold {what}: it asks {need} bytes ({need / 2**30:.2f} GiB) and {device} has "
            f"{free} bytes free ({free / 2**30:.2f} of {total / 2**30:.1f} GiB); allowed: a smaller capacity, or "
            "device='cpu'")


def check_room(device: torch.device, need: int, what: str) -> None:
    """ValueError (one line: bytes asked and free) when a CUDA device has less than ``need`` bytes free. (The
    host's memory is checked by ReservoirStream against half the machine's RAM.)"""
    if device.type == "cuda" and need > free_bytes(device)[0]:
        raise ValueError(no_room_line(device, need, what))


class Reservoir:
    """The store itself: up to ``capacity`` trajectories with use counts; no threads, no solver.

    u: float32 [capacity, T, C, *space] (allocated at the first insert) and params [capacity, P] on ``device``
    (the training device: gathers run there), with index_t int64 [capacity], the index's copy there; the
    bookkeeping stays on the host, so drawing never waits for the device: index, uses, serial (insertion
    order, -1: empty slot), priority (draw "priority": the last reported loss) [capacity]; window_uses
    [capacity, n_windows].
    A trajectory is drawable while uses < cap_uses, and evictable once uses >= 1.
    """

    def __init__(self, capacity: int, cap_uses: int, n_windows: int, eviction: str, draw: str,
                 rng: np.random.Generator, device: torch.device | str = "cpu", priority_power: float = 1.0,
                 priority_floor: float = 0.25):
        self.capacity, self.cap_uses, self.n_windows = capacity, cap_uses, n_windows
        self.priority_power, self.priority_floor = priority_power, priority_floor
        self.priority = np.ones(capacity)  # draw "priority": each slot's last reported loss (> 0)
        self.eviction, self.draw_policy, self.rng = eviction, draw, rng
        self.device = torch.device(device)
        self.u = self.params = self.index_t = None
        self.index = np.full(capacity, -1, np.int64)
        self.uses = np.zeros(capacity, np.int64)
        self.window_uses = np.zeros((capacity, n_windows), np.int64)
        self.serial = np.full(capacity, -1, np.int64)
        self.next_serial = self.inserted = self.evicted = self.drawn = 0
        # evicted trajectories by use count (index: uses): a fixed-size histogram, so neither memory nor the
        # checkpoint grows with the length of the run
        self.evicted_counts = np.zeros(cap_uses + 1, np.int64)
        self._held: list = []  # (event, tensors): sources of device copies, kept until the copies have run

    def live(self) -> np.ndarray:
        return np.flatnonzero(self.serial >= 0)

    def room(self) -> int:
        """Trajectories that can be inserted now: empty slots plus evictable ones."""
        return int(((self.serial < 0) | (self.uses >= 1)).sum())

    def eligible(self) -> np.ndarray:
        return np.flatnonzero((self.serial >= 0) & (self.uses < self.cap_uses))

    def allocate(self, shape: tuple, dtype: torch.dtype, n_params: int) -> None:
        """The storage on ``device``: u [capacity, *shape], params [capacity, n_params], index_t [capacity].
        One line (ValueError) when the device cannot hold it: the bytes asked and the bytes free there."""
        if self.u is not None:
            return
        need = self.capacity * (math.prod(shape) * dtype.itemsize + n_params * 4 + 8)
        check_room(self.device, need, f"a reservoir of {self.capacity} trajectories")
        try:
            self.u = torch.empty((self.capacity, *shape), dtype=dtype, device=self.device)
            self.params = torch.empty((self.capacity, n_params), dtype=torch.float32, device=self.device)
        except torch.OutOfMemoryError:
            self.u = self.params = None
            raise ValueError(no_room_line(self.device, need, f"a reservoir of {self.capacity} trajectories")) from None
        self.params_host = np.zeros((self.capacity, n_params), np.float32)  # what reports and states read
        # on the CPU the index tensor is the bookkeeping array itself (shared memory): nothing to keep in step
        self.index_t = torch.from_numpy(self.index) if self.device.type == "cpu" else \
            torch.from_numpy(self.index).to(self.device)

    def to(self, device: torch.device | str) -> None:
        """Move the storage (if any) to ``device``; the bookkeeping stays where it is (host)."""
        device = torch.device(device)
        if device == self.device:
            return
        if self.u is not None:
            need = self.u.nbytes + self.params.nbytes + self.index_t.nbytes
            check_room(device, need, f"a reservoir of {self.capacity} trajectories")
            self.u, self.params = self.u.to(device), self.params.to(device)
            self.index_t = torch.from_numpy(self.index) if device.type == "cpu" else torch.from_numpy(self.index).to(device)
        self.device = device

    def put(self, slots: np.ndarray, u: torch.Tensor, params: torch.Tensor) -> None:
        """Copy trajectories u [m, ...] and params [m, P] into ``slots`` [m] (distinct) of the storage, one copy
        each whatever device they come from (a solver's GPU buffer through DLPack: device to device; a worker
        process's numpy: host to device); ``index[slots]`` must already hold their indices."""
        if self.u is None:
            self.allocate(tuple(u.shape[1:]), u.dtype, params.shape[1])
        self.params_host[slots] = params.detach().cpu().numpy()  # (a solve's params come as numpy: no wait)
        dev = self.device
        if dev.type == "cpu":  # (no event to wait on: copies on the CPU are done when they return)
            at = torch.from_numpy(slots)
            self.u.index_copy_(0, at, u.to(dev))
            self.params.index_copy_(0, at, params.to(dev, torch.float32))
            return
        at = torch.from_numpy(slots).to(dev)
        self.u.index_copy_(0, at, u.to(dev, non_blocking=True))
        self.params.index_copy_(0, at, params.to(dev, torch.float32, non_blocking=True))
        self.index_t.index_copy_(0, at, torch.from_numpy(self.index[slots]).to(dev))
        # the copies are queued on torch's stream: their sources (a JAX buffer shared through DLPack, which JAX
        # reuses once released) live until an event recorded after them has passed; no wait here
        self._held = [(e, t) for e, t in self._held if not e.query()]
        event = torch.cuda.Event()
        event.record(torch.cuda.current_stream(dev))
        self._held.append((event, (u, params)))

    def insert(self, u: torch.Tensor, params: torch.Tensor, index: np.ndarray) -> int:
        """Insert trajectories u [B, T, C, *space] (params [B, P], index [B]; any device); returns how many were
        evicted. The caller checks ``room() >= B`` first. Slots: the empty ones in order, then the evictable
        ones (used at least once), oldest first ("fifo") or one random draw each ("random")."""
        b = len(index)
        empty = np.flatnonzero(self.serial < 0)[:b]
        used = np.flatnonzero(self.uses >= 1)  # (a slot just filled has uses 0: never chosen twice)
        k = b - len(empty)
        if k > len(used):
            raise RuntimeError("reservoir full of unused trajectories (insert without room(): a bug)")
        if self.eviction == "fifo":
            out = used[np.argsort(self.serial[used], kind="stable")[:k]]
        else:  # one draw per trajectory from what is left, as many generator calls as trajectories
            out = np.empty(k, np.int64)
            for j in range(k):
                pick = self.rng.choice(len(used))
                out[j], used = used[pick], np.delete(used, pick)
        slots = np.concatenate([empty, out]).astype(np.int64)
        # new trajectories at the highest priority among those still drawable (not the evicted, not those at their
        # bound, whose priority no longer updates): drawn soon, so their own loss replaces it
        keep = (self.serial >= 0) & (self.uses < self.cap_uses)
        keep[out] = False
        self.priority[slots] = self.priority[keep].max() if keep.any() else 1.0
        np.add.at(self.evicted_counts, self.uses[out], 1)
        self.evicted += k
        self.index[slots], self.uses[slots] = index[:b], 0
        self.serial[slots] = self.next_serial + np.arange(b)
        self.window_uses[slots] = 0
        self.next_serial += b
        self.inserted += b
        self.put(slots, u[:b], params[:b])
        return k

    def draw(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to k examples, each trajectory at most once: (slots [m], window starts [m]), m <= k; m = 0 when
        every held trajectory is at its bound. "uniform": a random subset of the drawable trajectories and a
        random window each; "least_used": the least-drawn trajectories and, in each, its least-drawn window
        (ties broken at random)."""
        ok = self.eligible()
        m = min(k, len(ok))
        if m == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        if self.draw_policy == "least_used":
            order = np.lexsort((self.rng.random(len(ok)), self.uses[ok]))  # by uses, ties at random
            slots = ok[order[:m]]
            starts = (self.window_uses[slots] + self.rng.random((m, self.n_windows))).argmin(1)
        elif self.draw_policy == "priority":
            w = self.priority[ok] ** self.priority_power
            p = (1.0 - self.priority_floor) * w / w.sum() + self.priority_floor / len(ok)
            slots = self.rng.choice(ok, size=m, replace=False, p=p / p.sum())
            starts = self.rng.integers(self.n_windows, size=m)
        else:
            slots = self.rng.choice(ok, size=m, replace=False)
            starts = self.rng.integers(self.n_windows, size=m)
        self.uses[slots] += 1  # slots are distinct: one increment each
        self.window_uses[slots, starts] += 1
        self.drawn += m
        return slots, starts

    def set_priority(self, slots: np.ndarray, losses: np.ndarray) -> None:
        """Draw "priority": ``slots`` [m] get their examples' training losses [m] as priorities (clipped to
        [1e-30, 1e30], so a power up to 8 stays finite; a slot drawn twice in a batch keeps its last); a
        non-finite loss (a diverged step) leaves its slot's priority as it was."""
        ok = np.isfinite(losses)
        self.priority[slots[ok]] = np.clip(losses[ok], 1e-30, 1e30)

    def use_counts(self) -> np.ndarray:
        """Trajectories inserted so far (evicted and held) by use count: int64 [cap_uses + 1]."""
        return self.evicted_counts + np.bincount(self.uses[self.live()], minlength=self.cap_uses + 1)

    def reuse(self, per_trajectory: int) -> np.ndarray:
        """Uses / per_trajectory of every trajectory inserted so far (evicted and held), float64 [inserted]."""
        counts = self.use_counts()
        return np.repeat(np.arange(len(counts), dtype=np.float64), counts) / per_trajectory


class ReservoirStream(IterableDataset):
    """Batches drawn from a training reservoir fed by solver producers; ``DataLoader(stream, batch_size=None)``.

    pde: generator PDE or catalog name; view (+ view keyword arguments) as for TrajectoryStream; batch_size:
    examples per batch; capacity: trajectories held (>= batch_size and >= solve_batch); max_reuse (>= 1): the
    bound on uses per trajectory; warmup: trajectories held before the first batch (default
    max(solve_batch, capacity // 4)); eviction "fifo" | "random"; draw "uniform" | "least_used" | "priority"
    (+ priority_power in [0, 8] and priority_floor in (0, 1]: prioritized replay by the last reported loss, see
    the module docstring); mode
    "async" | "deterministic" (see the module docstring); producer "thread" | "process" | "dask" (+ workers,
    scheduler); inflight: solve jobs submitted ahead (default: 2 per producer slot); target_reuse (in
    [1, max_reuse]): pace the solver so each trajectory pays for about this many uses (async: a solve is
    submitted only once the draws have paid for the previous ones; deterministic: the schedule's rate; default:
    async solves as fast as it can, deterministic uses max_reuse); proposal "uniform" |
    "loss" | "active" (+ proposal_kwargs for ParamProposal); sim_budget: stop after this many solved trajectories
    (None: endless); on_blowup "raise" | "redraw" | "skip" (a failed sample is left out, one SkippedSamples
    warning line each, ``stats()["skipped"]`` counts them; deterministic mode stays a pure function of the
    settings as long as the solver fails the same samples every time, which a timeout does not promise).
    device: where the trajectories are kept and batches are gathered ("cpu", "cuda", "cuda:N"; None: the
    training device, which the training loop sets through ``place``, else the CPU): with the thread producer a
    solve on that GPU is copied in from JAX's buffer (DLPack, no host round trip), and every tensor of a batch
    is on that device. Batches are dicts as from the views, with "params" [B, P] and "index" [B]. The stream
    runs in the training process (num_workers=0); its producers are the parallelism.
    """

    def __init__(self, pde, seed: int = 0, view="next_step", batch_size: int = 32, capacity: int = 256,
                 max_reuse: float = 4.0, warmup: int | None = None, eviction: str = "fifo", draw: str = "uniform",
                 solve_batch: int = 16, mode: str = "async", producer: str = "thread", workers: int = 1,
                 scheduler: str | None = None, inflight: int | None = None, proposal: str = "uniform",
                 proposal_kwargs: dict | None = None, sim_budget: int | None = None, target_reuse: float | None = None,
                 device=None, on_blowup: str = "raise", priority_power: float = 1.0, priority_floor: float = 0.25,
                 **view_kwargs):
        self.pde = _bridge.resolve_pde(pde)
        if view_kwargs and not isinstance(view, str):
            raise ValueError(f"view options {sorted(view_kwargs)} only go with a view name, not a view object")
        self.view = for_sample(make_view(view, **view_kwargs), self.pde.n_frames, len(self.pde.INPUTS))
        self.seed = _check_int("seed", seed, 0)
        self.batch_size = _check_int("batch_size", batch_size, 1)
        self.solve_batch = _check_int("solve_batch", solve_batch, 1)
        self.capacity = _check_int("capacity", capacity, 1)
        if self.capacity < self.batch_size:
            raise ValueError(f"capacity={capacity} not allowed: must be >= batch_size ({batch_size})")
        if self.capacity < self.solve_batch:
            raise ValueError(f"capacity={capacity} not allowed: must be >= solve_batch ({solve_batch})")
        if isinstance(max_reuse, bool) or not isinstance(max_reuse, (int, float)) or not max_reuse >= 1 \
                or not math.isfinite(max_reuse):
            raise ValueError(f"max_reuse={max_reuse!r} not allowed; must be a finite number >= 1")
        self.max_reuse = float(max_reuse)
        default_warmup = max(self.solve_batch, self.capacity // 4)
        self.warmup = min(default_warmup, self.capacity) if warmup is None else _check_int("warmup", warmup, 1)
        if self.warmup > self.capacity:
            raise ValueError(f"warmup={warmup} not allowed: must be <= capacity ({capacity})")
        self.eviction = _check_choice("eviction", eviction, EVICTIONS)
        self.draw = _check_choice("draw", draw, DRAWS)
        if isinstance(priority_power, bool) or not isinstance(priority_power, (int, float)) or not 0 <= priority_power <= 8:
            raise ValueError(f"priority_power={priority_power!r} not allowed; must be in [0, 8] (0: uniform draws)")
        if isinstance(priority_floor, bool) or not isinstance(priority_floor, (int, float)) or not 0 < priority_floor <= 1:
            raise ValueError(f"priority_floor={priority_floor!r} not allowed; must be in (0, 1] (the uniform share of draws)")
        self.priority_power, self.priority_floor = float(priority_power), float(priority_floor)
        self.mode = _check_choice("mode", mode, MODES)
        self.producer, self.workers, self.scheduler = producer, workers, scheduler
        self.on_blowup = _bridge.check_on_blowup(on_blowup)
        self.sim_budget = None if sim_budget is None else _check_int("sim_budget", sim_budget, 1)
        self.inflight = None if inflight is None else _check_int("inflight", inflight, 1)
        n_frames = self.pde.n_frames
        self.n_windows = self.view.n_starts(n_frames) if hasattr(self.view, "n_starts") else 1
        self.per_trajectory = len(self.view.starts(n_frames, torch.Generator().manual_seed(0)))
        self.cap_uses = max(1, round(self.max_reuse * self.per_trajectory))
        if target_reuse is not None and (isinstance(target_reuse, bool) or not isinstance(target_reuse, (int, float))
                                         or not 1 <= target_reuse <= self.max_reuse):
            raise ValueError(f"target_reuse={target_reuse!r} not allowed; must be a number in [1, max_reuse={max_reuse}]")
        self.target_reuse = None if target_reuse is None else float(target_reuse)
        # draws that pay for one solve batch: the deterministic schedule's step, and async mode's solver pacing
        self.uses_per_solve = self.cap_uses if target_reuse is None else max(1, round(target_reuse * self.per_trajectory))
        self.config = self.pde.config()
        need = self.capacity * n_frames * len(_bridge.sample_channels(self.pde)) * math.prod(self.pde.grid.shape) * 4
        self.need = need + self.capacity * (4 * len(self.pde.PARAMS) + 8)  # u, params, index on the device
        self.device = None if device is None else storage_device(device)
        have = _physical_memory()
        if have and need > have // 2 and (self.device is None or self.device.type == "cpu"):
            raise ValueError(f"capacity={capacity} not allowed: holding {capacity} trajectories takes "
                             f"{need / 2**30:.1f} GiB, more than half of this machine's {have / 2**30:.1f} GiB")
        self._where = torch.device("cpu") if self.device is None else self.device  # where the storage goes
        check_room(self._where, self.need, f"capacity={capacity} ({capacity} trajectories)")
        self.proposal = ParamProposal(_bridge.param_domains(self.pde), mode=proposal, seed=self.seed,
                                      **(proposal_kwargs or {}))
        self.t = torch.from_numpy(np.asarray(self.pde.times()))
        self._t_dev = self.t.to(self._where)
        self._last = None  # (the last batch's params tensor, its host copy): report_losses reads no device
        self._reset_state()
        self._executor = self._closer = None

    def _reset_state(self) -> None:
        self.res = Reservoir(self.capacity, self.cap_uses, self.n_windows, self.eviction, self.draw,
                             np.random.default_rng([self.seed, 1]), self._where, self.priority_power, self.priority_floor)
        self._drawn = None  # (the last batch's params tensor, its slots, their serials): where its losses go
        self.next_index = 0  # the next sample index to submit
        self.pending: collections.deque = collections.deque()  # (indices, params, future) in submission order
        self.done: list = []  # async: finished jobs waiting for room
        self.drawn_since_insert = 0
        self.progress = StreamPosition(slots=1)  # batches handed out (one producer-side "worker": this process)
        self.t_wait = 0.0  # seconds the loop waited for solves
        self.t_insert = self.t_gather = 0.0  # seconds spent inserting solves and gathering batches (host clock)
        self.skipped = 0  # samples left out by on_blowup="skip"
        self._t_first = None  # when iteration started (rates in stats())

    def place(self, device) -> None:
        """The training loop's hook: a stream built with device=None keeps its trajectories on the model's
        ``device`` (moved there if it holds some already); a stream given a device keeps its own."""
        if self.device is not None:
            return
        where = storage_device(device)
        if where != self._where:
            self.res.to(where)  # (checks the room there first)
            self._where, self._t_dev = where, self.t.to(where)

    # --- producers ---------------------------------------------------------------------------------
    def _start(self) -> None:
        if self._executor is None:
            self._executor, self._closer, slots = open_producer(self.producer, self.workers, self.scheduler)
            self.max_inflight = self.inflight or 2 * slots
            _OPEN.add(self)
        if self._t_first is None:
            self._t_first = time.perf_counter()
        # jobs restored by load_state_dict (or stopped by close) are submitted again, in their order
        self.pending = collections.deque((i, p, self._submit(i, p) if f is None else f) for i, p, f in self.pending)
        self._fill_pipeline()

    def _submit(self, indices: np.ndarray, params: dict | None):
        """One solve job, padded to solve_batch (one compiled shape for every job)."""
        pad = np.resize(np.arange(len(indices)), self.solve_batch)
        padded_params = None if params is None else {k: np.asarray(v)[pad] for k, v in params.items()}
        # a thread solves in this process: its result stays in JAX's buffer (on its device) and is copied into
        # the storage from there; a worker process's or Dask's comes back as numpy (pickled)
        return self._executor.submit(_bridge.solve_job, self.config, self.seed, indices[pad], padded_params,
                                     self.on_blowup, self.producer == "thread")

    def _fill_pipeline(self) -> None:
        while len(self.pending) + len(self.done) < self.max_inflight:
            budget = self.solve_batch if self.sim_budget is None else min(self.solve_batch, self.sim_budget - self.next_index)
            if budget <= 0 or self._paced():
                return
            indices = self._sample_indices(self.next_index, budget)
            params = self.proposal.propose(budget)
            self.next_index += budget
            self.pending.append((indices, params, self._submit(indices, params)))

    def _sample_indices(self, first: int, n: int) -> np.ndarray:
        """Global sample indices of this stream's submissions first .. first + n - 1: int64 [n], 0, 1, 2, ...
        here (a DDP rank's stream, ``datasets.ranks.RankReservoirStream``, takes every world_size-th)."""
        return np.arange(first, first + n, dtype=np.int64)

    def _paced(self) -> bool:
        """Async mode with target_reuse: hold the next solve until the draws so far have paid for the solves
        submitted (one batch ahead), so a solver faster than that leaves its core to training."""
        if self.mode != "async" or self.target_reuse is None or not len(self.res.eligible()):
            return False  # (nothing drawable: the loop is waiting, so solve regardless)
        paid = self.warmup + self.res.drawn / self.uses_per_solve
        return self.next_index >= paid + self.solve_batch

    def _insert(self, indices: np.ndarray, result: dict) -> None:
        t0 = time.perf_counter()
        # each index of the job once (the padding repeats them); on_blowup="skip" may have left some out
        _, first = np.unique(result["index"], return_index=True)
        rows = np.sort(first)
        self.skipped += len(indices) - len(rows)
        _bridge.warn_skipped(dict.fromkeys(result.get("skipped", ())))  # (a padded job repeats its lines)
        if len(rows):
            u = result["u"]
            # (rows is 0..m-1 unless a sample was skipped: then a slice, no copy of the solve batch)
            pick = slice(0, len(rows)) if rows[-1] == len(rows) - 1 else rows
            if isinstance(u, torch.Tensor):  # on JAX's device (DLPack): gathered there
                u = u[pick] if isinstance(pick, slice) else u[torch.as_tensor(pick, device=u.device)]
            else:  # numpy from a worker process (writable: torch wants that)
                u = torch.from_numpy(np.require(u[pick], requirements="W"))
            self.res.insert(u, torch.from_numpy(np.asarray(result["params"][rows])), result["index"][rows])
        self.drawn_since_insert = 0
        self.t_insert += time.perf_counter() - t0

    def _take_oldest(self) -> None:
        """Deterministic mode: wait for the oldest job and insert it."""
        indices, _params, future = self.pending.popleft()
        t0 = time.perf_counter()
        result = _solved(future, indices)
        self.t_wait += time.perf_counter() - t0
        self._insert(indices, result)
        self._fill_pipeline()

    def _collect(self, block: bool) -> None:
        """Async mode: move finished jobs to ``done`` (waiting for one if ``block``) and insert what fits."""
        if block and self.pending and not self.done:
            t0 = time.perf_counter()
            wait([f for _i, _p, f in self.pending], return_when=FIRST_COMPLETED)
            self.t_wait += time.perf_counter() - t0
        still = collections.deque()
        for job in self.pending:
            (self.done if job[2].done() else still).append(job)
        self.pending = still
        while self.done and self.res.room() >= len(self.done[0][0]):
            indices, _params, future = self.done.pop(0)
            self._insert(indices, _solved(future, indices))  # a failed solve (BlowUpError) is raised here
        self._fill_pipeline()

    def _exhausted(self) -> bool:
        return not self.pending and not self.done

    # --- drawing -----------------------------------------------------------------------------------
    def _want_insert(self) -> bool:
        """Deterministic schedule: warm-up, then one solve batch per solve_batch x uses_per_solve draws, or when stuck."""
        res = self.res
        if not self.pending or res.room() < len(self.pending[0][0]):
            return False
        if res.inserted < self.warmup:
            return True
        return self.drawn_since_insert >= self.solve_batch * self.uses_per_solve or not len(res.eligible())

    def _draw(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to k examples (slots, starts), waiting for solves as needed; empty when the budget is spent."""
        res = self.res
        ready = min(self.warmup, self.sim_budget or self.warmup)
        while True:
            if self.mode == "deterministic":
                while self._want_insert():
                    self._take_oldest()
                if res.inserted >= ready:
                    # never draw past the next scheduled insertion: the schedule fixes the sequence
                    until = self.solve_batch * self.uses_per_solve - self.drawn_since_insert
                    slots, starts = res.draw(min(k, until) if self.pending and until > 0 else k)
                    if len(slots):
                        self.drawn_since_insert += len(slots)
                        return slots, starts
                if self._exhausted():
                    return np.zeros(0, np.int64), np.zeros(0, np.int64)
                if self.pending and res.room() < len(self.pending[0][0]):
                    raise RuntimeError("deterministic reservoir stuck: no room and nothing drawable (a bug)")
                self._take_oldest()
            else:
                self._collect(block=False)
                if res.inserted >= ready:
                    slots, starts = res.draw(k)
                    if len(slots):
                        self.drawn_since_insert += len(slots)
                        return slots, starts
                if self._exhausted():
                    return np.zeros(0, np.int64), np.zeros(0, np.int64)
                self._collect(block=True)

    def __iter__(self):
        if get_worker_info() is not None:
            raise ValueError("ReservoirStream runs in the training process (num_workers=0): its producers "
                             "(producer='process' or 'dask') are the parallelism")
        self._start()
        return self._batches()

    def _batches(self):
        while True:
            # each part is gathered as soon as it is drawn: the next _draw may insert a solve batch, which evicts
            # used trajectories, those of this very batch among them (gathering at the end read the newcomers)
            parts, got = [], 0
            while got < self.batch_size:
                s, w = self._draw(self.batch_size - got)
                if not len(s):
                    break
                parts.append((self._gather(s, w), s, self.res.serial[s].copy(), self.res.params_host[s]))
                got += len(s)
            if not got:
                return
            batch = parts[0][0] if len(parts) == 1 else {k: torch.cat([p[0][k] for p in parts]) for k in parts[0][0]}
            slots, serial = np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])
            self._drawn = (batch["params"], slots, serial)
            if self._where.type != "cpu":  # the host's copy of the batch's parameters, for report_losses
                self._last = (batch["params"], torch.from_numpy(np.concatenate([p[3] for p in parts])))
            self.progress.add(0, 1)
            yield batch

    def _gather(self, slots: np.ndarray, starts: np.ndarray) -> dict:
        """The examples (slots [m], window starts [m]) as a batch, gathered where the storage is: on a GPU the
        m pairs go over in one pinned, asynchronous copy and nothing waits for the device (a later insert is
        queued behind the gather on the same stream)."""
        t0 = time.perf_counter()
        res, host = self.res, torch.from_numpy(np.stack([slots, starts]))
        sel = host if self._where.type == "cpu" else host.pin_memory().to(self._where, non_blocking=True)
        batch = gather(self.view, res.u, self._t_dev, res.params, res.index_t, sel[0], sel[1])
        self.t_gather += time.perf_counter() - t0
        return batch

    # --- the training loop's hooks ------------------------------------------------------------------
    def report_losses(self, batch: dict, per_example: torch.Tensor) -> None:
        """Per-example training losses [B] of ``batch`` (the loop calls this after each step): they steer
        ``proposal="loss"`` and ``"active"`` and feed the loss-over-domain plot in any mode."""
        params = batch["params"]
        if self._last is not None and params is self._last[0]:
            params = self._last[1]  # the same values, from the host: no wait for the device
        losses = per_example.detach().cpu().numpy()
        self.proposal.record(params.detach().cpu().numpy(), losses)
        if self.draw == "priority":
            self._prioritize(batch, losses)

    def _prioritize(self, batch: dict, losses: np.ndarray) -> None:
        """Draw "priority": the batch's per-example losses [B] become its trajectories' priorities; a trajectory
        evicted since the batch was drawn is left alone (its slot holds another one now)."""
        res = self.res
        if self._drawn is not None and batch["params"] is self._drawn[0]:
            slots, serial = self._drawn[1], self._drawn[2]
            ok = res.serial[slots] == serial
        else:  # a batch other than the last one drawn: find its trajectories by index
            index = batch["index"].detach().cpu().numpy()
            live = res.live()
            where = {int(i): s for i, s in zip(res.index[live], live)}
            slots = np.array([where.get(int(i), -1) for i in index], np.int64)
            ok = slots >= 0
        if len(losses) == len(slots):
            res.set_priority(slots[ok], losses[ok])

    def stats(self) -> dict:
        """Reservoir figures for metrics.csv and the progress bar (flat dict of numbers)."""
        res = self.res
        counts = res.use_counts()  # [cap_uses + 1]: reuse statistics without listing every trajectory
        total, used = int(counts.sum()), np.flatnonzero(counts)
        elapsed = max(self._elapsed(), 1e-9)
        return {"inserted": res.inserted, "evicted": res.evicted, "held": len(res.live()),
                "reuse_mean": float(counts @ np.arange(len(counts))) / total / self.per_trajectory if total else 0.0,
                "reuse_max": float(used[-1]) / self.per_trajectory if total else 0.0,
                "solver_traj_per_s": res.inserted / elapsed, "examples_per_s": res.drawn / elapsed,
                "wait_share": self.t_wait / elapsed, "skipped": self.skipped}

    def report(self) -> dict:
        """What a run saves about its data: stats, reuse of every trajectory (1 = one FIFO pass), and where
        the simulations went against the training loss along the first random parameter."""
        random = self.proposal.random
        return {"stats": self.stats(), "reuse": self.res.reuse(self.per_trajectory).tolist(),
                "proposal": self.proposal.mode, "density": self.proposal.density(),
                "param": random[0] if random else None,
                "domain": self.proposal.domains[random[0]] if random else None}

    def _elapsed(self) -> float:
        return 0.0 if self._t_first is None else time.perf_counter() - self._t_first

    # --- state ---------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Where the stream stands: held trajectories (index, params, uses), jobs submitted, generator
        states, proposal. Plain values only. Exact for mode="deterministic"; async resumes approximately."""
        res = self.res
        live = res.live()
        jobs = [(i, p) for i, p, _f in self.pending] + [(i, p) for i, p, _f in self.done]
        return {
            "kind": "reservoir", "seed": self.seed, "config_hash": self.pde.config_hash(), "mode": self.mode,
            "capacity": self.capacity, "max_reuse": self.max_reuse, "view": self.view.name,
            "n_windows": self.n_windows,
            "slots": live.tolist(), "index": res.index[live].tolist(),
            "params": res.params_host[live].tolist() if res.params is not None else [],
            "uses": res.uses[live].tolist(), "window_uses": res.window_uses[live].tolist(),
            "priority": res.priority[live].tolist(),
            "serial": res.serial[live].tolist(),
            "counters": {"next_serial": res.next_serial, "inserted": res.inserted, "evicted": res.evicted,
                         "drawn": res.drawn, "next_index": self.next_index,
                         "drawn_since_insert": self.drawn_since_insert, "batches": self.progress.consumed(0)},
            "evicted_counts": res.evicted_counts.tolist(),
            "rng": _plain(res.rng.bit_generator.state),
            "jobs": [{"indices": i.tolist(), "params": None if p is None else {k: np.asarray(v).tolist() for k, v in p.items()}}
                     for i, p in jobs],
            "proposal": self.proposal.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        """Resume from ``state_dict()``: re-solve the held trajectories (bit-identical: sample identity),
        restore counts and generators, and queue the jobs that were in flight."""
        if state.get("kind") != "reservoir":
            raise ValueError("not a reservoir state (was it saved from a TrajectoryStream?)")
        mine = {"seed": self.seed, "config_hash": self.pde.config_hash(), "mode": self.mode, "capacity": self.capacity,
                "max_reuse": self.max_reuse, "view": self.view.name, "n_windows": self.n_windows}
        for key, value in mine.items():
            # states saved before capacity, max_reuse, view and n_windows were recorded are not compared on them
            if (key in state or key in ("seed", "config_hash", "mode")) and state.get(key) != value:
                raise ValueError(f"reservoir state has {key}={state.get(key)!r} but this stream has {key}={value!r}")
        self._check_state(state)
        try:  # the proposal's part, on a scratch copy: a damaged one is refused before anything changes
            copy.deepcopy(self.proposal).load_state_dict(state["proposal"])
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"reservoir state: its proposal entry is damaged ({type(err).__name__}: {err})") from None
        self.close()
        self._reset_state()
        res = self.res
        slots = np.asarray(state["slots"], np.int64)
        if len(slots):
            names = list(self.pde.PARAMS)
            params = np.asarray(state["params"], np.float32).reshape(len(slots), len(names))
            index = np.asarray(state["index"], np.int64)
            res.index[slots] = index
            for lo in range(0, len(slots), self.solve_batch):
                sel = np.arange(lo, min(lo + self.solve_batch, len(slots)))
                pad = np.resize(sel, self.solve_batch)
                out = _bridge.solve_job(self.config, self.seed, index[pad],
                                        {n: params[pad, j] for j, n in enumerate(names)}, on_device=True)
                res.put(slots[sel], out["u"][: len(sel)], torch.from_numpy(out["params"][: len(sel)]))
            res.uses[slots] = state["uses"]
            res.window_uses[slots] = np.asarray(state["window_uses"], np.int64).reshape(len(slots), -1)
            res.serial[slots] = state["serial"]
            # (states saved before draw "priority" existed have none: every priority 1)
            res.priority[slots] = np.asarray(state.get("priority", np.ones(len(slots))), np.float64)
        c = state["counters"]
        res.next_serial, res.inserted, res.evicted, res.drawn = c["next_serial"], c["inserted"], c["evicted"], c["drawn"]
        self.next_index, self.drawn_since_insert = c["next_index"], c["drawn_since_insert"]
        self.progress.restore(0, [c["batches"]])
        res.evicted_counts = np.asarray(state["evicted_counts"], np.int64)
        res.rng.bit_generator.state = state["rng"]
        for job in state["jobs"]:
            params = None if job["params"] is None else {k: np.asarray(v, np.float64) for k, v in job["params"].items()}
            self.pending.append((np.asarray(job["indices"], np.int64), params, None))
        self.proposal.load_state_dict(state["proposal"])

    def _check_state(self, state: dict) -> None:
        """One line, before anything changes, for a state whose integers are out of range or whose lists
        disagree in length (a hand-edited or corrupted checkpoint); JSON/torch give Python ints of any size."""
        last = _bridge.max_index()

        def ints(name: str, values, low: int, high: int) -> np.ndarray:
            values = list(values) if isinstance(values, (list, tuple)) else [values]
            bad = [v for v in values if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not low <= v <= high]
            if bad:
                raise ValueError(f"reservoir state: {name} holds {_plain(bad[0])!r}; allowed: integers in [{low}, {high}]")
            return np.asarray(values, np.int64)

        try:
            n = len(ints("slots", state["slots"], 0, self.capacity - 1))
            if len(set(state["slots"])) != n:
                raise ValueError("reservoir state: slots repeat a slot")
            for name, high in (("index", last), ("uses", 2**62), ("serial", 2**62)):
                if len(ints(name, state[name], 0, high)) != n:
                    raise ValueError(f"reservoir state: {name} has {len(state[name])} entries for {n} slots")
            if len(ints("window_uses", np.ravel(state["window_uses"]).tolist(), 0, 2**62)) != n * self.n_windows:
                raise ValueError(f"reservoir state: window_uses has {np.size(state['window_uses'])} entries for {n} "
                                 f"slots of {self.n_windows} windows")
            for name, value in state["counters"].items():
                ints(f"counters.{name}", value, 0, last + 1 if name == "next_index" else 2**62)
            ints("evicted_counts", list(state["evicted_counts"]), 0, 2**62)
            if "priority" in state:
                priority = np.asarray(state["priority"], np.float64)
                if priority.shape != (n,) or not ((priority >= 1e-30) & (priority <= 1e30)).all():
                    raise ValueError(f"reservoir state: priority must be {n} numbers in [1e-30, 1e30], one per slot")
        except (KeyError, TypeError) as err:
            raise ValueError(f"reservoir state is incomplete or malformed ({type(err).__name__}: {err})") from None

    def normalization(self, n: int = 64):
        """Per-field mean/std from samples 0..n-1 of this seed (the same calibration as TrajectoryStream)."""
        from .normalize import compute_normalization

        return compute_normalization(self.pde, seed=self.seed, n=n, solve_batch=self.solve_batch)

    def close(self) -> None:
        """Stop the producers (a thread's job in flight stops at its next bounded call, worker processes end at
        once; stopped jobs are solved again on the next iteration); the stream can be iterated again afterwards."""
        if self._closer is not None:
            self.proposal.close()
            closer, self._closer, self._executor = self._closer, None, None
            self.pending = collections.deque((i, p, None) for i, p, _f in self.pending)
            closer.close()
            _OPEN.discard(self)

    def __getstate__(self):
        raise TypeError("a ReservoirStream holds live producers and is not pickled; use it with num_workers=0")

