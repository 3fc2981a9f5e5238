"""PDEBench's per-seed HDF5 layout, for the three sets PDEBench ships that way (its ``single_file: False`` configs,
read by ``FNODatasetMult`` / ``UNetDatasetMult``): 1D diffusion-sorption, 2D diffusion-reaction and the 2D radial
dam break (shallow water).

Every top-level key of such a file is one sample, a group named by its index, zero-padded to 4 digits (PDEBench's
``str(seed).zfill(4)``; wider past 9999, so sorted names stay in sample order, which is how the loaders split off
their test set). A group holds ``data`` [T, x(, y), C] (time first, x first, the fields on the last axis: the fields
PDEBench's own file holds for the set, in its order) and ``grid/x`` (, ``grid/y``), ``grid/t``. What PDEBench's file
does not hold stays beside it, where its loaders do not look: our other fields as datasets [T, x(, y)] in the group
(shallow water's ``hu``, ``hv``), the sample's index, redraws and parameters as the group's attributes, the cache's
attributes and each field's and coordinate's attributes on the file. Nothing else sits at the top level: the
loaders take every top-level key for a sample.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import schema
from .store import plain

# the sets PDEBench ships per seed: {entry: the fields of its ``data``, in PDEBench's channel order}
PER_SEED_CHANNELS: dict[str, tuple[str, ...]] = {
    "diffusion_sorption1d": ("u",),  # 1D_diff-sorp_NA_NA.h5: [101, 1024, 1]
    "diffusion_reaction2d": ("u", "v"),  # 2D_diff-react_NA_NA.h5: [101, 128, 128, 2] (activator, inhibitor)
    "shallow_water2d": ("h",),  # 2D_rdb_NA_NA.h5: [101, 128, 128, 1] (water height only)
}
FIELD_ATTRS = "pdestream_field_attrs"  # JSON {field or coordinate: its attributes}, on the file
SAMPLE, REDRAWS = "pdestream_sample", "pdestream_redraws"  # a group's attributes


def per_seed_entry(ds) -> str | None:
    """The entry of a cache if PDEBench ships its set per seed, else None."""
    name = json.loads(ds.attrs[schema.CONFIG_ATTR]).get("pde")
    return name if name in PER_SEED_CHANNELS else None


def _json_attrs(a: dict) -> dict:
    return {k: (v.tolist() if isinstance(v, np.ndarray) else plain(v)) for k, v in a.items()
            if k not in ("coordinates", "_FillValue")}


def write(ds, out: Path, new_hdf5, read) -> None:
    """Write the complete time-dependent cache ``ds`` at ``out`` in the per-seed layout (``new_hdf5``: export's
    file opener; ``read(ds, name, lo=None, hi=None)``: export's read of a variable, which checks what it reads)."""
    entry = per_seed_entry(ds)
    fields = tuple(str(ds.attrs["pdestream_fields"]).split())
    params = tuple(str(ds.attrs["pdestream_params"]).split())
    channels = PER_SEED_CHANNELS[entry]
    beside = [f for f in fields if f not in channels]
    ndim = schema.space_ndim(ds[fields[0]].dims)
    space = schema.SPACE[:ndim]
    n = ds.sizes["sample"]
    width = max(4, len(str(n - 1)))
    coords = {d: np.asarray(ds[d].values) for d in space}
    t = np.asarray(ds["time"].values)
    sample = np.asarray(ds["sample"].values, np.int64)
    redraws = np.asarray(ds["redraws"].values, np.int8)
    values = {p: read(ds, p).astype(np.float32, copy=False) for p in params}
    with new_hdf5(out) as f:
        for k, v in ds.attrs.items():
            f.attrs[k] = v
        f.attrs["pdestream_export"] = "pdebench"
        f.attrs["pdestream_layout"] = "per-seed"
        f.attrs[FIELD_ATTRS] = json.dumps({name: _json_attrs(ds[name].attrs) for name in (*fields, *params, *space,
                                                                                          "time")})
        for lo in range(0, n, 64):  # 64 samples read at a time: bounded memory
            hi = min(lo + 64, n)
            block = {name: schema.from_disk(read(ds, name, lo, hi).astype(np.float32, copy=False), ndim)
                     for name in fields}  # [b, T, x(, y)]
            for i in range(lo, hi):
                g = f.create_group(str(i).zfill(width))
                g.create_dataset("data", data=np.stack([block[c][i - lo] for c in channels], axis=-1))
                for d in space:
                    g.create_dataset(f"grid/{d}", data=coords[d])
                g.create_dataset("grid/t", data=t)
                for name in beside:
                    g.create_dataset(name, data=block[name][i - lo])
                g.attrs.update({SAMPLE: sample[i], REDRAWS: redraws[i], **{p: values[p][i] for p in params}})


def looks_like(f) -> bool:
    """True for a file in the per-seed layout (its first key a group with ``data`` and ``grid``)."""
    import h5py

    first = next(iter(f.keys()), None)
    return first is not None and isinstance(f[first], h5py.Group) and "data" in f[first] and "grid" in f[first]


def read(f) -> dict:
    """What a per-seed export written by ``write`` holds, in ExportFormat.read's form, with the samples' indices
    and redraws ("sample", "redraws")."""
    keys = sorted(f.keys())
    fields = tuple(str(plain(f.attrs["pdestream_fields"])).split())
    params = tuple(str(plain(f.attrs["pdestream_params"])).split())
    attrs = json.loads(str(plain(f.attrs[FIELD_ATTRS])))
    channels = PER_SEED_CHANNELS[json.loads(str(plain(f.attrs[schema.CONFIG_ATTR])))["pde"]]
    first = f[keys[0]]
    space = tuple(d for d in schema.SPACE if d in first["grid"])
    coords = {d: (first["grid"][d][()], attrs.get(d, {})) for d in space}
    coords["time"] = (first["grid"]["t"][()], attrs.get("time", {}))
    data = {name: [] for name in fields}
    got_params = {p: [] for p in params}
    sample, redraws = [], []
    for k in keys:
        g = f[k]
        stacked = g["data"][()]  # [T, x(, y), C]
        for name in fields:
            data[name].append(stacked[..., channels.index(name)] if name in channels else g[name][()])
        for p in params:
            got_params[p].append(g.attrs[p])
        sample.append(g.attrs[SAMPLE])
        redraws.append(g.attrs[REDRAWS])
    return {"space": space, "coords": coords,
            "fields": {name: (np.stack(a), attrs.get(name, {})) for name, a in data.items()},
            "params": {p: (np.asarray(v, np.float32), attrs.get(p, {})) for p, v in got_params.items()},
            "drop": ("pdestream_layout", FIELD_ATTRS), "drop_var": (),
            "sample": np.asarray(sample, np.int64), "redraws": np.asarray(redraws, np.int8)}
