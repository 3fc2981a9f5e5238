"""What a cache holds, in words (``summary``) and in a picture (``plot``)."""

from __future__ import annotations

import json

import numpy as np

from . import schema
from .cache import is_complete, open_cache


def field_stats(ds, name: str, rows: np.ndarray, block: int = 64) -> dict:
    """mean / std / min / max of field ``name`` over samples ``rows``, read ``block`` samples at a time, and
    "damaged": the rows whose data is non-finite or unreadable (left out of the statistics)."""
    total, total_sq, count, lo, hi, damaged = 0.0, 0.0, 0, np.inf, -np.inf, []
    for k in range(0, len(rows), block):
        part = rows[k : k + block]
        try:
            a = ds[name].isel(sample=part).values.astype(np.float64)
        except Exception:  # a corrupted chunk: every sample of this read is suspect
            damaged.extend(part)
            continue
        finite = np.isfinite(a.reshape(len(a), -1)).all(1)  # a written sample is always finite
        damaged.extend(part[~finite])
        a = a[finite]
        if a.size:
            total, total_sq, count = total + a.sum(), total_sq + (a * a).sum(), count + a.size
            lo, hi = min(lo, a.min()), max(hi, a.max())
    if count == 0:
        return {"mean": np.nan, "std": np.nan, "min": np.nan, "max": np.nan, "damaged": damaged}
    mean = total / count
    return {"mean": mean, "std": np.sqrt(max(total_sq / count - mean * mean, 0.0)), "min": lo, "max": hi,
            "damaged": damaged}


def summary(path) -> str:
    """Several lines: PDE, equation, config, samples complete of total, parameter ranges, field statistics,
    bytes on disk."""
    ds = open_cache(path)
    try:
        a = ds.attrs
        complete = ds["complete"].values == 1
        rows = np.flatnonzero(complete)
        state = "complete" if is_complete(ds) else "INCOMPLETE (finish with `pdestream generate ... --resume`)"
        sizes = ", ".join(f"{d}={n}" for d, n in ds.sizes.items())
        lines = [
            f"{path}: pdestream cache ({schema.cache_format(path)}), {schema.disk_bytes(path):,} bytes on disk",
            f"  pde: {a['pde']}: {a['equation']}",
            f"  samples: {int(complete.sum())} of {complete.size} complete, {state}; seed {a['pdestream_seed']}",
            f"  dims: {sizes}; time in [{float(ds.time[0]):g}, {float(ds.time[-1]):g}]",
            f"  config: {json.dumps(json.loads(a[schema.CONFIG_ATTR]), sort_keys=True)}",
            f"  provenance: hash {a['pdestream_config_hash']}, pdestream {a['pdestream_version']}, "
            f"jax {a['jax_version']} (threefry_partitionable={a['jax_threefry_partitionable']})",
        ]
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
        for name in a["pdestream_fields"].split():
            s = field_stats(ds, name, rows)
            damaged.update(s["damaged"])
            lines.append(f"  field {name}: mean {s['mean']:.4g}  std {s['std']:.4g}  min {s['min']:.4g}  max {s['max']:.4g}")
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
    """A PNG of up to ``n_show`` complete samples: space-time images (1D) or first/middle/last snapshots
    (2D) of the first field. Returns the path written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ds = open_cache(path, complete_only=True)
    try:
        if ds.sizes["sample"] == 0:
            raise ValueError(f"{path}: no complete samples to plot")
        name = ds.attrs["pdestream_fields"].split()[0]
        show = min(n_show, ds.sizes["sample"])
        u = ds[name].isel(sample=slice(0, show)).values  # [S, T, x(, y)]
        t, x = ds.time.values, ds.x.values
        params = ds.attrs["pdestream_params"].split()
        label = [", ".join(f"{p}={float(ds[p][i]):.3g}" for p in params) for i in range(show)]
        index = ds["sample"].values[:show]
        if u.ndim == 3:
            fig, axes = plt.subplots(1, show, figsize=(3.2 * show, 3), squeeze=False)
            for i, ax in enumerate(axes[0]):
                im = ax.imshow(u[i], aspect="auto", origin="lower", cmap="RdBu_r",
                               extent=[x[0], x[-1], t[0], t[-1]])
                ax.set(title=f"#{index[i]} {label[i]}", xlabel="x", ylabel="t" if i == 0 else None)
                fig.colorbar(im, ax=ax)
        else:
            frames = sorted({0, u.shape[1] // 2, u.shape[1] - 1})
            fig, axes = plt.subplots(show, len(frames), figsize=(3 * len(frames), 2.8 * show), squeeze=False)
            for i in range(show):
                for j, f in enumerate(frames):
                    ax = axes[i, j]
                    ax.imshow(u[i, f].T, origin="lower", cmap="RdBu_r")
                    ax.set(title=f"#{index[i]} t={t[f]:.3g}", xticks=[], yticks=[])
                axes[i, 0].set_ylabel(label[i])
        fig.suptitle(f"{ds.attrs['pde']}: {name}")
        fig.tight_layout()
        try:
            fig.savefig(out, dpi=100)
        except OSError as err:
            raise ValueError(f"cannot write plot {out}: {err.strerror or err}") from None
        finally:
            plt.close(fig)
        return str(out)
    finally:
        ds.close()
