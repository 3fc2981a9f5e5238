"""StreamPosition: where an iterable dataset stands (epoch, units consumed per worker), shared with spawned workers.

A stream's ``set_epoch`` and ``load_state_dict`` run in the main process, but persistent DataLoader workers
read where to start from; so the counts live in shared memory that spawn/forkserver workers map, not copy.
"""

from __future__ import annotations

import multiprocessing as mp
import numbers

MAX_WORKERS = 64  # consumed-count slots (workers per rank)
_LIMIT = 2**63  # counts are int64; larger values would wrap around in shared memory


def _count(name: str, value) -> int:
    """``value`` as a non-negative int64, or one line naming it."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 <= value < _LIMIT:
        plain = value.item() if hasattr(value, "item") and not isinstance(value, (list, tuple)) else value
        raise ValueError(f"{name}={plain!r} not allowed; must be an integer in [0, 2**63)")
    return int(value)


class StreamPosition:
    """Epoch and per-worker consumed counts, for TrajectoryStream, StreamLoader or any other stream.

    Shared (int64, seen by the main process and its spawned workers):
      ``epoch``: the epoch the next iteration covers;
      ``workers``: worker counts recorded (0: none yet), so a resume with another worker count is refused;
      ``consumed(w)``: units (examples, batches: the owner decides) consumed from worker w's shard this epoch.
    Per process (travel with pickling but are not shared):
      ``running``: [epoch, consumed] of the iterator running in this process (None before the first);
      ``pending``: (epoch, consumed) restored inside a worker, taken by the next ``start`` in that worker;
      ``unpickled``: this copy came by pickling (e.g. into a spawned worker), not by fork.
    Plain pickling (copy.deepcopy, torch.save) makes an independent copy; pickling while a spawn/forkserver
    process is being started shares the memory with it.
    """

    def __init__(self, slots: int = MAX_WORKERS):
        self.slots = slots
        self._shared = mp.get_context("spawn").RawArray("q", 2 + slots)  # [epoch, workers, consumed 0..slots)
        self.running: list[int] | None = None
        self.pending: tuple[int, int] | None = None
        self.unpickled = False

    # --- shared fields -----------------------------------------------------------------------------
    @property
    def epoch(self) -> int:
        """The epoch the next iteration covers."""
        return int(self._shared[0])

    def set_epoch(self, epoch: int) -> None:
        """Start ``epoch`` from its beginning: no worker count recorded, every consumed count 0."""
        self._shared[0] = _count("epoch", epoch)
        self._shared[1:] = [0] * (1 + self.slots)

    @property
    def workers(self) -> int:
        """Worker counts recorded (0: none yet)."""
        return int(self._shared[1])

    def check_workers(self, workers: int, num_workers: int | None = None) -> None:
        """Refuse to go on with ``workers`` workers when the state was recorded with another number.
        ``num_workers``: what the user set, for the message (0 where the main process is the one "worker")."""
        if self.workers and self.workers != workers:
            saved = "0 or 1" if self.workers == 1 else self.workers  # one shard either way
            now = workers if num_workers is None else num_workers
            raise ValueError(f"state saved with num_workers={saved} per rank, resumed with num_workers={now}; "
                             "resume with the same number of workers")

    def record_workers(self, workers: int) -> None:
        """Check (as ``check_workers``), then record ``workers`` as the worker count."""
        self.check_workers(workers)
        self._shared[1] = workers

    def consumed(self, worker: int) -> int:
        """Units consumed from worker ``worker``'s shard in this epoch."""
        return int(self._shared[2 + worker])

    def add(self, worker: int, n: int) -> None:
        """Count ``n`` more units consumed from worker ``worker``'s shard."""
        self._shared[2 + worker] += n

    # --- state_dict ----------------------------------------------------------------------------------
    def snapshot(self, workers: int, worker: int | None = None) -> tuple[int, list[int]]:
        """(epoch, consumed [workers]). From the main process (worker None): the shared counts. Inside worker
        ``worker``: its running iterator's position (else the shared one) and 0 for the other workers."""
        if worker is None:
            return self.epoch, [self.consumed(w) for w in range(workers)]
        epoch, done = self.running or (self.epoch, self.consumed(worker))
        counts = [0] * workers
        counts[worker] = done
        return epoch, counts

    def restore(self, epoch: int, consumed: list[int], worker: int | None = None, workers: int | None = None) -> None:
        """Go back to ``snapshot`` output. From the main process (worker None): into shared memory, so persistent
        workers see it. Inside worker ``worker`` of ``workers`` (torchdata's StatefulDataLoader): ``pending``."""
        consumed = [_count("consumed", c) for c in consumed]
        epoch = _count("epoch", epoch)
        if not 1 <= len(consumed) <= self.slots:
            raise ValueError(f"state has {len(consumed)} worker counts; allowed 1..{self.slots}")
        if worker is not None:
            if len(consumed) != workers:
                raise ValueError(f"state saved with {len(consumed)} workers, resumed with {workers}")
            self.pending = (epoch, consumed[worker])
            return
        self.set_epoch(epoch)
        self._shared[1] = len(consumed)
        self._shared[2 : 2 + len(consumed)] = consumed

    # --- the iterator running in this process ----------------------------------------------------------
    def start(self, worker: int, workers: int, share: bool, num_workers: int | None = None) -> tuple[int, int]:
        """Begin an iteration as worker ``worker`` of ``workers``: (epoch, units already consumed) to resume
        from, ``pending`` if a worker restored one, else the shared position. ``share``: this is the process
        that owns the shared counts (the main one), so it records ``workers``; ``num_workers`` as in
        ``check_workers``."""
        if self.pending is not None:
            (epoch, done), self.pending = self.pending, None
        else:
            self.check_workers(workers, num_workers)
            epoch, done = self.epoch, self.consumed(worker)
        if share:
            self._shared[1] = workers
        self.running = [epoch, done]
        return epoch, done

    def advance(self, worker: int, n: int, share: bool) -> None:
        """The running iterator handed out ``n`` more units; ``share``: publish its count as ``consumed(worker)``."""
        self.running[1] += n
        if share:
            self._shared[2 + worker] = self.running[1]

    # --- pickling ------------------------------------------------------------------------------------
    def __getstate__(self):
        state = self.__dict__.copy()
        if mp.context.get_spawning_popen() is None:  # plain pickling: a copy, not the shared memory
            state["_shared"] = list(self._shared)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if isinstance(self._shared, list):
            values, self._shared = self._shared, mp.get_context("spawn").RawArray("q", len(self._shared))
            self._shared[:] = values
        self.unpickled = True
