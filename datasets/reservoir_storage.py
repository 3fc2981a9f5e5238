"""The training reservoir's storage: where held trajectories live, slot by slot (torchrl's "storage").

``Storage`` is the declared interface: a storage keeps, for each of ``capacity`` slots, a trajectory
u [T, C, *space], its params [P] and its sample index, and gathers batches from them. ``TensorStorage`` is the one
there is: torch tensors on the host or on a GPU (the training device: batches are gathered there). Another
storage (a memory-mapped spill to disk, say) is a new class implementing ``Storage``, handed to ``Reservoir``
(``storage=``) or to the stream (``ReservoirConfig.storage``); nothing else changes.

Also here: the device helpers (``storage_device``, ``check_room``) that refuse a device in one line.
"""

from __future__ import annotations

import math
import os
from abc import ABC, abstractmethod

import numpy as np
import torch

from .views import gather


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


def physical_memory() -> int:
    """Bytes of RAM (0 where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 0


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


class Storage(ABC):
    """Where a reservoir's trajectories live: ``capacity`` slots, each a trajectory, its params and its index.

    Attributes every storage has: ``capacity``; ``device`` (where ``gather`` returns batches); ``index``: int64
    numpy [capacity] on the host, the sample index in each slot (-1: never filled; the reservoir's bookkeeping
    reads it); ``params_host``: float32 numpy [capacity, P] on the host once the first trajectory is in (None
    before), what reports and saved states read. The held data itself is not saved: a resumed reservoir solves
    its trajectories again from (index, params) (sample identity) and ``put``s them back.
    """

    capacity: int
    device: torch.device
    index: np.ndarray
    params_host: np.ndarray | None

    @abstractmethod
    def put(self, slots: np.ndarray, u: torch.Tensor, params: torch.Tensor, index: np.ndarray) -> None:
        """Store trajectories u [m, T, C, *space] (any device), params [m, P] and sample indices int64 [m] in
        ``slots`` [m] (distinct), replacing what they held."""

    @abstractmethod
    def gather(self, view, t: torch.Tensor, slots: np.ndarray, starts: np.ndarray) -> dict:
        """The examples (slots [m], window starts [m], host int64) under ``view`` as a batch dict on ``device``
        ("params" [m, P], "index" [m], and the view's entries); ``t`` [T]: the frame times, on ``device``."""

    @abstractmethod
    def to(self, device: torch.device | str) -> None:
        """Move what is held to ``device`` (one line when it has no room there); later batches come from there."""

    def state_dict(self, slots: np.ndarray) -> dict:
        """What resumes the held ``slots`` [n]: their sample indices and params (plain lists)."""
        return {"index": self.index[slots].tolist(),
                "params": self.params_host[slots].tolist() if self.params_host is not None else []}


class TensorStorage(Storage):
    """Trajectories in torch tensors on ``device`` (the host or a GPU, where the batches are gathered).

    u: float32 [capacity, T, C, *space] (allocated at the first ``put``), params [capacity, P] and index_t int64
    [capacity], the index's copy there (on the host: the ``index`` array itself, shared memory).
    """

    def __init__(self, capacity: int, device: torch.device | str = "cpu"):
        self.capacity, self.device = capacity, torch.device(device)
        self.index = np.full(capacity, -1, np.int64)
        self.u = self.params = self.index_t = self.params_host = None
        self._held: list = []  # (event, tensors): sources of device copies, kept until the copies have run

    def _index_on(self, device: torch.device) -> torch.Tensor:
        # on the CPU the index tensor is the bookkeeping array itself (shared memory): nothing to keep in step
        return torch.from_numpy(self.index) if device.type == "cpu" else torch.from_numpy(self.index).to(device)

    def allocate(self, shape: tuple, dtype: torch.dtype, n_params: int) -> None:
        """u [capacity, *shape], params [capacity, n_params], index_t [capacity] on ``device``; one line
        (ValueError) when the device cannot hold them: the bytes asked and the bytes free there."""
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
        self.params_host = np.zeros((self.capacity, n_params), np.float32)
        self.index_t = self._index_on(self.device)

    def to(self, device: torch.device | str) -> None:
        device = torch.device(device)
        if device == self.device:
            return
        if self.u is not None:
            need = self.u.nbytes + self.params.nbytes + self.index_t.nbytes
            check_room(device, need, f"a reservoir of {self.capacity} trajectories")
            self.u, self.params = self.u.to(device), self.params.to(device)
            self.index_t = self._index_on(device)
        self.device = device

    def put(self, slots: np.ndarray, u: torch.Tensor, params: torch.Tensor, index: np.ndarray) -> None:
        """One copy each whatever device they come from (a solver's GPU buffer through DLPack: device to device;
        a worker process's numpy: host to device); nothing waits for the device."""
        if self.u is None:
            self.allocate(tuple(u.shape[1:]), u.dtype, params.shape[1])
        self.index[slots] = index
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

    def gather(self, view, t: torch.Tensor, slots: np.ndarray, starts: np.ndarray) -> dict:
        """On a GPU the m (slot, start) pairs go over in one pinned, asynchronous copy and nothing waits for the
        device (a later ``put`` is queued behind the gather on the same stream)."""
        host = torch.from_numpy(np.stack([slots, starts]))
        sel = host if self.device.type == "cpu" else host.pin_memory().to(self.device, non_blocking=True)
        return gather(view, self.u, t, self.params, self.index_t, sel[0], sel[1])
