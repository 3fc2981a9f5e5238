"""How a cache is stored: the run settings it was written with (``CacheSettings``, read from its root
attributes in one place) and its format (``CacheFormat``: HDF5 or Zarr behind one small interface, chosen by
the path's suffix with ``format_of``). The layout itself (arrays, dims, attributes) is ``datasets.schema``.

Nothing here imports JAX: readers (``datasets.loader``) use it too.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from . import schema

# attributes that describe the run a cache came from, besides the PDE config (compared on --resume)
PROVENANCE = ("jax_version", "jax_threefry_partitionable", "pdestream_numerics", "pdestream_schema")


def plain(value):
    """A value read back from HDF5/Zarr attributes as a plain Python value, for messages (no np.int64(0))."""
    value = value.item() if isinstance(value, np.generic) else value
    return value.decode() if isinstance(value, bytes) else value


@dataclass(frozen=True)
class CacheSettings:
    """The settings a cache is written with: the resolved PDE config (a JSON-able dict) and its hash, the seed,
    the sample count, samples per block, the blow-up policy, field and parameter names (PDE order), and the
    JAX provenance that makes samples reproducible (``PROVENANCE`` attributes). ``inputs``: a steady PDE's
    random input fields, stored as variables before its fields (empty otherwise)."""

    config: dict
    config_hash: str
    seed: int
    n_samples: int
    block: int
    on_blowup: str
    fields: tuple[str, ...]
    params: tuple[str, ...]
    provenance: dict
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()  # the PDE's per-sample outputs (PDE.OUTPUTS), each a variable

    @classmethod
    def of(cls, pde, n_samples: int, seed: int, block: int, on_blowup: str, provenance: dict) -> CacheSettings:
        """The settings of a new cache of ``pde`` (a generator PDE)."""
        return cls(pde.config(), pde.config_hash(), int(seed), int(n_samples), int(block), on_blowup,
                   tuple(pde.FIELDS), tuple(pde.PARAMS), {**provenance, "pdestream_schema": schema.SCHEMA_VERSION},
                   tuple(getattr(pde, "INPUTS", ())), tuple(getattr(pde, "OUTPUTS", {})))

    @classmethod
    def from_attrs(cls, attrs, path) -> CacheSettings:
        """The settings stored in a cache's root attributes (the one place they are read back); a one-line
        ValueError naming ``path`` and the attribute that is missing or not what pdestream writes."""
        def get(name, check, what):
            if name not in attrs:
                raise ValueError(f"{path} is not a pdestream cache (missing attribute {name})")
            value = plain(attrs[name])
            if not check(value):
                shown = repr(value)
                shown = shown if len(shown) <= 60 else shown[:57] + "..."
                raise ValueError(f"{path} is damaged: attribute {name} = {shown} is not {what}")
            return value

        def whole(low):
            return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= low

        text = get(schema.CONFIG_ATTR, lambda v: isinstance(v, str) and _json_object(v) is not None,
                   "a JSON object (the PDE config pdestream writes)")
        return cls(
            config=_json_object(text),
            config_hash=get("pdestream_config_hash", lambda v: isinstance(v, str), "a string"),
            seed=get("pdestream_seed", whole(0), "an integer >= 0"),
            n_samples=get("pdestream_n_samples", whole(1), "an integer >= 1"),
            block=get("pdestream_block", whole(1), "an integer >= 1"),
            on_blowup=get("pdestream_on_blowup", lambda v: v in ("raise", "redraw"), "'raise' or 'redraw'"),
            fields=tuple(get("pdestream_fields", lambda v: isinstance(v, str) and v.split(),
                             "a space-separated list of field names").split()),
            params=tuple(get("pdestream_params", lambda v: isinstance(v, str), "a space-separated list").split()),
            provenance={k: plain(attrs.get(k)) for k in PROVENANCE},
            inputs=tuple(plain(attrs.get("pdestream_inputs", "")).split())
            if isinstance(plain(attrs.get("pdestream_inputs", "")), str) else (),
            outputs=tuple(plain(attrs.get("pdestream_outputs", "")).split())  # absent in caches before them
            if isinstance(plain(attrs.get("pdestream_outputs", "")), str) else (),
        )

    @property
    def variables(self) -> tuple[str, ...]:
        """Every per-sample data variable: the input fields (steady PDEs), the fields, the parameters, the outputs."""
        return (*self.inputs, *self.fields, *self.params, *self.outputs)

    def differences(self, other: CacheSettings) -> list[str]:
        """What differs from ``other`` that makes samples differ, as "name: cache X vs asked Y" (self: the cache)."""
        out = []
        if self.config_hash != other.config_hash:
            settings = [f"{k}: cache {a.get(k, 'its default')} vs asked {b.get(k, 'its default')}"
                        for a, b in [(_flat(self.config), _flat(other.config))]
                        for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
            out.append(f"config_hash: cache {self.config_hash!r} vs asked {other.config_hash!r}"
                       + (f" (settings that differ: {'; '.join(settings)})" if settings else ""))
        for name in ("seed", "n_samples", "on_blowup"):
            if getattr(self, name) != getattr(other, name):
                out.append(f"{name}: cache {getattr(self, name)!r} vs asked {getattr(other, name)!r}")
        for k in PROVENANCE:
            if self.provenance.get(k) != other.provenance.get(k):
                name = k[10:] if k.startswith("pdestream_") else k
                out.append(f"{name}: cache {self.provenance.get(k)!r} vs asked {other.provenance.get(k)!r}")
        return out


def _json_object(text: str) -> dict | None:
    try:
        value = json.loads(text)
    except ValueError:
        return None
    return value if isinstance(value, dict) else None


def _flat(config: dict, prefix: str = "") -> dict:
    """{"ic": {"alpha": 2}} -> {"ic.alpha": 2}: the names --set uses."""
    out = {}
    for k, v in config.items():
        out.update(_flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


# --- formats ---------------------------------------------------------------------------------------
class Store(Protocol):
    """An open cache: ``store[name]`` is an array indexed like numpy (``[lo:hi]`` reads and writes)."""

    def __getitem__(self, name: str): ...

    def __contains__(self, name: str) -> bool: ...

    def flush(self) -> None:
        """Make the writes so far reach the disk (before the flags that vouch for them)."""

    def close(self) -> None: ...


class CacheFormat(Protocol):
    """One on-disk format of a cache (``HDF5``, ``ZARR``); paths are ``pathlib.Path``."""

    name: str  # "hdf5" / "zarr", as messages say it
    noun: str  # "an HDF5 file" / "a Zarr store", for messages about what is at a path
    parallel_writers: bool  # several processes may write different blocks at once (the Dask executor)

    def kind_problem(self, path: Path) -> str | None:
        """What is at an existing ``path`` when it is not this format's kind of entry (file / directory), else None."""

    def create(self, path: Path, lay: schema.Layout, block: int) -> None:
        """A new cache at ``path`` with every array laid out (``schema``); writing blocks then changes data only."""

    def open(self, path: Path, writable: bool = False) -> Store:
        """The cache's arrays for reading (or for writing blocks); a one-line ValueError when it cannot be opened."""

    def mark_complete(self, store: Store, value: int = 1) -> None:
        """Set (or with 0 clear) the global completion flag, in one step that a kill cannot leave half done."""

    def dataset(self, path: Path):
        """The cache as a lazy ``xarray.Dataset`` (any library error propagates; ``open_cache`` names it)."""

    def root_attrs(self, path: Path) -> dict:
        """The root attributes, read without writing or locking; OSError / ValueError when ``path`` is not one."""

    def extra_entries(self, path: Path, attrs: dict) -> list[str]:
        """Entries inside the cache (root attributes ``attrs``) that pdestream did not write (a user's files,
        lost with it on --overwrite)."""

    def replace(self, new: Path, path: Path, aside: Path) -> None:
        """Put the finished cache ``new`` at ``path`` in place of the old one (``aside``: where the old one may wait
        between two renames), then delete the old one."""

    def remove(self, path: Path) -> None:
        """Delete a cache of this format (ours: a work copy, or a failed new cache)."""


def format_of(path) -> CacheFormat:
    """The format of a cache path from its suffix (.h5/.hdf5: HDF5, .zarr: Zarr); one-line ValueError otherwise."""
    return FORMATS[schema.cache_format(path)]


def identity(path) -> tuple[int, int]:
    """(device, inode) of what is at ``path`` now: a replacement built beside and renamed into place has another.
    OSError when nothing is there."""
    st = os.stat(path)
    return st.st_dev, st.st_ino


def remove_any(path: Path) -> None:
    """Delete a file, link or directory tree at ``path`` (nothing there: nothing done)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _first_line(err: BaseException) -> str:
    text = str(err)
    return text.splitlines()[0] if text else type(err).__name__


class Hdf5Format:
    """One HDF5 file (netCDF4-compatible, through h5netcdf); HDF5 allows one writer per file."""

    name = "hdf5"
    noun = "an HDF5 file"
    parallel_writers = False

    def kind_problem(self, path):
        if path.is_file():
            return None
        return "a directory, not an HDF5 file" if path.is_dir() else "not a regular file"

    def create(self, path, lay, block):
        schema.create_hdf5(str(path), lay)

    def open(self, path, writable=False):
        import h5py

        try:
            return h5py.File(path, "r+" if writable else "r")
        except OSError as err:
            if "unable to lock file" in str(err):  # HDF5's own lock: another process has the file open
                raise ValueError(f"{path} is held open by another process (HDF5 locks a file while a program "
                                 f"{'reads or ' if writable else ''}writes it); close that program or wait for "
                                 "it, then run this again") from None
            raise ValueError(f"{path} is not a readable hdf5 cache (truncated or corrupted?): {_first_line(err)}") from None

    def mark_complete(self, store, value=1):
        store.attrs["pdestream_complete"] = np.int64(value)
        store.flush()

    def dataset(self, path):
        import xarray as xr

        return xr.open_dataset(path, engine="h5netcdf", phony_dims="access")  # foreign files too

    def root_attrs(self, path):
        import h5py

        try:
            f = h5py.File(path, "r", locking=False)  # read-only; another process may hold it open (and locked)
        except OSError:  # HDF5 refuses a second open with other locking flags: this process holds it open
            f = h5py.File(path, "r")
        with f:
            return dict(f.attrs)

    def extra_entries(self, path, attrs):
        return []  # a file holds nothing but what its writer put there

    def replace(self, new, path, aside):
        os.replace(new, path)  # one atomic rename over the old file (a reader holding it keeps the old inode)

    def remove(self, path):
        path.unlink(missing_ok=True)


class _ZarrStore:
    """A zarr.Group with the ``Store`` methods (Zarr writes each chunk when assigned: nothing to flush or close)."""

    def __init__(self, path: Path, group):
        self.path, self.group = path, group

    def __getitem__(self, name):
        return self.group[name]

    def __contains__(self, name):
        return name in self.group

    def flush(self):
        pass

    def close(self):
        pass


class ZarrFormat:
    """A Zarr v3 directory store with consolidated metadata; blocks cover whole chunks, so several processes
    may write different blocks at once."""

    name = "zarr"
    noun = "a Zarr store"
    parallel_writers = True

    def kind_problem(self, path):
        return None if path.is_dir() else "a file, not a Zarr store (a directory)"

    def create(self, path, lay, block):
        schema.create_zarr(str(path), lay, block)

    def open(self, path, writable=False):
        import zarr

        if not (path / "zarr.json").is_file():
            raise ValueError(f"{path} is not a readable zarr cache: no zarr.json in it")
        try:
            group = zarr.open_group(str(path), mode="r+" if writable else "r", zarr_format=3, use_consolidated=False)
        except Exception as err:  # zarr / json errors of every kind: name the store
            raise ValueError(f"{path} is not a readable zarr cache (truncated or corrupted?): {_first_line(err)}") from None
        return _ZarrStore(path, group)

    def mark_complete(self, store, value=1):
        # one atomic replace of the root zarr.json (attributes and consolidated metadata together): a kill at
        # any point leaves the old or the new file, both readable
        meta_path = store.path / "zarr.json"
        meta = json.loads(meta_path.read_text())
        if not meta.get("consolidated_metadata"):  # a cache cut by an older writer between its two steps
            schema.consolidate(str(store.path))
            meta = json.loads(meta_path.read_text())
        meta["attributes"]["pdestream_complete"] = int(value)
        schema.atomic_write(meta_path, json.dumps(meta, indent=2).encode())

    def dataset(self, path):
        import xarray as xr

        try:
            return xr.open_zarr(path, consolidated=True)
        except ValueError as err:  # no consolidated entry (a writer cut by an older pdestream): read the parts
            if "onsolidated metadata" not in str(err):
                raise
            return xr.open_zarr(path, consolidated=False)

    def root_attrs(self, path):
        attrs = json.loads((path / "zarr.json").read_text()).get("attributes")
        if not isinstance(attrs, dict):
            raise ValueError(f"{path}/zarr.json has no attributes")
        return attrs

    def extra_entries(self, path, attrs):
        names = " ".join(str(attrs.get(f"pdestream_{k}", "")) for k in ("inputs", "fields", "params")).split()
        known = {"zarr.json", "sample", "time", "x", "y", "z", "redraws", "complete", *names}
        return sorted(p.name for p in path.iterdir() if p.name not in known)

    def replace(self, new, path, aside):
        if not path.exists():
            os.rename(new, path)
            return
        if _exchange(new, path):  # one atomic step; the old store now sits at ``new``
            shutil.rmtree(new)
            return
        os.rename(path, aside)  # a kill between the two renames leaves the old store at ``aside``, not lost
        try:
            os.rename(new, path)
        except BaseException:
            os.rename(aside, path)
            raise
        shutil.rmtree(aside)

    def remove(self, path):
        remove_any(path)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one atomic step (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


HDF5, ZARR = Hdf5Format(), ZarrFormat()
FORMATS: dict[str, CacheFormat] = {"hdf5": HDF5, "zarr": ZARR}
