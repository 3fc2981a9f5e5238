"""What a cache holds, in words (``summary``) and in a picture (``plot``)."""

from __future__ import annotations

import json
import os
import textwrap
from pathlib import Path

import numpy as np

from ..boundaries import PERIODIC
from . import schema
from .cache import is_complete, open_cache
from .derived import flow_vorticity


def field_stats(ds, name: str, rows: np.ndarray, block: int = 64) -> dict:
    """mean / std / min / max of field ``name`` over samples ``rows`` (every frame and grid point), read ``block``
    samples at a time and accumulated in float64 by ``normalize.Moments`` (as normalization statistics are), and
    "damaged": the rows whose data is non-finite or unreadable (left out of the statistics)."""
    import torch

    from .normalize import Moments

    moments, lo, hi, damaged = Moments(0), np.inf, -np.inf, []  # ndim 0: every value of the field is one channel
    for k in range(0, len(rows), block):
        part = rows[k : k + block]
        try:
            a = ds[name].isel(sample=part).values
        except Exception:  # a corrupted chunk: every sample of this read is suspect
            damaged.extend(part)
            continue
        finite = np.isfinite(a.reshape(len(a), -1)).all(1)  # a written sample is always finite
        damaged.extend(part[~finite])
        a = a[finite]
        if a.size:
            moments.add(torch.from_numpy(a.reshape(len(a), -1, 1)), index=part[finite])  # [b, values, 1 channel]
            lo, hi = min(lo, float(a.min())), max(hi, float(a.max()))
    raw = moments.raw()
    if raw is None:
        return {"mean": np.nan, "std": np.nan, "min": np.nan, "max": np.nan, "damaged": damaged}
    _, mean, var = raw  # the raw moments: a constant field reports std 0, not 1
    return {"mean": float(mean[0]), "std": float(np.sqrt(var[0])), "min": lo, "max": hi, "damaged": damaged}


def output_line(ds, name: str, rows: np.ndarray) -> tuple[str, np.ndarray]:
    """One line on a per-sample output over samples ``rows``: a 0/1 flag's count, else mean / std / min / max
    with its dims and units; and the rows whose values are non-finite (a written output is always finite)."""
    var = ds[name]
    values = var.values[rows]
    finite = np.isfinite(values.reshape(len(rows), -1)).all(1) if len(rows) else np.zeros(0, bool)
    values = values[finite]
    dims = ", ".join(var.dims)
    if "flag_values" in var.attrs:
        return f"  output {name}: {int((values == 1).sum())} of {len(values)} samples  ({var.attrs.get('long_name', '')})", \
            rows[~finite]
    units = var.attrs.get("units", "1")
    if not values.size:
        return f"  output {name} [{units}] ({dims}): (none written)", rows[~finite]
    return (f"  output {name} [{units}] ({dims}): mean {values.mean():.4g}  std {values.std():.4g}  "
            f"min {values.min():.4g}  max {values.max():.4g}"), rows[~finite]


def boundary_line(attrs: dict, ndim: int) -> str:
    """'x dirichlet (wall), y periodic (periodic)': each space axis's boundary condition and The Well's word."""
    bcs = schema.cache_boundaries(attrs, ndim)
    types = str(attrs.get("bc_type") or " ".join([PERIODIC.bc_type] * ndim)).split()
    recorded = "" if attrs.get("bc") else " (not recorded: a cache written before boundaries were)"
    return ", ".join(f"{schema.SPACE[i]} {b} ({t})" for i, (b, t) in enumerate(zip(bcs, types))) + recorded


def split_note(recipe: str, seed: int, n: int) -> str:
    """' (the test split's seed: its first 16 of 200)': which split of ``recipe`` the seed is, and how much of it
    the cache holds ('' when the seed is none of its splits')."""
    from pdestream.recipes import RECIPES

    r = RECIPES.get(recipe)
    split = next((k for k, s in r.splits.items() if s.seed == seed), None) if r else None
    if split is None:
        return ""
    size = r.splits[split].n
    held = "all" if n == size else f"its first {n} of {size}" if n < size else f"its {size} and {n - size} beyond it"
    return f" (the {split} split's seed: {held})"


PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


PLOT_MARK = "pdestream inspect"  # in a figure's metadata (PNG Software, PDF / SVG Creator): one we may replace
MARK_KEY = {".png": "Software", ".pdf": "Creator", ".svg": "Creator"}  # JPEG holds no metadata here


def check_plot_path(out) -> None:
    """One line for a --plot path no figure can be written to: a directory or a name without a figure suffix
    (``--plot .`` wrote a hidden '.png'), a parent directory that does not exist, or an existing file that
    ``plot`` did not write (it replaces only its own figures: the file's metadata names PLOT_MARK)."""
    out = Path(out)
    if out.is_dir() or out.suffix.lower() not in PLOT_SUFFIXES:
        raise ValueError(f"--plot {out}: allowed: a file ending in {', '.join(PLOT_SUFFIXES)}")
    if not out.parent.is_dir():
        raise ValueError(f"cannot write plot {out}: directory {out.parent} does not exist")
    if out.exists() and not _our_figure(out):
        jpeg = " (a JPEG holds no mark of it)" if out.suffix.lower() not in MARK_KEY else ""
        raise ValueError(f"--plot {out}: the file exists and is not a figure pdestream inspect wrote{jpeg}; choose "
                         "another path or remove it (inspect replaces only its own figures)")


def _our_figure(path: Path) -> bool:
    """Whether ``path`` is a figure ``plot`` wrote (PLOT_MARK in its first 64 KiB, where its metadata is)."""
    try:
        with open(path, "rb") as f:
            return PLOT_MARK.encode() in f.read(65536)
    except OSError:
        return False


def summary(path, plot=None) -> str:
    """Several lines: PDE, equation, config, samples complete of total, parameter ranges, field statistics,
    bytes on disk. ``plot``: a --plot path, checked first (``check_plot_path``)."""
    if plot is not None:
        check_plot_path(plot)
    ds = open_cache(path)
    try:
        a = ds.attrs
        complete = ds["complete"].values == 1
        rows = np.flatnonzero(complete)
        state = "complete" if is_complete(ds) else "INCOMPLETE (finish with `pdestream generate ... --resume`)"
        sizes = ", ".join(f"{d}={n}" for d, n in ds.sizes.items())
        refine = json.loads(a[schema.CONFIG_ATTR]).get("refine", 1)
        if refine > 1:  # the stored grid is a subsample (a MAC-grid flow: the block means) of the one solved on
            kept = (f"each {refine}x{refine} block's means stored" if a.get("sides")
                    else f"1 point in {refine} kept")
            sizes += f" (solved on {refine} times as many points per axis, {kept})"
        lines = [
            f"{path}: pdestream cache ({schema.cache_format(path)}), {schema.disk_bytes(path):,} bytes on disk",
            f"  pde: {a['pde']}: {a['equation']}",
            f"  samples: {int(complete.sum())} of {complete.size} complete, {state}; seed {a['pdestream_seed']}",
            f"  dims: {sizes}; " + (f"time in [{float(ds.time[0]):g}, {float(ds.time[-1]):g}]" if "time" in ds.dims
                                    else "steady (no time axis)"),
            "  boundaries: " + boundary_line(a, sum(d in ds.dims for d in schema.SPACE)),
            f"  config: {json.dumps(json.loads(a[schema.CONFIG_ATTR]), sort_keys=True)}",
            f"  provenance: hash {a['pdestream_config_hash']}, pdestream {a['pdestream_version']}, "
            f"jax {a['jax_version']} (threefry_partitionable={a['jax_threefry_partitionable']})",
        ]
        if a.get("pdestream_recipe"):
            from pdestream.recipes import changed_note

            changed = changed_note(a["pdestream_recipe"], json.loads(a[schema.CONFIG_ATTR]))
            lines.insert(2, f"  recipe: {a['pdestream_recipe']}{changed}: {a.get('pdestream_recipe_source', '')}")
            lines[3] += split_note(a["pdestream_recipe"], int(a["pdestream_seed"]), complete.size)
        damaged = set()
        for name in a["pdestream_params"].split():
            values = ds[name].values[rows]
            damaged.update(rows[~np.isfinite(values)])  # a deleted parameter chunk reads as NaN
            values = values[np.isfinite(values)]
            units = ds[name].attrs.get("units", "1")
            span = f"[{values.min():.4g}, {values.max():.4g}]" if len(values) else "(none written)"
            lines.append(f"  param {name}: {span} [{units}], domain {ds[name].attrs.get('domain', '?')}")
        if len(rows):
            redraws = ds["redraws"].values[rows]
            if redraws.any():
                lines.append(f"  blow-up redraws: {int((redraws > 0).sum())} samples")
        for name in _fields(ds):
            s = field_stats(ds, name, rows)
            damaged.update(s["damaged"])
            lines.append(f"  field {name}: mean {s['mean']:.4g}  std {s['std']:.4g}  min {s['min']:.4g}  max {s['max']:.4g}")
        for name in str(a.get("pdestream_outputs", "")).split():  # the PDE's per-sample outputs (PDE.OUTPUTS)
            line, bad = output_line(ds, name, rows)
            damaged.update(bad)
            lines.append(line)
        if damaged:
            idx = [int(i) for i in ds["sample"].values[sorted(damaged)]]
            shown = ", ".join(map(str, idx[:8])) + (f", ... ({len(idx)} in all)" if len(idx) > 8 else "")
            lines[2] = (f"  samples: {int(complete.sum())} of {complete.size} flagged complete, DAMAGED: samples {shown} "
                        "hold non-finite or missing data (recompute them with `pdestream generate ... --resume`); "
                        f"seed {a['pdestream_seed']}")
        return "\n".join(lines)
    finally:
        ds.close()


def plot(path, out, n_show: int = 4) -> str:
    """Write ``figure(path, n_show)`` as a PNG to ``out``; returns the path written."""
    import matplotlib

    matplotlib.use("Agg")  # a file, no window (and no display needed)
    import matplotlib.pyplot as plt

    check_plot_path(out)
    fig = figure(path, n_show)
    out = Path(out)
    key = MARK_KEY.get(out.suffix.lower())
    tmp = out.with_name(f".{out.stem}.tmp-{os.getpid()}{out.suffix}")  # replaced whole: never half a figure
    try:
        fig.savefig(tmp, dpi=80, **({"metadata": {key: PLOT_MARK}} if key else {}))
        os.replace(tmp, out)
    except OSError as err:
        raise ValueError(f"cannot write plot {out}: {err.strerror or err}") from None
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return str(out)


def figure(path, n_show: int = 4):
    """A matplotlib Figure of up to ``n_show`` complete samples of the cache at ``path`` (``draw``)."""
    ds = open_cache(path, complete_only=True)
    try:
        if ds.sizes["sample"] == 0:
            raise ValueError(f"{path}: no complete samples to plot")
        return draw(ds, n_show)
    finally:
        ds.close()


def draw(ds, n_show: int = 4):
    """Every field of the first ``n_show`` samples of a cache's Dataset, as a Figure (current backend).

    1D: space-time images (x across, t up), one row per field, one column per sample. 2D: first/middle/last
    frames (x across, y up, origin lower, aspect equal), one row per sample, one group of columns per field (at
    most three fields across; more go to a further band of rows),
    frame times in the titles; 3D: the three orthogonal planes through the centre (x-y, x-z, y-z) at the last frame
    instead of three frames, named in the figure's title. Colour ranges: in 1D one per field over all
    its panels; in 2D/3D one per field and frame column, shared by that column's samples, with its own colourbar
    below it (one range over all frames left ns2d's t = 0 column blank: its vorticity grows ~100x under the
    forcing). Colourbars carry the field's name and units (the PDE's FIELD_UNITS); maps are diverging and centred
    on zero for a signed field, sequential for a one-signed one (``colour_scale``). Axis labels come from the
    coordinates' long_name/units attrs, as in xarray's own plots.
    """
    import matplotlib.pyplot as plt

    fields = _fields(ds)
    show = min(n_show, ds.sizes["sample"])
    params = ds.attrs["pdestream_params"].split()
    # wrapped to a panel's width (~34 characters at 8 pt): diffusion_sorption1d's five parameters ran into the next panel
    label = [textwrap.fill(", ".join(f"{p}={float(ds[p][i]):.3g}" for p in params), 34) for i in range(show)]
    index = ds["sample"].values[:show]
    space = [d for d in ds[fields[0]].dims if d in schema.SPACE]  # stored order: (z,) (y,) x
    mask = None
    if ds.attrs.get("sides"):  # a MAC-grid flow: its bodies drawn over every panel, its vorticity shown first
        if "solid" in fields:
            fields, mask = [f for f in fields if f != "solid"], ds["solid"]
        if {"u", "v"} <= set(fields):  # in 3D its z component alone, named so (it read as the flow's vorticity)
            name = "vorticity_z" if len(space) == 3 else "vorticity"
            w = flow_vorticity(ds)
            if len(space) == 3:
                w = w.assign_attrs(long_name="z-vorticity dv/dx - du/dy")
            ds = ds.assign({name: w})
            fields = [name, *fields]
    if len(space) == 1:
        fig = _space_time(plt, ds, fields, show, index, label, space)
    else:
        fig = _snapshots(plt, ds, fields, show, index, label, space, mask)
    # wrapped to the figure's width (~14 characters per inch at 9 pt): darcy2d's equation ran past the right edge
    title = textwrap.fill(f"{ds.attrs['pde']}: {ds.attrs['equation']}", max(20, int(14 * fig.get_figwidth())))
    if slices_note(ds, space):  # which planes a 3D cache's panels are
        title += "\n" + textwrap.fill(slices_note(ds, space), max(20, int(14 * fig.get_figwidth())))
    fig.suptitle(title, fontsize=9)
    return fig


def _fields(ds) -> list[str]:
    """The cache's field variables: a steady PDE's input fields (darcy2d's coefficient a) first, then its fields."""
    return ds.attrs.get("pdestream_inputs", "").split() + ds.attrs["pdestream_fields"].split()


OUTLIER_RATIO = 3.0  # largest |value| over the 99.5th percentile beyond which the extremes saturate


def colour_scale(values: np.ndarray) -> dict:
    """imshow keywords (cmap, vmin, vmax) shared by every panel of one field: a diverging map centred on zero
    when the values take both signs, a sequential one when they keep one sign (e.g. concentrations). Values
    reaching less than 10% of the largest magnitude to the other side of zero do not make a field signed: a
    spectral solver's Gibbs ringing undershoots a concentration's sharp edge by up to ~9% of the jump."""
    finite = values[np.isfinite(values)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    span = max(abs(lo), abs(hi)) or 1.0
    if lo < -0.1 * span and hi > 0.1 * span:
        # a few cells far above the rest (a flow's vorticity at a body's corners, +-100 where the wake is +-3)
        # would wash the picture out: then the range is the 99.5th percentile of |value| and those cells saturate
        bulk = float(np.percentile(np.abs(finite), 99.5))
        if 0 < bulk < span / OUTLIER_RATIO:
            span = bulk
        return {"cmap": "RdBu_r", "vmin": -span, "vmax": span}
    return {"cmap": "viridis", "vmin": lo, "vmax": hi if hi > lo else lo + 1.0}


def axis_label(var) -> str:
    """An xarray variable's label from its attrs, as xarray prints it: "long_name [units]" (name if unset)."""
    name = var.attrs.get("long_name", var.name)
    units = var.attrs.get("units")
    return f"{name} [{units}]" if units else str(name)


def _edges(coord: np.ndarray, cell_left: bool) -> tuple[float, float]:
    """The extent of an image over ``coord``: cells [c_j, c_j + d) for grid points, centred cells for times."""
    d = float(coord[1] - coord[0]) if len(coord) > 1 else 1.0
    return (float(coord[0]), float(coord[-1]) + d) if cell_left else (float(coord[0]) - d / 2, float(coord[-1]) + d / 2)


def _space_time(plt, ds, fields, show, index, label, space):
    """1D: one row per field, one column per sample, t up, x across; one colourbar per row."""
    x, t = ds[space[0]].values, ds.time.values
    extent = [*_edges(x, True), *_edges(t, False)]
    fig, axes = plt.subplots(len(fields), show, figsize=(2.6 * show + 0.8, 2.4 * len(fields) + 0.6), squeeze=False,
                             layout="constrained")
    for r, name in enumerate(fields):
        u = ds[name].isel(sample=slice(0, show)).transpose("sample", "time", *space).values  # [S, T, x]
        scale = colour_scale(u)
        for i, ax in enumerate(axes[r]):
            im = ax.imshow(u[i], origin="lower", aspect="auto", extent=extent, interpolation="nearest", **scale)
            ax.set_title(f"#{index[i]} {label[i]}", fontsize=8)
            ax.set_xlabel(axis_label(ds[space[0]]) if r == len(fields) - 1 else "")
            ax.set_ylabel(axis_label(ds.time) if i == 0 else "")
        fig.colorbar(im, ax=list(axes[r]), label=axis_label(ds[name]), fraction=0.04, pad=0.01)
    return fig


MAX_COLUMNS = 9  # panels across a 2D/3D cache's figure (three fields' first/middle/last frames)


def _views(ds, space: list[str]) -> list[tuple]:
    """The panels of one field, (frame index or None, slab {dim: index}, up dim, across dim, where in words): in
    2D its first, middle and last frames; in 3D the three orthogonal planes through the grid's centre (x-y at the
    middle z, x-z at the middle y, y-z at the middle x) at the last frame."""
    timed = "time" in ds.dims
    n_frames = ds.sizes["time"] if timed else 1
    if len(space) < 3:
        return [(f if timed else None, {}, space[-2], space[-1], "") for f in sorted({0, n_frames // 2, n_frames - 1})]
    z, y, x = space  # stored order
    mid = {d: ds.sizes[d] // 2 for d in space}
    last = n_frames - 1 if timed else None
    return [(last, {d: mid[d]}, up, across, f" {d}={float(ds[d][mid[d]]):.3g}")
            for d, up, across in ((z, y, x), (y, z, x), (x, z, y))]


def slices_note(ds, space: list[str]) -> str:
    """A 3D figure's title line: which planes its panels are ("" in 1D / 2D)."""
    if len(space) < 3:
        return ""
    where = ", ".join(f"{d}={float(ds[d][ds.sizes[d] // 2]):.3g}" for d in sorted(space))
    when = f" at the last frame t={float(ds.time[-1]):.4g}" if "time" in ds.dims else ""
    return f"3D: mid-slices {where}{when} (x-y, x-z and y-z planes through the centre)"


def _snapshots(plt, ds, fields, show, index, label, space, mask=None):
    """2D: one row per sample, first/middle/last frame of each field, x across, y up; 3D: the three orthogonal
    mid-slices at the last frame instead of the frames (``_views``); at most MAX_COLUMNS panels across (further
    fields in another band of rows); one colourbar per field and column. A steady PDE's cache (no time axis): one
    panel per field, input fields first. ``mask``: a flow's solid cells [sample, time, (z,) y, x], drawn in grey
    over every panel."""
    views = _views(ds, space)
    # at most MAX_COLUMNS panels across: a flow's vorticity, u, v, p and scalar made 15 in one row; further fields
    # go to another band of rows (one row per sample in each band)
    per_band = max(1, MAX_COLUMNS // len(views))
    bands = -(-len(fields) // per_band)
    across_fields = min(len(fields), per_band)
    cols = across_fields * len(views)
    fig, axes = plt.subplots(show * bands, cols, figsize=(2.2 * cols + 0.8 * across_fields, 2.4 * show * bands + 0.7),
                             squeeze=False, layout="constrained")
    for ax in axes[(bands - 1) * show:, (len(fields) - (bands - 1) * per_band) * len(views):].flat:
        ax.set_axis_off()  # the last band's empty slots
    for c, name in enumerate(fields):
        band, slot = divmod(c, per_band)
        block = axes[band * show:(band + 1) * show, slot * len(views):(slot + 1) * len(views)]
        for j, (f, slab, up, across, where) in enumerate(views):
            var = ds[name].isel(sample=slice(0, show), **slab)
            var = var.isel(time=f) if f is not None else var
            u = var.transpose("sample", up, across).values  # [S, up, across]: row up, column across
            extent = [*_edges(ds[across].values, True), *_edges(ds[up].values, True)]
            scale = colour_scale(u)  # per column: a forced field grows ~100x from t = 0 (ns2d)
            for i in range(show):
                ax = block[i, j]
                im = ax.imshow(u[i], origin="lower", aspect="equal", extent=extent, interpolation="nearest", **scale)
                if mask is not None:
                    m = mask.isel(sample=i, **({"time": f} if f is not None else {}), **slab).transpose(up, across).values
                    ax.imshow(np.ma.masked_where(m < 0.5, m), origin="lower", aspect="equal", extent=extent,
                              interpolation="nearest", cmap="Greys", vmin=0.0, vmax=1.6)
                title = f"{name} #{index[i]}" + (f" t={float(ds.time[f]):.4g}" if f is not None else "") + where
                ax.set_title(title + (f"\n{label[i]}" if j == 0 and label[i] else ""), fontsize=7)
                ax.set_xlabel(axis_label(ds[across]) if i == show - 1 else "", fontsize=8)
                ax.set_ylabel(axis_label(ds[up]) if j == 0 and slot == 0 or where else "", fontsize=8)
                ax.tick_params(labelsize=7)
            bar = fig.colorbar(im, ax=list(block[:, j]), location="bottom", shrink=0.9, fraction=0.05, pad=0.02)
            bar.ax.tick_params(labelsize=7)
            bar.set_label(axis_label(ds[name]), fontsize=8)
    return fig
