"""Cache samples to HDF5 or Zarr (``write_cache``), open a cache with xarray (``open_cache``).

Samples 0..N-1 are generated in fixed-size blocks (one compile) by ``generator.sample`` in a background
thread while the previous block is written, so writing costs little generation throughput. The schema
and crash-safety scheme are in ``datasets.schema``. The map-style loader is ``datasets.loader``.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import glob
import json
import os
import shutil
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import schema
from ._prefetch import prefetch

TARGET_BLOCK_BYTES = 32 * 2**20  # default block: ~32 MiB of samples (bounded memory, few block writes)


@dataclass
class WriteSummary:
    """What ``write_cache`` did: samples written this run, of total; wall seconds; bytes on disk."""

    path: str
    n_samples: int
    written: int
    seconds: float
    bytes: int
    repaired: int = 0  # damaged samples found by --resume and recomputed

    def line(self) -> str:
        """The one-line summary ``pdestream generate`` prints."""
        rate = self.written / self.seconds if self.seconds > 0 else 0.0
        fixed = f"; {self.repaired} damaged samples recomputed" if self.repaired else ""
        return (f"wrote {self.written} samples ({self.n_samples} of {self.n_samples} complete{fixed}) to {self.path} "
                f"in {self.seconds:.1f} s ({rate:.1f} samples/s), {self.bytes / 2**20:.1f} MiB")


def default_block(pde, n_samples: int) -> int:
    """Samples per block: ~TARGET_BLOCK_BYTES of float32 data (4 B x C x T x n**NDIM each), 1..256."""
    per_sample = 4 * len(pde.FIELDS) * pde.n_frames * pde.n**pde.NDIM
    return max(1, min(n_samples, 256, TARGET_BLOCK_BYTES // per_sample))


def _check_int(name: str, value, low: int, high: int | None = None) -> None:
    """ValueError naming ``value`` unless it is an integer in [low, high]."""
    ok = not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= low
    if not ok or (high is not None and value > high):
        allowed = f"an integer >= {low}" if high is None else f"an integer in [{low}, {high}]"
        raise ValueError(f"{name}={_plain(value)!r} not allowed: need {allowed}")


def _plain(value):
    """A value read back from HDF5/Zarr attributes as a plain Python value, for messages (no np.int64(0))."""
    value = value.item() if isinstance(value, np.generic) else value
    return value.decode() if isinstance(value, bytes) else value


def _check_writable(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise NotADirectoryError(f"cannot write {path}: {parent} is not a directory")
    if not parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"cannot write {path}: directory {parent} is not writable")


def _hidden(path: Path, tag: str) -> Path:
    """A hidden sibling of ``path`` for this process, keeping the suffix (the format is read from it)."""
    return path.with_name(f".{path.name}.{os.getpid()}.{tag}{path.suffix}")


def _rmtree_or_unlink(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _make(path: Path, fmt: str, lay: schema.Layout, block: int) -> None:
    schema.create_hdf5(str(path), lay) if fmt == "hdf5" else schema.create_zarr(str(path), lay, block)


def _create(path: Path, fmt: str, lay: schema.Layout, block: int) -> None:
    """Create under a temporary name and rename: a kill during creation leaves no half-made cache."""
    tmp = _hidden(path, "new")
    try:
        _make(tmp, fmt, lay, block)
        os.replace(tmp, path)
    except BaseException:
        _rmtree_or_unlink(tmp)
        raise


@contextmanager
def write_lock(path: Path):
    """One writer per cache, whatever the format: an exclusive ``flock`` on the hidden sidecar ``.NAME.lock``,
    held while the block runs and removed after. FileExistsError naming the holder's pid otherwise."""
    lock = path.with_name(f".{path.name}.lock")
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise ValueError(f"cannot lock {path}: {lock}: {err.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise FileExistsError(f"{path} is being written by another process (pid {pid}); wait for it to "
                                  "finish or stop it") from None
        try:  # the previous holder may have removed the sidecar between our open and flock: lock the live one
            live = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            live = False
        if live:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.unlink(lock)  # still held: a process that opened this inode finds it unlinked and retries
        os.close(fd)


def _foreign(path: Path) -> str | None:
    """None when ``path`` is a pdestream cache (ours to replace); otherwise what is there, in words."""
    if path.is_symlink():
        return f"a symlink to {os.readlink(path)}"
    fmt = schema.cache_format(path)
    if fmt == "zarr" and not path.is_dir():
        return "a file, not a Zarr store (a directory)"
    if fmt == "hdf5" and not path.is_file():
        return "a directory, not an HDF5 file" if path.is_dir() else "not a regular file"
    try:
        names = schema.root_attr_names(path)
    except (OSError, ValueError):
        if fmt == "zarr":
            held = sorted(p.name for p in path.iterdir())
            return f"a directory that is not a Zarr store (holds {', '.join(held[:3]) or 'nothing'}" + \
                (", ..." if len(held) > 3 else "") + ")"
        return "a file that is not a readable HDF5 file (if it is a damaged cache, remove it yourself)"
    ours = {schema.CONFIG_ATTR, "pdestream_schema", "pdestream_fields", "pdestream_params"}
    if not ours <= names:
        return f"{'a Zarr store' if fmt == 'zarr' else 'an HDF5 file'} without pdestream's attributes"
    if fmt == "zarr":  # files a user added inside our store would be lost with it
        attrs = json.loads((path / "zarr.json").read_text())["attributes"]
        variables = f"{attrs['pdestream_fields']} {attrs['pdestream_params']}".split()
        known = {"zarr.json", "sample", "time", *schema.SPACE, "redraws", "complete", *variables}
        extra = sorted(p.name for p in path.iterdir() if p.name not in known)
        if extra:
            return f"a pdestream cache with other files in it ({', '.join(extra[:3])}{', ...' if len(extra) > 3 else ''})"
    return None


def _remove_stale(path: Path) -> None:
    """Remove hidden work copies of ``path`` left by pdestream writers that were killed (their pid is gone).
    Called under the write lock, so no live writer of ``path`` owns one."""
    for p in path.parent.glob(f".{glob.escape(path.name)}.*.*{glob.escape(path.suffix)}"):
        pid, _, tag = p.name[len(path.name) + 2 : len(p.name) - len(path.suffix)].partition(".")
        if tag in ("new", "tmp") and pid.isdigit() and not _alive(int(pid)):
            _rmtree_or_unlink(p)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


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


def _swap_in(new: Path, path: Path) -> None:
    """Put the finished cache ``new`` at ``path`` in place of the old one, then delete the old one."""
    if new.is_file() or not path.exists():
        os.replace(new, path)  # one atomic rename over the old file (or into a place left empty)
        return
    if _exchange(new, path):  # the old store now sits at ``new``
        shutil.rmtree(new)
        return
    aside = _hidden(path, "old")  # a kill between the two renames leaves the old store here, not lost
    os.rename(path, aside)
    try:
        os.rename(new, path)
    except BaseException:
        os.rename(aside, path)
        raise
    shutil.rmtree(aside)


def _check_resume(path: Path, attrs: dict, lay: schema.Layout) -> None:
    """Refuse to finish a cache that another configuration (or JAX PRNG set-up) started."""
    keys = ("pdestream_config_hash", "pdestream_seed", "pdestream_n_samples", "pdestream_on_blowup",
            "jax_version", "jax_threefry_partitionable", "pdestream_schema")
    diff = []
    for k in keys:
        cached, asked = _plain(attrs.get(k)), _plain(lay.attrs[k])
        if cached == asked:
            continue
        line = f"{k[10:] if k.startswith('pdestream_') else k}: cache {cached!r} vs asked {asked!r}"
        if k == "pdestream_config_hash":  # name the settings behind the hash
            settings = _config_diff(attrs.get(schema.CONFIG_ATTR), lay.attrs[schema.CONFIG_ATTR])
            line += f" (settings that differ: {'; '.join(settings)})" if settings else ""
        diff.append(line)
    if diff:
        raise ValueError(f"cannot resume {path}: it was written with a different set-up ({'; '.join(diff)}); "
                         "use the same PDE settings, seed and --n, or --overwrite to start again")


def _config_diff(cached_json, asked_json) -> list[str]:
    """The PDE settings that differ between two stored configs (JSON), as "name: cache X vs asked Y"."""
    try:
        cached, asked = _flat(json.loads(_plain(cached_json))), _flat(json.loads(asked_json))
    except (TypeError, ValueError):
        return []  # an unreadable stored config: the caller names the config as a whole
    return [f"{k}: cache {cached.get(k, '(unset)')} vs asked {asked.get(k, '(unset)')}"
            for k in sorted(set(cached) | set(asked)) if cached.get(k) != asked.get(k)]


def _flat(config: dict, prefix: str = "") -> dict:
    """{"ic": {"alpha": 2}} -> {"ic.alpha": 2}: the names --set uses."""
    out = {}
    for k, v in config.items():
        out.update(_flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def solve_block(pde, seed: int, lo: int, hi: int, block: int, on_blowup: str):
    """Samples lo..hi-1 solved as one batch padded to ``block`` (one compile for every block):
    (u float32 [hi-lo, T, C, *space], {param: float32 [hi-lo]}, redraws int8 [hi-lo]) as numpy."""
    from ._bridge import sample_numpy

    idx = np.minimum(np.arange(lo, lo + block), hi - 1)  # pad by repeating the last index
    u, params, redraws = sample_numpy(pde, idx, seed, on_blowup)
    return (u[: hi - lo], {k: v[: hi - lo] for k, v in params.items()},
            np.minimum(redraws[: hi - lo], 127).astype(np.int8))


def write_block(store, pde, lo: int, hi: int, u, params, redraws) -> None:
    """Write one block's data, then its ``complete`` flags (the flags vouch for data already written)."""
    for c, name in enumerate(pde.FIELDS):
        store[name][lo:hi] = schema.to_disk(u[:, :, c], pde.NDIM)  # stored (z,) y, x: see datasets.schema
    for name, values in params.items():
        store[name][lo:hi] = values
    store["redraws"][lo:hi] = redraws
    if hasattr(store, "flush"):
        store.flush()  # data reaches the file before the flags that vouch for it
    store["complete"][lo:hi] = np.ones(hi - lo, np.int8)
    if hasattr(store, "flush"):
        store.flush()


def write_cache(pde, path, n_samples: int, seed: int = 0, resume: bool = False, overwrite: bool = False,
                block: int | None = None, on_blowup: str = "raise", progress: bool = True) -> WriteSummary:
    """Write samples 0..n_samples-1 of ``pde`` under ``seed`` to ``path`` (.h5/.hdf5 or .zarr).

    Fields are float32 [sample, time, (z,) (y,) x] on disk (schema and axis order in ``datasets.schema``).
    ``block`` samples are solved per batch (default: ~32 MiB); ``resume`` finishes an interrupted cache of the same set-up
    (bit-identical to an uninterrupted run); ``overwrite`` replaces an existing pdestream cache (the new one
    is built beside it and swapped in only once complete). ``progress`` shows a tqdm bar when stderr is a
    terminal.
    """
    from ._bridge import resolve_pde

    pde = resolve_pde(pde)  # a catalog name or a generator PDE, like every other entry point
    start = time.perf_counter()
    with writing(pde, path, n_samples, seed, resume, overwrite, block, on_blowup) as job:
        written = _fill(pde, job, progress)
    return WriteSummary(str(job.path), int(n_samples), written, time.perf_counter() - start,
                        schema.disk_bytes(job.path), job.repaired)


@dataclass
class Job:
    """A cache being written: ``path`` (where it ends up), ``work`` (where blocks are written: ``path``, or a
    hidden sibling when replacing an old cache), its layout and block."""

    path: Path
    work: Path
    lay: schema.Layout
    block: int
    repaired: int = 0  # damaged samples of a resumed cache, reopened to be recomputed


@contextmanager
def writing(pde, path, n_samples, seed=0, resume=False, overwrite=False, block=None, on_blowup="raise"):
    """Check the arguments, lock ``path``, create the cache (or check the one to resume) and yield a ``Job``.
    Shared by ``write_cache`` and the Dask writer (``datasets.distributed``).

    Safety: a refused call creates nothing; ``overwrite`` replaces only a pdestream cache, building the new
    one beside it and swapping it in when the block exits cleanly (a failure or Ctrl-C removes the new one and
    leaves the old untouched); a failed fresh cache with no sample written is removed (nothing to resume).
    """
    from ._bridge import configure_jax, jax_provenance, max_index, resolve_pde

    # every argument is checked before anything is created: a refused run leaves nothing behind
    path = Path(path)
    fmt = schema.cache_format(path)
    pde = resolve_pde(pde)  # a generator PDE (its config was checked when it was built) or a catalog name
    _check_int("n_samples", n_samples, 1, max_index() + 1)
    _check_int("seed", seed, 0, 2**63 - 1)
    if block is not None:
        _check_int("block", block, 1)
    if resume and overwrite:
        raise ValueError("--resume and --overwrite exclude each other: resume finishes a cache, overwrite replaces it")
    if on_blowup not in ("raise", "redraw"):
        raise ValueError(f"on_blowup={on_blowup!r} not allowed; allowed: 'raise', 'redraw'")
    if path.is_symlink():  # acting through a link would replace or fill whatever it points at
        raise ValueError(f"{path} is a symlink to {os.readlink(path)}; pdestream does not write through links: "
                         "give the real path")
    if path.exists() and not (resume or overwrite):
        raise FileExistsError(f"{path} exists; pass --resume to finish it or --overwrite to replace it")
    _check_writable(path)
    with write_lock(path):
        exists = path.exists()  # again, under the lock: another writer may have made it meanwhile
        if exists and not (resume or overwrite):
            raise FileExistsError(f"{path} exists; pass --resume to finish it or --overwrite to replace it")
        if overwrite and exists and (what := _foreign(path)):
            raise ValueError(f"refusing to overwrite {path}: it is {what}; --overwrite replaces only a pdestream "
                             "cache (remove it yourself or choose another path)")
        configure_jax()
        stored = None
        if resume and exists:
            info = open_cache(path)  # clear error if it is not a cache
            stored, info = dict(info.attrs), info.close()
        if block is None:
            block = stored["pdestream_block"] if stored else default_block(pde, n_samples)
        block = int(min(block, n_samples))
        lay = schema.layout(pde, int(n_samples), int(seed), block, on_blowup, jax_provenance())
        if stored:
            _check_resume(path, stored, lay)
            if stored["pdestream_block"] != block:
                raise ValueError(f"cannot resume {path} with block={block}: it was started with block="
                                 f"{stored['pdestream_block']} (leave --block out to use it)")
        _remove_stale(path)
        repaired = _reopen_damaged(path, lay, block) if stored else 0
        job = Job(path, _hidden(path, "tmp") if exists and overwrite else path, lay, block, repaired)
        created = not stored
        try:
            if created:
                try:  # a replacement is built at its hidden work path, a new cache made whole then renamed
                    _make(job.work, fmt, lay, block) if job.work != path else _create(path, fmt, lay, block)
                except OSError as err:
                    raise ValueError(f"cannot create {path}: {err}") from None
            yield job
            if job.work != path:
                if path.exists() and (what := _foreign(path)):  # replaced by someone else while we wrote
                    raise ValueError(f"refusing to overwrite {path}: it became {what} during the run")
                _swap_in(job.work, path)
        except BaseException:
            if job.work != path:
                _rmtree_or_unlink(job.work)  # ours: the old cache at ``path`` was never touched
            elif created and not _any_written(path):
                _rmtree_or_unlink(path)  # ours, and nothing in it to resume: a rerun needs no --overwrite
            raise


def damaged_samples(store, names, block: int = 64) -> np.ndarray:
    """Positions of samples flagged complete whose data in ``names`` (fields, parameters) is non-finite or
    unreadable: a written sample is always finite, a deleted Zarr chunk reads as NaN, a corrupted one fails
    its checksum. Reads ``block`` samples at a time."""
    done = np.asarray(store["complete"][:]) == 1
    bad = []
    for lo in range(0, len(done), block):
        hi = min(lo + block, len(done))
        if not done[lo:hi].any():
            continue
        ok = np.ones(hi - lo, bool)
        for name in names:
            try:
                ok &= np.isfinite(np.asarray(store[name][lo:hi]).reshape(hi - lo, -1)).all(1)
            except Exception:  # an unreadable chunk: every sample of the block is suspect
                ok[:] = False
        bad.extend(lo + np.flatnonzero(done[lo:hi] & ~ok))
    return np.asarray(bad, np.int64)


def _reopen_damaged(path: Path, lay: schema.Layout, block: int) -> int:
    """Resume: clear the flags of damaged samples (and the global flag) so they are solved again."""
    store = schema.open_store(str(path), "r+")
    try:
        bad = damaged_samples(store, [*lay.fields, *(p for p in lay.per_sample if p not in ("redraws", "complete"))],
                              block)
        if len(bad):
            schema.mark_complete(store, str(path), value=0)  # no longer complete until they are rewritten
            flags = np.asarray(store["complete"][:])
            flags[bad] = 0
            store["complete"][:] = flags
    finally:
        schema.close(store)
    return len(bad)


def _any_written(path: Path) -> bool:
    """True when a sample of the cache at ``path`` is flagged complete (or it cannot be read: keep it)."""
    try:
        store = schema.open_store(str(path), "r")
        try:
            return bool((np.asarray(store["complete"][:]) == 1).any())
        finally:
            schema.close(store)
    except Exception:
        return True


def pending_blocks(store, block: int) -> list[tuple[int, int]]:
    """The (lo, hi) blocks of a cache with a sample not yet marked complete."""
    done = np.asarray(store["complete"][:]) == 1
    return [(lo, min(lo + block, len(done))) for lo in range(0, len(done), block) if not done[lo : lo + block].all()]


def _fill(pde, job: Job, progress: bool) -> int:
    """Solve and write every pending block of ``job``, then mark it complete; returns the samples written."""
    from tqdm import tqdm

    lay, block = job.lay, job.block
    n = lay.dims["sample"]
    store = schema.open_store(str(job.work), "r+")
    written = 0
    try:
        todo = pending_blocks(store, block)
        bar = tqdm(total=n, initial=n - sum(hi - lo for lo, hi in todo), unit="sample", desc=pde.NAME, smoothing=0.1,
                   disable=not progress or not sys.stderr.isatty())
        seed, on_blowup = lay.attrs["pdestream_seed"], lay.attrs["pdestream_on_blowup"]
        # one block solved ahead of the one being written; each padded to ``block`` samples (one compile)
        solved = prefetch(lambda: ((lo, hi, *solve_block(pde, seed, lo, hi, block, on_blowup)) for lo, hi in todo))
        try:
            for item in solved:
                lo, hi = item[:2]
                write_block(store, pde, *item)
                written += hi - lo
                bar.update(hi - lo)
        finally:
            # stops the solver thread; Ctrl-C or a failed write waits at most for the solve in flight
            solved.close()
            bar.close()
        if not (np.asarray(store["complete"][:]) == 1).all():
            raise RuntimeError(f"{job.path}: blocks missing after writing (a bug)")
        schema.mark_complete(store, str(job.work))
    finally:
        schema.close(store)
    return written


def open_cache(path, complete_only: bool = False):
    """The cache at ``path`` as an xarray.Dataset (lazy); ``complete_only`` keeps written samples only.

    ValueError (one line) for a missing path, a file that is not a pdestream cache, or an unreadable one.
    """
    import xarray as xr

    path = Path(path)
    fmt = schema.cache_format(path)
    if not path.exists():
        raise ValueError(f"no cache at {path}: the path does not exist")
    try:
        if fmt == "hdf5":
            ds = xr.open_dataset(path, engine="h5netcdf", phony_dims="access")  # foreign files too
        else:
            try:
                ds = xr.open_zarr(path, consolidated=True)
            except ValueError as err:  # no consolidated entry (a writer cut by an older pdestream): read the parts
                if "onsolidated metadata" not in str(err):
                    raise
                ds = xr.open_zarr(path, consolidated=False)
    except Exception as err:  # h5py / zarr / json errors of every kind: name the file, not the library
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        if "unable to lock file" in detail:
            raise ValueError(f"{path} is open for writing by another process (HDF5 locks it while a "
                             "generate runs); wait for it to finish or stop it") from None
        raise ValueError(f"{path} is not a readable {fmt} cache (truncated or corrupted?): {detail}") from None
    missing = [k for k in (schema.CONFIG_ATTR, "pdestream_n_samples", "pdestream_fields", "pdestream_params")
               if k not in ds.attrs]
    missing += [v for v in ("complete", "sample") if v not in ds.variables]
    if missing:
        ds.close()
        raise ValueError(f"{path} is not a pdestream cache (missing {', '.join(missing)})")
    stored = [f for f in str(ds.attrs["pdestream_fields"]).split() if f in ds.variables]
    try:  # a schema-1 cache of 2D fields stored them (x, y): refused rather than read the wrong way round
        schema.check_readable(path, ds.attrs, ds[stored[0]].dims if stored else ())
    except ValueError:
        ds.close()
        raise
    if ds.sizes["sample"] != ds.attrs["pdestream_n_samples"]:
        ds.close()
        raise ValueError(f"{path} is damaged: {ds.sizes['sample']} samples stored, {ds.attrs['pdestream_n_samples']} expected")
    if complete_only:
        ds = ds.isel(sample=np.flatnonzero(ds["complete"].values == 1))
    return ds


def is_complete(ds) -> bool:
    """True when every sample is written and the writer finished (the flag it sets last)."""
    return bool(ds.attrs.get("pdestream_complete") == 1 and (ds["complete"].values == 1).all())
