"""Saying what a long run is doing: a bar on a terminal, plain periodic lines in a log.

Every phase of a command that may take more than a few seconds (building test sets, training, rolling out)
reports through here, so a run piped into a log file is not silent for minutes: on a terminal, training shows a
tqdm bar; elsewhere a plain line every ``EVERY`` seconds (and one when a phase longer than that ends).
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

from tqdm import tqdm

from pdestream.meter import FIRST, Meter, duration, progress_to

EVERY = 10.0  # seconds between plain progress lines when stderr is not a terminal


def _terminal() -> bool:
    return sys.stderr.isatty()


def _line(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


class RunProgress:
    """The training loop's progress: a tqdm bar on a terminal, else a plain line (steps, their rate, the time left)
    meter.FIRST seconds in, then every ``every`` seconds.
    total: steps of the run (None: a run of seconds); initial: steps already done (a resumed run)."""

    def __init__(self, label: str, total: int | None, initial: int = 0, every: float | None = None):
        self.label, self.total, self.every = label, total, EVERY if every is None else every
        self.bar = tqdm(total=total, initial=initial, desc=label, leave=False) if _terminal() else None
        self.step, self.initial, self.start = initial, initial, time.perf_counter()
        self.last_line = self.start - self.every + min(FIRST, self.every)  # the first line FIRST s in

    def show(self, step: int, postfix: dict) -> None:
        """Training reached ``step``; postfix: a few figures (loss, the data source's waiting)."""
        if self.bar is not None:
            self.bar.update(step - self.step)
            self.bar.set_postfix(postfix)
        elif time.perf_counter() - self.last_line >= self.every:
            of = f"/{self.total}" if self.total else ""
            elapsed = time.perf_counter() - self.start
            rate = (step - self.initial) / elapsed if elapsed > 0 and step > self.initial else None
            pace = f"{rate:.3g} steps/s, " if rate else ""
            left = f"~{duration((self.total - step) / rate)} left, " if rate and self.total else ""
            _line(f"{self.label}: step {step}{of}, {elapsed:.0f} s, {pace}{left}"
                  + ", ".join(f"{k} {v}" for k, v in postfix.items()))
            self.last_line = time.perf_counter()
        self.step = step

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


@contextmanager
def phase(what: str, every: float | None = None, total: int | None = None, unit: str = "trajectories",
          solves: int = 1):
    """Report a phase (``what``: e.g. "test set: 32 trajectories") that may run long: a plain line every
    ``every`` seconds while it runs ("... still running, 20 s"), and one with its time when it ends if any was
    printed; a quick phase prints nothing.

    With ``total`` (the ``unit`` the phase makes, in ``solves`` solves of equal size, as a test set's padded
    batches): the lines give a count, a rate and the time left instead, moved by the progress the phase's solves
    report (``pdestream.meter``): "what: 12.50/32 trajectories, 2.1 s/trajectory, ~41 s left (30 s so far)",
    the first after meter.FIRST s, then every meter.EVERY s."""
    if total is not None:
        with _counted(what, total, unit, solves):
            yield
        return
    done, t0, every = threading.Event(), time.perf_counter(), EVERY if every is None else every

    def tick():
        while not done.wait(every):
            _line(f"{what}: still running, {time.perf_counter() - t0:.0f} s")

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        yield
    finally:
        done.set()
        ticker.join()
        if time.perf_counter() - t0 >= every:
            _line(f"{what}: done in {time.perf_counter() - t0:.0f} s")


def solve_counter(meter: Meter, solves: int):
    """A ``progress_to`` callback moving ``meter`` over ``solves`` solves of equal size, one after another: a
    report after one that reached its total starts the next solve."""
    state = {"finished": 0, "last": 0.0}

    def moved(done: int, of: int) -> None:
        if state["last"] >= 1.0:
            state["finished"] += 1
        state["last"] = done / of
        meter.set(min(1.0, (state["finished"] + state["last"]) / max(solves, 1)) * meter.total)

    return moved


@contextmanager
def _counted(what: str, total: int, unit: str, solves: int):
    meter = Meter(what, total, unit, terminal=False)  # plain lines, as every phase (a training bar may be up)
    try:
        with progress_to(solve_counter(meter, solves)):
            yield
    finally:
        meter.close()
        if meter.lines:
            _line(f"{what}: done in {meter.clock() - meter.t0:.0f} s")
