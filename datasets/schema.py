"""The on-disk schema of a pdestream cache, one layout for HDF5 (.h5/.hdf5) and Zarr v3 (.zarr).

Readable by plain xarray (``xr.open_dataset(path, engine="h5netcdf")``, ``xr.open_zarr(path)``)::

    dims         sample (N), time (T), then space in plotting order: x (1D), y x (2D), z y x (3D)
    data vars    one per field of the PDE (PDE.FIELDS), float32 [sample, time, (z,) (y,) x]; a steady PDE
                 (PDE.STEADY, e.g. darcy2d) has no time dim nor coord: its random input fields (PDE.INPUTS,
                 darcy2d's coefficient a) and its solution fields are each float32 [sample, (z,) (y,) x]
    coords       time [T] float32, x [n], y [n], z [n] float32 (cell-left points), sample [N] int64 (global
                 index), one float32 [sample] per PDE parameter (units, long_name), redraws int8 [sample]
                 (blow-up redraws used), complete int8 [sample] (1 once the sample is written)
    outputs      one per declared per-sample output (PDE.OUTPUTS, e.g. karman2d's drag, lift, sdf, strouhal,
                 developed): float32 or int8 (a 0/1 flag) over [sample], [sample, time] or [sample, (z,) (y,) x]
                 (per sample, per frame, or a static field), with long_name and units; listed in the attribute
                 pdestream_outputs
    attributes   pde, equation, pdestream_config (full resolved config, JSON), pdestream_config_hash,
                 pdestream_fields, pdestream_params, pdestream_outputs (names in PDE order, space-separated),
                 pdestream_seed, pdestream_n_samples, pdestream_block, pdestream_on_blowup,
                 pdestream_version, jax_version, jax_threefry_partitionable, pdestream_numerics, pdestream_schema,
                 pdestream_complete (0 until every block is written; set last)

Axis order: the generator's arrays are [..., x, y(, z)] (u[i, j] = u(x_i, y_j)); a cache stores the space
axes reversed, [..., (z,) y, x], because xarray (and matplotlib's imshow/pcolormesh) put the last dim on the
horizontal axis: ``ds.vorticity.isel(sample=0, time=-1).plot()`` then shows x across, y up. The mapping lives
here only: ``to_disk`` on write, ``from_disk`` on every raw read, so readers get the generator's tensors bit
for bit. Schema 1 stored the generator's order; a schema-1 cache with 2+ space dims is refused
(``check_readable``), a 1D one (same layout) is read.

Crash safety: every array is fully laid out when the file is created (HDF5: contiguous, allocated
early, the int8 flags zeroed; Zarr: chunks along ``sample`` that divide the write block, so a block
covers whole chunks), so writing a block changes data only, never metadata. A block's ``complete`` flags
are written after its data, so a killed writer leaves a cache that reads as incomplete. The global flag
is set last, for Zarr in one atomic replace of the root ``zarr.json``. A replacement (``--overwrite``) is
built under a hidden sibling name and renamed into place once complete; one writer per cache holds an
exclusive lock on the hidden sidecar ``.NAME.lock`` (``datasets.cache.write_lock``).
"""

from __future__ import annotations

import errno
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..boundaries import words as stored_words

SCHEMA_VERSION = 2  # 2: space axes stored reversed ((y, x), (z, y, x)); 1: generator order
SPACE = ("x", "y", "z")  # the generator's space axes, in its array order
SUFFIXES = {".h5": "hdf5", ".hdf5": "hdf5", ".zarr": "zarr"}
CONFIG_ATTR = "pdestream_config"
CHUNK_BYTES = 256 * 2**10  # target Zarr chunk size (see chunk_samples)


def cache_format(path) -> str:
    """"hdf5" or "zarr" from the path's suffix; ValueError for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"cache path {str(path)!r} must end in .h5, .hdf5 or .zarr (got {suffix or 'no suffix'!r})")
    return SUFFIXES[suffix]


@dataclass
class Layout:
    """What a cache holds: dims, coordinates written at creation, per-sample and field arrays, attrs."""

    dims: dict[str, int]
    coords: dict[str, tuple[tuple[str, ...], np.ndarray, dict]]
    per_sample: dict[str, tuple[str, dict]]  # name -> (dtype, attrs), dims ("sample",)
    fields: dict[str, dict]  # name -> attrs, float32 over field_dims
    field_dims: tuple[str, ...]
    attrs: dict = field(default_factory=dict)
    outputs: dict[str, tuple[tuple[str, ...], str, dict]] = field(default_factory=dict)  # name -> (dims, dtype, attrs)


def package_version() -> str:
    """The installed pdestream's version, or "unknown (not installed)" when it runs from a source tree on PYTHONPATH
    (a cache written that way must not fail at its last attribute)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pdestream")
    except PackageNotFoundError:
        return "unknown (not installed)"


def layout(pde, n_samples: int, seed: int, block: int, on_blowup: str, provenance: dict) -> Layout:
    """The layout of a cache of samples 0..n_samples-1 of ``pde`` under ``seed``."""
    space = disk_space_dims(pde.NDIM)
    time = () if pde.STEADY else ("time",)  # a steady PDE's sample has no time axis
    dims = {"sample": n_samples, **{d: pde.n_frames for d in time}, **{d: pde.grid.shape[SPACE.index(d)] for d in space}}
    # long_name and units are what xarray's plots print as axis and colourbar labels ("x [length]")
    coords = {
        "sample": (("sample",), np.arange(n_samples, dtype=np.int64), {"long_name": "sample index"}),
        **{d: ((d,), pde.times(), {"long_name": "t", "units": "time", "axis": "T"}) for d in time},
    }
    points = getattr(pde.grid, "POINTS", "cell-left grid points of a periodic domain")
    bcs, types = boundaries(pde), tuple(pde.grid.bc_type)
    for d in space:
        axis = SPACE.index(d)  # x, y, z are the sample's space axes 0, 1, 2 (stored in reverse)
        coords[d] = ((d,), pde.grid.coords(axis), {"long_name": d, "units": "length", "axis": d.upper(),
                                                   "comment": points, "bc": bcs[axis], "bc_type": types[axis]})
    per_sample = {name: ("float32", {"long_name": p.description, "units": p.units,
                                     "domain": str(getattr(pde, name))})
                  for name, p in pde.PARAMS.items()}
    declared = getattr(pde, "OUTPUTS", {})
    taken = {*coords, *pde.INPUTS, *pde.FIELDS, *declared, "redraws", "complete"}
    clash = sorted(set(pde.PARAMS) & taken)
    if clash:  # (a user's parameter "x" made Zarr fail with "array exists at path 'x'" half-way through the write)
        raise ValueError(f"{pde.NAME}: parameter(s) {clash} would be stored under a name the cache already uses; "
                         f"rename them (taken: {', '.join(sorted(taken))})")
    per_sample["redraws"] = ("int8", {"long_name": "blow-up redraws used for this sample", "units": "1"})
    per_sample["complete"] = ("int8", {"long_name": "sample fully written", "flag_values": [0, 1],
                                       "flag_meanings": "missing written"})
    link = " ".join(per_sample)  # CF: the per-sample coordinates of every field
    # fields: a name and the units the PDE declares (FIELD_UNITS; xarray's plots print "u [length/time]")
    units = getattr(pde, "FIELD_UNITS", {})
    fields = {f: {"long_name": f, "coordinates": link, **({"units": units[f]} if f in units else {})}
              for f in (*pde.INPUTS, *pde.FIELDS)}
    outputs = {}
    for name, out in declared.items():  # a problem's per-sample outputs (generator.problem.Output)
        extra = {"": (), "time": time, "space": space}[out.dims]
        attrs = {"long_name": out.description, "units": out.units}
        if out.dtype == "int8":
            attrs.update(flag_values=[0, 1], flag_meanings="no yes")
        outputs[name] = (("sample", *extra), out.dtype, attrs)
    attrs = {
        "Conventions": "CF-1.10",
        "title": f"pdestream cache: {pde.NAME}, samples 0..{n_samples - 1}, seed {seed}",
        "pde": pde.NAME,
        "equation": pde.EQUATION,
        CONFIG_ATTR: json.dumps(pde.config(), sort_keys=True),
        "pdestream_config_hash": pde.config_hash(),
        "pdestream_fields": " ".join(pde.FIELDS),  # data variables, in PDE.FIELDS order
        # per space axis x, y, z: the boundary condition, and The Well's word for it (periodic / wall / open)
        "bc": " ".join(bcs),
        "bc_type": " ".join(types),
        # a flow's box states each side (left=inflow right=outflow bottom=wall top=wall); empty for other grids
        "sides": " ".join(f"{k}={v}" for k, v in zip(("left", "right", "bottom", "top"), getattr(pde.grid, "sides", ()))),
        "pdestream_inputs": " ".join(pde.INPUTS),  # a steady PDE's input fields (variables too), else empty
        "pdestream_params": " ".join(pde.PARAMS),  # parameter coordinates, in PDE.PARAMS order
        "pdestream_outputs": " ".join(declared),  # per-sample outputs (PDE.OUTPUTS order), variables too
        "pdestream_seed": int(seed),
        "pdestream_n_samples": int(n_samples),
        "pdestream_block": int(block),
        "pdestream_on_blowup": on_blowup,
        "pdestream_version": package_version(),
        **provenance,
        **recipe_attrs(pde),
        "pdestream_schema": SCHEMA_VERSION,
        "pdestream_complete": 0,
    }
    return Layout(dims, coords, per_sample, fields, ("sample", *time, *space), attrs, outputs)


def recipe_attrs(pde) -> dict:
    """The recipe a problem was made from and its source ({} for a plain entry): pdestream_recipe and
    pdestream_recipe_source (paper, where in it, URL; then the generator's files and lines)."""
    name = getattr(pde, "recipe", "")
    if not name:
        return {}
    from pdestream.recipes import RECIPES

    recipe = RECIPES.get(name)
    source = f"{recipe.source}; {recipe.code}" if recipe else "(a recipe this version does not declare)"
    return {"pdestream_recipe": name, "pdestream_recipe_source": source}


def boundaries(pde) -> tuple[str, ...]:
    """Per-axis boundary conditions (x, y, z order) of a problem's grid: 'periodic', 'dirichlet' or 'neumann'."""
    return tuple(pde.grid.bc)


def cache_boundaries(attrs: dict, ndim: int) -> tuple[str, ...]:
    """Per-axis boundary conditions recorded in a cache's root attributes; a cache written before they were
    recorded is periodic (every pdestream domain was)."""
    return stored_words(attrs.get("bc"), ndim)


def disk_space_dims(ndim: int) -> tuple[str, ...]:
    """The space dims of a cache, in stored order: ("x",), ("y", "x"), ("z", "y", "x")."""
    if not 1 <= ndim <= len(SPACE):
        raise ValueError(f"a cache holds 1 to {len(SPACE)} space dims, not {ndim}")
    return SPACE[:ndim][::-1]


def _reverse_space(a, ndim: int):
    """``a`` with its last ``ndim`` axes in reverse order (a view; its own inverse)."""
    if ndim < 2:
        return a
    lead = a.ndim - ndim
    return a.transpose(*range(lead), *range(a.ndim - 1, lead - 1, -1))


def to_disk(u: np.ndarray, ndim: int) -> np.ndarray:
    """A field in the generator's order [..., x, y(, z)] -> the stored order [..., (z,) y, x] (a view)."""
    return _reverse_space(u, ndim)


def from_disk(a: np.ndarray, ndim: int) -> np.ndarray:
    """A field read raw from a cache, [..., (z,) y, x] -> the generator's order [..., x, y(, z)] (a view).
    ``ndim``: the space dims among the last axes of ``a`` (``space_ndim`` of the stored field's dims)."""
    return _reverse_space(a, ndim)


def space_ndim(dims) -> int:
    """How many of ``dims`` (a stored field's dim names) are space dims."""
    return sum(d in SPACE for d in dims)


def check_readable(path, attrs, field_dims) -> None:
    """ValueError (one line) for a cache whose stored axis order this version cannot read: a schema-1 cache
    with 2+ space dims (its fields were stored (x, y)), or one from a newer schema."""
    version = attrs.get("pdestream_schema")
    version = int(version) if isinstance(version, (int, np.integer)) else version
    if version == SCHEMA_VERSION or (version == 1 and space_ndim(field_dims) < 2):
        return
    if version == 1:
        raise ValueError(f"{path} was written by an older pdestream (cache schema 1, fields stored as "
                         f"({', '.join(field_dims)})); this version reads schema {SCHEMA_VERSION} (stored as "
                         f"({', '.join(('sample', 'time', *disk_space_dims(space_ndim(field_dims))))})): "
                         "regenerate it with `pdestream generate ... --overwrite`")
    raise ValueError(f"{path} has cache schema {version!r}; this pdestream reads schema {SCHEMA_VERSION} "
                     "(and schema 1 for 1D): regenerate it, or use the pdestream that wrote it")


# --- HDF5 ------------------------------------------------------------------------------------------
def _early_dcpl(zero: bool = False):
    """Allocate the whole dataset at creation, so later writes are data only. ``zero``: write zeros into it
    at creation (HDF5 may hand out freed space holding stale bytes: an unwritten ``complete`` flag must read
    0); otherwise never write fill values (field data is only read once its flag says it was written)."""
    import h5py

    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    if zero:
        dcpl.set_fill_value(np.zeros((), np.int8))
        dcpl.set_fill_time(h5py.h5d.FILL_TIME_ALLOC)
    else:
        dcpl.set_fill_time(h5py.h5d.FILL_TIME_NEVER)
    return dcpl


def hdf5_bytes(lay: Layout) -> int:
    """The bytes of the arrays of ``lay`` in an HDF5 cache (all allocated at creation)."""
    field = int(np.prod([lay.dims[d] for d in lay.field_dims])) * 4
    sample = sum(np.dtype(dtype).itemsize for dtype, _ in lay.per_sample.values()) * lay.dims["sample"]
    outputs = sum(np.dtype(dtype).itemsize * int(np.prod([lay.dims[d] for d in dims]))
                  for dims, dtype, _ in lay.outputs.values())
    return field * len(lay.fields) + sample + outputs + sum(data.nbytes for _, data, _ in lay.coords.values())


def cache_bytes(pde, n_samples: int) -> int:
    """``hdf5_bytes`` of a cache of ``n_samples`` samples of ``pde``, without building its layout (whose sample
    coordinate alone would take 8 bytes per sample): the bytes grow linearly with the samples, so they are read off
    the layouts of 1 and 2 samples."""
    one, two = (hdf5_bytes(layout(pde, k, 0, 1, "raise", {})) for k in (1, 2))
    return one + (two - one) * (n_samples - 1)


def create_hdf5(path: str, lay: Layout) -> None:
    """A netCDF4-compatible HDF5 file (dimension scales through h5netcdf) with every array allocated."""
    import h5netcdf

    f = h5netcdf.File(path, "w")
    try:
        f.dimensions = lay.dims
        for name, (dims, data, attrs) in lay.coords.items():
            f.create_variable(name, dims, data=data).attrs.update(attrs)
        for name, (dtype, attrs) in lay.per_sample.items():
            zero = dtype == "int8"  # the flags (redraws, complete): 0 until their sample is written
            f.create_variable(name, ("sample",), dtype, dcpl=_early_dcpl(zero)).attrs.update(attrs)
        for name, attrs in lay.fields.items():
            f.create_variable(name, lay.field_dims, "float32", dcpl=_early_dcpl()).attrs.update(attrs)
        for name, (dims, dtype, attrs) in lay.outputs.items():
            f.create_variable(name, dims, dtype, dcpl=_early_dcpl(dtype == "int8")).attrs.update(attrs)
        f.attrs.update(lay.attrs)
        f.close()
    except BaseException:
        _abandon(f)
        raise


def _abandon(f) -> None:
    """Release an h5netcdf file whose writing or closing failed (disk full, file size limit) without closing it
    again: h5netcdf's ``__del__`` would flush it when it is collected, into HDF5 objects the failed close left
    half-freed, and crash the process (a segfault after the command's error line)."""
    h5 = None if f._closed else getattr(f, "_File__h5file", None)
    f._closed = True  # h5netcdf's own flag: close() and __del__ then do nothing
    try:
        if h5 is not None:
            h5.id.close()  # the file descriptor (HDF5 reports the failed flush again: ignored)
    except Exception:
        pass


def create_zarr(path: str, lay: Layout, block: int) -> None:
    """A Zarr v3 group with dimension_names; fields chunked per sample, per-sample arrays per block."""
    import zarr
    from zarr.codecs import ZstdCodec

    group = zarr.open_group(path, mode="w-", zarr_format=3, attributes=lay.attrs)
    for name, (dims, data, attrs) in lay.coords.items():
        arr = group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=data.shape,
                                 dimension_names=dims, attributes=attrs)
        arr[...] = data
    for name, (dtype, attrs) in lay.per_sample.items():
        fill = np.nan if dtype == "float32" else 0
        group.create_array(name, shape=(lay.dims["sample"],), dtype=dtype, chunks=(block,), fill_value=fill,
                           dimension_names=("sample",), attributes=attrs)
    shape = tuple(lay.dims[d] for d in lay.field_dims)
    chunk = chunk_samples(4 * int(np.prod(shape[1:])), block)
    for name, attrs in lay.fields.items():
        # checksums catch corrupted chunks
        group.create_array(name, shape=shape, dtype="float32", chunks=(chunk, *shape[1:]), fill_value=np.nan,
                           compressors=ZstdCodec(level=1, checksum=True), dimension_names=lay.field_dims,
                           attributes=attrs)
    for name, (dims, dtype, attrs) in lay.outputs.items():
        shape = tuple(lay.dims[d] for d in dims)
        chunk = chunk_samples(np.dtype(dtype).itemsize * int(np.prod(shape[1:])), block)
        group.create_array(name, shape=shape, dtype=dtype, chunks=(chunk, *shape[1:]),
                           fill_value=np.nan if dtype == "float32" else 0, dimension_names=dims, attributes=attrs)
    consolidate(path)


def chunk_samples(sample_bytes: int, block: int, target: int = CHUNK_BYTES) -> int:
    """Samples per Zarr chunk: the largest divisor of ``block`` whose chunk stays within ``target`` bytes.

    Zarr spends ~1 ms of CPU per chunk written or read whatever its size, so small samples share a chunk
    (writing then costs generation little); random reads still decode at most ~``target`` bytes. A
    divisor of the write block keeps every block whole chunks (no read-modify-write, safe for parallel
    writers of different blocks).
    """
    best = 1
    for c in range(1, block + 1):
        if block % c == 0 and c * sample_bytes <= target:
            best = c
    return best


def consolidate(path: str) -> None:
    """Consolidated metadata, so xr.open_zarr(path) opens quickly and without a warning."""
    import warnings

    import zarr

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "consolidated metadata is not part of the Zarr v3 spec"
        zarr.consolidate_metadata(path)


def publish_new(tmp: Path, out: Path) -> None:
    """Move the finished file or directory ``tmp`` to ``out``, which must not exist, in one step that never replaces
    what another process put there meanwhile (a check first and ``os.replace`` after it let the second of two
    writers replace the first's file). A file is hard-linked into place (refused by the kernel if ``out`` exists),
    then its temp name removed; a directory is renamed (refused onto anything but an empty directory).
    FileExistsError naming ``out`` when it exists; ``tmp`` is left for the caller to remove."""
    tmp, out = Path(tmp), Path(out)
    taken = FileExistsError(f"{out} exists (another process wrote it meanwhile); choose another path")
    if tmp.is_dir():
        if out.exists() or out.is_symlink():
            raise taken
        try:
            os.rename(tmp, out)
        except OSError as err:
            if err.errno in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR, errno.EISDIR):
                raise taken from None
            raise
        return
    try:
        os.link(tmp, out)
    except FileExistsError:
        raise taken from None
    except OSError:  # a file system without hard links: the check-then-rename of before, the best it allows
        if out.exists() or out.is_symlink():
            raise taken from None
        os.replace(tmp, out)
        return
    tmp.unlink()


def _umask() -> int:
    """The process's umask: from /proc (Linux), else by setting it and setting it back (which other threads could
    see for that instant)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path: Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` all at once: a temp file in the same directory (unique, so two writers never
    share one), fsync, os.replace, then fsync of the directory; readers, a kill or a power cut see the old file or
    the new one, never half of one (at worst a stray ``.NAME.*.tmp``). The one atomic write of the project (caches'
    metadata, run files, checkpoints)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes it 0600: a run's or cache's files read as any file would
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())  # the bytes are on disk before the rename makes them the file
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)  # the rename itself survives a power cut once the directory is synced
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def disk_bytes(path) -> int:
    """Apparent size on disk: the file, or every file under a Zarr directory."""
    path = Path(path)
    if path.is_file():
        return path.stat().st_size
    return sum(os.path.getsize(os.path.join(root, f)) for root, _, files in os.walk(path) for f in files)
