"""Data sources for training and evaluation, all through ``datasets`` (never the solver directly).

- ``train_loader(pde, source, ...)``: "stream" -> the on-the-fly TrajectoryStream; a path -> a cache read by
  CachedTrajectories (refused when it holds another PDE or other settings than asked); a file written by
  ``pdestream export`` is read through a temporary cache made from it (``datasets.export.as_cache``).
- ``test_set(pde, seed, n)``: whole trajectories of a held-out seed, as a list of batch dicts.
"""

from __future__ import annotations

import torch
from torch.utils.data import DataLoader, Sampler

from pdestream import datasets
from pdestream.datasets.export import as_cache
from pdestream.datasets.ranks import RankReservoirStream, placement
from pdestream.datasets.reservoir_config import ReservoirConfig

from .checks import check_cache_matches, check_count

TEST_SEED_OFFSET = 1_000_003  # test seeds never coincide with a training seed below this offset
# data_cfg {"kind": "reservoir", ...}: the ReservoirStream keyword arguments a run may set (ReservoirConfig's plain
# settings: the device is the run's, a storage factory is not a value run.json can hold)
RESERVOIR_SETTINGS = set(ReservoirConfig.names()) - {"device", "storage"}


def to_device(batch: dict, device: torch.device | str) -> dict:
    """The batch's tensors on ``device`` (a stream whose solver runs on that GPU already delivers them there:
    then nothing is copied); other entries unchanged."""
    return {k: (v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}


def check_device(device: str) -> torch.device:
    """torch.device for a --device value; one line when it is malformed or not there."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"--device={device!r} not allowed; use cpu, cuda or cuda:N") from None
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"--device={device!r} not allowed; use cpu, cuda or cuda:N")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"--device={device}: torch sees no GPU here (a CPU-only torch build or no driver); "
                             "use --device cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"--device={device}: torch sees {torch.cuda.device_count()} GPU(s)")
    return dev


def model_device(model: torch.nn.Module) -> torch.device:
    """Where the model's parameters live (the training loop moves batches there)."""
    return next(model.parameters()).device


def train_loader(pde, source: str, view, batch_size: int, seed: int = 0, data_seed: int = 0,
                 explicit: dict | None = None, data_cfg: dict | None = None, device: str | None = None):
    """(DataLoader of batch dicts, the PDE the data comes from) for ``source`` = "stream" or a cache path.

    Stream: samples 0, 1, 2, ... of (pde, data_seed), never repeated. Cache: its samples, reshuffled each
    epoch by an ``EpochBatchSampler`` seeded with ``seed`` (resumable: ``loader.batch_sampler.state_dict()``).
    data_cfg: opaque settings of the data source recorded in run.json (None: the defaults above). device: where
    the model trains; a training reservoir keeps its trajectories there (checked for room before anything runs).
    Under several torch.distributed ranks: the stream shards its samples by rank, a reservoir is this rank's
    ``RankReservoirStream`` (disjoint samples), and a cache is refused (it is not sharded by rank).
    """
    rank, ranks = placement()
    if ranks > 1 and source != "stream":
        raise ValueError(f"training on {ranks} ranks reads --source stream (with or without --reservoir); a cache "
                         f"({source}) is not sharded across ranks")
    if source == "stream" and (data_cfg or {}).get("kind") == "reservoir":
        settings = {k: v for k, v in data_cfg.items() if k != "kind"}
        unknown = sorted(set(settings) - RESERVOIR_SETTINGS)
        if unknown:
            raise ValueError(f"unknown reservoir setting(s) {unknown}; allowed: {', '.join(sorted(RESERVOIR_SETTINGS))}")
        if ranks > 1:
            settings.update(rank=rank, world_size=ranks)  # (one rank alone is the plain reservoir, bit for bit)
        kind = RankReservoirStream if ranks > 1 else datasets.ReservoirStream
        stream = kind(pde, seed=data_seed, view=view, batch_size=batch_size, device=device,
                      **settings)
        return DataLoader(stream, batch_size=None), stream.pde
    if source == "stream":
        stream = datasets.TrajectoryStream(pde, seed=data_seed, view=view, batch_size=batch_size)
        return datasets.stream_loader(stream), stream.pde
    path = as_cache(source)  # an export of The Well's or PDEBench's layout: a temporary cache made from it
    try:
        cached = datasets.CachedTrajectories(path, view=view)
        check_cache_matches(cached.path, cached.config, pde, explicit)
    except ValueError as err:  # named after what the user gave
        raise ValueError(str(err).replace(str(path), str(source))) from None
    sampler = EpochBatchSampler(len(cached), batch_size, seed, drop_last=len(cached) >= batch_size)
    # the generator only feeds the DataLoader's per-iteration worker seed, which would otherwise be drawn
    # from the global torch RNG (that one also draws random next_step windows, and a resume restores it)
    loader = DataLoader(cached, batch_sampler=sampler, collate_fn=datasets.collate, generator=torch.Generator())
    return loader, cached.pde


def epoch_seed(seed: int, epoch: int) -> int:
    """The generator seed of one epoch's shuffle: distinct for every (seed < 2**31, epoch < 2**32) pair."""
    return (seed << 32) + epoch


class EpochBatchSampler(Sampler):
    """Batches of example indices (lists of ``batch_size`` ints), one shuffled pass per epoch, resumable.

    Epoch e's order is ``torch.randperm(n)`` drawn from a generator seeded with ``epoch_seed(seed, e)`` (as
    ``DistributedSampler`` seeds one per epoch with seed + epoch), so it is a pure function of (seed, e) that
    no other draw shifts. ``state_dict()`` records (epoch, batches handed out) -- exact for a DataLoader without
    workers, which asks for one batch at a time.
    """

    def __init__(self, n: int, batch_size: int, seed: int, drop_last: bool = False):
        check_count("n", n)
        check_count("batch_size", batch_size)
        if check_count("seed", seed, 0) >= 2**31:
            raise ValueError(f"seed={seed!r} not allowed; must be an integer in [0, 2**31)")
        self.n, self.batch_size, self.seed, self.drop_last = n, batch_size, seed, bool(drop_last)
        self.epoch, self.consumed = 0, 0

    def __len__(self) -> int:
        return self.n // self.batch_size if self.drop_last else -(-self.n // self.batch_size)

    def _permutation(self, epoch: int) -> torch.Tensor:
        """Epoch ``epoch``'s order [n]."""
        return torch.randperm(self.n, generator=torch.Generator().manual_seed(epoch_seed(self.seed, epoch)))

    def __iter__(self):
        if self.consumed >= len(self):  # resumed right at the end of an epoch
            self.epoch, self.consumed = self.epoch + 1, 0
        epoch, order = self.epoch, self._permutation(self.epoch).tolist()
        for b in range(self.consumed, len(self)):
            self.consumed = b + 1  # counted when handed out, so a state taken after this batch skips it
            yield order[b * self.batch_size : (b + 1) * self.batch_size]
        self.epoch, self.consumed = epoch + 1, 0

    def state_dict(self) -> dict:
        return {"sampler": "epoch_batch", "seed": self.seed, "n": self.n, "batch_size": self.batch_size,
                "drop_last": self.drop_last, "epoch": self.epoch, "consumed": self.consumed}

    def load_state_dict(self, state: dict) -> None:
        """Continue after the last batch handed out when ``state`` was taken (same seed, size and batching)."""
        for key in ("seed", "n", "batch_size", "drop_last"):
            if state.get(key) != getattr(self, key):
                raise ValueError(f"sampler state has {key}={state.get(key)!r} but this cache source has "
                                 f"{key}={getattr(self, key)!r}")
        self.epoch, self.consumed = int(state["epoch"]), int(state["consumed"])


def test_set(pde, seed: int, n: int, batch_size: int = 32) -> list[dict]:
    """n whole trajectories {"u": [B, T, C, *space], "params": [B, P], "index": [B]} of seed TEST_SEED_OFFSET + seed."""
    stream = datasets.TrajectoryStream(pde, seed=TEST_SEED_OFFSET + seed, view="whole", batch_size=batch_size,
                                       n_samples=n, shuffle=False, solve_batch=min(n, 32))
    return list(DataLoader(stream, batch_size=None))
