"""Tail metrics of per-trajectory errors, their bootstrap intervals, and how many trajectories a tail rests on.

Every metric is a function of the per-trajectory relative L2 errors e [N] of one test set:

- ``mean``;
- ``p95``, ``p99``: ``np.percentile(e, 95 / 99)`` (numpy's default linear interpolation between order statistics:
  with the errors sorted ascending, position q (N - 1) / 100);
- ``cvar95`` (CVaR at level 0.95, the expected shortfall): the mean of the worst k = ceil(0.05 N) errors (N = 128:
  the worst 7; N = 20 or fewer: the max);
- ``max``.

``bootstrap_intervals`` gives each metric a percentile bootstrap interval over the test trajectories: ``resamples``
resamples of the N trajectory indices, drawn with replacement by ``np.random.default_rng(seed)`` (so a report is
reproducible), the metric recomputed on each, and the (1 - level) / 2 and (1 + level) / 2 quantiles of those
values. With several model seeds evaluated on the same test set the resample is paired: the same indices for
every seed, the metric averaged over seeds (the value the tables show). The interval says how much the figure
would move with another draw of test trajectories of the same size; it knows nothing of the seed spread. A
bootstrap of the max can never exceed the observed max: for a max (and a p99 of few trajectories) the interval
is a lower bound on the uncertainty, which is why ``tail_note`` says when a test set is too small for tail claims.
"""

from __future__ import annotations

import math

import numpy as np

METRICS = ("mean", "p95", "p99", "cvar95", "max")
CVAR_LEVEL = 0.95
TAIL_MIN = 1024  # test trajectories for a tail claim: p99 then rests on ~12 trajectories, CVaR_0.95 on 52


def cvar(errors: np.ndarray, level: float = CVAR_LEVEL, axis: int = -1) -> np.ndarray | float:
    """Mean of the worst ceil((1 - level) N) errors along ``axis`` (CVaR / expected shortfall at ``level``)."""
    e = np.sort(np.asarray(errors, np.float64), axis=axis)
    n = e.shape[axis]
    k = max(1, math.ceil(round((1.0 - level) * n, 9)))
    out = np.take(e, np.arange(n - k, n), axis=axis).mean(axis=axis)
    return float(out) if np.ndim(out) == 0 else out


def tail_metrics(errors: np.ndarray, axis: int = -1) -> dict:
    """{metric: value} for METRICS over ``axis`` of ``errors`` (floats for a 1-D array, arrays otherwise)."""
    e = np.asarray(errors, np.float64)
    out = {"mean": e.mean(axis), "p95": np.percentile(e, 95, axis=axis), "p99": np.percentile(e, 99, axis=axis),
           "cvar95": cvar(e, CVAR_LEVEL, axis), "max": e.max(axis)}
    return {k: float(v) if np.ndim(v) == 0 else v for k, v in out.items()}


def bootstrap_intervals(errors, resamples: int = 1000, level: float = 0.95, seed: int = 0) -> dict:
    """{metric: (lo, hi)}: percentile bootstrap intervals over the test trajectories of the seed-mean of each
    metric. ``errors``: [N] (one seed) or [S, N] (S seeds on the same N trajectories: paired resampling)."""
    e = np.atleast_2d(np.asarray(errors, np.float64))  # [S, N]
    rng = np.random.default_rng(seed)
    idx = rng.integers(e.shape[1], size=(resamples, e.shape[1]))  # [R, N]
    values = tail_metrics(e[:, idx], axis=-1)  # each [S, R]
    lo, hi = 100 * (1 - level) / 2, 100 * (1 + level) / 2
    return {m: (float(np.percentile(v.mean(0), lo)), float(np.percentile(v.mean(0), hi))) for m, v in values.items()}


def rests_on(n: int) -> dict:
    """How many of the worst trajectories each tail metric of N errors depends on: {"p95", "p99": the count at or
    above the lower order statistic the percentile interpolates from, "cvar95": ceil(0.05 N), "max": 1}."""
    return {"p95": n - math.floor(0.95 * (n - 1)), "p99": n - math.floor(0.99 * (n - 1)),
            "cvar95": max(1, math.ceil(round(0.05 * n, 9))), "max": 1}


def tail_note(sizes: dict) -> str:
    """A plain-words line for compare.md: what the p99, CVaR and max of each test set ({name: N}) rest on, and a
    warning when a set has fewer than TAIL_MIN trajectories (a tail claim on it is a claim about a handful)."""
    parts = []
    for name, n in sizes.items():
        r = rests_on(n)
        parts.append(f"{name}: {n} trajectories, p99 rests on the worst {r['p99']}, CVaR_0.95 on the worst "
                     f"{r['cvar95']}, max on 1")
    small = [name for name, n in sizes.items() if n < TAIL_MIN]
    head = (f"**Too few test trajectories for a tail claim** ({', '.join(small)}): tail claims (p99, CVaR, max) need "
            f">= {TAIL_MIN} test trajectories (--test-samples {TAIL_MIN}); " if small else "Tail metrics: ")
    return head + "; ".join(parts) + "."
