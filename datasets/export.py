"""Export a complete cache to The Well's or PDEBench's HDF5 layout (``export_cache``), read such an export back
as an xarray.Dataset in pdestream's layout (``read_export``) and turn it into a pdestream cache again
(``import_export``). ``pdestream train NAME --source EXPORT`` trains on an export directly: ``as_cache`` imports
it into a private temporary cache for the run (removed when the process exits).

One small interface per format (``ExportFormat``: ``write``, ``written_by``, ``read``), chosen by name
(``FORMATS``) on export and by recognising the file on read. An export holds the cache's root attributes
(config, seed, provenance, ``pdestream_*``) plus ``pdestream_export`` (the format's name), the global sample
indices and blow-up redraws in a group ``pdestream`` (both formats' loaders ignore it), and the per-sample
parameters; that is what makes reading it back exact. A file the other project wrote (without those
attributes) is recognised and refused in one line: it has no PDE config for pdestream to train with.

The Well (``--to the-well``): one HDF5 file in the layout of The Well's ``WellDataset`` (the_well 1.2): root
attributes ``dataset_name`` (the PDE's name), ``grid_type`` "cartesian", ``n_spatial_dims``, ``n_trajectories``,
``simulation_parameters`` (parameter names); ``dimensions`` with ``time`` and ``x``(, ``y``, ``z``)
(``spatial_dims``; ``sample_varying``/``time_varying`` False); ``boundary_conditions`` with one group per
axis, ``{axis}_{bc_type}``, whose ``bc_type`` is the cache's (WALL / OPEN / PERIODIC) and whose ``mask`` marks
both ends of the axis (no ``values``: pdestream records the kind of boundary, not its values); ``scalars``
with each parameter as a sample-varying, time-constant scalar [N] (WellDataset's ``constant_scalars``);
``t0_fields`` with every field as a scalar field [N, T, x(, y, z)] in x-first order, except an incompressible
flow's (a MAC-grid entry's) velocity: one vector field ``t1_fields/velocity`` [N, T, x, y(, z), d] (its
components' names and attributes in its ``pdestream_names`` / ``u.long_name`` attributes, so reading it back is
exact; its statistics in stats.yaml are lists, one value per component; ``t2_fields`` is empty). WellDataset reads a directory of such files,
``DIR/data/SPLIT/*.hdf5``: export to ``DIR/data/train/NAME.hdf5`` and load
``WellDataset(path=DIR, well_split_name="train")``. The cache's statistics (``datasets.stats``) go to
``DIR/stats.yaml``, where WellDataset's ``use_normalization`` reads them (an export elsewhere writes none:
``pdestream inspect CACHE --stats`` writes them beside the cache). Steady caches (no time axis) are refused: The Well holds
time series.

PDEBench (``--to pdebench``): one HDF5 file in the layout of PDEBench's own loaders (``FNODatasetSingle`` /
``UNetDatasetSingle``): a single-field cache's field is ``tensor`` [N, T, x(, y, z)] (x first) as in the 1D and
2D scalar files; a cache of several fields has one dataset per field [N, T, x(, y)] (the CFD files' layout), named
as in the cache, except a compressible flow's primitive fields (rho, u(, v, w), p: euler1d / 2d, compressible_ns1d
/ 2d), named density, Vx(, Vy, Vz), pressure as PDEBench's CFD files and loaders name them; an incompressible
flow's (a MAC-grid entry's) velocity is PDEBench's ``velocity`` [N, T, x, y(, z), d] and its smoke ``particles``
[N, T, x, y(, z), 1] with the frame times ``t`` [N, T], as its incompressible NS files; plus ``x-coordinate``
(, ``y-coordinate``, ``z-coordinate``) and ``t-coordinate`` (the T frame times). A steady cache is laid out as
PDEBench's Darcy file: its input field as ``nu`` [N, x(, y)] (where its loader reads Darcy's coefficient; several
inputs: each under its own name), its solution as ``tensor`` [N, 1, x(, y)] (no ``t-coordinate``). Each parameter
is a dataset [N] named after it. The sets PDEBench ships one group per sample (diffusion-sorption,
diffusion-reaction, shallow water) get that layout instead (``datasets.pdebench_seeds``).

Both formats keep a cache's per-sample outputs (a flow's drag, lift, sdf) in the ``pdestream`` group, in the
cache's own layout (neither project's loaders read that group; ``import`` does).

Writes are atomic (``OUT.tmp-PID``, then ``os.replace``); an existing OUT is refused unless ``overwrite`` is
given and OUT is an export pdestream wrote (anything else is never replaced).
"""

from __future__ import annotations

import os
import re
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Protocol

import numpy as np

from ..boundaries import PERIODIC
from . import schema
from .store import plain

CHUNK_SAMPLES = 64  # samples copied at once (bounded memory for large caches)
GROUP = "pdestream"  # sample indices and redraws: ignored by both formats' loaders
WELL_OWN = ("dataset_name", "grid_type", "n_spatial_dims", "n_trajectories", "simulation_parameters")


class ExportFormat(Protocol):
    """One foreign layout: write an open complete cache to ``out``, recognise and read a file back."""

    name: str

    def write(self, ds, out: Path) -> None:
        """Write the cache ``ds`` (``open_cache``'s dataset) as a new HDF5 file at ``out``."""

    def looks_like(self, f) -> bool:
        """True when the open h5py file ``f`` has this format's layout (whoever wrote it)."""

    def read(self, f) -> dict:
        """What an export holds, arrays in the generator's order, each as (array, attrs): {"space": ("x", ...),
        "coords": {"time": (or None when steady), "x": ...}, "fields": {name: [N, T, *space] or [N, *space]},
        "params": {name: [N]}, "drop": root attributes of the format's own, "drop_var": its variable attributes}."""


# --- shared pieces ---------------------------------------------------------------------------------
def _names(ds) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """(inputs, fields, params) of a cache, in PDE order."""
    return tuple(str(ds.attrs.get("pdestream_inputs", "")).split()), tuple(str(ds.attrs["pdestream_fields"]).split()), \
        tuple(str(ds.attrs["pdestream_params"]).split())


def _space(ds) -> tuple[str, ...]:
    """The cache's space dims in the generator's (x-first) order."""
    first = _names(ds)[1][0]
    return schema.SPACE[: schema.space_ndim(ds[first].dims)]


def _attrs(a: dict) -> dict:
    """Attributes HDF5 can hold, as plain values (xarray's decoded ones stay out)."""
    return {k: v for k, v in a.items() if k not in ("coordinates", "_FillValue")}


def _copy_field(ds, name: str, dset, ndim: int, time_axis: bool = False) -> None:
    """Copy field ``name`` into the h5py dataset ``dset`` in the generator's order, CHUNK_SAMPLES at a time;
    ``time_axis``: insert a length-1 time axis (a steady field as PDEBench's Darcy ``tensor``)."""
    n = ds.sizes["sample"]
    for lo in range(0, n, CHUNK_SAMPLES):
        hi = min(lo + CHUNK_SAMPLES, n)
        a = schema.from_disk(_block(ds, name, lo, hi).astype(np.float32, copy=False), ndim)
        dset[lo:hi] = a[:, None] if time_axis else a


def _common(ds, f, fmt: str) -> None:
    """Root attributes of the cache, the format's name, and the per-sample bookkeeping group."""
    for k, v in ds.attrs.items():
        f.attrs[k] = v
    f.attrs["pdestream_export"] = fmt
    g = f.create_group(GROUP)
    g.create_dataset("sample", data=np.asarray(ds["sample"].values, np.int64))
    g.create_dataset("redraws", data=np.asarray(ds["redraws"].values, np.int8))
    _write_outputs(ds, g)


def _write_outputs(ds, g) -> None:
    """The cache's per-sample outputs (a flow's drag, lift and signed distance) in ``GROUP/outputs``, in the cache's
    own layout (its dims in ``pdestream_dims``): neither project's loaders read them, ``import`` does."""
    names = str(ds.attrs.get("pdestream_outputs", "")).split()
    if not names:
        return
    out = g.create_group("outputs")
    n = ds.sizes["sample"]
    for name in names:
        var = ds[name]
        v = out.create_dataset(name, shape=var.shape, dtype=var.dtype)
        for lo in range(0, n, CHUNK_SAMPLES):
            v[lo:min(lo + CHUNK_SAMPLES, n)] = _block(ds, name, lo, min(lo + CHUNK_SAMPLES, n))
        v.attrs.update({**_attrs(var.attrs), "pdestream_dims": " ".join(var.dims)})


def _read_outputs(f) -> dict:
    """{name: (dims, values, attrs)} of ``_write_outputs``' group (empty for an export without outputs)."""
    group = f[GROUP].get("outputs") if GROUP in f else None
    if group is None:
        return {}
    return {name: (tuple(str(plain(group[name].attrs["pdestream_dims"])).split()), group[name][()],
                   {k: v for k, v in group[name].attrs.items() if k != "pdestream_dims"}) for name in group}


def _new_hdf5(out: Path):
    """A new HDF5 file (h5py.File) without HDF5's sieve buffer: a failed data write (disk full, file size limit)
    raises at the write, instead of when a dataset is closed (garbage-collected), where h5py can only print it."""
    import h5py

    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_sieve_buf_size(0)
    fapl.set_fclose_degree(h5py.h5f.CLOSE_STRONG)
    return h5py.File(h5py.h5f.create(os.fsencode(out), h5py.h5f.ACC_TRUNC, fapl=fapl))


def _param_data(ds, name: str) -> np.ndarray:
    return _block(ds, name).astype(np.float32, copy=False)


_DAMAGED: ContextVar[set | None] = ContextVar("pdestream_export_damaged", default=None)


def _block(ds, name: str, lo: int | None = None, hi: int | None = None) -> np.ndarray:
    """Variable ``name``'s values (samples lo:hi, or all), as an export reads them to write them: its one read of
    the cache. Inside ``_damaged_reads`` the positions of samples holding NaN/Inf, or in a chunk that cannot be read
    (a deleted Zarr chunk reads as NaN, a corrupted one fails its checksum: NaN stands in), are collected there."""
    var = ds[name] if lo is None else ds[name].isel(sample=slice(lo, hi))
    seen = _DAMAGED.get()
    try:
        a = np.asarray(var.values)
    except Exception:  # an unreadable chunk: every sample of the block is suspect
        if seen is None:
            raise
        a = np.full(var.shape, np.nan, np.float32)
    if seen is not None and a.dtype.kind == "f" and "sample" in var.dims:
        rows = np.moveaxis(a, var.dims.index("sample"), 0)
        seen.update(int(i) for i in (lo or 0) + np.flatnonzero(~np.isfinite(rows.reshape(len(rows), -1)).all(1)))
    return a


@contextmanager
def _damaged_reads():
    """The set of sample positions ``_block`` found damaged while the block ran (the export's NaN check, folded into
    its own read: as a second read it cost 24-27% of an export's time, docs/results/benchmarks.md)."""
    seen: set = set()
    token = _DAMAGED.set(seen)
    try:
        yield seen
    finally:
        _DAMAGED.reset(token)


# --- The Well --------------------------------------------------------------------------------------
class TheWell:
    """The Well's HDF5 layout (see the module docstring)."""

    name = "the-well"

    def write(self, ds, out: Path) -> None:
        _, fields, params = _names(ds)
        if "time" not in ds.dims:
            raise ValueError(f"{ds.attrs.get('pde')} is steady (no time axis); The Well holds time series: "
                             "export it with --to pdebench")
        space = _space(ds)
        n = ds.sizes["sample"]
        with _new_hdf5(out) as f:
            _common(ds, f, self.name)
            f.attrs.update({"dataset_name": str(ds.attrs["pde"]), "grid_type": "cartesian",
                            "n_spatial_dims": len(space), "n_trajectories": n,
                            "simulation_parameters": list(params)})
            dims = f.create_group("dimensions")
            dims.attrs["spatial_dims"] = list(space)
            for d in ("time", *space):
                v = dims.create_dataset(d, data=ds[d].values)
                v.attrs.update(_attrs(ds[d].attrs))
                v.attrs.update({"sample_varying": False, "time_varying": d == "time"})
            bcs = f.create_group("boundary_conditions")
            for d in space:
                kind = str(ds[d].attrs.get("bc_type", PERIODIC.bc_type)).upper()
                g = bcs.create_group(f"{d}_{kind.lower()}")
                g.attrs.update({"associated_dims": [d], "associated_fields": [], "bc_type": kind,
                                "sample_varying": False, "time_varying": False,
                                "pdestream_bc": str(ds[d].attrs.get("bc", ""))})
                mask = np.zeros(ds.sizes[d], bool)
                mask[[0, -1]] = True
                g.create_dataset("mask", data=mask)
            sc = f.create_group("scalars")
            sc.attrs["field_names"] = list(params)
            for p in params:
                v = sc.create_dataset(p, data=_param_data(ds, p))
                v.attrs.update({**_attrs(ds[p].attrs), "sample_varying": True, "time_varying": False})
            varying = {"dim_varying": [True] * len(space), "sample_varying": True, "time_varying": True}
            velocity = (_incompressible(ds, fields) or ((),))[0]  # a flow's: t1_fields/velocity [N, T, *space, d]
            t1 = f.create_group("t1_fields")
            t1.attrs["field_names"] = ["velocity"] if velocity else []
            if velocity:
                _write_stacked(ds, t1, "velocity", velocity, len(space))
                t1["velocity"].attrs.update(varying)
            fields = tuple(k for k in fields if k not in velocity)
            t0 = f.create_group("t0_fields")
            t0.attrs["field_names"] = list(fields)
            shape = (n, ds.sizes["time"], *(ds.sizes[d] for d in space))
            for name in fields:
                v = t0.create_dataset(name, shape=shape, dtype="float32")
                _copy_field(ds, name, v, len(space))
                v.attrs.update({**_attrs(ds[name].attrs), **varying})
            f.create_group("t2_fields").attrs["field_names"] = []

    def looks_like(self, f) -> bool:
        return all(k in f for k in ("dimensions", "t0_fields", "scalars")) and "n_trajectories" in f.attrs

    def read(self, f) -> dict:
        space = tuple(plain(d) for d in f["dimensions"].attrs["spatial_dims"])
        coords = {d: (f["dimensions"][d][()], dict(f["dimensions"][d].attrs)) for d in ("time", *space)}
        fields = {name: (f["t0_fields"][name][()], dict(f["t0_fields"][name].attrs))
                  for name in (plain(x) for x in f["t0_fields"].attrs["field_names"])}
        if "velocity" in f.get("t1_fields", {}):  # a flow's components, stacked last
            fields.update(_read_stacked(f["t1_fields"]["velocity"]))
            order = str(plain(f.attrs.get("pdestream_fields", ""))).split()
            fields = {k: fields[k] for k in (*order, *fields) if k in fields}  # the cache's order
        params = {name: (f["scalars"][name][()], dict(f["scalars"][name].attrs))
                  for name in (plain(x) for x in f["scalars"].attrs["field_names"])}
        return {"space": space, "coords": coords, "fields": fields, "params": params,
                "drop": WELL_OWN, "drop_var": ("dim_varying", "sample_varying", "time_varying")}


# --- PDEBench --------------------------------------------------------------------------------------
CFD_NAMES = {"rho": "density", "u": "Vx", "v": "Vy", "w": "Vz", "p": "pressure"}  # PDEBench's compressible files


def _pdebench_input_keys(inputs, names) -> dict[str, str]:
    """Each input field's dataset: a steady cache's single input is ``nu``, as in PDEBench's Darcy file (its loader
    reads the coefficient there), unless a field or parameter is called so; else the input's own name."""
    if len(inputs) == 1 and "nu" not in names:
        return {inputs[0]: "nu"}
    return {f: f for f in inputs}


VELOCITY = ("u", "v", "w")  # an incompressible flow's components, stacked last in PDEBench's ``velocity``
PARTICLES = "smoke"  # the passive scalar a flow carries: PDEBench's ``particles`` (its smoke density)


def _incompressible(ds, fields) -> tuple[tuple[str, ...], str | None] | None:
    """(velocity components, passive scalar or None) of a MAC-grid flow's cache (``sides`` set, a pressure ``p``,
    no density):
    PDEBench's incompressible files hold ``velocity`` [N, T, x, y(, z), d] and ``particles`` [N, T, x, y(, z), 1];
    None for any other cache."""
    if not ds.attrs.get("sides") or "rho" in fields or "p" not in fields:  # (diffusion_sorption1d has sides, u)
        return None
    parts = tuple(c for c in VELOCITY if c in fields)
    if parts != VELOCITY[:len(parts)] or len(parts) != len(_space(ds)):
        return None
    return parts, (PARTICLES if PARTICLES in fields else None)


def _write_stacked(ds, f, key: str, names: tuple[str, ...], ndim: int) -> None:
    """Fields ``names`` [N, T, *space] stacked on a last axis as dataset ``key`` [N, T, *space, len(names)]."""
    n, frames = ds.sizes["sample"], ds.sizes["time"]
    grid = tuple(ds.sizes[d] for d in schema.SPACE[:ndim])
    v = f.create_dataset(key, shape=(n, frames, *grid, len(names)), dtype="float32")
    for lo in range(0, n, CHUNK_SAMPLES):
        hi = min(lo + CHUNK_SAMPLES, n)
        v[lo:hi] = np.stack([schema.from_disk(_block(ds, c, lo, hi).astype(np.float32, copy=False), ndim)
                             for c in names], axis=-1)
    v.attrs["pdestream_names"] = " ".join(names)
    for c in names:  # each component's own attributes (long_name differs), as "u.long_name"
        v.attrs.update({f"{c}.{k}": a for k, a in _attrs(ds[c].attrs).items()})


def _read_stacked(dset) -> dict:
    """{component: (array [N, T, *space], its own attributes)} of a dataset ``_write_stacked`` wrote."""
    stacked, attrs = dset[()], dict(dset.attrs)
    names = str(plain(attrs["pdestream_names"])).split()
    if len(names) != stacked.shape[-1]:  # (an IndexError traceback, or components left out)
        raise ValueError(f"{dset.name.rsplit('/', 1)[-1]} holds {stacked.shape[-1]} components but pdestream_names "
                         f"lists {len(names)} ({' '.join(names)})")
    out = {}
    for i, name in enumerate(names):
        out[name] = (stacked[..., i], {k[len(name) + 1:]: v for k, v in attrs.items() if k.startswith(f"{name}.")})
    return out


def _pdebench_keys(fields) -> dict[str, str]:
    """Each field's dataset in a PDEBench file: ``tensor`` for a single field, PDEBench's CFD names for a
    compressible flow's primitive fields (its loader reads density, Vx, ..., pressure), else the field's name."""
    if len(fields) == 1:
        return {fields[0]: "tensor"}
    if {"rho", "u", "p"} <= set(fields) <= set(CFD_NAMES):
        return {f: CFD_NAMES[f] for f in fields}
    return {f: f for f in fields}


class PDEBench:
    """PDEBench's HDF5 layout (see the module docstring)."""

    name = "pdebench"

    def write(self, ds, out: Path) -> None:
        from . import pdebench_seeds

        if pdebench_seeds.per_seed_entry(ds) is not None:  # a set PDEBench ships per seed: its layout
            return pdebench_seeds.write(ds, out, _new_hdf5, _block)
        inputs, fields, params = _names(ds)
        space = _space(ds)
        n, timed = ds.sizes["sample"], "time" in ds.dims
        with _new_hdf5(out) as f:
            _common(ds, f, self.name)
            for d in space:
                f.create_dataset(f"{d}-coordinate", data=ds[d].values).attrs.update(_attrs(ds[d].attrs))
            if timed:
                f.create_dataset("t-coordinate", data=ds["time"].values).attrs.update(_attrs(ds["time"].attrs))
            grid = tuple(ds.sizes[d] for d in space)
            for name, key in _pdebench_input_keys(inputs, (*fields, *params)).items():  # a steady PDE's: [N, *space]
                v = f.create_dataset(key, shape=(n, *grid), dtype="float32")
                _copy_field(ds, name, v, len(space))
                v.attrs.update({**_attrs(ds[name].attrs), "pdestream_name": name})
            frames = ds.sizes["time"] if timed else 1
            flow = _incompressible(ds, fields) if timed else None
            if flow is not None:  # PDEBench's incompressible NS files: velocity, particles, t [N, T]
                velocity, scalar = flow
                _write_stacked(ds, f, "velocity", velocity, len(space))
                if scalar is not None:
                    _write_stacked(ds, f, "particles", (scalar,), len(space))
                f.create_dataset("t", data=np.broadcast_to(ds["time"].values.astype(np.float32), (n, frames)))
                fields = tuple(k for k in fields if k not in velocity and k != scalar)
            for name, key in ({k: k for k in fields} if flow else _pdebench_keys(fields)).items():  # p: "p"
                v = f.create_dataset(key, shape=(n, frames, *grid), dtype="float32")
                _copy_field(ds, name, v, len(space), time_axis=not timed)
                v.attrs.update({**_attrs(ds[name].attrs), "pdestream_name": name})
            for p in params:
                f.create_dataset(p, data=_param_data(ds, p)).attrs.update(_attrs(ds[p].attrs))

    def looks_like(self, f) -> bool:
        from . import pdebench_seeds

        return ("x-coordinate" in f and ("tensor" in f or "density" in f or "pdestream_fields" in f.attrs)) \
            or pdebench_seeds.looks_like(f)

    def read(self, f) -> dict:
        from . import pdebench_seeds

        if "x-coordinate" not in f and pdebench_seeds.looks_like(f):
            return pdebench_seeds.read(f)
        space = tuple(d for d in schema.SPACE if f"{d}-coordinate" in f)
        timed = "t-coordinate" in f
        coords = {d: (f[f"{d}-coordinate"][()], dict(f[f"{d}-coordinate"].attrs)) for d in space}
        coords["time"] = (f["t-coordinate"][()], dict(f["t-coordinate"].attrs)) if timed else None
        names = str(plain(f.attrs["pdestream_fields"])).split()
        inputs = str(plain(f.attrs.get("pdestream_inputs", ""))).split()
        params = {p: (f[p][()], dict(f[p].attrs)) for p in str(plain(f.attrs["pdestream_params"])).split()}
        fields = {}
        for name, key in _pdebench_input_keys(inputs, (*names, *params)).items():
            a = f[key if key in f else name]  # an export written before Darcy's name: the input's own
            fields[name] = (a[()], dict(a.attrs))
        rest, flow = names, "velocity" in f and "pdestream_names" in f["velocity"].attrs
        for key in ("velocity", "particles") if flow else ():  # an incompressible flow's stacked fields
            if key in f:
                parts = _read_stacked(f[key])
                fields.update(parts)
                rest = [k for k in rest if k not in parts]
        for name, key in ({k: k for k in rest} if flow else _pdebench_keys(rest)).items():
            a = f[key if key in f else name]  # an export written before the CFD names: the field's own
            fields[name] = (a[()] if timed else a[:, 0], dict(a.attrs))
        fields = {k: fields[k] for k in (*inputs, *names)}  # the cache's order
        return {"space": space, "coords": coords, "fields": fields, "params": params, "drop": (),
                "drop_var": ("pdestream_name",)}


FORMATS: dict[str, ExportFormat] = {f.name: f for f in (TheWell(), PDEBench())}


# --- export ----------------------------------------------------------------------------------------
def _check_out(out: Path, overwrite: bool) -> None:
    """Refuse an OUT that exists (unless ``overwrite`` and it is a pdestream export) or whose directory is missing
    or not writable."""
    from .cache import _check_writable

    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise ValueError(f"--out {str(out)!r} must end in .h5 or .hdf5 (got {out.suffix or 'no suffix'!r}): both "
                         "formats are HDF5 files")
    if out.is_symlink():
        raise ValueError(f"{out} is a symlink to {os.readlink(out)}; pdestream does not write through links: "
                         "give the real path")
    if out.exists():
        if not overwrite:
            raise FileExistsError(f"{out} exists; pass --overwrite to replace it (only a pdestream export is replaced)")
        if exported_as(out) is None:
            raise ValueError(f"refusing to overwrite {out}: it is not an export written by pdestream (remove it "
                             "yourself or choose another path)")
    _check_writable(out)  # a directory that is missing or read-only: before the cache is read


def export_cache(cache, to: str, out, overwrite: bool = False) -> Path:
    """Write the complete cache at ``cache`` to ``out`` in format ``to`` ("the-well" or "pdebench"); returns
    ``out``. One-line ValueError for an unknown format, an incomplete or unreadable cache, an existing ``out``
    (without ``overwrite``, or one that is not a pdestream export)."""
    from .cache import check_room, is_complete, open_cache

    if to not in FORMATS:
        raise ValueError(f"--to {to!r} not allowed; allowed: {', '.join(FORMATS)}")
    fmt, out = FORMATS[to], Path(out)
    _check_out(out, overwrite)
    ds = open_cache(cache)
    try:
        if not is_complete(ds):
            done = int((ds["complete"].values == 1).sum())
            raise ValueError(f"{cache} is incomplete ({done} of {ds.sizes['sample']} samples written); only a "
                             "complete cache is exported: finish it with `pdestream generate ... --resume`")
        check_room(out, sum(int(ds[v].size) * 4 for v in ds.data_vars))  # float32 fields, the rest is small
        tmp = out.with_name(f"{out.name}.tmp-{os.getpid()}")
        try:
            with _write_failures(out), _damaged_reads() as damaged:
                fmt.write(ds, tmp)
            if damaged:  # (the file written is removed below)
                _refuse_damaged(cache, ds, damaged)
            if overwrite and out.exists():  # checked above: a pdestream export, replaced as asked
                os.replace(tmp, out)
            else:
                schema.publish_new(tmp, out)  # a file another export made meanwhile is never replaced
        except BaseException:
            tmp.unlink(missing_ok=True)  # ours
            raise
        velocity = (_incompressible(ds, _names(ds)[1]) or ((),))[0]
    finally:
        ds.close()
    stats = well_stats_path(out) if to == "the-well" else None
    if stats is not None:
        from .stats import cache_stats, write_stats

        write_stats(cache, stats, _vector_stats(cache_stats(cache), velocity))
    return out


def _vector_stats(stats: dict, velocity: tuple[str, ...]) -> dict:
    """``stats`` (``cache_stats``) plus, for a flow's velocity (The Well's t1 field), each statistic as the list of
    its components' values (``{"mean": {"velocity": [mean u, mean v]}}``, as The Well's stats.yaml holds a vector
    field's); the components' own entries stay (pdestream's normalization reads them)."""
    for key, values in stats.items():
        if velocity and key != "pdestream" and isinstance(values, dict):
            values["velocity"] = [values[c] for c in velocity]
    return stats


def _refuse_damaged(cache, ds, damaged: set) -> None:
    """One line for a cache whose complete samples (positions ``damaged``) hold NaN/Inf (a deleted Zarr chunk, a
    changed file): it was exported with rc 0 into a file that `import` refuses."""
    idx = [int(i) for i in ds["sample"].values[sorted(damaged)]]
    shown = ", ".join(map(str, idx[:8])) + (f", ... ({len(idx)} in all)" if len(idx) > 8 else "")
    raise ValueError(f"{cache} is damaged: samples {shown} hold non-finite or missing data; recompute them with "
                     "`pdestream generate ... --resume`, then export it")


def well_stats_path(out: Path) -> Path | None:
    """Where a The Well export's statistics go: ``DIR/stats.yaml`` (where WellDataset looks) for an export to
    ``DIR/data/train/NAME.hdf5``; None (nothing written) elsewhere, or where a stats.yaml pdestream did not write
    is (left alone)."""
    from .stats import read_stats

    well = out.parent.parent.parent / "stats.yaml"
    if out.parent.name != "train" or out.parent.parent.name != "data":
        return None
    try:
        return well if not well.exists() or read_stats(well) else None
    except ValueError:  # someone else's statistics
        return None


@contextmanager
def _write_failures(out: Path):
    """A write that fails at the OS level (disk full, file size limit, I/O error) as one line naming ``out``;
    the caller removes its temporary file."""
    from .cache import CacheWriteError, is_write_failure, os_error_cause

    try:
        yield
    except (OSError, RuntimeError) as err:
        if not is_write_failure(err):
            raise
        raise CacheWriteError(f"cannot write {out}: {os_error_cause(err)}; nothing was written") from None


# --- reading back ----------------------------------------------------------------------------------
def exported_as(path) -> str | None:
    """The format name of a pdestream export at ``path``; None when it is not one (or not readable)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            name = plain(f.attrs.get("pdestream_export"))
            return name if name in FORMATS and FORMATS[name].looks_like(f) else None
    except (OSError, ValueError):
        return None


def cached_config(path) -> dict | None:
    """The PDE config (``PDE.config()``: "pde" and every setting) a pdestream cache or export at ``path`` holds,
    read from its attributes alone (no torch, no JAX); None when ``path`` is not one or cannot be read (the
    reader's own checks then say why)."""
    import json

    try:
        path = Path(path)
        if path.is_dir():  # a Zarr cache
            import zarr

            attrs = dict(zarr.open_group(str(path), mode="r").attrs)
        else:
            import h5py

            with h5py.File(path, "r") as f:
                attrs = {schema.CONFIG_ATTR: f.attrs.get(schema.CONFIG_ATTR)}
        config = json.loads(str(plain(attrs.get(schema.CONFIG_ATTR))))
    except Exception:  # anything unreadable: not ours to explain here
        return None
    return config if isinstance(config, dict) else None


def cache_written(path) -> tuple[int, int] | None:
    """(samples written, samples) of a pdestream cache at ``path`` whose writer did not finish (``cache.is_complete``
    false: its pdestream_complete flag unset or a sample's ``complete`` flag 0), read from the flags alone (no
    torch, no JAX, no xarray); None for a finished cache, an export (no flags) or anything unreadable."""
    try:
        path = Path(path)
        if path.is_dir():  # a Zarr cache
            import zarr

            group = zarr.open_group(str(path), mode="r")
            done, flags = group.attrs.get("pdestream_complete"), np.asarray(group["complete"][:])
        else:
            import h5py

            with h5py.File(path, "r") as f:
                if "complete" not in f:
                    return None
                done, flags = f.attrs.get("pdestream_complete"), np.asarray(f["complete"][:])
    except Exception:  # not a cache this reads: the reader's own checks say why
        return None
    if plain(done) == 1 and (flags == 1).all():
        return None
    return int((flags == 1).sum()), int(flags.size)


def named_pde(path) -> str | None:
    """The PDE a pdestream cache or export at ``path`` holds (its config's ``pde``), or None (``cached_config``)."""
    name = (cached_config(path) or {}).get("pde")
    return name if isinstance(name, str) and name else None


def read_export(path):
    """An export written by ``export_cache`` as an xarray.Dataset in pdestream's layout (what ``open_cache``
    gives for the cache it came from, loaded): fields [sample, time, (z,) y, x], per-sample parameters,
    ``redraws`` and ``complete`` as coordinates, the cache's root attributes. One-line ValueError for a file
    that is not an export of a known format, or one the other project wrote (no pdestream config)."""
    import h5py
    import xarray as xr

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no export at {path}: not a file")
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise ValueError(f"{path} is not a readable HDF5 file: {str(err).splitlines()[0]}") from None
    with f:
        found = [fmt for fmt in FORMATS.values() if fmt.looks_like(f)]
        if not found:
            raise ValueError(f"{path} is neither a The Well nor a PDEBench HDF5 file; allowed: files written by "
                             "`pdestream export --to the-well|pdebench`")
        if schema.CONFIG_ATTR not in f.attrs:
            raise ValueError(f"{path} is a {found[0].name} file not written by pdestream (no {schema.CONFIG_ATTR} "
                             "attribute): pdestream reads back only its own exports")
        fmt = FORMATS.get(plain(f.attrs.get("pdestream_export")), found[0])
        try:
            got = fmt.read(f)
            attrs = {k: plain(v) for k, v in f.attrs.items() if k not in (*got["drop"], "pdestream_export")}
            # the per-seed layout keeps them in each sample's group (its loaders take every top-level key for one)
            sample = got["sample"] if "sample" in got else f[GROUP]["sample"][()].astype(np.int64)
            redraws = got["redraws"] if "redraws" in got else f[GROUP]["redraws"][()].astype(np.int8)
            outputs = _read_outputs(f)
        except KeyError as err:  # a dataset or attribute the format puts there is gone
            text = str(err.args[0] if err.args else err)
            named = re.search(r"object '([^']+)'", text)  # h5py: "Unable to ... open object (object 'nu' ...)"
            raise ValueError(f"{path} is a damaged {fmt.name} export: {named.group(1) if named else text} is "
                             "missing; export the cache again") from None
        except ValueError as err:  # numpy's stack of unequal shapes, a config that is not JSON: name the file
            raise ValueError(f"{path} is a damaged {fmt.name} export: {str(err).splitlines()[0]}; export the "
                             "cache again") from None
    _check_export_attrs(path, attrs, got)
    _check_samples(path, fmt.name, attrs, got, len(sample))
    space, ndim = got["space"], len(got["space"])
    disk = schema.disk_space_dims(ndim)
    timed = got["coords"].get("time") is not None

    def clean(a: dict, drop=()) -> dict:
        return {k: plain(v) if not isinstance(v, np.ndarray) else v for k, v in a.items()
                if k not in (*drop, "sample_varying", "time_varying")}

    coords = {"sample": ("sample", sample, {"long_name": "sample index"})}
    if timed:
        t, ta = got["coords"]["time"]
        coords["time"] = ("time", t, clean(ta))
    for d in space:
        coords[d] = (d, got["coords"][d][0], clean(got["coords"][d][1]))
    for p, (v, a) in got["params"].items():
        coords[p] = ("sample", _finite(path, p, v.astype(np.float32)), clean(a))
    coords["redraws"] = ("sample", redraws, {"long_name": "blow-up redraws used for this sample", "units": "1"})
    coords["complete"] = ("sample", np.ones(len(sample), np.int8),
                          {"long_name": "sample fully written", "flag_values": [0, 1], "flag_meanings": "missing written"})
    inputs = set(str(attrs.get("pdestream_inputs", "")).split())
    data = {}
    for name, (a, at) in got["fields"].items():
        dims = ("sample", *(("time",) if timed and name not in inputs else ()), *disk)
        values = _finite(path, name, np.ascontiguousarray(schema.to_disk(a.astype(np.float32), ndim)))
        data[name] = (dims, values, clean(at, got["drop_var"]))
    for name in str(attrs.get("pdestream_outputs", "")).split():  # a flow's drag, lift, sdf
        if name not in outputs:
            raise ValueError(f"{path} is a damaged {fmt.name} export: its output {name} is missing (an export "
                             "written before outputs were kept); export the cache again")
        dims, values, at = outputs[name]
        data[name] = (dims, values, clean(at))
    try:
        ds = xr.Dataset(data, coords=coords, attrs=attrs)
    except ValueError as err:  # xarray: "conflicting sizes for dimension 'sample'" (an array cut short)
        raise ValueError(f"{path} is a damaged {fmt.name} export: {str(err).splitlines()[0]}; export the cache "
                         "again") from None
    return ds[[*data]]  # the cache's variable order


def _check_samples(path: Path, fmt: str, attrs: dict, got: dict, n: int) -> None:
    """One line for an export whose sample count (``n``, the samples read) is not the one it lists
    (``pdestream_n_samples``: a per-seed group deleted was imported, and the cache then read as damaged), or
    whose cache schema this version cannot read (imported, then refused by every reader)."""
    listed = attrs.get("pdestream_n_samples")
    try:
        ok = int(listed) == n and float(listed) == int(listed)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{path} is a damaged {fmt} export: it lists {listed} samples (pdestream_n_samples), "
                         f"{n} are in the file; export the cache again")
    first = next(iter(got["fields"].values()))[0]
    schema.check_readable(path, attrs, ("sample", *(("time",) if first.ndim > len(got["space"]) + 1 else ()),
                                        *schema.disk_space_dims(len(got["space"]))))


def _finite(path, name: str, a: np.ndarray) -> np.ndarray:
    """``a`` [sample, ...]; one-line ValueError naming the samples when any value is NaN/Inf (pdestream writes
    none: such an export was changed after it was written, and a cache made from it would train on NaN)."""
    bad = ~np.isfinite(a.reshape(len(a), -1)).all(axis=1) if a.size else np.zeros(0, bool)
    if bad.any():
        rows = np.flatnonzero(bad)
        raise ValueError(f"{path}: {name} holds NaN/Inf in {rows.size} sample(s) (rows {rows[:5].tolist()}"
                         f"{' ...' if rows.size > 5 else ''}); allowed: finite values, as pdestream exports them")
    return a


def _check_export_attrs(path: Path, attrs: dict, got: dict) -> None:
    """One line for an export whose pdestream attributes do not describe its content: a config that is not JSON
    (every reader of the imported cache would refuse it), a listed field or parameter that is not there."""
    import json

    try:
        config = json.loads(attrs[schema.CONFIG_ATTR])
        if not isinstance(config, dict):
            raise ValueError("not a JSON object")
    except (ValueError, TypeError) as err:
        raise ValueError(f"{path} is a damaged export: its {schema.CONFIG_ATTR} attribute is not a JSON object "
                         f"({err}); export the cache again") from None
    for what, listed, have in (("field", attrs.get("pdestream_fields", ""), got["fields"]),
                               ("input", attrs.get("pdestream_inputs", ""), got["fields"]),
                               ("parameter", attrs.get("pdestream_params", ""), got["params"])):
        missing = [n for n in str(listed).split() if n not in have]
        if missing:
            raise ValueError(f"{path} is a damaged export: {what} {', '.join(missing)} is listed but not in the "
                             "file; export the cache again")
    if not str(attrs.get("pdestream_fields", "")).split():
        raise ValueError(f"{path} is a damaged export: it lists no fields (pdestream_fields); export the cache again")


def import_export(path, out) -> Path:
    """Write the export at ``path`` back as a complete pdestream cache at ``out`` (.h5/.hdf5 or .zarr; the layout
    ``pdestream generate`` writes), so `pdestream train NAME --source OUT` trains on it. Refuses an existing
    ``out``; built under a hidden name and renamed into place."""
    from .cache import _check_name, _check_writable, _hidden, check_room
    from .store import format_of, remove_any

    out = Path(out)
    fmt = format_of(out)
    _check_name(out)
    if out.exists() or out.is_symlink():
        raise FileExistsError(f"{out} exists; choose another path (import never replaces a file)")
    _check_writable(out)
    ds = read_export(path)
    inputs, fields, params = _names(ds)
    outputs = str(ds.attrs.get("pdestream_outputs", "")).split()
    first = ds[fields[0]]
    lay = schema.Layout(
        dims=dict(ds.sizes),
        coords={d: ((d,), ds[d].values, dict(ds[d].attrs)) for d in ("sample", *(["time"] if "time" in ds.dims
                                                                                  else []), *_space(ds))},
        per_sample={**{p: ("float32", dict(ds[p].attrs)) for p in params},
                    "redraws": ("int8", dict(ds["redraws"].attrs)), "complete": ("int8", dict(ds["complete"].attrs))},
        fields={n: {**ds[n].attrs, "coordinates": " ".join((*params, "redraws", "complete"))} for n in (*inputs, *fields)},
        field_dims=first.dims,
        attrs={**ds.attrs, "pdestream_complete": 0},
        outputs={n: (ds[n].dims, str(ds[n].dtype), dict(ds[n].attrs)) for n in outputs},
    )
    block = int(ds.attrs.get("pdestream_block", ds.sizes["sample"]))
    if fmt.name == "hdf5":
        check_room(out, schema.hdf5_bytes(lay))
    tmp = _hidden(out, "new")
    try:
        with _write_failures(out):
            fmt.create(tmp, lay, min(block, ds.sizes["sample"]))
            store = fmt.open(tmp, writable=True)
            try:
                for n in (*inputs, *fields, *params, *outputs, "redraws"):
                    store[n][...] = ds[n].values
                store.flush()
                store["complete"][...] = np.ones(ds.sizes["sample"], np.int8)
                store.flush()
                fmt.mark_complete(store)
            finally:
                store.close()
        schema.publish_new(tmp, out)  # never over a cache another import made meanwhile
    except BaseException:
        remove_any(tmp)
        raise
    return out


_IMPORTED: dict[tuple, Path] = {}  # (export path, its identity) -> the temporary cache made from it


def as_cache(path) -> Path:
    """``path`` for anything but an export; for an export written by ``export_cache``, a cache made from it
    (``import_export``) in a private temporary directory, once per process and version of the file. The
    directory is removed when the process exits, after an interrupt too (a kill -9 leaves it in the system's
    temporary directory: ``pdestream-import-*``)."""
    import shutil
    import tempfile
    from multiprocessing.util import Finalize

    path = Path(path)
    if exported_as(path) is None:
        return path
    st = path.stat()
    key = (str(path.resolve()), st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size)
    if key not in _IMPORTED:
        tmp = Path(tempfile.mkdtemp(prefix="pdestream-import-"))
        # run at exit by multiprocessing's exit hook, which the CLI's exit after an interrupt runs as well;
        # ignored in child processes
        Finalize(None, shutil.rmtree, args=(str(tmp),), kwargs={"ignore_errors": True}, exitpriority=0)
        _IMPORTED[key] = import_export(path, tmp / path.with_suffix(".h5").name)
    return _IMPORTED[key]
