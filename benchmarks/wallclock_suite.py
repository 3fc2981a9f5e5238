"""Issue 30's equal-wall-clock measurement: the stream (reservoir) against the precomputed dataset at the same
seconds per arm, with the data routes at their defaults, on the active suite's five problems; resumable unit by unit.

``python -m benchmarks.wallclock_suite [--out DIR] [--problems fisher_kpp1d,ns2d] [--seeds 3] [--max-minutes M]
[--summary-only]``: rerun the same command to go on from the finished units.

**What is decided** (issue 30, done-when 2): at equal wall clock with defaults, the streaming arm trains at least as
many optimizer steps as the precomputed arm (within 5%) and is not worse beyond the seed spread (compare.md's rule:
the margin against the two arms' standard deviations added) on any metric (mean, p95, p99, CVaR_0.95, max), in-domain
or shifted, on the five problems; and active sampling's own cost counted on two of them (the steered arm at the same
wall clock against the uniform stream).

**Settings, written before any run (2026-11-27, stop 41).** Everything the active suite fixes
(``benchmarks.active_suite``: the problems and their order, the grid and horizon rules, FNO width 32 / 12 modes / 3
layers, operator view u(0) -> u(t_end), relative-L2 loss, batch 32, lr 3e-3 cosine, one torch thread), with a
time budget instead of a simulation budget: **90 s per arm**, solving, caching and training all counted (compare's
``--budget``). Every data-route option at compare's default: the precomputed arm sizes its dataset as a careful user
would (``experiments.budget.precompute_size``: as many trajectories as it can solve and train on max-reuse times,
from the rates it measures, solving at most half the budget); the reservoir paces its solver to cost training at
most 5% of its steps (``target_reuse`` auto). Arms: ``precomputed`` and ``reservoir`` on every problem, and
``reservoir_active`` (compare's steered arm at its defaults) on the two untuned entries, burgers2d and
fisher_kpp1d. 90 s is twice the 45 s of the tuned burgers1d / kdv1d comparisons (docs/results/compare.md), for the
2D entries' slower steps; 36 units of ~100 s fit one working session with the test sets.

**Test sets:** per problem, compare's stratified in-domain set and its shifted set (each random parameter's domain
moved 25% of its width below the range, ``experiments.compare.shifted_pde``), 256 trajectories each (compare's
default is 128; 2 x 1024 solves of the 2D entries would not fit the session), seed 0, solved once and kept in
DIR/<problem>/test.pt and shifted.pt (not committed: solved again from their seed).

**Units, order, resume, summary:** as the active suite (its module docstring): each (problem, seed, arm) is
finished when its ``arm.json`` is there; seed by seed, problems cheapest first. DIR/summary.md gives each arm's
steps and metrics, the ratios precomputed / stream and stream / active with their verdicts, the stream's steps
against the precomputed arm's, and where each arm's seconds went (solve share, dataset size, reuse target,
producer idle).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

from .active_suite import SETTINGS, Suite
from .active_suite import main as run_suite

BUDGET_S = 90.0
RESULTS = Path(__file__).parent / "results" / "wallclock_suite"
WALL_CLOCK = Suite(
    title="Equal wall clock: stream against precomputed (issue 30)",
    settings={**{k: v for k, v in SETTINGS.items() if k not in ("sim_budget", "steps", "sim_warmup_share")},
              "budget": BUDGET_S},
    arms=("precomputed", "reservoir"), pairs=(("precomputed", "reservoir"), ("reservoir", "reservoir_active")),
    results=RESULTS, labels={"precomputed": "precomputed", "reservoir": "stream", "reservoir_active": "active"},
    shift=-0.25, n_test=256, extra={"burgers2d": ("reservoir_active",), "fisher_kpp1d": ("reservoir_active",)})

main = partial(run_suite, suite=WALL_CLOCK, doc=__doc__)

if __name__ == "__main__":
    main()
