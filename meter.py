"""Counts, rates and time left of long work, and the hook through which solves report their progress. No JAX,
no torch (the surrogate side and the CLI import it).

Solves report: ``report(done, total)`` after each bounded call (``generator.dispatch`` re-exports it; the spectral
rollouts, the flows' advance and the external solvers call it), read by the callback of ``progress_to(callback)``
in force in the calling thread (``datasets``' prefetch thread inherits its consumer's). Reports only read
counters: a solve's calls and bits are the same with or without a callback.

``Meter`` shows a count (fractional within a solve), a rate and the time left: a tqdm bar on a terminal, else a
plain line FIRST seconds after it starts and then at most every EVERY seconds (a ticker thread, so a line comes
while the work is inside one long solve). Given the times of a previous run (``last``: its start-up, the
seconds to its first count, which is mostly the solver's compile, and its seconds per unit; ``measured()``
gives them, ``datasets.timings`` keeps them), a Meter gives a time left from them until it has a rate of its own. PDESTREAM_PROGRESS=0 in the environment turns every Meter off (logs
that want only the results; the test suite, whose one-line checks would otherwise depend on how busy the
machine is).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from contextlib import contextmanager
from typing import Callable

FIRST = 3.0  # seconds before the first plain line of a Meter
EVERY = 5.0  # seconds between a Meter's plain lines
BAR_REFRESH = 0.5  # seconds between refreshes of a terminal bar

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


def singular(unit: str) -> str:
    """The unit of one: "trajectories" -> "trajectory", "samples" -> "sample", "steps" -> "step"."""
    if unit.endswith("ies"):
        return unit[:-3] + "y"
    return unit[:-1] if unit.endswith("s") and len(unit) > 1 else unit


def _count(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:.2f}"


class Meter:
    """``done`` of ``total`` ``unit`` (``initial`` already done before it started: a resumed cache), with a rate
    and the time left. ``set``/``add`` may come from any thread (a solve's callback); the lines come from a ticker
    thread (``live``), or from ``tick(now)`` (tests, with a fake ``clock``). ``terminal``: a tqdm bar instead of
    plain lines (default: whether stderr is a terminal); ``enabled=False`` shows nothing. ``last``: a previous
    run's ``measured()`` times, the time left until this one has a rate. ``starting``: what a line says before
    the first count (e.g. 'compiling the solver')."""

    def __init__(self, label: str, total: float, unit: str = "samples", initial: float = 0.0,
                 first: float | None = None, every: float | None = None, clock: Callable[[], float] | None = None,
                 terminal: bool | None = None, enabled: bool = True, live: bool = True, last: dict | None = None,
                 starting: str = "no rate yet"):
        self.label, self.total, self.unit = label, float(total), unit
        self.starting, self.last = starting, last
        self.clock = clock or time.monotonic
        self.first, self.every = FIRST if first is None else first, EVERY if every is None else every
        self.done = self.initial = float(initial)
        self.t0, self.last_line, self.lines = self.clock(), None, 0
        self.enabled = enabled and os.environ.get("PDESTREAM_PROGRESS", "1") != "0"
        enabled = self.enabled
        self._mark = None  # (time, count) of the first count above ``initial``: the rate is measured from there
        self._latest = None  # time of the last count that moved
        self._lock, self._show, self._stop = threading.Lock(), threading.Lock(), threading.Event()
        terminal = sys.stderr.isatty() if terminal is None else terminal
        self.bar = None
        if enabled and terminal:
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, initial=self.initial, desc=label, unit=singular(unit),
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.0f} "
                                       "[{elapsed}<{remaining}, {rate_fmt}{postfix}]", smoothing=0.1)
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
        one = singular(self.unit)
        pace = f"{rate:.3g} {self.unit}/s" if rate >= 1 else f"{1 / rate:.3g} s/{one}"
        if not recorded:
            return f"{head}, {pace}, ~{duration(left)} left {so_far}"
        basis = self.last.get("basis", "last time")
        start = f" ({self.starting}: about {duration(self.last['startup_s'])} {basis})" if self._mark is None else ""
        return f"{head}, ~{pace} {basis}, ~{duration(left)} left{start} {so_far}"

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
            est = self.left(now) if self.last else None  # before its own rate: the last run's time left
            basis = self.last.get("basis", "last time") if self.last else ""
            self.bar.set_postfix_str(f"~{duration(est[1])} left, {basis}" if est and est[2] else "", refresh=False)
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

    def measured(self) -> dict | None:
        """{"startup_s": seconds from the start to the first count, "unit_s": seconds per unit of the counts
        after it, up to the last that moved}; None before a second count a second or more after the first."""
        with self._lock:
            if self._mark is None or self.done <= self._mark[1] or self._latest - self._mark[0] < 1.0:
                return None
            return {"startup_s": self._mark[0] - self.t0, "unit_s": (self._latest - self._mark[0]) / (self.done - self._mark[1])}

    def close(self) -> None:
        """Stop the ticker; a terminal bar shows the final count and goes."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self.bar is not None:
            with self._show:
                self._tick(self.clock())
                self.bar.close()
