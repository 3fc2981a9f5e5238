"""Issue 30's decisive measurement: active sampling against uniform, with the settings fixed on burgers1d and kdv1d,
run unchanged on ks2d, ns2d, grayscott2d and two catalog entries nobody tuned on; resumable unit by unit.

``python -m benchmarks.active_suite [--out DIR] [--problems fisher_kpp1d,ns2d] [--seeds 3] [--max-minutes M]
[--summary-only]``: rerun the same command to go on from the finished units.

**The two untuned entries (rule written before any run, 2026-11-27).** In catalog order (``catalog_names.NAMES``),
the first two entries that are time-dependent; in the nonlinear or reaction-diffusion group (the families of the
anchors' problems: OGAS's KS / NS / Gray-Scott, AL4PDE's Burgers / KS); not a flow (fluids group: cost); of
dimension <= 2 (cost); with at least one random parameter (the proposal steers parameters); not burgers1d / kdv1d
(tuned on) nor ks2d / grayscott2d (already in the suite). That gives **ks1d** and **burgers2d** (``UNTUNED_ORDER``).
An entry a default FNO does not train on at this budget (the uniform arm's seed-0 mean relative L2 >= 0.5) is
reported as such and replaced by the next entry in that order (fisher_kpp1d, then allen_cahn1d): ks1d (t_end 100,
chaotic: u(0) -> u(100) is not learnable) did not train (uniform 1.456, active 1.404, seed 0), so the two are
**burgers2d** and **fisher_kpp1d**; ks1d's two units are kept in DIR/ks1d as the evidence.

**The fixed settings** (``SETTINGS``): those of the burgers1d / kdv1d set-up in docs/results/active.md, the
``compare --sim-budget`` runs: 256 solves per arm, a quarter of them before the first step and the rest paced and
steered, 1500 optimizer steps, batch 32, lr 3e-3 (cosine), FNO width 32 / 12 modes / 3 layers, operator view
u(0) -> u(t_end), the relative-L2 training loss (the one compare.md says matters more than any sampling), one
torch thread, the active arm's proposal at its defaults (floor 0.25, skill gate on, over the parameters). Arms:
``reservoir`` (uniform) and ``reservoir_active`` (proposal + prioritized replay).

**Per-problem settings, a rule (``grid``), not tuned on any result:** only what the operator view and the CPU need.
Every entry keeps its own t_end, domain, IC and parameter box; n_frames = 2 (the operator view reads only the
first and the last frame); a 1D entry runs at n = 128 (burgers1d's and kdv1d's grid in the tuned runs); a 2D entry
at the coarsest n of 32, 64 at which its own solver does not blow up on 32 draws at its default dt rule (ks2d
blew up at n = 32: n = 64; the others n = 32).

**The horizon, a rule (added 2026-11-27, stop 39, before any unit at a new horizon ran):** the operator is
learned over the longest of t_end, t_end / 2, t_end / 4, ... at which a 1e-4 relative perturbation of the initial
state grows at most tenfold (median of 8 samples at the suite's grid; ``benchmarks.predictability``, its docstring
says why). Measured 2026-11-27 (``python -m benchmarks.predictability --set n=128`` for the 1D entries, ``n=32`` /
``n=64`` for the 2D ones): amplification at t_end 0.06 burgers1d, 0.81 kdv1d, 0.0002 fisher_kpp1d, 0.04 burgers2d,
2.2 grayscott2d, 2.6 ns2d (all keep their t_end), ks2d 1.6e5 at t_end 100, 21 at 25, 1.6 at 12.5: **ks2d's
operator is u(0) -> u(12.5)** (``HORIZON``). Its grid and test-set size follow from the rules here at that
horizon (n = 32 blew up on 1 of 32 draws: n = 64; 1024 test solves under 5 minutes: 1024). Its unit at t_end 100
(uniform seed 0: mean 1.256, not trained, 49 min) is kept in DIR/ks2d_t_end100 as the evidence. ns2d keeps t_end 10
under the rule although it does not train there (seed 0: uniform mean 0.885): it is not chaotic at n = 32 (the
perturbation grows 2.6x) but the forcing carries the state 5x its initial norm away; reported as not trained.

**Test sets:** one in-domain stratified set per problem (``experiments.budget.stratified_test_set``, the
comparison's own, seed 0), 1024 trajectories (the size issue 30 asks for tail claims) where 1024 solves cost under
5 minutes at the rate measured on this machine, else 256: ks2d (0.7 s a solve at n = 64, measured 2026-11-27) gets
256, the others 1024. No shifted set (the measurement is in-domain; it would double the test solves). Each set is
solved once and kept in DIR/<problem>/test.pt.

**Units:** each (problem, seed, arm) trains in DIR/<problem>/<arm>_seed<s>/ through ``experiments.budget.run_arm``,
the call ``compare`` makes for each arm and seed, with the ``BudgetConfig`` ``compare`` builds
(``experiments.command.budget_setup``). A unit is finished when its ``arm.json`` (compare's record of a finished
run) is there; it runs in a ``.tmp-`` directory renamed into place when done, so a unit stopped at --max-minutes, a
Ctrl-C or a kill leaves only a ``.tmp-`` directory, removed at the next start: never a half-recorded unit. Order:
seed 0 of every problem (both arms) first, then seed 1, then seed 2; within a seed the problems in ``PROBLEMS``'
order (cheapest first). A unit is not started when its estimate (the mean wall time of finished units of the same
problem, else none) would pass --max-minutes; one under way at --max-minutes is discarded.

**Summary** (DIR/summary.md, rewritten after each unit): per problem and arm, mean +- std over the finished
seeds of the test mean, p95, p99, CVaR_0.95 and max (``surrogate.tails``), the ratio uniform / active (> 1: active
is better) and compare.md's verdict (the margin against the two arms' standard deviations added; one seed: no
verdict); and how much of the variance of the uniform arm's log error the parameters explain
(``benchmarks.active_bench``'s binning), which bounds what a proposal over parameters can steer.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

PROBLEMS = ("fisher_kpp1d", "ns2d", "burgers2d", "grayscott2d", "ks2d")  # cheapest first (measured solve, step cost)
UNTUNED_ORDER = ("ks1d", "burgers2d", "fisher_kpp1d", "allen_cahn1d")  # the rule's entries, in catalog order
ARMS = ("reservoir", "reservoir_active")
SETTINGS = {"sim_budget": 256, "steps": 1500, "sim_warmup_share": 0.25, "batch_size": 32, "lr": 3e-3,
            "model_cfg": {"width": 32, "modes": 12, "layers": 3}, "loss": "relative", "threads": 1}
GRID_2D = {"ks2d": 64}  # the rule above: coarsest of 32, 64 without blow-ups (ks2d blew up at 32)
TEST_SMALL: dict[str, int] = {}  # the rule above: 1024 test solves would cost over 5 minutes (none at their horizon)
HORIZON = {"ks2d": "12.5"}  # the horizon rule above: t_end where the entry's own is beyond its predictability
METRICS = ("mean", "p95", "p99", "cvar95", "max")
UNTRAINED = 0.5  # a uniform arm's mean relative L2 at or above this: the FNO did not learn the operator


@dataclass(frozen=True)
class Suite:
    """One resumable measurement over PROBLEMS: its ``compare`` settings (``CompareCommand`` fields), its arms
    (``extra``: more arms on some problems), the pairs its verdicts compare ((baseline, contender): a ratio
    baseline / contender > 1 says the contender is better), its test sets (in-domain, and compare's shifted one when
    ``shift`` is set) and where its units live (``results``, the default --out)."""

    title: str
    settings: dict
    arms: tuple
    pairs: tuple
    results: Path
    labels: dict  # arm -> the name the summary gives it
    shift: float | None = None
    n_test: int | None = None  # test trajectories per set (None: the rule above, n_test())
    extra: dict = field(default_factory=dict)  # problem -> arms run there beside ``arms``

    def arms_of(self, name: str) -> tuple:
        return self.arms + tuple(self.extra.get(name, ()))


# Where the units are kept by default: in the repository, so a later session (a fresh machine) resumes from them;
# each unit's record is ~100 KB (its weights are dropped), the test sets are not committed (.gitignore)
RESULTS = Path(__file__).parent / "results" / "active_suite"
ACTIVE = Suite(title="Active sampling suite (issue 30)", settings=SETTINGS, arms=ARMS,
               pairs=(("reservoir", "reservoir_active"),), results=RESULTS,
               labels={"reservoir": "uniform", "reservoir_active": "active"})


class Deadline(BaseException):
    """Raised in the unit under way when --max-minutes is reached (a BaseException: nothing on the way catches it)."""


def grid(name: str, ndim: int) -> dict:
    """The per-problem settings of the rules in the module docstring: {"n", "n_frames"[, "t_end"]} as --set strings."""
    g = {"n": str(128 if ndim == 1 else GRID_2D.get(name, 32)), "n_frames": "2"}
    return {**g, "t_end": HORIZON[name]} if name in HORIZON else g


def n_test(name: str) -> int:
    return TEST_SMALL.get(name, 1024)


def setup(name: str, tiny: dict | None = None, suite: Suite = ACTIVE):
    """(pde, BudgetConfig, view) of ``name`` under the suite's settings and its grid, as compare builds them;
    ``tiny`` overrides settings and the suite's entries (the harness's own test)."""
    from pdestream import datasets, generator
    from pdestream.experiments.command import CompareCommand, budget_setup
    from pdestream.surrogate.modes import make_mode, training_view

    s = {**suite.settings, **(tiny or {})}
    settings = {**grid(name, generator.get_pde(name).NDIM), **s.pop("settings", {})}
    n = s.pop("n_test", suite.n_test or n_test(name))
    cmd = CompareCommand(pde=name, out="", settings=settings, arms=suite.arms_of(name), seeds=1, test_samples=n,
                         shift=-0.25 if suite.shift is None else suite.shift, **s)
    pde, cfg = budget_setup(cmd, log=lambda line: None)
    view = training_view(make_mode(cfg.mode), datasets.for_sample(datasets.make_view(cfg.view), pde.n_frames,
                                                                  len(pde.INPUTS)))
    return pde, cfg, view


def test_set(pde, cfg, path: Path) -> list[dict]:
    """The stratified test set of ``pde`` (its own domain), solved once and kept at ``path`` (written whole or
    not at all)."""
    import torch

    from pdestream.experiments.budget import stratified_test_set

    if path.is_file():
        return torch.load(path, weights_only=True)  # tensors only: nothing in --out is unpickled as code
    tests = stratified_test_set(pde, cfg.n_test, 0)
    tmp = path.with_suffix(".tmp")
    torch.save(tests, tmp)
    tmp.replace(path)
    return tests


def unit_dir(out: Path, name: str, arm: str, seed: int) -> Path:
    return out / name / f"{arm}_seed{seed}"


def units(problems, seeds: int, suite: Suite = ACTIVE) -> list[tuple]:
    """(problem, seed, arm) in run order: seed by seed, problems in the given order, the suite's arms in order."""
    return [(p, s, a) for s in range(seeds) for p in problems for a in suite.arms_of(p)]


def prepare(out: Path, name: str, tiny: dict | None = None, suite: Suite = ACTIVE):
    """(pde, cfg, view, tests) of ``name``: its settings and its test sets ("test", and "shifted" where the suite
    has a shift: compare's shifted domain), solved on the first call, then read."""
    from pdestream.experiments.compare import shifted_pde

    pde, cfg, view = setup(name, tiny, suite)
    (out / name).mkdir(parents=True, exist_ok=True)
    tests = {"test": test_set(pde, cfg, out / name / "test.pt")}
    shifted = None if suite.shift is None else shifted_pde(pde, suite.shift)
    if shifted is not None:
        tests["shifted"] = test_set(shifted, cfg, out / name / "shifted.pt")
    params = out / name / "test_params.json"
    if not params.is_file():
        import torch

        params.write_text(json.dumps(torch.cat([b["params"] for b in tests["test"]]).tolist()))
    return pde, cfg, view, tests


def run_unit(out: Path, name: str, seed: int, arm: str, tiny: dict | None = None, suite: Suite = ACTIVE) -> dict:
    """Train and evaluate one unit into its directory via a ``.tmp-`` directory renamed when finished (its
    arm.json, compare's record, and unit.json: the unit's wall seconds, test set excluded)."""
    from pdestream.experiments.budget import run_arm

    pde, cfg, view, tests = prepare(out, name, tiny, suite)
    t0 = time.monotonic()
    final = unit_dir(out, name, arm, seed)
    tmp = final.with_name(".tmp-" + final.name)
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        rec = run_arm(arm, pde, view, cfg, tmp, tests, log=lambda line: None, seed=seed)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for f in ("model.pt", "checkpoint.pt", "cache.h5"):  # weights and data are not part of the record (MBs)
        (tmp / f).unlink(missing_ok=True)
    (tmp / "unit.json").write_text(json.dumps({"unit_s": time.monotonic() - t0}))
    tmp.replace(final)
    return rec


def _load(out: Path, name: str, arm: str, seeds: int) -> list[dict]:
    recs = []
    for s in range(seeds):
        f = unit_dir(out, name, arm, s) / "arm.json"
        if f.is_file():
            recs.append(json.loads(f.read_text()))
    return recs


def explained(out: Path, name: str, runs: list[dict]) -> float | None:
    """Share of the variance of the uniform arm's log error (seed mean per test trajectory) that the parameters
    explain, binned as benchmarks.active_bench does (about 8 cells of the unit box)."""
    from pdestream import datasets, generator

    from .active_bench import _bins

    tp = out / name / "test_params.json"
    if not runs or not tp.is_file():
        return None
    pde = generator.get_pde(name)
    domains = {k: tuple(v) if not isinstance(v, (list, tuple)) else (v[0], v[1], v[2], tuple(v[3]))
               for k, v in datasets.param_domains(pde).items()}
    bins = _bins({"domains": domains, "test_params": {"test": json.loads(tp.read_text())}})
    y = np.log(np.mean([r["errors"]["test"] for r in runs], 0))
    fitted = np.array([y[bins == b].mean() for b in bins])
    return float(1 - ((y - fitted) ** 2).sum() / max(((y - y.mean()) ** 2).sum(), 1e-300))


def _verdict(runs: dict, stats: dict, pair: tuple, metric: str, labels: dict) -> str:
    """compare.md's rule for one metric of one pair: the margin against the two arms' standard deviations added."""
    (base, cont), key = pair, metric
    (mb, sb), (mc, sc) = stats[base][key], stats[cont][key]
    if min(len(runs[base]), len(runs[cont])) < 2:
        verdict = "one seed, no verdict"
    elif abs(mb - mc) > sb + sc:
        verdict = f"{labels[cont]} {'better' if mb > mc else 'worse'}, outside the spread"
    else:
        verdict = "within the spread"
    return f"x{mb / max(mc, 1e-300):.2f} ({verdict})"


def summary(out: Path, problems, seeds: int, suite: Suite = ACTIVE) -> str:
    """summary.md's text: per problem, each arm over its finished seeds (steps, wall, the metrics of every test
    set) and, for each of the suite's pairs, the ratio baseline / contender with compare.md's verdict per metric
    and the contender's steps against the baseline's."""
    from pdestream import generator

    sets = ("test",) if suite.shift is None else ("test", "shifted")
    keys = [f"{t}_{m}" for t in sets for m in METRICS]
    head = [m if t == "test" else f"{t} {m}" for t in sets for m in METRICS]
    named = ", ".join(f"{v} ({k})" for k, v in suite.labels.items())
    lines = [f"# {suite.title}", "",
             f"Settings: {json.dumps(suite.settings)}; arms {named}; per-trajectory relative L2 on in-domain"
             + (f" and shifted (shift {suite.shift:g})" if suite.shift is not None else "") + " stratified test sets"
             " per problem; mean ± std over the finished seeds (std with ddof 1).", "",
             "| problem (grid, test set) | arm | seeds | steps (mean) | wall s (mean) | " + " | ".join(head) + " |",
             "| --- " * (5 + len(keys)) + "|"]
    notes = []
    for name in problems:
        runs = {a: _load(out, name, a, seeds) for a in suite.arms_of(name)}
        stats = {}
        for a, rs in runs.items():
            if not rs:
                continue
            v = {k: np.array([r[k] for r in rs]) for k in keys}
            stats[a] = {k: (x.mean(), x.std(ddof=1) if len(x) > 1 else 0.0) for k, x in v.items()}
            stats[a]["steps"] = (np.mean([r["steps"] for r in rs]), 0.0)
            g = grid(name, generator.get_pde(name).NDIM)
            horizon = f", t_end={g['t_end']}" if "t_end" in g else ""
            lines.append(f"| {name} (n={g['n']}{horizon}, {len(rs[0]['errors']['test'])}) | {suite.labels[a]} | "
                         f"{','.join(str(r['seed']) for r in rs)} | {stats[a]['steps'][0]:.0f} | "
                         f"{np.mean([r['wall_s'] for r in rs]):.0f} | "
                         + " | ".join(f"{stats[a][k][0]:.4f} ± {stats[a][k][1]:.4f}" for k in keys) + " |")
        for base, cont in suite.pairs:
            if base not in stats or cont not in stats:
                continue
            cells = [_verdict(runs, stats, (base, cont), k, suite.labels) for k in keys]
            steps = stats[cont]["steps"][0] / max(stats[base]["steps"][0], 1e-300)
            met = "at least 95%: met" if steps >= 0.95 else f"short of 95% by {100 * (0.95 - steps):.0f} points"
            lines.append(f"| {name} | **{suite.labels[base]} / {suite.labels[cont]}** | | {suite.labels[cont]} "
                         f"x{steps:.2f} the steps ({met}) | | " + " | ".join(cells) + " |")
        first = stats.get(suite.pairs[0][0])
        if first and first["test_mean"][0] >= UNTRAINED:
            notes.append(f"- {name}: **not trained** ({suite.labels[suite.pairs[0][0]]} mean {first['test_mean'][0]:.3f}"
                         f" >= {UNTRAINED}): the FNO does not learn u(0) -> u(t_end) at this budget, so its ratios "
                         "compare untrained models.")
        for arm in suite.arms_of(name):
            gate = [r["stats"] for r in runs.get(arm, []) if "proposal_skill" in (r.get("stats") or {})]
            if gate:
                lift = [said for said in map(_bounds, gate) if said]
                notes.append(f"- {name}: the {suite.labels[arm]} arm's gate at the end, per seed: skill "
                             + ", ".join(f"{g['proposal_skill']:.2f}" for g in gate) + "; steered share "
                             + ", ".join(f"{g['proposal_steer']:.2f}" for g in gate) + " (of 0.75 at most: floor 0.25)"
                             + ("; the lift " + ", ".join(lift) if lift else "") + ".")
        notes += _spending(name, runs, suite.labels)
        share = explained(out, name, runs.get("reservoir", []))
        if share is not None:
            notes.append(f"- {name}: the parameters explain {100 * share:.0f}% of the variance of the "
                         f"{suite.labels['reservoir']} arm's log error (test trajectories binned in the unit parameter box).")
    missing = [f"{p} {a} seed {s}" for p, s, a in units(problems, seeds, suite)
               if not (unit_dir(out, p, a, s) / "arm.json").is_file()]
    return "\n".join(lines + ["", *notes, "", f"Units missing ({len(missing)}): " + (", ".join(missing) or "none")]) + "\n"


def _bounds(stats: dict) -> str:
    """A steered unit's lift at the end in words: "[low, high]", "low >= L" (units recorded before the upper bound
    was), "" where it was not measured (NaN or absent)."""
    low, high = stats.get("proposal_lift"), stats.get("proposal_lift_high")
    if low is None or low != low:
        return ""
    return f"[{low:.2f}, {high:.2f}]" if high is not None and high == high else f"low >= {low:.2f}"


def _spending(name: str, runs: dict, labels: dict) -> list[str]:
    """Where a time-budget arm's seconds went (mean over its seeds): the precomputed arm's solve share and dataset,
    a reservoir's solves, its reuse target and its producer's idle share. Empty at a simulation budget."""
    lines = []
    for arm, rs in runs.items():
        plans = [r["precompute"] for r in rs if r.get("precompute") and "solve_share" in r["precompute"]]
        if plans:
            lines.append(f"- {name} {labels[arm]}: solved {np.mean([r['trajectories_solved'] for r in rs]):.0f} "
                         f"trajectories in {100 * np.mean([p['solve_share'] for p in plans]):.0f}% of its budget, "
                         f"then trained {np.mean([r['steps'] for r in rs]):.0f} steps over them "
                         f"({np.mean([p['epochs_planned'] for p in plans]):.1f} epochs planned).")
        paced = [r["stats"] for r in rs if "target_reuse" in (r.get("stats") or {})]
        if paced and rs[0].get("precompute") is None and "pace_slowdown" in paced[0]:
            # what solving cost training by the pacer's own measure: busy share D x k / (1 + k) (its docstring)
            cost = [(1 - s.get("producer_idle_share", 1.0)) * s["pace_slowdown"] / (1 + s["pace_slowdown"]) for s in paced]
            lines.append(f"- {name} {labels[arm]}: solved {np.mean([r['trajectories_solved'] for r in rs]):.0f} "
                         f"trajectories, reuse target {np.mean([float(s['target_reuse'] or 0) for s in paced]):.1f}, "
                         f"producer idle {100 * np.mean([s.get('producer_idle_share', 0.0) for s in paced]):.0f}%, "
                         f"solving cost ~{100 * np.mean(cost):.0f}% of the steps (busy share x k / (1 + k), k "
                         f"{np.mean([s['pace_slowdown'] for s in paced]):.2f}){_probed(paced)}, "
                         f"training loop waiting {100 * np.mean([r['wait_share'] for r in rs]):.0f}%.")
    return lines


def _probed(paced: list[dict]) -> str:
    """The pacer's probes' words (datasets/reservoir_pacer.py): the share of steps the producer's pace cost as they
    measured it and the k they read, mean over seeds; "" where no probe was pooled."""
    got = [s for s in paced if s.get("pace_probes", 0) and s.get("pace_probe_cost") == s.get("pace_probe_cost")]
    if not got:
        return ""
    k = [s["pace_probe_k"] for s in got if s["pace_probe_k"] == s["pace_probe_k"]]
    return (f"; its probes measured {100 * np.mean([s['pace_probe_cost'] for s in got]):.1f}% of the steps lost "
            f"({np.mean([s['pace_probes'] for s in got]):.0f} probes" + (f", k {np.mean(k):.2f}" if k else "") + ")")


def main(argv: list[str] | None = None, tiny: dict | None = None, suite: Suite = ACTIVE, doc: str = __doc__) -> None:
    """The command line of a suite (``python -m benchmarks.active_suite``, ``benchmarks.wallclock_suite``)."""
    prog = "benchmarks.active_suite" if suite is ACTIVE else "benchmarks.wallclock_suite"
    p = argparse.ArgumentParser(prog=f"python -m {prog}", description=doc.splitlines()[0])
    p.add_argument("--out", type=Path, default=suite.results, help="output directory (default: the records committed "
                   f"in the repository, {suite.results.relative_to(Path(__file__).parent.parent)}: rerun to resume)")
    p.add_argument("--problems", default=",".join(PROBLEMS), help=f"comma-separated (default {','.join(PROBLEMS)})")
    p.add_argument("--seeds", type=int, default=3, help="seeds per arm (default 3)")
    p.add_argument("--max-minutes", type=float, default=60.0, help="stop cleanly before this wall time (default 60)")
    p.add_argument("--summary-only", action="store_true", help="write and print DIR/summary.md, run nothing")
    a = p.parse_args(argv)
    from pdestream.catalog_names import NAMES

    problems = [x for x in a.problems.split(",") if x]
    bad = [x for x in problems if x not in NAMES]
    if bad or not problems:
        sys.exit(f"--problems {a.problems!r}: unknown {', '.join(bad) or '(empty)'}; catalog entries, e.g. "
                 f"{','.join(PROBLEMS)}")
    if a.seeds < 1 or not (a.max_minutes > 0 and math.isfinite(a.max_minutes)):
        sys.exit(f"--seeds {a.seeds} / --max-minutes {a.max_minutes}: need seeds >= 1 and a positive number of minutes")
    out = a.out
    out.mkdir(parents=True, exist_ok=True)
    if a.summary_only:
        text = summary(out, problems, a.seeds, suite)
        (out / "summary.md").write_text(text)
        print(text, flush=True)
        return
    start, limit = time.monotonic(), 60 * a.max_minutes
    every = units(problems, a.seeds, suite)
    todo = [(p_, s, arm) for p_, s, arm in every if not (unit_dir(out, p_, arm, s) / "arm.json").is_file()]
    print(f"{suite.title}: {len(todo)} of {len(every)} units to run, stop before "
          f"{a.max_minutes:g} min", flush=True)

    def on_alarm(signum, frame):
        raise Deadline()

    def on_unraisable(unraisable):  # a Deadline raised where Python cannot raise (a JAX gc callback): again, later
        if issubclass(unraisable.exc_type, Deadline):
            signal.alarm(1)
        else:
            redeliver_interrupt(unraisable)  # the pdestream commands' rule for a lost Ctrl-C

    from pdestream.interrupts import first_interrupt, redeliver_interrupt

    saved = (signal.signal(signal.SIGALRM, on_alarm), signal.signal(signal.SIGINT, first_interrupt), sys.unraisablehook)
    sys.unraisablehook = on_unraisable
    try:
        _loop(out, todo, problems, a, start, limit, tiny, suite)
    finally:
        signal.signal(signal.SIGALRM, saved[0])
        signal.signal(signal.SIGINT, saved[1])
        sys.unraisablehook = saved[2]
    text = summary(out, problems, a.seeds, suite)
    (out / "summary.md").write_text(text)
    print(text, flush=True)


def _loop(out: Path, todo: list, problems: list, a, start: float, limit: float, tiny, suite: Suite) -> None:
    """Run the units of ``todo`` in order until one would pass ``limit`` seconds from ``start`` (see main)."""
    done = 0
    for name, seed, arm in todo:
        elapsed = time.monotonic() - start
        est = _estimate(out, name)
        if est is not None and elapsed + est > limit:
            print(f"stop: {name} {arm} seed {seed} would take ~{est / 60:.1f} min, "
                  f"{(limit - elapsed) / 60:.1f} min left", flush=True)
            break
        rest = sum(_estimate(out, u[0]) or float("nan") for u in todo[todo.index((name, seed, arm)):])
        print(f"[{done + 1}/{len(todo)}] {name} {arm} seed {seed}: starting at {elapsed / 60:.1f} min; this unit ~"
              f"{'?' if est is None else f'{est / 60:.1f}'} min, all left ~"
              f"{'? (no unit of some problem finished yet)' if rest != rest else f'{rest / 3600:.1f} h'}", flush=True)
        signal.alarm(max(1, int(limit - elapsed)))
        t0 = time.monotonic()
        try:
            prepare(out, name, tiny, suite)  # the test sets, once per problem (not in the unit's estimate)
            t0 = time.monotonic()
            rec = run_unit(out, name, seed, arm, tiny, suite)
        except Deadline:
            print(f"stop: {max(a.max_minutes, 0):g} min reached; {name} {arm} seed {seed} discarded", flush=True)
            break
        except KeyboardInterrupt:
            sys.exit(f"interrupted: {name} {arm} seed {seed} discarded; rerun the same command to go on")
        finally:
            signal.alarm(0)
        unit = time.monotonic() - t0
        done += 1
        print(f"  done in {unit / 60:.1f} min: mean {rec['test_mean']:.4f} p95 {rec['test_p95']:.4f} p99 "
              f"{rec['test_p99']:.4f} cvar95 {rec['test_cvar95']:.4f}; {rec['steps']} steps", flush=True)
        (out / "summary.md").write_text(summary(out, problems, a.seeds, suite))


def _estimate(out: Path, name: str) -> float | None:
    """Mean seconds of a finished unit of ``name`` (its unit.json: training and evaluation, test set excluded), or None."""
    d = out / name
    unit_s = [json.loads(f.read_text())["unit_s"] for f in d.glob("*/unit.json")] if d.is_dir() else []
    return float(np.mean(unit_s)) if unit_s else None


if __name__ == "__main__":
    main()
