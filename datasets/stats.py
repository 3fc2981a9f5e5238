"""A cache's normalization statistics, written once beside it in The Well's ``stats.yaml`` layout.

``cache_stats(CACHE)`` reads every complete sample once (``CachedTrajectories.moments``: float64 Welford/Chan
partials per sample, merged in sample order, so the bits do not depend on how the reads were split) and returns
The Well's keys, each a dict keyed by field name (per-field scalars, physical units of the field):
``mean``, ``std`` (population), ``rms`` (sqrt(mean^2 + std^2)) over every frame and grid point, and ``mean_delta``,
``std_delta``, ``rms_delta`` of the time differences u[t+1] - u[t] (absent for a steady cache), plus
``pdestream``: {"samples", "normalization": ``Normalization.to_dict()`` (what training applies, parameters
included)}. ``write_stats`` writes it to ``CACHE.stats.yaml`` (``pdestream inspect CACHE --stats``); the file
is JSON text whose numbers YAML 1.1 reads as floats, so both ``json.load`` and ``yaml.safe_load`` read it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

STATS_SUFFIX = ".stats.yaml"


def stats_path(cache) -> Path:
    """Where ``write_stats`` puts a cache's statistics: beside it, ``CACHE.stats.yaml``."""
    return Path(str(cache).rstrip("/") + STATS_SUFFIX)


def _number(x: float) -> str:
    text = repr(float(x))
    if not math.isfinite(x):
        raise ValueError(f"statistic {text} is not finite")
    mantissa, e, exp = text.partition("e")  # YAML 1.1 reads 1e-05 as a string: write 1.0e-05
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + (e + ("+" + exp if exp[0] != "-" else exp) if e else "")


def dumps(obj, indent: str = "") -> str:
    """JSON text of dicts, lists, strings, ints, floats, bools and None that YAML 1.1 reads the same."""
    inner = indent + "  "
    if isinstance(obj, dict):
        items = [f"{inner}{json.dumps(str(k))}: {dumps(v, inner)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}" if items else "{}"
    if isinstance(obj, (list, tuple)):
        return "[" + ", ".join(dumps(v, inner) for v in obj) + "]"
    if isinstance(obj, (float, np.floating)):
        return _number(float(obj))
    return json.dumps(obj.item() if isinstance(obj, np.generic) else obj)


def _keyed(fields, mean: np.ndarray, var: np.ndarray, suffix: str = "") -> dict:
    rms = np.sqrt(mean * mean + var)
    return {f"mean{suffix}": dict(zip(fields, map(float, mean))), f"std{suffix}": dict(zip(fields, map(float, np.sqrt(var)))),
            f"rms{suffix}": dict(zip(fields, map(float, rms)))}


def cache_stats(cache, chunk: int = 64) -> dict:
    """The Well's stats of the complete samples of ``cache`` (see the module docstring); one pass over the file."""
    from .loader import CachedTrajectories

    ds = CachedTrajectories(cache)  # an incomplete cache is refused in one line: its statistics would change
    try:
        moments, deltas = ds.moments(chunk, delta=True)
        norm = moments.result(ds.fields, ds.param_names, samples=len(ds.rows), inputs=ds.n_inputs)
        out = _keyed(ds.fields, *moments.raw(0)[1:])
        if deltas is not None and deltas.raw(0) is not None:
            out.update(_keyed(ds.fields, *deltas.raw(0)[1:], suffix="_delta"))
    finally:
        ds.close()
    out["pdestream"] = {"samples": len(ds.rows), "normalization": norm.to_dict()}
    return out


def write_stats(cache, out=None, stats: dict | None = None) -> Path:
    """Write ``cache_stats(cache)`` (or ``stats``) to ``out`` (default ``stats_path(cache)``), atomically; returns
    the path."""
    from .schema import atomic_write

    out = stats_path(cache) if out is None else Path(out)
    atomic_write(out, (dumps(cache_stats(cache) if stats is None else stats) + "\n").encode())
    return out


def read_stats(path) -> dict:
    """A stats file written by ``write_stats``; ValueError (one line) when it is missing or not one."""
    try:
        stats = json.loads(Path(path).read_text())
    except (OSError, ValueError) as err:
        raise ValueError(f"cannot read statistics {path}: {str(err).splitlines()[0]}") from None
    if not isinstance(stats, dict) or "normalization" not in stats.get("pdestream", {}):
        raise ValueError(f"{path} is not a statistics file written by pdestream (no pdestream.normalization)")
    return stats
