"""TrajectoryStream: the JAX sampler as a torch IterableDataset (no dataset on disk).

Sample identity is (PDE, seed, global index). Epoch e of a finite stream covers the indices
``e * n_samples + [0, n_samples)`` (``resample=False``: ``[0, n_samples)`` every epoch); an endless stream
counts 0, 1, 2, ... Shard ``rank * num_workers + worker_id`` takes every ``world_size * num_workers``-th
index, so workers and ranks together see each index once, whatever their number. A shard solves
``solve_batch`` trajectories at a time (one fixed shape: JAX compiles once), turns them into examples with
the view, shuffles them within that solve batch and yields collated batches of ``batch_size`` examples.
Random window starts and the shuffle are seeded from (seed, epoch, index), so a resumed run replays bits.

The position (epoch, examples consumed per worker) lives in a ``datasets.progress.StreamPosition`` in shared memory so
``set_epoch`` and ``load_state_dict`` reach persistent spawn workers; ``stream_loader`` builds the DataLoader
that keeps it.
"""

from __future__ import annotations

import ast
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info
from torch.utils.data.dataloader import _MultiProcessingDataLoaderIter

from . import _bridge
from ._prefetch import prefetch
from .progress import MAX_WORKERS, StreamPosition
from .views import for_sample, gather, make_view


def _int_arg(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name}={_plain(value)!r} not allowed; must be an integer >= {low}")
    return int(value)


def _plain(value):
    """A numpy scalar as the plain Python value, for messages (``seed 0``, not ``np.int64(0)``)."""
    return value.item() if isinstance(value, np.generic) else value


def _derived_seed(*words: int) -> int:
    """A 63-bit torch seed that is a pure function of the words (seed, epoch, index, purpose)."""
    return int(np.random.SeedSequence([int(w) for w in words]).generate_state(2, np.uint32).view(np.uint64)[0] >> 1)


class TrajectoryStream(IterableDataset):
    """Batches of training examples solved on demand; use as ``DataLoader(stream, batch_size=None)``.

    pde: generator PDE or catalog name; view: "whole" / "next_step" / "operator" or a view object (extra
    keyword arguments configure a named view, e.g. k_in=2, windows=4); batch_size: examples per batch;
    n_samples: trajectories per epoch (None: endless); solve_batch: trajectories per solver call;
    rank/world_size: default from torch.distributed when initialized; on_blowup: "raise", "redraw" or "skip"
    (a failed sample is left out with a SkippedSamples warning naming it: its examples are missing from the
    epoch, and a stream resumed from ``state_dict`` counts the examples consumed as if none were skipped, so a
    resume after a skip may repeat or miss a few examples of that solve batch).
    Batches are dicts of tensors as in ``datasets.views`` (e.g. next_step: x [B, k_in, C, *space],
    y [B, k_out, C, *space], t0 [B], params [B, P], index [B]).
    """

    def __init__(self, pde, seed: int = 0, view="next_step", batch_size: int = 32, n_samples: int | None = None,
                 solve_batch: int = 16, shuffle: bool = True, resample: bool = True, drop_last: bool = False,
                 rank: int | None = None, world_size: int | None = None, prefetch: bool = True,
                 on_blowup: str = "raise", **view_kwargs):
        self.pde = _bridge.resolve_pde(pde)
        if view_kwargs and not isinstance(view, str):
            raise ValueError(f"view options {sorted(view_kwargs)} only go with a view name, not a view object")
        self.view = for_sample(make_view(view, **view_kwargs), self.pde.n_frames, len(self.pde.INPUTS))
        self.seed = _int_arg("seed", seed, 0)
        self.batch_size = _int_arg("batch_size", batch_size, 1)
        self.solve_batch = _int_arg("solve_batch", solve_batch, 1)
        self.n_samples = None if n_samples is None else _int_arg("n_samples", n_samples, 1)
        if self.n_samples is not None and self.n_samples > _bridge.max_index() + 1:
            raise ValueError(f"n_samples={n_samples} exceeds the generator's index range ({_bridge.max_index() + 1})")
        if (rank is None) != (world_size is None):
            raise ValueError(f"give both rank and world_size or neither (got rank={rank}, world_size={world_size})")
        if world_size is not None:
            world_size = _int_arg("world_size", world_size, 1)
            if not (isinstance(rank, (int, np.integer)) and 0 <= rank < world_size):
                raise ValueError(f"rank={_plain(rank)!r} not allowed; must be in [0, {world_size})")
        self.rank, self.world_size = rank, world_size
        _bridge.check_on_blowup(on_blowup)
        self.on_blowup, self.shuffle, self.resample = on_blowup, bool(shuffle), bool(resample)
        self.drop_last, self.prefetch = bool(drop_last), bool(prefetch)
        self.per_trajectory = len(self.view.starts(self.pde.n_frames, torch.Generator()))
        self._progress = StreamPosition()  # epoch and examples consumed per worker, shared with spawn workers
        self.num_workers = 0  # set by stream_loader; how many consumed counts state_dict reports

    # --- placement -------------------------------------------------------------------------------
    def placement(self) -> tuple[int, int]:
        """(rank, world_size): explicit, else torch.distributed's when initialized, else (0, 1)."""
        if self.world_size is not None:
            return self.rank, self.world_size
        dist = torch.distributed
        if dist.is_available() and dist.is_initialized():
            return dist.get_rank(), dist.get_world_size()
        return 0, 1

    def _shard(self) -> tuple[int, int, int, int]:
        """(worker id, workers, shard, stride) of the calling process."""
        info = get_worker_info()
        wid, nw = (0, 1) if info is None else (info.id, info.num_workers)
        rank, world = self.placement()
        return wid, nw, rank * nw + wid, world * nw

    def _base(self, epoch: int) -> int:
        return epoch * self.n_samples if (self.n_samples is not None and self.resample) else 0

    def _shard_count(self, epoch: int, shard: int, stride: int) -> int:
        last = _bridge.max_index()
        total = self.n_samples if self.n_samples is not None else last + 1
        if self._base(epoch) + total - 1 > last:
            raise ValueError(f"epoch {epoch} with n_samples={self.n_samples} runs past sample index {last}")
        return max(0, -(-(total - shard) // stride))

    # --- epochs and state ------------------------------------------------------------------------
    def set_epoch(self, epoch: int) -> None:
        """Start epoch ``epoch`` from its beginning (reaches persistent workers through shared memory)."""
        self._progress.set_epoch(_int_arg("epoch", epoch, 0))

    @property
    def epoch(self) -> int:
        """The epoch the next iteration of this stream covers."""
        return self._progress.epoch

    def state_dict(self) -> dict:
        """Where the stream stands: epoch and examples consumed per worker (shard) of this rank."""
        rank, world = self.placement()
        info = get_worker_info()
        if info is None:
            epoch, consumed = self._progress.snapshot(max(1, self.num_workers))
        else:  # inside a worker: only this worker's progress (StatefulDataLoader merges them)
            epoch, consumed = self._progress.snapshot(info.num_workers, info.id)
        return {"seed": self.seed, "n_samples": self.n_samples, "rank": rank, "world_size": world,
                "epoch": epoch, "consumed": consumed}

    def load_state_dict(self, state: dict) -> None:
        """Resume from ``state_dict()`` output: the next batch is the one after the last consumed."""
        rank, world = self.placement()
        missing = [k for k in ("epoch", "consumed") if not isinstance(state, dict) or k not in state]
        if missing:
            raise ValueError(f"not a TrajectoryStream state (no {', '.join(missing)}); pass stream.state_dict() output")
        for key, mine in (("seed", self.seed), ("n_samples", self.n_samples), ("rank", rank), ("world_size", world)):
            if state.get(key) != mine:
                raise ValueError(f"state has {key}={_plain(state.get(key))!r} but this stream has {key}={mine!r}")
        if not isinstance(state["consumed"], (list, tuple)):
            raise ValueError(f"state has consumed={_plain(state['consumed'])!r}; must be a list of counts, one per worker")
        info = get_worker_info()
        if info is None:
            self._progress.restore(state["epoch"], state["consumed"])
        else:  # torchdata's StatefulDataLoader loads it inside each worker: for that worker's next iteration
            self._progress.restore(state["epoch"], state["consumed"], info.id, info.num_workers)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["rank"], state["world_size"] = self.placement()  # torch.distributed is not set up in workers
        return state  # StreamPosition pickles itself: a plain copy, or the shared memory for a spawning worker

    # --- iteration -------------------------------------------------------------------------------
    def __iter__(self):
        # A plain function (not a generator) so that the state is settled when iter() returns.
        wid, nw, shard, stride = self._shard()
        in_main = get_worker_info() is None
        if not in_main and not self._progress.unpickled:
            raise ValueError("TrajectoryStream in a forked DataLoader worker: JAX is not fork-safe; use "
                             "datasets.stream_loader(stream, num_workers=N) or multiprocessing_context='spawn'")
        epoch, skip = self._progress.start(wid, nw, share=in_main, num_workers=0 if in_main else nw)
        return self._batches(epoch, skip, shard, stride, wid, in_main)

    def _batches(self, epoch, skip, shard, stride, wid, in_main):
        count = self._shard_count(epoch, shard, stride)
        per_chunk = self.solve_batch * self.per_trajectory
        first, offset = divmod(skip, per_chunk)
        chunks = self._chunks(epoch, shard, stride, range(first, -(-count // self.solve_batch)), count)
        pieces, filled = [], 0
        try:
            for data, traj, start in chunks:
                traj, start, offset = traj[offset:], start[offset:], 0
                pos = 0
                while pos < len(traj):
                    take = min(self.batch_size - filled, len(traj) - pos)
                    piece = gather(self.view, data["u"], data["t"], data["params"], data["index"],
                                   traj[pos : pos + take], start[pos : pos + take])
                    for name in getattr(self.pde, "OUTPUTS", {}):  # the sample's outputs, whole (drag [T], sdf)
                        piece[name] = data[name][traj[pos : pos + take]]
                    pieces.append(piece)
                    pos, filled = pos + take, filled + take
                    if filled == self.batch_size:
                        yield self._emit(pieces, wid, in_main)
                        pieces, filled = [], 0
            if pieces and not self.drop_last:
                yield self._emit(pieces, wid, in_main)
        finally:
            chunks.close()
        if self.n_samples is not None:  # epoch complete: the next iteration starts the next one
            self._progress.running = [epoch + 1, 0]
            if in_main:
                self.set_epoch(epoch + 1)

    def _emit(self, pieces, wid, in_main) -> dict:
        batch = pieces[0] if len(pieces) == 1 else {k: torch.cat([p[k] for p in pieces]) for k in pieces[0]}
        self._progress.advance(wid, len(batch["index"]), share=in_main)  # when handed out: state_dict has it
        return batch

    def _chunk(self, epoch: int, shard: int, stride: int, c: int, count: int):
        """Solve batch c of a shard: (tensors of its trajectories, example trajectory [N], window start [N])."""
        positions = np.arange(c * self.solve_batch, min((c + 1) * self.solve_batch, count))
        indices = self._base(epoch) + shard + positions * stride
        padded = np.resize(indices, self.solve_batch)  # one shape for the solver; extras are dropped
        data = _bridge.sample_tensors(self.pde, padded, self.seed, self.on_blowup)
        # each index once (the padding repeats them), in order; with on_blowup="skip" the failed ones are gone
        _, first = np.unique(data["index"].numpy(), return_index=True)
        rows = torch.from_numpy(np.sort(first))
        rowwise = ("u", "params", "index", *getattr(self.pde, "OUTPUTS", {}))
        data = {k: (v[rows] if k in rowwise else v) for k, v in data.items()}
        indices = data["index"].numpy()
        traj, start = [], []
        for b, i in enumerate(indices):
            rng = torch.Generator().manual_seed(_derived_seed(self.seed, epoch, i, 0))
            s = self.view.starts(self.pde.n_frames, rng)
            traj += [b] * len(s)
            start += s
        traj, start = torch.tensor(traj), torch.tensor(start)
        if self.shuffle:  # mix examples of the solve batch's trajectories
            rng = torch.Generator().manual_seed(_derived_seed(self.seed, epoch, indices[0], 1))
            perm = torch.randperm(len(traj), generator=rng)
            traj, start = traj[perm], start[perm]
        return data, traj, start

    def _chunks(self, epoch, shard, stride, chunk_ids, count):
        """Solve batches in order; with prefetch, a thread solves the next while the caller consumes."""
        def solve():
            return (self._chunk(epoch, shard, stride, c, count) for c in chunk_ids)

        return prefetch(solve) if self.prefetch else solve()

    def normalization(self, n: int = 64):
        """Per-field mean/std from the first ``n`` samples of this seed (see datasets.normalize)."""
        from .normalize import compute_normalization

        return compute_normalization(self.pde, seed=self.seed, n=n, solve_batch=self.solve_batch)


# How long closing a loader waits for its workers before stopping them. A worker sees torch's "done" event only
# between two batches, and one busy solving the next (or compiling) held a script that broke out of its loop
# ~5 s (torch's join timeout, MP_STATUS_CHECK_INTERVAL) per worker; a worker's state is of no use once closed.
WORKER_JOIN_S = 0.5


class _PromptShutdown(_MultiProcessingDataLoaderIter):
    """torch's worker iterator, whose shutdown waits WORKER_JOIN_S for all workers together, then terminates
    the ones still busy (each is its own process: no JAX call of this process is torn down)."""

    def _shutdown_workers(self):
        if not getattr(self, "_shutdown", True) and getattr(self, "_workers", None):
            self._workers_done_event.set()
            deadline = time.monotonic() + WORKER_JOIN_S
            for w in self._workers:
                w.join(timeout=max(0.0, deadline - time.monotonic()))
            for w in self._workers:
                if w.is_alive():
                    w.terminate()
        super()._shutdown_workers()  # torch's own clean-up (queues, pin-memory thread), now without waiting


class StreamLoader(DataLoader):
    """A DataLoader that records, batch by batch, what the training loop consumed from worker shards,
    so ``stream.state_dict()`` is exact with workers, and that starts the next epoch after a full one.
    Closing it (or leaving the script) stops busy workers within WORKER_JOIN_S."""

    def _get_iterator(self):
        if self.num_workers == 0:
            return super()._get_iterator()
        self.check_worker_number_rationality()
        return _PromptShutdown(self)

    def __iter__(self):
        stream = self.dataset
        if self.num_workers == 0:  # the stream counts for itself in this process
            yield from super().__iter__()
            return
        rank, world = stream.placement()
        nw = self.num_workers
        progress = stream._progress
        progress.record_workers(nw)
        for batch in super().__iter__():
            shard = (int(batch["index"][0]) - stream._base(progress.epoch)) % (world * nw)
            progress.add(shard - rank * nw, len(batch["index"]))
            yield batch
        if stream.n_samples is not None:
            stream.set_epoch(progress.epoch + 1)


class MainGuardError(ValueError, SystemExit):
    """check_main_guard's refusal: a ValueError to callers that catch it, and, left uncaught in the script it
    names, a SystemExit whose code is the message: Python prints that one line and exits 1, no traceback (the
    README's promise; a plain ValueError printed a traceback before its line)."""

    def __init__(self, message: str):
        super().__init__(message)
        self.code = message


def check_main_guard(what: str) -> None:
    """Refuse (one line) to start spawned processes from a script's top-level code that is not under
    ``if __name__ == "__main__":``: each spawned process imports the script again, would run that code again,
    and Python stops it with a screenful of RuntimeError. Scripts only; interactive use passes."""
    import __main__

    path = getattr(__main__, "__file__", None)
    if not path or not str(path).endswith(".py"):
        return
    line, frame = None, sys._getframe(1)
    while frame is not None:  # the script's top-level line that (through any calls) led here
        if frame.f_globals is vars(__main__) and frame.f_code.co_name == "<module>":
            line = frame.f_lineno
        frame = frame.f_back
    try:
        tree = ast.parse(Path(path).read_text())
    except (OSError, SyntaxError, ValueError, UnicodeDecodeError):
        return
    if line is None or any(isinstance(node, ast.If) and _is_main_test(node.test) and node.lineno <= line <= node.end_lineno
                           for node in tree.body):
        return
    raise MainGuardError(f"{what} starts spawned worker processes, which import {Path(path).name} again: put the code "
                     f"that runs it (line {line}) under `if __name__ == \"__main__\":`")


def _is_main_test(test) -> bool:
    """True for the test ``__name__ == "__main__"`` (either way round)."""
    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = {ast.dump(test.left), ast.dump(test.comparators[0])}
    return sides == {ast.dump(ast.Name("__name__", ast.Load())), ast.dump(ast.Constant("__main__"))}


def stream_loader(stream: TrajectoryStream, num_workers: int = 0, prefetch_factor: int = 2,
                  context: str = "spawn", **kwargs) -> StreamLoader:
    """A DataLoader for ``stream``: batch_size=None; with workers, a spawn (or forkserver) context since
    JAX is not fork-safe, persistent workers, and JAX on the CPU in each worker with the shared
    compilation cache. Extra keyword arguments go to DataLoader (e.g. pin_memory=True).

    Spawned workers import the calling script again: a script must run its training under
    ``if __name__ == "__main__":`` (refused with one line otherwise, see ``check_main_guard``)."""
    if not isinstance(stream, TrajectoryStream):  # a PDE passed here failed later with FrozenInstanceError
        raise ValueError(f"stream_loader takes a TrajectoryStream, got {type(stream).__name__}: "
                         "stream_loader(TrajectoryStream(pde, seed), ...)")
    num_workers = _int_arg("num_workers", num_workers, 0)
    if num_workers > MAX_WORKERS:
        raise ValueError(f"num_workers={num_workers} not allowed; at most {MAX_WORKERS}")
    if context not in ("spawn", "forkserver"):
        raise ValueError(f"context={context!r} not allowed; allowed: 'spawn', 'forkserver' (JAX is not fork-safe)")
    stream.num_workers = num_workers
    if num_workers == 0:
        return StreamLoader(stream, batch_size=None, **kwargs)
    check_main_guard(f"stream_loader(num_workers={num_workers})")
    kwargs.setdefault("persistent_workers", True)
    return StreamLoader(stream, batch_size=None, num_workers=num_workers, multiprocessing_context=context,
                        prefetch_factor=prefetch_factor, worker_init_fn=_bridge.configure_worker, **kwargs)
