"""The training reservoir's producer pipeline: solve jobs from submission to the store.

``SolvePipeline`` opens a producer (``datasets.producers``: a thread, spawned processes or a Dask cluster),
submits jobs of ``solve_batch`` samples ahead (numbered by ``sample_indices``, parameters from ``propose``),
and inserts finished ones into a ``Reservoir``: in submission order (``take_oldest``, the deterministic
schedule) or as they finish, when there is room (``collect``, async). Its state is where submission stands:
the next sample index and the jobs in flight (re-submitted on resume). It tells the stream's pacing
(``reservoir_pacer.Pacer``, ``pacer``) what each job cost, and whether a solve is running (``busy``, ``last_done``).
"""

from __future__ import annotations

import collections
import math
import time
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, wait

import numpy as np
import torch

from . import _bridge
from .producers import open_producer


def _solved(future, indices: np.ndarray) -> dict:
    """A solve job's result; a producer process that died under it (killed, out of memory) is one line naming the
    samples, not concurrent.futures' BrokenProcessPool traceback (the pool cannot run anything after that)."""
    try:
        return future.result()
    except BrokenExecutor:
        raise ValueError(f"a solver process of the reservoir's producer died (killed, or out of memory) while "
                         f"solving samples {int(indices[0])}..{int(indices[-1])}; the stream stops (a run goes "
                         "on with --resume from its last checkpoint)") from None


class SolvePipeline:
    """Solve jobs in flight between a producer and the store.

    config, seed: the PDE's config and the stream's seed (sample identity); solve_batch: samples per job (every
    job padded to it: one compiled shape); producer, workers, scheduler: ``open_producer``'s; inflight: jobs
    submitted ahead (None: 2 per producer slot); on_blowup: the solver's rule for a failed sample; sim_budget:
    samples to solve in all (None: endless); propose(n, indices) -> params dict or None (indices: the n samples' [n]); sample_indices(first, n) ->
    int64 [n]; paced() -> True to hold the next submission back; clock: the host clock the stream reads (the time a
    job finished, ``last_done``, is on it); pacer: told each job's solve seconds and insertion seconds (None: none).
    """

    def __init__(self, config: dict, seed: int, solve_batch: int, producer: str, workers: int, scheduler,
                 inflight: int | None, on_blowup: str, sim_budget: int | None, propose, sample_indices, paced,
                 clock=time.perf_counter, pacer=None):
        self.config, self.seed, self.solve_batch = config, seed, solve_batch
        self.producer, self.workers, self.scheduler, self.inflight = producer, workers, scheduler, inflight
        self.on_blowup, self.sim_budget = on_blowup, sim_budget
        self.propose, self.sample_indices, self.paced = propose, sample_indices, paced
        self.next_index = 0  # the next submission's position (sample_indices maps it to sample indices)
        self.pending: collections.deque = collections.deque()  # (indices, params, future) in submission order
        self.done: list = []  # async: finished jobs waiting for room
        self.t_wait = self.t_insert = 0.0  # seconds waiting for solves, and inserting them (host clock)
        self.skipped = 0  # samples left out by on_blowup="skip"
        self.executor = self._closer = None
        self.clock, self.pacer = clock, pacer
        self.slots = 1  # jobs the producer runs at once
        self.last_done = -math.inf  # when (clock) a job last finished

    @property
    def open(self) -> bool:
        return self.executor is not None

    def open_producer(self) -> None:
        """Open the producer, once (one line for a bad producer name)."""
        if self.executor is None:
            self.executor, self._closer, slots = open_producer(self.producer, self.workers, self.scheduler)
            self.max_inflight, self.slots = self.inflight or 2 * slots, slots

    def start(self) -> None:
        """Open the producer (once) and submit: the jobs restored or stopped, in their order, then new ones."""
        self.open_producer()
        self.pending = collections.deque((i, p, self._submit(i, p) if f is None else f) for i, p, f in self.pending)
        self.fill()

    def _submit(self, indices: np.ndarray, params: dict | None):
        """One solve job, padded to solve_batch (one compiled shape for every job)."""
        pad = np.resize(np.arange(len(indices)), self.solve_batch)
        padded_params = None if params is None else {k: np.asarray(v)[pad] for k, v in params.items()}
        # a thread solves in this process: its result stays in JAX's buffer (on its device) and is copied into
        # the storage from there; a worker process's or Dask's comes back as numpy (pickled)
        future = self.executor.submit(_bridge.solve_job, self.config, self.seed, indices[pad], padded_params,
                                      self.on_blowup, self.producer == "thread")
        future.add_done_callback(self._finished)
        return future

    def _finished(self, _future) -> None:
        # (in the thread that finished it: this process's clock whatever ran the job)
        self.last_done = max(self.last_done, self.clock())

    def busy(self) -> bool:
        """A job submitted and not finished (the producer is solving, or about to)."""
        return any(f is not None and not f.done() for _i, _p, f in self.pending)

    def fill(self) -> None:
        """Submit new jobs up to ``max_inflight`` in flight, within the simulation budget and the pacing."""
        while len(self.pending) + len(self.done) < self.max_inflight:
            budget = self.solve_batch if self.sim_budget is None else min(self.solve_batch, self.sim_budget - self.next_index)
            if budget <= 0 or self.paced():
                return
            indices = self.sample_indices(self.next_index, budget)
            params = self.propose(budget, indices)
            self.next_index += budget
            self.pending.append((indices, params, self._submit(indices, params)))

    def exhausted(self) -> bool:
        """Nothing in flight and nothing waiting: the simulation budget is spent."""
        return not self.pending and not self.done

    def next_size(self) -> int | None:
        """Samples in the oldest job in flight (None: none)."""
        return len(self.pending[0][0]) if self.pending else None

    def _insert(self, res, indices: np.ndarray, result: dict) -> None:
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
            latent = result.get("latent")
            res.insert(u, torch.from_numpy(np.asarray(result["params"][rows])), result["index"][rows],
                       None if latent is None else latent[rows])
        spent = time.perf_counter() - t0
        self.t_insert += spent
        if self.pacer is not None:
            self.pacer.solved(len(indices), result.get("seconds", -1.0))
            self.pacer.inserted(len(rows), spent)

    def take_oldest(self, res) -> None:
        """Deterministic mode: wait for the oldest job and insert it into ``res``."""
        indices, _params, future = self.pending.popleft()
        t0 = time.perf_counter()
        result = _solved(future, indices)
        self.t_wait += time.perf_counter() - t0
        self._insert(res, indices, result)
        self.fill()

    def collect(self, res, block: bool) -> int:
        """Async mode: move finished jobs to ``done`` (waiting for one if ``block``) and insert into ``res`` what
        fits; returns the number of jobs inserted."""
        if block and self.pending and not self.done:
            t0 = time.perf_counter()
            wait([f for _i, _p, f in self.pending], return_when=FIRST_COMPLETED)
            self.t_wait += time.perf_counter() - t0
        still, n = collections.deque(), 0
        for job in self.pending:
            (self.done if job[2].done() else still).append(job)
        self.pending = still
        while self.done and res.room() >= len(self.done[0][0]):
            indices, _params, future = self.done.pop(0)
            self._insert(res, indices, _solved(future, indices))  # a failed solve (BlowUpError) is raised here
            n += 1
        self.fill()
        return n

    def refill(self, res, slots: np.ndarray, index: np.ndarray, params, names: list, latent=None) -> None:
        """Solve the samples ``index`` [n] (params [n][P], in ``names`` order; latent: their IC latents [n, L], NaN
        rows the key's, or None) again, here and now, into ``slots`` [n] of the store ``res``: bit-identical to what
        was held (sample identity)."""
        params = np.asarray(params, np.float32).reshape(len(slots), len(names))
        for lo in range(0, len(slots), self.solve_batch):
            sel = np.arange(lo, min(lo + self.solve_batch, len(slots)))
            pad = np.resize(sel, self.solve_batch)
            given = {n: params[pad, j] for j, n in enumerate(names)}
            if latent is not None:
                given[_bridge.LATENT] = latent[pad]
            out = _bridge.solve_job(self.config, self.seed, index[pad], given, on_device=True)
            res.storage.put(slots[sel], out["u"][: len(sel)], torch.from_numpy(out["params"][: len(sel)]), index[sel])
            res.set_latent(slots[sel], None if latent is None else latent[sel])

    def close(self) -> None:
        """Stop the producer (a thread's job in flight stops at its next bounded call, worker processes end at
        once); the jobs in flight are submitted again by the next ``start``."""
        if self._closer is not None:
            closer, self._closer, self.executor = self._closer, None, None
            self.pending = collections.deque((i, p, None) for i, p, _f in self.pending)
            closer.close()

    # --- state -----------------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """{"next_index", "jobs": the jobs submitted and not inserted, in order: indices and params}."""
        jobs = [(i, p) for i, p, _f in self.pending] + [(i, p) for i, p, _f in self.done]
        return {"next_index": self.next_index,
                "jobs": [{"indices": i.tolist(),
                          "params": None if p is None else {k: np.asarray(v).tolist() for k, v in p.items()}}
                         for i, p in jobs]}

    def check_state(self, state: dict, ints) -> None:
        ints("producer.next_index", state["next_index"], 0, _bridge.max_index() + 1)
        for job in state["jobs"]:
            ints("producer.jobs.indices", job["indices"], 0, _bridge.max_index())

    def load_state_dict(self, state: dict) -> None:
        """Resume submission: the next index, and the jobs queued (submitted by the next ``start``)."""
        self.next_index = state["next_index"]
        for job in state["jobs"]:
            params = None if job["params"] is None else {k: np.asarray(v, np.float64) for k, v in job["params"].items()}
            self.pending.append((np.asarray(job["indices"], np.int64), params, None))
