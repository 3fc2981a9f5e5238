"""Data sources for training and evaluation, all through ``datasets`` (never the solver directly).

- ``train_loader(pde, source, ...)``: "stream" -> the on-the-fly TrajectoryStream; a path -> a cache read by
  CachedTrajectories (refused when it holds another PDE or other settings than asked).
- ``test_set(pde, seed, n)``: whole trajectories of a held-out seed, as a list of batch dicts.
"""

from __future__ import annotations

import torch
from torch.utils.data import DataLoader

import datasets

TEST_SEED_OFFSET = 1_000_003  # test seeds never coincide with a training seed below this offset


def check_cache_matches(cached, pde, explicit: dict | None = None) -> None:
    """ValueError when the cache holds another PDE, or differs from settings the user set explicitly."""
    name = cached.config.get("pde")
    if name != pde.NAME:
        raise ValueError(f"cache {cached.path} holds {name!r} samples, not {pde.NAME!r}; "
                         f"train on {name} or generate a {pde.NAME} cache")
    wanted = pde.config()
    differ = [k for k in (explicit or {}) if k.split(".")[0] in wanted and _lookup(wanted, k) != _lookup(cached.config, k)]
    if differ:
        detail = ", ".join(f"{k}: cache {_lookup(cached.config, k)!r} vs asked {_lookup(wanted, k)!r}" for k in differ)
        raise ValueError(f"cache {cached.path} was written with other settings ({detail})")


def _lookup(config: dict, key: str):
    head, _, rest = key.partition(".")
    value = config.get(head)
    return _lookup(value, rest) if rest and isinstance(value, dict) else value


def train_loader(pde, source: str, view, batch_size: int, seed: int = 0, data_seed: int = 0,
                 explicit: dict | None = None):
    """(DataLoader of batch dicts, the PDE the data comes from) for ``source`` = "stream" or a cache path.

    Stream: samples 0, 1, 2, ... of (pde, data_seed), never repeated. Cache: its samples, reshuffled each
    epoch by a torch generator seeded with ``seed``.
    """
    if source == "stream":
        stream = datasets.TrajectoryStream(pde, seed=data_seed, view=view, batch_size=batch_size)
        return datasets.stream_loader(stream), stream.pde
    cached = datasets.CachedTrajectories(source, view=view)
    check_cache_matches(cached, pde, explicit)
    gen = torch.Generator().manual_seed(seed)
    loader = DataLoader(cached, batch_size=batch_size, shuffle=True, generator=gen,
                        drop_last=len(cached) >= batch_size, collate_fn=datasets.collate)
    return loader, cached.pde


def test_set(pde, seed: int, n: int, batch_size: int = 32) -> list[dict]:
    """n whole trajectories {"u": [B, T, C, *space], "params": [B, P], "index": [B]} of seed TEST_SEED_OFFSET + seed."""
    stream = datasets.TrajectoryStream(pde, seed=TEST_SEED_OFFSET + seed, view="whole", batch_size=batch_size,
                                       n_samples=n, shuffle=False, solve_batch=min(n, 32))
    return list(DataLoader(stream, batch_size=None))
