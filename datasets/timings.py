"""Measured times of earlier runs, so a run's progress line gives a time left within seconds, while the solver
still compiles (``meter.Meter(last=...)``).

One small JSON (``history_path()``: ~/.cache/pdestream/progress.json; $PDESTREAM_PROGRESS_HISTORY names another
file, set and empty: nothing read or written) maps a key (``_bridge.progress_key``: the command, the entry's
config hash, JAX's backend) to the last run's {"startup_s": seconds to its first count (mostly the
compile), "unit_s": seconds per sample after it}. A missing, unreadable or garbled file is an empty one; one that
cannot be written only costs the next run its early estimate.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from .schema import atomic_write

HISTORY_ENV = "PDESTREAM_PROGRESS_HISTORY"
HISTORY_KEYS = 200  # records kept (the most recent)


def history_path() -> Path | None:
    """$PDESTREAM_PROGRESS_HISTORY, else progress.json under $XDG_CACHE_HOME/pdestream (~/.cache/pdestream);
    None when the variable is set and empty."""
    named = os.environ.get(HISTORY_ENV)
    if named is not None:
        return Path(named) if named else None
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pdestream" / "progress.json"


def _history() -> dict:
    path = history_path()
    try:
        data = json.loads(path.read_text()) if path is not None else {}
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def recall(key: str, typical: dict | None = None) -> dict | None:
    """The times to start a progress line from, {"startup_s": s, "unit_s": s per unit > 0, "basis": words}, or
    None: ``key``'s last record ("last time"); else the newest record of the same command, entry and backend under
    another config ("last time, another config": the compile costs about the same); else ``typical``, the entry's
    own declared times ("typical on 2 CPU cores", ``Problem.TYPICAL_TIMES``), so a first run on a fresh machine
    also has an estimate while it compiles."""
    data = _history()
    rec = _valid(data.get(key))
    if rec:
        return {**rec, "basis": "last time"}
    parts = key.split(" ")  # _bridge.progress_key: "COMMAND ENTRY CONFIG_HASH BACKEND"
    same = (parts[0], parts[1], parts[-1]) if len(parts) >= 4 else None
    for other in reversed(list(data)):
        theirs = other.split(" ")
        if same and len(theirs) >= 4 and (theirs[0], theirs[1], theirs[-1]) == same:
            rec = _valid(data[other])
            if rec:
                return {**rec, "basis": "last time, another config"}
    rec = _valid(typical)
    return {**rec, "basis": typical.get("basis", "typical")} if rec else None


def _valid(rec) -> dict | None:
    if not isinstance(rec, dict):
        return None
    times = {k: rec.get(k) for k in ("startup_s", "unit_s")}
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0 for v in times.values()):
        return None
    return {k: float(v) for k, v in times.items()} if times["unit_s"] > 0 else None


def remember(key: str, times: dict | None) -> None:
    """Record ``times`` (``Meter.measured()``; None: nothing) as ``key``'s last, keeping the HISTORY_KEYS most
    recent keys."""
    path = history_path()
    if path is None or not times:
        return
    data = _history()
    data.pop(key, None)
    data[key] = {"startup_s": round(times["startup_s"], 3), "unit_s": times["unit_s"], "at": round(time.time())}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, json.dumps(dict(list(data.items())[-HISTORY_KEYS:]), indent=0).encode())
    except OSError:
        pass
