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
- **pacing** (async mode, ``target_reuse``): the producer solves what training consumes at a reuse target R and
  holds its next job otherwise (``reservoir_pacer``, whose docstring states the rule): by default ("auto") R is
  the smallest reuse at which solving costs training at most 5% of its steps, from rates re-measured as the run
  goes (solve seconds per trajectory, step seconds, batch size, and how much a running solve slows a step);
  a number fixes R, None ("off") solves flat out. When nothing held is drawable (the loop would wait) it
  solves regardless. Pacing changes when jobs are submitted, never which samples they solve.
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
  sharp mode, over a uniform floor; ``proposal="generative"`` draws near the hardest fresh solves instead;
  ``"uniform"`` leaves the parameters to the solver's own draws.

- **device**: the trajectories live on the training device (``device=``; None: the model's, through the
  training loop's ``place`` hook), a thread producer's solves are copied in from JAX's buffer there (DLPack) and
  batches are gathered there; the bookkeeping above stays on the host, so drawing never waits for the GPU.

The parts (torchrl's replay-buffer seams), each with its own state: ``reservoir_storage`` (where trajectories
live: ``Storage``, ``TensorStorage``), ``reservoir_sampler`` (draws and the reuse bound: ``Sampler``),
``reservoir_writer`` (occupancy and eviction: ``Writer``), ``reservoir_store`` (``Reservoir``: the three
composed), ``reservoir_producer`` (``SolvePipeline``: solve jobs into the store) and ``reservoir_config``
(``ReservoirConfig``: the settings and their defaults, once). A saved state is the composition of the parts'.

``max_reuse=1``, ``capacity=solve_batch``, ``draw="least_used"`` and deterministic mode is the plain FIFO
stream. Sample identity is (PDE config, seed, index, params): samples are numbered 0, 1, 2, ... in
submission order, and batches carry "index" and "params" as every other source does.
"""

from __future__ import annotations

import atexit
import copy
import math
import time
import weakref
from dataclasses import replace

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from . import _bridge
from .progress import StreamPosition
from .proposal import ParamProposal
from .reservoir_config import DRAWS, EVICTIONS, MODES, PROPOSAL_SPACES, ReservoirConfig, _check_int
from .reservoir_pacer import Pacer
from .reservoir_producer import SolvePipeline
from .reservoir_storage import check_room, free_bytes, physical_memory, storage_device
from .reservoir_store import Reservoir, from_flat, ints
from .views import for_sample, make_view

__all__ = ["DRAWS", "EVICTIONS", "MODES", "Reservoir", "ReservoirConfig", "ReservoirStream", "check_room",
           "free_bytes", "storage_device"]
_OPEN: "weakref.WeakSet[ReservoirStream]" = weakref.WeakSet()
_COMPARED = ("seed", "config_hash", "mode", "capacity", "max_reuse", "view", "n_windows")  # a state's settings


@atexit.register
def _close_all() -> None:
    # a script may leave a stream open: let producers finish their job in flight instead of dying in JAX
    for stream in list(_OPEN):
        stream.close()


class ReservoirStream(IterableDataset):
    """Batches drawn from a training reservoir fed by solver producers; ``DataLoader(stream, batch_size=None)``.

    pde: generator PDE or catalog name; view (+ view keyword arguments) as for TrajectoryStream; batch_size:
    examples per batch; config: a ``ReservoirConfig`` (None: its defaults), whose settings may also be given
    as keyword arguments (they override it; see ``ReservoirConfig`` and the module docstring for each).
    on_blowup "skip": a failed sample is left out, one SkippedSamples warning line each, ``stats()["skipped"]``
    counts them (deterministic mode stays a pure function of the settings as long as the solver fails the same
    samples every time, which a timeout does not promise). device: where the trajectories are kept and batches
    gathered (None: the training device, which the training loop sets through ``place``, else the CPU): with
    the thread producer a solve on that GPU is copied in from JAX's buffer (DLPack, no host round trip), and
    every tensor of a batch is on that device. Batches are dicts as from the views, with "params" [B, P] and
    "index" [B]. The stream runs in the training process (num_workers=0); its producers are the parallelism.
    """

    def __init__(self, pde, seed: int = 0, view="next_step", batch_size: int = 32,
                 config: ReservoirConfig | None = None, **kwargs):
        names = ReservoirConfig.names()
        view_kwargs = {k: v for k, v in kwargs.items() if k not in names}
        given = replace(config or ReservoirConfig(), **{k: v for k, v in kwargs.items() if k in names})
        self.pde = _bridge.resolve_pde(pde)
        if view_kwargs and not isinstance(view, str):
            raise ValueError(f"view options {sorted(view_kwargs)} only go with a view name, not a view object")
        self.view = for_sample(make_view(view, **view_kwargs), self.pde.n_frames, len(self.pde.INPUTS))
        self.seed = _check_int("seed", seed, 0)
        self.batch_size = _check_int("batch_size", batch_size, 1)
        cfg = self.reservoir_config = given.checked(self.batch_size)
        self.capacity, self.max_reuse, self.solve_batch, self.warmup = cfg.capacity, cfg.max_reuse, cfg.solve_batch, \
            cfg.warmup_for()
        self.eviction, self.draw, self.mode = cfg.eviction, cfg.draw, cfg.mode
        self.priority_power, self.priority_floor = cfg.priority_power, cfg.priority_floor
        self.producer, self.workers, self.scheduler = cfg.producer, cfg.workers, cfg.scheduler
        self.on_blowup = _bridge.check_on_blowup(cfg.on_blowup)
        self.sim_budget, self.inflight, self.target_reuse = cfg.sim_budget, cfg.inflight, cfg.target_reuse
        n_frames = self.pde.n_frames
        self.n_windows = self.view.n_starts(n_frames) if hasattr(self.view, "n_starts") else 1
        self.per_trajectory = len(self.view.starts(n_frames, torch.Generator().manual_seed(0)))
        self.cap_uses = max(1, round(self.max_reuse * self.per_trajectory))
        # draws that pay for one solve batch: the deterministic schedule's step (the bound unless a number fixes
        # it: "auto" reads clocks, which the schedule must not), and a fixed target's pacing in async mode
        fixed = isinstance(self.target_reuse, float)
        self.uses_per_solve = max(1, round(self.target_reuse * self.per_trajectory)) if fixed else self.cap_uses
        self.pacer = Pacer(self.batch_size, self.per_trajectory, self.max_reuse, self.target_reuse)
        self._clock = time.perf_counter  # the host clock pacing reads (a test drives its own)
        self.config = self.pde.config()
        capacity = self.capacity
        need = capacity * n_frames * len(_bridge.sample_channels(self.pde)) * math.prod(self.pde.grid.shape) * 4
        self.need = need + capacity * (4 * len(self.pde.PARAMS) + 8)  # u, params, index on the device
        self.device = None if cfg.device is None else storage_device(cfg.device)
        have = physical_memory()
        if have and need > have // 2 and (self.device is None or self.device.type == "cpu"):
            raise ValueError(f"capacity={capacity} not allowed: holding {capacity} trajectories takes "
                             f"{need / 2**30:.1f} GiB, more than half of this machine's {have / 2**30:.1f} GiB")
        self._where = torch.device("cpu") if self.device is None else self.device  # where the storage goes
        check_room(self._where, self.need, f"capacity={capacity} ({capacity} trajectories)")
        kwargs = dict(cfg.proposal_kwargs or {})
        self.proposal_space = kwargs.pop("space", "params")
        self.proposal = ParamProposal(_bridge.param_domains(self.pde), mode=cfg.proposal, seed=self.seed,
                                      latent_prior=self._latent_prior(cfg.proposal), **kwargs)
        self.t = torch.from_numpy(np.asarray(self.pde.times()))
        self._t_dev = self.t.to(self._where)
        self._last = None  # (the last batch's params tensor, its host copy): report_losses reads no device
        self._reset_state()

    def _latent_prior(self, proposal: str):
        """The IC latent's law for a joint proposal (proposal_space "params+ic"), None for "params"; one line for an
        unknown space, for "params+ic" with a uniform proposal (nothing steers) or on an IC without a latent."""
        space = self.proposal_space
        if space not in PROPOSAL_SPACES:
            raise ValueError(f"proposal space={space!r} not allowed; allowed: {', '.join(PROPOSAL_SPACES)}")
        if space == "params":
            return None
        if proposal == "uniform":
            raise ValueError("proposal space='params+ic' goes with proposal 'loss', 'active' or 'generative' (a uniform proposal "
                             "steers nothing)")
        if not _bridge.latent_size(self.pde):
            raise ValueError(f"proposal space='params+ic' not allowed on {self.pde.NAME}: its ic "
                             f"({getattr(self.pde, 'ic', None)}) has no latent coordinates; allowed: 'params'")
        return _bridge.latent_prior(self.pde)

    def _reset_state(self) -> None:
        factory = self.reservoir_config.storage
        self.res = Reservoir(self.capacity, self.cap_uses, self.n_windows, self.eviction, self.draw,
                             np.random.default_rng([self.seed, 1]), self._where, self.priority_power,
                             self.priority_floor, storage=None if factory is None else factory(self.capacity, self._where))
        self.pipeline = SolvePipeline(self.config, self.seed, self.solve_batch, self.producer, self.workers,
                                      self.scheduler, self.inflight, self.on_blowup, self.sim_budget,
                                      propose=self.proposal.propose, sample_indices=self._sample_indices,
                                      paced=self._paced, clock=lambda: self._clock(), pacer=self.pacer)
        self._paid, self._paid_drawn = float(self.warmup), 0  # pacing: trajectories the draws so far paid for
        self._drawn = None  # (the last batch's params tensor, its slots, their serials, first draws?, sample indices)
        self.drawn_since_insert = 0
        self.progress = StreamPosition(slots=1)  # batches handed out (one producer-side "worker": this process)
        self.t_gather = 0.0  # seconds spent gathering batches (host clock)
        self._t_first = None  # when iteration started (rates in stats())

    # the producer pipeline's figures, under the stream's names
    t_wait = property(lambda self: self.pipeline.t_wait)  # seconds the loop waited for solves
    t_insert = property(lambda self: self.pipeline.t_insert)  # seconds spent inserting solves
    skipped = property(lambda self: self.pipeline.skipped)  # samples left out by on_blowup="skip"
    _executor = property(lambda self: self.pipeline.executor)

    @property
    def next_index(self) -> int:
        """The next submission's position (its sample indices: ``_sample_indices``)."""
        return self.pipeline.next_index

    @next_index.setter
    def next_index(self, value: int) -> None:
        self.pipeline.next_index = value

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
        if not self.pipeline.open:
            self.pipeline.open_producer()
            _OPEN.add(self)
        if self._t_first is None:
            self._t_first = time.perf_counter()
        self.pipeline.start()  # jobs restored by load_state_dict (or stopped by close) first, in their order

    def _sample_indices(self, first: int, n: int) -> np.ndarray:
        """Global sample indices of this stream's submissions first .. first + n - 1: int64 [n], 0, 1, 2, ...
        here (a DDP rank's stream, ``datasets.ranks.RankReservoirStream``, takes every world_size-th)."""
        return np.arange(first, first + n, dtype=np.int64)

    def _paced(self) -> bool:
        """Async mode with a reuse target (``reservoir_pacer``'s rule): hold the next solve until the draws so far
        have paid for the solves submitted (one batch ahead): warmup + the uses drawn, each at the target R in
        force when it was drawn, / R, and during the pacer's probes. A solver faster than that leaves its core to
        training."""
        if self.mode != "async" or self.target_reuse is None:
            return False
        r = self.pacer.target()
        uses = self.uses_per_solve if isinstance(self.target_reuse, float) else r * self.per_trajectory
        drawn = self.res.drawn
        self._paid += (drawn - self._paid_drawn) / uses
        self._paid_drawn = drawn
        if not len(self.res.eligible()):
            return False  # (nothing drawable: the loop is waiting, so solve regardless)
        ahead = self.next_index >= self._paid  # (a producer behind the draws is the bottleneck: no probe holds it)
        return self.next_index >= self._paid + self.solve_batch or (ahead and self.pacer.probing())

    def _step_done(self, busy: bool, t0: float) -> None:
        """The training step between a batch handed out at ``t0`` and now, for pacing: its seconds and the share
        of them a solve ran (no job is submitted during a step: one running at its start ran until ``last_done``
        or throughout)."""
        t1 = self._clock()
        if t1 <= t0:
            return
        pipe = self.pipeline
        if not busy:
            share = 0.0 if not pipe.busy() else None
        else:
            share = 1.0 if pipe.busy() else min(max((pipe.last_done - t0) / (t1 - t0), 0.0), 1.0)
        if share is not None:
            self.pacer.step(t1 - t0, share)

    def _take_oldest(self) -> None:
        self.pipeline.take_oldest(self.res)
        self.drawn_since_insert = 0

    def _collect(self, block: bool) -> None:
        if self.pipeline.collect(self.res, block):
            self.drawn_since_insert = 0

    # --- drawing -----------------------------------------------------------------------------------
    def _want_insert(self) -> bool:
        """Deterministic schedule: warm-up, then one solve batch per solve_batch x uses_per_solve draws, or when stuck."""
        res, size = self.res, self.pipeline.next_size()
        if size is None or res.room() < size:
            return False
        if res.inserted < self.warmup:
            return True
        return self.drawn_since_insert >= self.solve_batch * self.uses_per_solve or not len(res.eligible())

    def _draw(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to k examples (slots, starts), waiting for solves as needed; empty when the budget is spent."""
        res, pipe = self.res, self.pipeline
        ready = min(self.warmup, self.sim_budget or self.warmup)
        while True:
            if self.mode == "deterministic":
                while self._want_insert():
                    self._take_oldest()
                if res.inserted >= ready:
                    # never draw past the next scheduled insertion: the schedule fixes the sequence
                    until = self.solve_batch * self.uses_per_solve - self.drawn_since_insert
                    slots, starts = res.draw(min(k, until) if pipe.pending and until > 0 else k)
                    if len(slots):
                        self.drawn_since_insert += len(slots)
                        return slots, starts
                if pipe.exhausted():
                    return np.zeros(0, np.int64), np.zeros(0, np.int64)
                if pipe.pending and res.room() < pipe.next_size():
                    raise RuntimeError("deterministic reservoir stuck: no room and nothing drawable (a bug)")
                self._take_oldest()
            else:
                self._collect(block=False)
                if res.inserted >= ready:
                    slots, starts = res.draw(k)
                    if len(slots):
                        self.drawn_since_insert += len(slots)
                        return slots, starts
                if pipe.exhausted():
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
                # fresh: the trajectory's first draw (its loss, reported after the step, measures the proposal's
                # skill before the proposal has seen it)
                parts.append((self._gather(s, w), s, self.res.serial[s].copy(), self.res.params_host[s],
                              self.res.uses[s] == 1, self.res.latent_of(s)))
                got += len(s)
            if not got:
                return
            batch = parts[0][0] if len(parts) == 1 else {k: torch.cat([p[0][k] for p in parts]) for k in parts[0][0]}
            slots, serial = np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])
            # (the IC latents of a joint proposal's samples, read now: a later insert may evict these slots)
            latent = None if parts[0][5] is None else np.concatenate([p[5] for p in parts])
            self._drawn = (batch["params"], slots, serial, np.concatenate([p[4] for p in parts]),
                           self.res.index[slots].copy(), latent)
            if self._where.type != "cpu":  # the host's copy of the batch's parameters, for report_losses
                self._last = (batch["params"], torch.from_numpy(np.concatenate([p[3] for p in parts])))
            self.progress.add(0, 1)
            busy, t0 = self.pipeline.busy(), self._clock()
            yield batch
            self._step_done(busy, t0)

    def _gather(self, slots: np.ndarray, starts: np.ndarray) -> dict:
        """The examples (slots [m], window starts [m]) as a batch, gathered where the storage is
        (``Storage.gather``: on a GPU nothing waits for the device)."""
        t0 = time.perf_counter()
        batch = self.res.storage.gather(self.view, self._t_dev, slots, starts)
        self.t_gather += time.perf_counter() - t0
        return batch

    # --- the training loop's hooks ------------------------------------------------------------------
    def report_losses(self, batch: dict, per_example: torch.Tensor) -> None:
        """Per-example training losses [B] of ``batch`` (the loop calls this after each step): they steer
        ``proposal="loss"``, ``"active"`` and ``"generative"`` and feed the loss-over-domain plot in any mode."""
        params = batch["params"]
        if self._last is not None and params is self._last[0]:
            params = self._last[1]  # the same values, from the host: no wait for the device
        losses = per_example.detach().cpu().numpy()
        # which rows are first draws (the proposal's skill gate scores those): known for the batch last drawn (the
        # same tensor, or a copy moved to the model's device: the same sample indices); any other batch has none
        fresh, latent, index = np.zeros(len(losses), bool), None, None  # (latent: a joint proposal's; unknown rows are dropped)
        if self._drawn is not None and len(self._drawn[3]) == len(losses):
            if batch["params"] is self._drawn[0] or np.array_equal(batch["index"].detach().cpu().numpy(), self._drawn[4]):
                fresh, latent, index = self._drawn[3], self._drawn[5], self._drawn[4]
        self.proposal.record(params.detach().cpu().numpy(), losses, fresh=fresh, latent=latent, indices=index)
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
        pace = self.pacer.stats()
        if self.mode == "deterministic":  # the schedule's reuse per solve, whatever the clocks say
            pace["target_reuse"] = self.uses_per_solve / self.per_trajectory
        elif self.target_reuse is None:
            pace["target_reuse"] = float("nan")  # off: flat out
        # the producer's idle time: its slots' time since the first batch less the solving they did
        idle = max(0.0, elapsed * self.pipeline.slots - self.pacer.solve_s)
        return {"inserted": res.inserted, "evicted": res.evicted, "held": len(res.live()),
                "reuse_mean": float(counts @ np.arange(len(counts))) / total / self.per_trajectory if total else 0.0,
                "reuse_max": float(used[-1]) / self.per_trajectory if total else 0.0,
                "solver_traj_per_s": res.inserted / elapsed, "examples_per_s": res.drawn / elapsed,
                "wait_share": self.t_wait / elapsed, "skipped": self.skipped, **pace, "producer_idle_s": idle,
                "producer_idle_share": idle / (elapsed * self.pipeline.slots),
                **({"proposal_skill": self.proposal.skill, "proposal_steer": self.proposal.steer,
                    "proposal_lift": self._lift(0), "proposal_lift_high": self._lift(1)}
                   if self.proposal.mode != "uniform" else {})}

    def _lift(self, end: int) -> float:
        """The lift's lower (end 0) or upper (1) bound (``datasets.proposal_lift``; log-loss units), NaN while it is
        not measured."""
        bounds = self.proposal.lift.bounds()
        return float("nan") if bounds is None else bounds[end]

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
        """Where the stream stands, plain values only, as the composition of its parts' states: {"kind",
        "layout": 2, the settings a resume must share, "reservoir": the store's (``Reservoir.state_dict``: held
        slots, storage, writer, sampler, generator), "producer": the pipeline's (next index, jobs in flight),
        "schedule": {"drawn_since_insert", "batches"}, "proposal", "latent_twins"}. Exact for mode="deterministic"; async
        resumes approximately."""
        return {"kind": "reservoir", "layout": 2, "seed": self.seed, "config_hash": self.pde.config_hash(),
                "mode": self.mode, "capacity": self.capacity, "max_reuse": self.max_reuse, "view": self.view.name,
                "n_windows": self.n_windows, "reservoir": self.res.state_dict(), "producer": self.pipeline.state_dict(),
                "schedule": {"drawn_since_insert": self.drawn_since_insert, "batches": self.progress.consumed(0)},
                "proposal": self.proposal.state_dict(), "latent_twins": True}

    def load_state_dict(self, state: dict) -> None:
        """Resume from ``state_dict()`` (or the flat layout saved before the parts: ``reservoir_store.from_flat``):
        re-solve the held trajectories (bit-identical: sample identity), restore counts and generators, and
        queue the jobs that were in flight. A damaged state is refused in one line before anything changes."""
        if not isinstance(state, dict) or state.get("kind") != "reservoir":
            raise ValueError("not a reservoir state (was it saved from a TrajectoryStream?)")
        mine = {"seed": self.seed, "config_hash": self.pde.config_hash(), "mode": self.mode, "capacity": self.capacity,
                "max_reuse": self.max_reuse, "view": self.view.name, "n_windows": self.n_windows}
        for key in _COMPARED:
            # states saved before capacity, max_reuse, view and n_windows were recorded are not compared on them
            if (key in state or key in ("seed", "config_hash", "mode")) and state.get(key) != mine[key]:
                raise ValueError(f"reservoir state has {key}={state.get(key)!r} but this stream has {key}={mine[key]!r}")
        if self.proposal.n_latent and self.pde.NDIM > 1 and not state.get("latent_twins"):
            # its held trajectories' IC latents, re-solved now, would be read with another layout (generator.ics)
            raise ValueError("reservoir state saved before a 2D / 3D IC latent paired its conjugate twins (stop 52): "
                             "its latents now give other initial conditions; start a new run")
        try:
            if "layout" not in state:
                state = from_flat(state)
            self.res.check_state(state["reservoir"], _bridge.max_index())
            self.pipeline.check_state(state["producer"], ints)
            for name in ("drawn_since_insert", "batches"):
                ints(f"schedule.{name}", state["schedule"][name], 0, 2**62)
        except (KeyError, TypeError) as err:
            raise ValueError(f"reservoir state is incomplete or malformed ({type(err).__name__}: {err})") from None
        try:  # the proposal's part, on a scratch copy: a damaged one is refused before anything changes
            copy.deepcopy(self.proposal).load_state_dict(state["proposal"])
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"reservoir state: its proposal entry is damaged ({type(err).__name__}: {err})") from None
        self.close()
        self._reset_state()
        names = list(self.pde.PARAMS)
        self.res.load_state_dict(state["reservoir"], lambda slots, index, params, latent=None: self.pipeline.refill(
            self.res, slots, index, params, names, latent))
        self.pipeline.load_state_dict(state["producer"])
        self.drawn_since_insert = state["schedule"]["drawn_since_insert"]
        self.progress.restore(0, [state["schedule"]["batches"]])
        self.proposal.load_state_dict(state["proposal"])

    def normalization(self, n: int = 64):
        """Per-field mean/std from samples 0..n-1 of this seed (the same calibration as TrajectoryStream)."""
        from .normalize import compute_normalization

        return compute_normalization(self.pde, seed=self.seed, n=n, solve_batch=self.solve_batch)

    def close(self) -> None:
        """Stop the producers (a thread's job in flight stops at its next bounded call, worker processes end at
        once; stopped jobs are solved again on the next iteration); the stream can be iterated again afterwards."""
        if self.pipeline.open:
            self.proposal.close()
            self.pipeline.close()
            _OPEN.discard(self)

    def __getstate__(self):
        raise TypeError("a ReservoirStream holds live producers and is not pickled; use it with num_workers=0")
