"""CachedTrajectories: the precomputed fallback, a map-style torch Dataset over a cache file.

It gives the same example dicts as the stream (``datasets.views``; "params" [P] in PDE.PARAMS order,
"index" the global sample index), so a model trains on a cache or on the stream alike. The file is opened
lazily in each process that reads (never carried across fork or spawn). A cache whose samples fit in
IN_MEMORY_BYTES is read whole on first use in each process (one sequential read instead of one chunk read
per example, which dominates training time on small samples); larger ones are read example by example.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from . import schema
from .cache import is_complete, open_cache
from .store import CacheSettings, format_of, identity
from .views import examples, for_sample, make_view

IN_MEMORY_BYTES = 512 * 2**20


class CachedTrajectories(torch.utils.data.Dataset):
    """Examples of a cache under a view.

    Item k: ``whole``/``operator``: sample k; ``next_step`` with windows="all": the pair (sample, start)
    k // n_starts, k % n_starts; with windows=W: sample k // W at a start drawn by torch's RNG.
    ``allow_incomplete=True`` reads only the complete samples of an interrupted cache. ``in_memory``: read
    all samples at once per process (None: when they fit in IN_MEMORY_BYTES; each DataLoader worker holds a copy).
    """

    def __init__(self, path, view="whole", allow_incomplete: bool = False, in_memory: bool | None = None,
                 **view_kwargs):
        self.path = str(path)
        self.view = make_view(view, **view_kwargs)
        self._fmt = format_of(self.path)
        self._pin = _pin(self.path)
        ds = open_cache(self.path)
        try:
            settings = CacheSettings.from_attrs(ds.attrs, self.path)  # the run settings, read in one place
            self.config, self.seed = settings.config, settings.seed
            # the channels of a sample (datasets._bridge.sample_channels): a steady PDE's input fields, then its fields
            self.fields = [*settings.inputs, *settings.fields]
            self.n_inputs = len(settings.inputs)
            self.param_names = list(settings.params)
            complete = ds["complete"].values == 1
            if not is_complete(ds) and not allow_incomplete:
                raise ValueError(
                    f"{self.path} is incomplete ({int(complete.sum())} of {complete.size} samples written); finish "
                    "it with `pdestream generate ... --resume`, or pass allow_incomplete=True to read the written ones")
            self.rows = np.flatnonzero(complete)  # positions in the file
            self.indices = ds["sample"].values[self.rows].astype(np.int64)
            cols = [ds[n].values[self.rows] for n in self.param_names]
            self.params = torch.from_numpy(np.stack(cols, 1) if cols else np.zeros((len(self.rows), 0), np.float32))
            bad = np.flatnonzero(~torch.isfinite(self.params).all(1).numpy())
            if len(bad):  # a deleted parameter chunk reads as NaN
                raise self._damaged(bad)
            timed = "time" in ds[self.fields[0]].dims  # a steady PDE's samples have no time axis
            self.t = torch.from_numpy(ds["time"].values.astype(np.float32) if timed else np.zeros(0, np.float32))
            self._axis = 2 if timed else 1  # the channel axis of [N, T, C, *space] / [N, C_in + C, *space]
            nbytes = len(self.rows) * len(self.fields) * int(np.prod(ds[self.fields[0]].shape[1:])) * 4
            self._ndim = schema.space_ndim(ds[self.fields[0]].dims)  # raw reads go through schema.from_disk
        finally:
            ds.close()
        # the cache read above is the one pinned: what is at the path now, and whose inode ``_pin`` keeps from
        # being reused while this reader lives; every read checks the path still leads to it
        self._identity = identity(self._pin) if self._pin is not None else None
        self._check_same()
        n_frames = len(self.t)
        self.view = for_sample(self.view, n_frames, self.n_inputs)
        self.per_sample = self.view.per_trajectory(n_frames)  # examples per stored sample
        self.in_memory = nbytes <= IN_MEMORY_BYTES if in_memory is None else bool(in_memory)
        self._store, self._pid, self._memory = None, None, None

    @property
    def pde(self):
        """The cached PDE (rebuilt from the stored config; imports generator, hence JAX, on first use)."""
        from ._bridge import pde_from_config

        try:
            return pde_from_config(self.config)
        except (ValueError, TypeError, KeyError) as err:  # a config no PDE of this version accepts
            raise ValueError(f"{self.path}: its stored PDE config cannot be used: {err}") from None

    def __len__(self) -> int:
        return len(self.rows) * self.per_sample

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_store"], state["_pid"] = None, None  # a file handle never crosses processes
        state["_memory"] = None  # each process reads its own copy
        state["_pin"] = None  # the creating process's pin keeps the inode; other processes compare identities
        return state

    def _check_same(self) -> None:
        """ValueError when the path no longer leads to the cache this reader opened (an --overwrite builds the
        new cache beside the old one and renames it into place): data read by path could be either's."""
        try:
            same = identity(self.path) == self._identity
        except OSError:
            same = False
        if not same:
            raise ValueError(f"the cache at {self.path} was replaced while open; reopen it")

    def _open(self):
        if self._store is None or self._pid != os.getpid():
            self._store, self._pid = self._fmt.open(Path(self.path)), os.getpid()
            self._check_same()  # a process opening after a replacement would read the new cache
        return self._store

    def close(self) -> None:
        """Close this process's file handle (reopened by the next read); a forked copy's is left alone."""
        store, self._store = self._store, None
        if store is not None and self._pid == os.getpid():
            store.close()

    def __del__(self):
        try:
            self.close()
            if getattr(self, "_pin", None) is not None:
                os.close(self._pin)
                self._pin = None
        except Exception:  # at interpreter exit h5py may already be torn down
            pass

    def normalization(self, chunk: int = 64):
        """Per-field mean/std over every stored sample (all frames and grid points) and per-parameter mean/std,
        accumulated as for a stream's calibration draw (datasets.normalize.Moments); reads ``chunk`` samples at once."""
        moments, _ = self.moments(chunk)
        return moments.result(self.fields, self.param_names, samples=len(self.rows), inputs=self.n_inputs)

    def moments(self, chunk: int = 64, delta: bool = False):
        """(Moments of every stored sample's fields and parameters, Moments of the time differences u[t+1] - u[t]
        per field, or None unless ``delta`` and the samples have a time axis), keyed by sample index."""
        from .normalize import Moments

        store = self._open()
        moments = Moments(self._ndim)
        deltas = Moments(self._ndim) if delta and self._axis == 2 else None
        for s in range(0, len(self.rows), chunk):
            rows = self.rows[s:s + chunk]
            lo = int(rows[0])
            try:
                u = np.stack([schema.from_disk(np.asarray(store[f][lo:int(rows[-1]) + 1])[rows - lo], self._ndim)
                              for f in self.fields], axis=self._axis)
            except Exception as err:  # a corrupted chunk: name the file and the samples read
                self._check_same()
                raise ValueError(f"{self.path}: cannot read samples {self.indices[s]}..{self.indices[s + len(rows) - 1]}: "
                                 f"{_first_line(err)}; recompute them with `pdestream generate ... --resume`") from None
            self._check_same()
            bad = np.flatnonzero(~np.isfinite(u.reshape(len(u), -1)).all(1))
            if len(bad):
                raise self._damaged(s + bad)
            moments.add(torch.from_numpy(u), self.params[s:s + chunk], index=self.indices[s:s + chunk])  # [b, T, C, *space]
            if deltas is not None and u.shape[1] > 1:
                deltas.add(torch.from_numpy(np.diff(u.astype(np.float64), axis=1)), index=self.indices[s:s + chunk])
        return moments, deltas

    def _damaged(self, positions) -> ValueError:
        """The error for readable samples at ``positions`` whose data is non-finite (never true of a written one)."""
        idx = [int(i) for i in self.indices[np.asarray(positions)]]
        shown = ", ".join(map(str, idx[:8])) + (f", ... ({len(idx)} in all)" if len(idx) > 8 else "")
        return ValueError(f"{self.path}: damaged samples {shown}: non-finite or missing data although flagged "
                          "complete; recompute them with `pdestream generate ... --resume`")

    def _samples(self) -> np.ndarray:
        """Every readable sample of the file in memory: float32 [N, T, C, *space] (read once per process)."""
        if self._memory is None or self._pid != os.getpid():
            store = self._open()
            try:
                self._memory = np.stack([schema.from_disk(np.asarray(store[f][:])[self.rows], self._ndim)
                                         for f in self.fields], axis=self._axis)
            except Exception as err:  # a corrupted chunk anywhere: name the file (in_memory=False names the sample)
                self._memory = None
                self._check_same()
                raise ValueError(f"{self.path}: cannot read its samples: {_first_line(err)}") from None
            try:
                self._check_same()  # read by path: after a replacement it would be the new cache's data
            except ValueError:
                self._memory = None
                raise
            bad = np.flatnonzero(~np.isfinite(self._memory.reshape(len(self._memory), -1)).all(1))
            if len(bad):
                self._memory = None
                raise self._damaged(bad)
        return self._memory

    def _read(self, j: int, frames: slice) -> np.ndarray:
        """Frames of readable sample j straight from the file: float32 [frames, C, *space] ([C, *space] when steady)."""
        store = self._open()
        try:
            u = np.stack([schema.from_disk(np.asarray(store[f][int(self.rows[j]), frames]), self._ndim)
                          for f in self.fields], axis=self._axis - 1)
        except Exception as err:  # a corrupted chunk or a file changed under us: name the file and sample
            self._check_same()
            raise ValueError(f"{self.path}: cannot read sample {self.indices[j]}: {_first_line(err)}") from None
        self._check_same()  # read by path: after a replacement it would be the new cache's data
        if not np.isfinite(u).all():  # a deleted chunk reads as NaN
            raise self._damaged([j])
        return u

    def __getitem__(self, k: int) -> dict:
        if not -len(self) <= k < len(self):
            raise IndexError(f"index {k} out of range for {len(self)} examples")
        k %= len(self)
        j, sub = divmod(k, self.per_sample)
        lo, hi, view = self.view.cut(len(self.t), sub)  # read only the frames this example needs
        frames = slice(lo, hi) if self._axis == 2 else slice(None)  # a steady sample: all of it, no frames
        u = self._samples()[j, frames] if self.in_memory else self._read(j, frames)  # [T', C, *space] / [C, *space]
        return examples(view, torch.from_numpy(u), self.t[lo:hi], self.params[j], int(self.indices[j]))[0]



def _pin(path: str) -> int | None:
    """A read-only descriptor of the cache file or directory at ``path``: while it is open the inode cannot be
    freed and reused, so an identity check cannot take a later cache for this one. None when ``path`` cannot
    be opened (``open_cache`` then names the problem)."""
    try:
        return os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None


def _first_line(err: BaseException) -> str:
    text = str(err)
    return text.splitlines()[0] if text else type(err).__name__
