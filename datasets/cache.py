"""Cache samples to HDF5 or Zarr (``write_cache``), open a cache with xarray (``open_cache``).

Samples 0..N-1 are generated in fixed-size blocks (one compile) by ``generator.sample`` in a background
thread while the previous block is written, so writing costs little generation throughput. The schema
and crash-safety scheme are in ``datasets.schema``. The map-style loader is ``datasets.loader``.
"""

from __future__ import annotations

import errno
import fcntl
import glob
import hashlib
import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import schema
from ._prefetch import prefetch
from .store import CacheFormat, CacheSettings, format_of, plain, remove_any

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
    """Samples per block: ~TARGET_BLOCK_BYTES of float32 data (4 B x C x T x n**NDIM each, n of the grid solved on:
    a refined spectral entry holds its block's trajectories there before keeping every refine-th point), 1..256."""
    solved = getattr(pde, "solved", pde)  # ``refine``: n * refine points per axis
    per_sample = 4 * len((*pde.INPUTS, *pde.FIELDS)) * pde.n_frames * math.prod(solved.grid.shape)  # steady: 1 frame
    return max(1, min(n_samples, 256, TARGET_BLOCK_BYTES // per_sample))


def _check_int(name: str, value, low: int, high: int | None = None) -> None:
    """ValueError naming ``value`` unless it is an integer in [low, high]."""
    ok = not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= low
    if not ok or (high is not None and value > high):
        allowed = f"an integer >= {low}" if high is None else f"an integer in [{low}, {high}]"
        raise ValueError(f"{name}={plain(value)!r} not allowed: need {allowed}")


def _name_max(directory: Path) -> int:
    """The longest file name (bytes) the filesystem of ``directory`` allows."""
    try:
        return os.pathconf(directory, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def _check_writable(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise NotADirectoryError(f"cannot write {path}: {parent} is not a directory")
    if not parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"cannot write {path}: directory {parent} is not writable")


def _check_name(path: Path) -> None:
    """ValueError when the name of ``path`` is longer than its filesystem allows (checked before any other use
    of the path, which would fail with the OS's bare "File name too long")."""
    parent = path.parent if str(path.parent) else Path(".")
    length, allowed = len(os.fsencode(path.name)), _name_max(parent)
    if length > allowed:
        raise ValueError(f"cannot write {path}: its name is {length} bytes long, the filesystem allows at most "
                         f"{allowed}; choose a shorter name")


def _hidden_stem(path: Path) -> str:
    """The stem of ``path``'s hidden siblings (lock, work copies): its own name, or a digest of a name so long
    (yet legal) that ``.NAME.PID.TAG.SUFFIX`` would pass the filesystem's limit on names."""
    name = path.name
    if len(os.fsencode(name)) + 32 <= _name_max(path.parent if str(path.parent) else Path(".")):  # 32: the additions
        return name
    return "pdestream-" + hashlib.sha256(os.fsencode(name)).hexdigest()[:24]


def _hidden(path: Path, tag: str) -> Path:
    """A hidden sibling of ``path`` for this process, keeping the suffix (the format is read from it)."""
    return path.with_name(f".{_hidden_stem(path)}.{os.getpid()}.{tag}{path.suffix}")


def _create(path: Path, fmt: CacheFormat, lay: schema.Layout, block: int) -> None:
    """Create under a temporary name and rename: a kill during creation leaves no half-made cache."""
    tmp = _hidden(path, "new")
    try:
        fmt.create(tmp, lay, block)
        os.replace(tmp, path)
    except BaseException:
        remove_any(tmp)
        raise


@contextmanager
def write_lock(path: Path):
    """One writer per cache, whatever the format: an exclusive ``flock`` on the hidden sidecar ``.NAME.lock``,
    held while the block runs and removed after. FileExistsError naming the holder's pid otherwise."""
    lock = path.with_name(f".{_hidden_stem(path)}.lock")
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
    fmt = format_of(path)
    if what := fmt.kind_problem(path):
        return what
    try:
        attrs = fmt.root_attrs(path)
    except (OSError, ValueError):
        if path.is_dir():
            held = sorted(p.name for p in path.iterdir())
            return f"a directory that is not a Zarr store (holds {', '.join(held[:3]) or 'nothing'}" + \
                (", ..." if len(held) > 3 else "") + ")"
        return "a file that is not a readable HDF5 file (if it is a damaged cache, remove it yourself)"
    if "pdestream_export" in attrs:  # (same attributes as a cache; it was replaced by one)
        return f"a pdestream export ({plain(attrs['pdestream_export'])} layout), not a cache"
    if not {schema.CONFIG_ATTR, "pdestream_schema", "pdestream_fields", "pdestream_params"} <= set(attrs):
        return f"{fmt.noun} without pdestream's attributes"
    extra = fmt.extra_entries(path, attrs)  # a user's files inside our store would be lost with it
    if extra:
        return f"a pdestream cache with other files in it ({', '.join(extra[:3])}{', ...' if len(extra) > 3 else ''})"
    return None


def _remove_stale(path: Path) -> None:
    """Remove hidden work copies of ``path`` left by pdestream writers that were killed (their pid is gone).
    Called under the write lock, so no live writer of ``path`` owns one."""
    stem = _hidden_stem(path)
    for p in path.parent.glob(f".{glob.escape(stem)}.*.*{glob.escape(path.suffix)}"):
        pid, _, tag = p.name[len(stem) + 2 : len(p.name) - len(path.suffix)].partition(".")
        if tag in ("new", "tmp") and pid.isdigit() and not _alive(int(pid)):
            remove_any(p)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _check_resume(path: Path, cached: CacheSettings, asked: CacheSettings) -> None:
    """Refuse to finish a cache that another configuration (or JAX PRNG set-up) started."""
    diff = cached.differences(asked)
    if diff:
        raise ValueError(f"cannot resume {path}: it was written with a different set-up ({'; '.join(diff)}); "
                         "use the same PDE settings, seed and --n, or --overwrite to start again")


def _errno_of(err: BaseException) -> int | None:
    code = getattr(err, "errno", None)
    if code is None and "errno = " in str(err):  # h5py: "... errno = 28, error message = ..."
        digits = str(err).split("errno = ", 1)[1].split(",", 1)[0]
        code = int(digits) if digits.isdigit() else None
    return code


def os_error_cause(err: BaseException) -> str:
    """An OS error in words, without the library's wrapping (h5py puts a whole report in its message)."""
    code, strerror = _errno_of(err), getattr(err, "strerror", None)
    if code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return os.strerror(code).lower()
    if code is not None and (strerror is None or "(" in str(strerror)):
        return os.strerror(code).lower()
    text = strerror or str(err)
    return text.splitlines()[0] if text else type(err).__name__


def is_write_failure(err: BaseException) -> bool:
    """An OSError, or h5py's RuntimeError around one (a failed close reports the OS's errno in its text)."""
    return isinstance(err, OSError) or (isinstance(err, RuntimeError) and _errno_of(err) is not None)


class CacheWriteError(ValueError):
    """Writing a block or the completion flag failed at the OS level (disk full, I/O error): one line naming the
    cache and the cause; ``writing`` adds what was kept."""


ROOM_MARGIN = 2**16  # bytes beyond the arrays: HDF5's metadata


def check_room(path: Path, nbytes: int, one_file: bool = True) -> None:
    """CacheWriteError when ``nbytes`` array bytes cannot fit at ``path``: above the free space of its filesystem,
    or, written as one file (HDF5), above the process's file size limit (``ulimit -f``). Checked before writing,
    since HDF5 may crash the process on a write that fails halfway through its bookkeeping, and a cache too large
    for its disk would otherwise solve until the disk is full. (A Zarr store is checked at its raw size: its
    compression is not known before the data.)"""
    import resource

    need = nbytes + ROOM_MARGIN
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if one_file and limit != resource.RLIM_INFINITY and need > limit:
        raise CacheWriteError(f"cannot write {path}: it needs {_mib(need)}, the file size limit (ulimit -f) is "
                              f"{_mib(limit)}")
    st = os.statvfs(path.parent if str(path.parent) else ".")
    if need > st.f_bavail * st.f_frsize:
        raise CacheWriteError(f"cannot write {path}: no space left on device ({_mib(need)} needed, "
                              f"{_mib(st.f_bavail * st.f_frsize)} free)")


def _mib(n: int) -> str:
    if n >= 2**30:
        return f"{n / 2**30:,.1f} GiB"
    return f"{n / 2**20:.2f} MiB" if n >= 2**20 else f"{n // 1024} KiB"


def solve_block(pde, seed: int, lo: int, hi: int, block: int, on_blowup: str):
    """Samples lo..hi-1 solved as one batch padded to ``block`` (one compile for every block):
    (u float32 [hi-lo, T, C, *space], {param: float32 [hi-lo]}, redraws int8 [hi-lo], {output: [hi-lo, ...]})
    as numpy (the outputs: the problem's OUTPUTS, empty where it declares none)."""
    from ._bridge import sample_numpy

    idx = np.minimum(np.arange(lo, lo + block), hi - 1)  # pad by repeating the last index
    u, params, redraws, outputs = sample_numpy(pde, idx, seed, on_blowup, with_outputs=True)
    return (u[: hi - lo], {k: v[: hi - lo] for k, v in params.items()},
            np.minimum(redraws[: hi - lo], 127).astype(np.int8), {k: v[: hi - lo] for k, v in outputs.items()})


def write_block(store, pde, lo: int, hi: int, u, params, redraws, outputs=None) -> None:
    """Write one block's data, then its ``complete`` flags (the flags vouch for data already written).
    outputs: {name: [hi-lo, *dims]} of the problem's OUTPUTS (a "space" one in the generator's axis order)."""
    axis = u.ndim - pde.NDIM - 1  # the channel axis: [B, T, C, *space], or [B, C_in + C, *space] when steady
    for c, name in enumerate((*pde.INPUTS, *pde.FIELDS)):  # datasets._bridge.sample_channels
        store[name][lo:hi] = schema.to_disk(np.take(u, c, axis=axis), pde.NDIM)  # stored (z,) y, x: see datasets.schema
    for name, values in params.items():
        store[name][lo:hi] = values
    for name, out in getattr(pde, "OUTPUTS", {}).items():
        values = np.asarray(outputs[name]).astype(out.dtype)
        store[name][lo:hi] = schema.to_disk(values, pde.NDIM) if out.dims == "space" else values
    store["redraws"][lo:hi] = redraws
    store.flush()  # data reaches the file before the flags that vouch for it
    store["complete"][lo:hi] = np.ones(hi - lo, np.int8)
    store.flush()


def write_cache(pde, path, n_samples: int, seed: int = 0, resume: bool = False, overwrite: bool = False,
                block: int | None = None, on_blowup: str = "raise", progress: bool = True) -> WriteSummary:
    """Write samples 0..n_samples-1 of ``pde`` (a generator PDE or a catalog name) under ``seed`` to ``path``
    (.h5/.hdf5 or .zarr).

    Fields are float32 [sample, time, x(, y)] (schema in ``datasets.schema``). ``block`` samples are
    solved per batch (default: ~32 MiB); ``resume`` finishes an interrupted cache of the same set-up
    (bit-identical to an uninterrupted run); ``overwrite`` replaces an existing pdestream cache (the new one
    is built beside it and swapped in only once complete). ``progress`` shows the samples solved (fractional within a
    block), their rate and the time left: a tqdm bar when stderr is a terminal, else plain lines
    (``pdestream.meter.Meter``). An OS failure while writing (disk full) is one ValueError line naming the path, the cause and
    what was kept.
    """
    from ._bridge import resolve_pde

    pde = resolve_pde(pde)  # a catalog name or a generator PDE, like every other entry point
    start = time.perf_counter()
    with writing(pde, path, n_samples, seed, resume, overwrite, block, on_blowup) as job:
        written = _fill(pde, job, progress)
    return WriteSummary(str(job.path), int(n_samples), written, time.perf_counter() - start,
                        schema.disk_bytes(job.path), job.repaired)


def write_solved(pde, path, seed: int, blocks: list, block: int, overwrite: bool = False) -> WriteSummary:
    """``write_cache`` of samples already solved: ``blocks`` are ``(lo, hi, *solve_block(pde, seed, lo, hi, block,
    "raise"))`` covering 0..N-1 in order, so the cache is the one ``write_cache(pde, path, N, seed, block=block)``
    writes. For a caller that decides N while it solves (a time budget's deadline)."""
    n = blocks[-1][1] if blocks else 0
    if [b[0] for b in blocks] != [0, *(b[1] for b in blocks[:-1])]:
        raise ValueError("write_solved: the blocks must cover samples 0..N-1 in order")
    start = time.perf_counter()
    with writing(pde, path, n, seed, overwrite=overwrite, block=block) as job:
        store = job.fmt.open(job.work, writable=True)
        try:
            for item in blocks:
                try:
                    write_block(store, pde, *item)
                except OSError as err:
                    raise CacheWriteError(f"cannot write {job.path}: {os_error_cause(err)}") from None
            job.fmt.mark_complete(store)
        finally:
            store.close()
    return WriteSummary(str(job.path), n, n, time.perf_counter() - start, schema.disk_bytes(job.path))


@dataclass
class Job:
    """A cache being written: ``path`` (where it ends up), ``work`` (where blocks are written: ``path``, or a
    hidden sibling when replacing an old cache), its format, settings and layout."""

    path: Path
    work: Path
    fmt: CacheFormat
    settings: CacheSettings
    lay: schema.Layout
    repaired: int = 0  # damaged samples of a resumed cache, reopened to be recomputed

    @property
    def block(self) -> int:
        return self.settings.block


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
    fmt = format_of(path)
    _check_name(path)
    pde = resolve_pde(pde)  # a generator PDE (its config was checked when it was built) or a catalog name
    _check_int("n_samples", n_samples, 1, max_index() + 1)
    _check_int("seed", seed, 0, 2**63 - 1)
    if block is not None:
        _check_int("block", block, 1)
    if resume and overwrite:
        raise ValueError("--resume and --overwrite exclude each other: resume finishes a cache, overwrite replaces it")
    if on_blowup == "skip":
        raise ValueError("on_blowup='skip' not allowed for a cache: a cache holds every index 0..N-1; allowed: "
                         "'raise', 'redraw' (or skip in the stream / the reservoir)")
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
        stored = cache_settings(path) if resume and exists else None  # clear error if it is not a cache
        if not stored:  # the one room check of a new cache (generate, the Dask writer), before its layout is built
            check_room(path, schema.cache_bytes(pde, n_samples), one_file=fmt.name == "hdf5")
        if block is None:
            block = stored.block if stored else default_block(pde, n_samples)
        settings = CacheSettings.of(pde, n_samples, seed, min(block, n_samples), on_blowup, jax_provenance())
        if stored:
            _check_resume(path, stored, settings)
            if stored.block != settings.block:
                raise ValueError(f"cannot resume {path} with block={settings.block}: it was started with block="
                                 f"{stored.block} (leave --block out to use it)")
        lay = schema.layout(pde, settings.n_samples, settings.seed, settings.block, settings.on_blowup,
                            settings.provenance)
        _remove_stale(path)
        repaired = _reopen_damaged(path, fmt, settings) if stored else 0
        job = Job(path, _hidden(path, "tmp") if exists and overwrite else path, fmt, settings, lay, repaired)
        created = not stored
        try:
            if created:
                try:  # a replacement is built at its hidden work path, a new cache made whole then renamed
                    fmt.create(job.work, lay, settings.block) if job.work != path else _create(path, fmt, lay,
                                                                                              settings.block)
                except OSError as err:
                    raise CacheWriteError(f"cannot create {path}: {os_error_cause(err)}") from None
            yield job
            if job.work != path:
                if path.exists() and (what := _foreign(path)):  # replaced by someone else while we wrote
                    raise ValueError(f"refusing to overwrite {path}: it became {what} during the run")
                fmt.replace(job.work, path, _hidden(path, "old"))
        except BaseException as err:
            if job.work != path:
                remove_any(job.work)  # ours: the old cache at ``path`` was never touched
                kept = "the old cache is unchanged"
            elif not path.exists() or (created and not _any_written(path, fmt)):
                remove_any(path)  # ours, and nothing in it to resume: a rerun needs no --overwrite
                kept = "nothing was kept"
            else:
                kept = "the samples written so far are kept: free space and finish it with --resume"
            if isinstance(err, CacheWriteError):
                raise CacheWriteError(f"{err}; {kept}") from None
            raise


def cache_settings(path) -> CacheSettings:
    """The settings of the cache at ``path`` (one-line ValueError when it is not a readable pdestream cache)."""
    ds = open_cache(path)
    try:
        return CacheSettings.from_attrs(ds.attrs, path)
    finally:
        ds.close()


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


def _reopen_damaged(path: Path, fmt: CacheFormat, settings: CacheSettings) -> int:
    """Resume: clear the flags of damaged samples (and the global flag) so they are solved again. Read first: a
    cache with none is not opened for writing (HDF5 rewrote 15 bytes of metadata of a complete cache)."""
    store = fmt.open(path)
    try:
        try:
            store["complete"]
        except KeyError:  # without the flags, which samples were written is unknown: say so, touch nothing
            raise ValueError(f"cannot resume {path}: its 'complete' flags are missing (deleted?), so which samples "
                             "were written is unknown; regenerate it with --overwrite") from None
        bad = damaged_samples(store, settings.variables, settings.block)
    finally:
        store.close()
    if not len(bad):
        return 0
    store = fmt.open(path, writable=True)
    try:
        if len(bad):
            fmt.mark_complete(store, value=0)  # no longer complete until they are rewritten
            flags = np.asarray(store["complete"][:])
            flags[bad] = 0
            store["complete"][:] = flags
    finally:
        store.close()
    return len(bad)


def _any_written(path: Path, fmt: CacheFormat) -> bool:
    """True when a sample of the cache at ``path`` is flagged complete (or it cannot be read: keep it)."""
    try:
        store = fmt.open(path)
        try:
            return bool((np.asarray(store["complete"][:]) == 1).any())
        finally:
            store.close()
    except Exception:
        return True


def pending_blocks(store, block: int) -> list[tuple[int, int]]:
    """The (lo, hi) blocks of a cache with a sample not yet marked complete."""
    done = np.asarray(store["complete"][:]) == 1
    return [(lo, min(lo + block, len(done))) for lo in range(0, len(done), block) if not done[lo : lo + block].all()]


def _finished(job: Job) -> bool:
    """True when the HDF5 cache of ``job`` has every sample written and is marked complete (read-only). Not for
    Zarr: its completion also rewrites the consolidated metadata, which repairs a store an older writer cut."""
    if job.fmt.name != "hdf5":
        return False
    try:
        if int(np.asarray(job.fmt.root_attrs(job.work).get("pdestream_complete", 0))) != 1:
            return False
        store = job.fmt.open(job.work)
        try:
            return not pending_blocks(store, job.block)
        finally:
            store.close()
    except Exception:  # anything odd: the writable path below decides, as before
        return False


def _fill(pde, job: Job, progress: bool) -> int:
    """Solve and write every pending block of ``job``, then mark it complete; returns the samples written."""
    from pdestream.meter import Meter

    from . import timings
    from ._bridge import progress_key, typical_times

    s, block = job.settings, job.block
    if _finished(job):  # a --resume of a complete cache: not opened for writing (HDF5 rewrote 15 bytes)
        return 0
    store = job.fmt.open(job.work, writable=True)
    written = 0
    try:
        todo = pending_blocks(store, block)
        initial = s.n_samples - sum(hi - lo for lo, hi in todo)
        # samples solved (fractional within a block: its solve reports after each bounded call), rate, time left
        # (from the last run's times until this one's rate is measured: the first call compiles the solver)
        key = progress_key("generate", pde)
        bar = Meter(pde.NAME, s.n_samples, "samples", initial=initial, enabled=progress,
                    last=timings.recall(key, typical_times(pde)) if progress else None, starting="compiling the solver")

        def solve_all():  # in the prefetch thread: one block solved ahead of the one being written
            base = initial
            for lo, hi in todo:
                with bar.solving(base, hi - lo):  # each padded to ``block`` samples (one compile)
                    item = (lo, hi, *solve_block(pde, s.seed, lo, hi, block, s.on_blowup))
                base += hi - lo
                yield item

        solved = prefetch(solve_all)
        try:
            for item in solved:
                lo, hi = item[:2]
                try:
                    write_block(store, pde, *item)
                except OSError as err:  # disk full, I/O error: one line, not the library's report
                    raise CacheWriteError(f"cannot write {job.path} (samples {lo}..{hi - 1}): {os_error_cause(err)}") from None
                written += hi - lo
        finally:
            # stops the solver thread: it ends at its next bounded compiled call (rollouts run in pieces)
            solved.close()
            bar.close()
            if progress:
                timings.remember(key, bar.measured())
        if not (np.asarray(store["complete"][:]) == 1).all():
            raise RuntimeError(f"{job.path}: blocks missing after writing (a bug)")
        try:
            job.fmt.mark_complete(store)
        except OSError as err:
            raise CacheWriteError(f"cannot mark {job.path} complete: {os_error_cause(err)}") from None
    finally:
        store.close()
    return written


def open_cache(path, complete_only: bool = False):
    """The cache at ``path`` as an xarray.Dataset (lazy fields; the per-sample coordinates are read now);
    ``complete_only`` keeps written samples only.

    ValueError (one line naming the path and the cause) for a missing path, a file that is not a pdestream
    cache, one held open by a writer, or a damaged one (unreadable, a variable or attribute missing or garbled).
    """
    path = Path(path)
    fmt = format_of(path)
    if not path.exists():
        raise ValueError(f"no cache at {path}: the path does not exist")
    try:
        ds = fmt.dataset(path)
    except Exception as err:  # h5py / zarr / json errors of every kind: name the file, not the library
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        if "unable to lock file" in detail:
            raise ValueError(f"{path} is open for writing by another process (HDF5 locks it while a "
                             "generate runs); wait for it to finish or stop it") from None
        raise ValueError(f"{path} is not a readable {fmt.name} cache (truncated or corrupted?): {detail}") from None
    try:
        missing = [k for k in (schema.CONFIG_ATTR, "pdestream_n_samples", "pdestream_fields", "pdestream_params")
                   if k not in ds.attrs]
        missing += [v for v in ("complete", "sample") if v not in ds.variables]
        if missing:
            layout = ds.attrs.get("pdestream_export")  # the layout an export names at its root (export._common)
            if isinstance(layout, str) and path.is_file():  # (it said "missing complete, sample")
                raise ValueError(f"{path} is an export written by `pdestream export --to {layout}`, not a cache: "
                                 f"`pdestream import {path} --out CACHE.h5` makes it one (train --source reads it as "
                                 "it is)")
            raise ValueError(f"{path} is not a pdestream cache (missing {', '.join(missing)})")
        settings = CacheSettings.from_attrs(ds.attrs, path)
        store = fmt.open(path)  # the arrays themselves: consolidated metadata lists a deleted Zarr array too
        try:
            # the flags too: without them a resume is refused, so inspect must not advise one
            gone = [v for v in (*settings.variables, "redraws", "complete") if v not in ds.variables or v not in store]
        finally:
            store.close()
        if gone:
            raise ValueError(f"{path} is damaged: variable{'s' if len(gone) > 1 else ''} {', '.join(gone)} "
                             "missing (deleted?); regenerate it with --overwrite")
        # a schema-1 cache of 2D fields stored them (x, y): refused rather than read the wrong way round
        schema.check_readable(path, ds.attrs, ds[settings.fields[0]].dims)
        if ds.sizes["sample"] != settings.n_samples:
            raise ValueError(f"{path} is damaged: {ds.sizes['sample']} samples stored, {settings.n_samples} expected")
        for name in ("sample", "complete", "redraws", *settings.params):  # small: read now, so a damaged one
            try:  # is named here rather than failing later in a reader
                ds.variables[name].load()  # the variable alone (a DataArray would load its coordinates)
            except Exception as err:
                detail = str(err).splitlines()[0] if str(err) else type(err).__name__
                raise ValueError(f"{path} is damaged: cannot read {name} ({detail}); regenerate it with "
                                 "--overwrite") from None
    except BaseException:
        ds.close()
        raise
    if complete_only:
        ds = ds.isel(sample=np.flatnonzero(ds["complete"].values == 1))
    return ds


def is_complete(ds) -> bool:
    """True when every sample is written and the writer finished (the flag it sets last)."""
    return bool(ds.attrs.get("pdestream_complete") == 1 and (ds["complete"].values == 1).all())
