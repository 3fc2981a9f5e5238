"""Many ranks (DDP): each rank its own training reservoir, fed with disjoint samples; rank-keyed resumable state.

Rank r of W ranks submits the global sample indices r, r + W, r + 2W, ... (its k-th submission is sample
k * W + r), every rank with the run's seed, so the ranks' samples are disjoint, together they are 0 .. N-1, and
each sample is still the pure function of (PDE config, seed, index[, explicit params]) that one process would
solve: sample identity and the reuse bound are the single reservoir's, per rank. A rank draws its batches from a
generator seeded with (seed, world size, rank); one rank alone (W = 1) is the plain ``ReservoirStream``, bit for
bit. In deterministic mode a rank's batch sequence is a pure function of (PDE config, seed, settings, rank, W).

Producers: each rank's stream opens its own producer. ``producer="thread"``: one solver thread per rank (per
device); ``producer="dask", scheduler="tcp://host:8786"``: every rank submits its jobs to that one cluster, one
pool of solver processes for all ranks (a job is a pure function of its arguments, so who solves it changes
nothing). ``producer="dask"`` without a scheduler: the cluster named by the environment variable
PDESTREAM_DASK_SCHEDULER (``pdestream train --ddp N`` starts one and names it for its ranks), else each rank's own.

State: ``RankStates`` wraps a data source so that ``state_dict()`` gathers every rank's state into one
rank-keyed dict (a collective: every rank calls it at the same step; rank 0 writes it) and
``load_state_dict`` hands each rank its own, refusing a state saved by another number of ranks in one line.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from .reservoir import ReservoirStream

SHARED_SCHEDULER = "PDESTREAM_DASK_SCHEDULER"  # the Dask cluster every rank's producer="dask" submits to


def placement(rank: int | None = None, world_size: int | None = None) -> tuple[int, int]:
    """(rank, world_size): explicit, else torch.distributed's when initialized, else (0, 1). ValueError (one line)
    for a rank outside [0, world_size)."""
    if (rank is None) != (world_size is None):
        raise ValueError(f"give both rank and world_size or neither (got rank={rank}, world_size={world_size})")
    if world_size is None:
        dist = torch.distributed
        if dist.is_available() and dist.is_initialized():
            return dist.get_rank(), dist.get_world_size()
        return 0, 1
    if isinstance(world_size, bool) or not isinstance(world_size, (int, np.integer)) or world_size < 1:
        raise ValueError(f"world_size={world_size!r} not allowed; must be an integer >= 1")
    if isinstance(rank, bool) or not isinstance(rank, (int, np.integer)) or not 0 <= rank < world_size:
        raise ValueError(f"rank={rank!r} not allowed; must be an integer in [0, {world_size})")
    return int(rank), int(world_size)


def rank_share(total: int, rank: int, world_size: int) -> int:
    """How many of the indices 0 .. total-1 are rank ``rank``'s (those with i % world_size == rank)."""
    return max(0, -(-(total - rank) // world_size))


class RankReservoirStream(ReservoirStream):
    """One DDP rank's training reservoir: a ``ReservoirStream`` whose k-th submitted sample is k * W + r.

    rank, world_size: default from torch.distributed when initialized (else 0 of 1); every other argument as
    for ``ReservoirStream`` (seed: the run's seed, the same on every rank: it is part of sample identity).
    sim_budget: the whole run's solves, split over the ranks (rank r solves the indices below it that are its
    own). Draws (and loss-driven proposals) come from generators seeded with (seed, world_size, rank).
    """

    def __init__(self, pde, seed: int = 0, *, rank: int | None = None, world_size: int | None = None,
                 sim_budget: int | None = None, **kwargs):
        # set before the base class builds its reservoir (``_reset_state`` seeds the draws from them)
        self.rank, self.world_size = placement(rank, world_size)
        share = sim_budget
        if sim_budget is not None and self.world_size > 1 and not isinstance(sim_budget, bool) \
                and isinstance(sim_budget, int):
            share = rank_share(sim_budget, self.rank, self.world_size)
            if share < 1:
                raise ValueError(f"sim_budget={sim_budget} not allowed with {self.world_size} ranks: rank {self.rank} "
                                 f"would solve nothing; must be >= {self.world_size}")
        if kwargs.get("producer") == "dask" and not kwargs.get("scheduler") and os.environ.get(SHARED_SCHEDULER):
            kwargs["scheduler"] = os.environ[SHARED_SCHEDULER]  # the launcher's one cluster (not in run.json)
        super().__init__(pde, seed=seed, sim_budget=share, **kwargs)
        if self.world_size > 1:
            self.proposal.rng = np.random.default_rng([self.seed, 2, self.world_size, self.rank])

    def _reset_state(self) -> None:
        super()._reset_state()
        if self.world_size > 1:  # one rank alone keeps the plain reservoir's generator: the same stream
            self.res.rng = np.random.default_rng([self.seed, 1, self.world_size, self.rank])

    def _sample_indices(self, first: int, n: int) -> np.ndarray:
        return np.arange(first, first + n, dtype=np.int64) * self.world_size + self.rank

    def state_dict(self) -> dict:
        """The reservoir's state (``ReservoirStream.state_dict``) with this rank's "rank" and "world_size"."""
        return {**super().state_dict(), "rank": self.rank, "world_size": self.world_size}

    def load_state_dict(self, state: dict) -> None:
        """Resume this rank from its own ``state_dict()``; a state of another rank or world size is refused."""
        for key, mine in (("world_size", self.world_size), ("rank", self.rank)):
            if isinstance(state, dict) and state.get(key, 1 if key == "world_size" else 0) != mine:
                raise ValueError(f"reservoir state was saved by rank {state.get('rank', 0)} of "
                                 f"{state.get('world_size', 1)}; this stream is rank {self.rank} of {self.world_size}")
        super().load_state_dict(state)


class RankStates:
    """A data source's resumable state across DDP ranks (the owner: anything with state_dict / load_state_dict).

    ``state_dict()`` -> {"kind": "ranks", "world_size": W, "ranks": [rank 0's state, ..., rank W-1's]}, gathered
    with ``all_gather_object`` (a collective: every rank calls it at the same step). ``load_state_dict`` gives
    this rank its own entry; ValueError (one line) for a state of another world size, or of one process.
    """

    def __init__(self, owner, rank: int, world_size: int):
        self.owner, self.rank, self.world_size = owner, rank, world_size

    def state_dict(self) -> dict:
        states = [None] * self.world_size
        torch.distributed.all_gather_object(states, self.owner.state_dict())
        return {"kind": "ranks", "world_size": self.world_size, "ranks": states}

    def load_state_dict(self, state: dict) -> None:
        check_world(state, self.world_size)
        self.owner.load_state_dict(state["ranks"][self.rank])


def saved_world(state) -> int:
    """The number of ranks that saved a data state (``RankStates`` -> W, anything else -> 1)."""
    if isinstance(state, dict) and state.get("kind") == "ranks":
        world = state.get("world_size")
        ranks = state.get("ranks")
        if isinstance(world, bool) or not isinstance(world, int) or not isinstance(ranks, list) or len(ranks) != world:
            raise ValueError("the checkpoint's rank-keyed data state is damaged (world_size and ranks disagree)")
        return world
    return 1


def check_world(state, world_size: int) -> None:
    """ValueError (one line) when the data state ``state`` was saved by another number of ranks than ``world_size``."""
    saved = saved_world(state)
    if saved != world_size:
        raise ValueError(f"the checkpoint was saved by {saved} rank(s) and this run has {world_size}: resume it with "
                         f"the same world size (--ddp {saved}, or torchrun --nproc-per-node {saved})")


def keyed(owner):
    """``owner`` itself in one process, a ``RankStates`` around it when torch.distributed runs several ranks."""
    rank, world = placement()
    return owner if world == 1 or owner is None else RankStates(owner, rank, world)
