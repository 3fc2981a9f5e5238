"""Counts, rates and time left of long work, and the hook through which solves report their progress. No JAX,
no torch (the surrogate side and the CLI import it).

Solves report: ``report(done, total)`` after each bounded call (``generator.dispatch`` re-exports it; the spectral
rollouts, the flows' advance and the external solvers call it), read by the callback of ``progress_to(callback)``
in force in the calling thread (``datasets``' prefetch thread inherits its consumer's). Reports only read
counters: a solve's calls and bits are the same with or without a callback.

``Meter`` shows a count (fractional within a solve), a rate and the time left: a tqdm bar on a terminal, else a
plain line FIRST seconds after it starts and then at most every EVERY seconds (a ticker thread, so a line comes
while the work is inside one long solve). A Meter with a ``key`` (generate: the entry's config hash, block and
JAX backend) records its start-up (seconds to the first count: the solver's compile) and seconds per unit in a
small JSON (``history_path()``; PDESTREAM_PROGRESS_HISTORY names another file, empty: none kept), and the next
Meter of that key gives a time left from them until it has measured its own rate.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

FIRST = 3.0  # seconds before the first plain line of a Meter
EVERY = 5.0  # seconds between a Meter's plain lines
BAR_REFRESH = 0.5  # seconds between refreshes of a terminal bar
HISTORY_ENV = "PDESTREAM_PROGRESS_HISTORY"
HISTORY_KEYS = 200  # records kept (the most recent)

_HOOK = threading.local()


@contextmanager
def progress_to(callback: Callable[[int, int], None] | None):
    """Inside the block, solves in the calling thread call ``callback(done, total)`` (steps or samples of the
    solve, 0 < done <= total) after each bounded call; the callback before it comes back after it."""
    before = getattr(_HOOK, "callback", None)
    _HOOK.callback = callback
    try:
        yield
    finally:
        _HOOK.callback = before


def current() -> Callable[[int, int], None] | None:
    """The callback of the calling thread's ``progress_to`` (None: none)."""
    return getattr(_HOOK, "callback", None)


def report(done: int, total: int) -> None:
    """A solve of the calling thread has done ``done`` of its ``total`` steps (or samples): to the callback of
    ``progress_to`` if any (clamped to [0, total]; nothing for total <= 0)."""
    callback = getattr(_HOOK, "callback", None)
    if callback is not None and total > 0:
        callback(min(max(done, 0), total), total)


def duration(seconds: float) -> str:
    """'4 s', '3 min 10 s', '2 h 5 min'."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {s % 3600 // 60} min"


def history_path() -> Path | None:
    """The JSON of measured times: $PDESTREAM_PROGRESS_HISTORY, else ~/.cache/pdestream/progress.json (under
    $XDG_CACHE_HOME if set); None when the variable is set and empty (nothing read or written)."""
    named = os.environ.get(HISTORY_ENV)
    if named is not None:
        return Path(named) if named else None
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pdestream" / "progress.json"


def _history() -> dict:
    path = history_path()
    try:
        data = json.loads(path.read_text()) if path is not None else {}
    except (OSError, ValueError):
        return {}  # none yet, unreadable or garbled: as if nothing was recorded
    return data if isinstance(data, dict) else {}


def recall(key: str) -> dict | None:
    """The last record of ``key``: {"startup_s": seconds to the first count, "unit_s": seconds per unit}, or None."""
    rec = _history().get(key)
    ok = isinstance(rec, dict) and all(isinstance(rec.get(k), (int, float)) and rec[k] >= 0 for k in ("startup_s", "unit_s"))
    return {"startup_s": float(rec["startup_s"]), "unit_s": float(rec["unit_s"])} if ok and rec["unit_s"] > 0 else None


def remember(key: str, startup_s: float, unit_s: float) -> None:
    """Record the times of ``key`` (replacing its last record; the HISTORY_KEYS most recent kept). A file that
    cannot be written only costs the next run its early estimate."""
    path = history_path()
    if path is None:
        return
    data = _history()
    data.pop(key, None)
    data[key] = {"startup_s": round(startup_s, 3), "unit_s": unit_s, "at": round(time.time())}
    data = dict(list(data.items())[-HISTORY_KEYS:])
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}")
        tmp.write_text(json.dumps(data, indent=0))
        os.replace(tmp, path)  # whole or not at all: a concurrent run reads the old or the new file
    except OSError:
        pass


def _count(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:.2f}"


class Meter:
    """``done`` of ``total`` ``unit`` (``initial`` already done before it started: a resumed cache), with a rate
    and the time left. ``set``/``add`` may come from any thread (a solve's callback); the lines come from a ticker
    thread (``live``), or from ``tick(now)`` (tests, with a fake ``clock``). ``terminal``: a tqdm bar instead of
    plain lines (default: whether stderr is a terminal); ``enabled=False`` shows nothing. ``key``: the times of
    the last Meter of that key (``recall``) give the time left before this one has a rate, and this one's are
    recorded at ``close`` (``remember``); ``last`` gives such times directly. ``starting``: what a line says
    before the first count (e.g. 'compiling the solver')."""

    def __init__(self, label: str, total: float, unit: str = "samples", initial: float = 0.0,
                 first: float | None = None, every: float | None = None, clock: Callable[[], float] | None = None,
                 terminal: bool | None = None, enabled: bool = True, live: bool = True, key: str | None = None,
                 last: dict | None = None, starting: str = "no rate yet"):
        self.label, self.total, self.unit = label, float(total), unit
        self.key, self.starting = key, starting
        self.last = last if last is not None or key is None or not enabled else recall(key)
        self.clock = clock or time.monotonic
        self.first, self.every = FIRST if first is None else first, EVERY if every is None else every
        self.done = self.initial = float(initial)
        self.t0, self.last_line, self.lines = self.clock(), None, 0
        self.enabled = enabled
        self._mark = None  # (time, count) of the first count above ``initial``: the rate is measured from there
        self._latest = None  # time of the last count that moved
        self._lock, self._show, self._stop = threading.Lock(), threading.Lock(), threading.Event()
        terminal = sys.stderr.isatty() if terminal is None else terminal
        self.bar = None
        if enabled and terminal:
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, initial=self.initial, desc=label, unit=unit.rstrip("s") or unit,
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.0f} "
                                       "[{elapsed}<{remaining}, {rate_fmt}]", smoothing=0.1)
        self._shown = self.initial
        self._thread = None
        if enabled and live:
            self._thread = threading.Thread(target=self._run, daemon=True, name="pdestream-meter")
            self._thread.start()

    # --- counting ----------------------------------------------------------------------------------------
    def set(self, done: float) -> None:
        """``done`` units done in all (never goes back; at most ``total``); a line if one is due."""
        with self._lock:
            before, self.done = self.done, max(self.done, min(float(done), self.total))
            if self.done > before:
                self._latest = self.clock()
            if self._mark is None and self.done > self.initial:
                self._mark = (self._latest, self.done)
        self.tick()

    def add(self, n: float) -> None:
        self.set(self.done + n)

    @contextmanager
    def solving(self, base: float, n: float):
        """Inside the block the calling thread's solves cover units base..base+n: their reports move the count
        within that range; the count is base+n after the block."""
        def moved(done: int, total: int) -> None:
            self.set(base + n * done / total)

        with progress_to(moved):
            yield
        self.set(base + n)

    # --- showing -----------------------------------------------------------------------------------------
    def rate(self, now: float | None = None) -> float | None:
        """Units per second measured by this Meter: since the first count above ``initial`` once a second has
        passed and more was done since (the first call's compile does not count); since the start once the
        first count is EVERY s old with nothing more (coarse counts: finished blocks); else None."""
        now = self.clock() if now is None else now
        if self._mark is None or now <= self.t0:
            return None
        since, at = now - self._mark[0], self._mark[1]
        if since >= 1.0 and self.done > at:
            return (self.done - at) / since
        return (self.done - self.initial) / (now - self.t0) if since >= self.every else None

    def left(self, now: float | None = None) -> tuple[float, float, bool] | None:
        """(units per second, seconds left, whether from the last record) or None: the measured rate, else the
        last record's (its start-up still to come before the first count), else None."""
        now = self.clock() if now is None else now
        rate = self.rate(now)
        if rate:
            return rate, (self.total - self.done) / rate, False
        if not self.last:
            return None
        startup = 0.0 if self._mark is not None else max(0.0, self.last["startup_s"] - (now - self.t0))
        return 1 / self.last["unit_s"], startup + (self.total - self.done) * self.last["unit_s"], True

    def text(self, now: float | None = None) -> str:
        """'karman2d: 1.25/4 samples, 22 s/sample, ~1 min 0 s left (40 s so far)'; before a rate of its own, from
        the last record: 'karman2d: 0/4 samples, ~22 s/sample last time, ~2 min 10 s left (compiling the solver:
        about 44 s last time) (12 s so far)'."""
        now = self.clock() if now is None else now
        est = self.left(now)
        so_far = f"({duration(now - self.t0)} so far)"
        head = f"{self.label}: {_count(self.done)}/{_count(self.total)} {self.unit}"
        if est is None:
            what = self.starting if self._mark is None else "no rate yet"
            return f"{head}, {what}, time left unknown {so_far}"
        rate, left, recorded = est
        one = self.unit[:-1] if self.unit.endswith("s") else self.unit
        pace = f"{rate:.3g} {self.unit}/s" if rate >= 1 else f"{1 / rate:.3g} s/{one}"
        if not recorded:
            return f"{head}, {pace}, ~{duration(left)} left {so_far}"
        start = f" ({self.starting}: about {duration(self.last['startup_s'])} last time)" if self._mark is None else ""
        return f"{head}, ~{pace} last time, ~{duration(left)} left{start} {so_far}"

    def tick(self, now: float | None = None) -> bool:
        """Show the count if due: a bar refresh on a terminal, else a plain line FIRST s after the start, then at
        most every EVERY s. Returns whether a plain line was printed."""
        if not self.enabled or self._stop.is_set():  # closed: a solve still reporting (a stream's prefetch) is quiet
            return False
        with self._show:
            return self._tick(self.clock() if now is None else now)

    def _tick(self, now: float) -> bool:
        if self.bar is not None:
            with self._lock:
                done = self.done
            if done > self._shown:
                self.bar.update(done - self._shown)
                self._shown = done
            else:
                self.bar.refresh()
            return False
        due = self.t0 + self.first if self.last_line is None else self.last_line + self.every
        if now < due:
            return False
        print(self.text(now), file=sys.stderr, flush=True)
        self.last_line, self.lines = now, self.lines + 1
        return True

    def _run(self) -> None:
        wait = BAR_REFRESH if self.bar is not None else max(0.05, min(0.5, self.first, self.every))
        while not self._stop.wait(wait):
            self.tick()

    def close(self) -> None:
        """Stop the ticker; a terminal bar shows the final count and goes; with a ``key``, record the start-up
        and the seconds per unit measured (when both were)."""
        if self.key is not None and self.enabled and self._mark is not None and self.done > self._mark[1]:
            # the counts after the first (the start-up apart), up to the last that moved
            remember(self.key, self._mark[0] - self.t0, (self._latest - self._mark[0]) / (self.done - self._mark[1]))
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self.bar is not None:
            with self._show:
                self._tick(self.clock())
                self.bar.close()
