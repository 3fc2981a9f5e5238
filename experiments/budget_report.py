"""compare.md, compare.csv and the verdicts of a budget-matched comparison (``experiments.budget``): one arm's
record over seeds, the tables, the precomputed arm's sizing sentence, and the warning for arms that barely trained.

Error columns, per test set (in-domain "test", "shifted"), over the per-trajectory relative L2 errors
(``surrogate.tails``): mean, p95, p99 (numpy percentiles, linear interpolation), CVaR_0.95 ("cvar95": the mean of
the worst ceil(0.05 N) trajectories) and max; each the mean over seeds, with a second table of 95% percentile
bootstrap intervals over the test trajectories (1000 resamples, seed 0) and a line saying how many trajectories
the tail figures rest on (a warning below 1024).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from pdestream import datasets
from pdestream.datasets.reservoir_pacer import PROBE_CYCLE, PROBE_STEPS, PROBE_STEPS_MIN, PROBE_WINDOW_S
from pdestream.surrogate.tails import METRICS, TAIL_MIN, bootstrap_intervals, rests_on, tail_note


def combine_seeds(runs: list[dict]) -> dict:
    """One arm's record over seeds: seed 0's record (curves, plots) with every error column replaced by its mean
    over seeds, its spread in COLUMN_std, the per-seed values and per-trajectory errors under "per_seed" (so a
    reader can recompute every figure), and under "intervals" {COLUMN: [lo, hi]} the percentile bootstrap
    interval of each error column over the test trajectories (``surrogate.tails.bootstrap_intervals``: BOOTSTRAP
    resamples, a fixed seed, paired across seeds), where the runs carry their per-trajectory "errors"."""
    out = dict(runs[0])
    out["per_seed"] = [{**{c: r[c] for c in (*COLUMNS, "steps", "trajectories_solved", "wall_s") if c in r},
                        **({"errors": r["errors"]} if "errors" in r else {})} for r in runs]
    for c in COLUMNS:
        if c in out:
            values = np.array([r[c] for r in runs])
            out[c], out[c + "_std"] = float(values.mean()), float(values.std(ddof=1)) if len(values) > 1 else 0.0
    if all("errors" in r for r in runs):
        out["intervals"] = {}
        for name in runs[0]["errors"]:
            per_seed = np.array([r["errors"][name] for r in runs], np.float64)  # [S, N]
            for m, (lo, hi) in bootstrap_intervals(per_seed, **BOOTSTRAP).items():
                if f"{name}_{m}" in COLUMNS:
                    out["intervals"][f"{name}_{m}"] = [lo, hi]
    return out


COLUMNS = tuple(f"{name}_{m}" for name in ("test", "shifted") for m in METRICS)
BOOTSTRAP = {"resamples": 1000, "level": 0.95, "seed": 0}  # compare.md's intervals: fixed, so a report reproduces


def write_tables(out: Path, result: dict, pde, cfg) -> None:
    """compare.csv and compare.md of ``result`` (``budget_compare``'s) for ``cfg`` (a BudgetConfig)."""
    rows = []
    for r in result["arms"]:
        st = r["stats"] or {}
        ci = r.get("intervals", {})
        rows.append({"arm": r["arm"], **{c: r[c] for c in COLUMNS if c in r},
                     **{f"{c}_{end}": ci[c][i] for c in COLUMNS if c in ci for i, end in enumerate(("lo", "hi"))},
                     "steps": r["steps"],
                     "trajectories_solved": r["trajectories_solved"], "wall_s": round(r["wall_s"], 1),
                     "wait_share": round(r["wait_share"], 4), "reuse_mean": st.get("reuse_mean", ""),
                     "reuse_max": st.get("reuse_max", ""), "target_reuse": _number(st.get("target_reuse")),
                     "producer_idle_share": _number(st.get("producer_idle_share")), "cache_bytes": r["cache_bytes"]})
    with open(out / "compare.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    budget = f"{cfg.budget_s:g} s wall clock per arm" if cfg.budget_s else \
        f"{cfg.sim_budget} solved trajectories and {cfg.steps} optimizer steps per arm"
    head = ["arm", *[c.replace("_", " ") for c in COLUMNS if c in rows[0]], "steps", "trajectories solved",
            "wall s", "data wait", "mean reuse", "max reuse", "reuse target", "producer idle"]
    lines = [f"{pde.NAME} (" + ", ".join(f"{k} ~ {v}" for k, v in pde.param_domains.items()) + f", n={pde.n}), "
             f"budget: {budget}; {cfg.model} {cfg.model_cfg}, batch {cfg.batch_size}, lr {cfg.lr}, "
             f"training loss {(cfg.mode or {}).get('loss', 'mse')}, view {datasets.make_view(cfg.view)}; errors: relative L2 per trajectory over {cfg.n_test} test "
             "trajectories stratified over the parameter box (mean, p95, p99, cvar95 = CVaR_0.95: the mean of the "
             "worst 5%, max)"
             + (f", each the mean ± std over {cfg.seeds} seeds (steps, trajectories, wall: seed 0)"
                if cfg.seeds > 1 else ""), "",
             "| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r, rec in zip(rows, result["arms"]):
        spread = [f" ± {rec[c + '_std']:.4f}" if cfg.seeds > 1 else "" for c in COLUMNS if c in r]
        cells = [r["arm"], *[f"{r[c]:.4f}{sd}" for c, sd in zip([c for c in COLUMNS if c in r], spread)],
                 str(r["steps"]), str(r["trajectories_solved"]),
                 f"{r['wall_s']:.0f}", f"{100 * r['wait_share']:.1f}%",
                 f"{r['reuse_mean']:.2f}" if r["reuse_mean"] != "" else "-",
                 f"{r['reuse_max']:.2f}" if r["reuse_max"] != "" else "-",
                 f"{r['target_reuse']:.2f}" if r["target_reuse"] != "" else "-",
                 f"{100 * r['producer_idle_share']:.0f}%" if r["producer_idle_share"] != "" else "-"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += interval_table(result["arms"])
    sizes = {k: len(v) for k, v in (result["arms"][0].get("errors") or {}).items()}
    if sizes:
        lines += ["", tail_note(sizes)]
    paced = getattr(cfg, "sim_budget", None) is None and getattr(cfg, "reservoir_mode", "async") == "async"
    pacing = pacing_line(result["arms"], getattr(cfg, "target_reuse", "auto")) if paced else ""
    if pacing:
        lines += ["", pacing]
    gate = gate_line(result["arms"], (getattr(cfg, "proposal_kwargs", None) or {}).get("gate", True))
    if gate:
        lines += ["", gate]
    plan = next((a.get("precompute") for a in result["arms"] if a["arm"] == "precomputed"), None)
    if plan:
        lines += ["", precompute_line(plan, next(a for a in result["arms"] if a["arm"] == "precomputed"))]
    if len(result["arms"]) > 1:
        lines += ["", "Verdicts (the winner's margin over the runner-up against the seed spread, the sum of "
                  "their two standard deviations):", "", *[f"- {v}" for v in verdicts(result["arms"], cfg.seeds)]]
    note = too_few_steps_note(result["arms"])
    if note:
        lines += ["", note]
    (out / "compare.md").write_text("\n".join(lines) + "\n")


def interval_table(arms: list[dict]) -> list[str]:
    """compare.md's second table: each error column as ``value [lo, hi]``, the 95% percentile bootstrap interval
    over the test trajectories (``combine_seeds``'s "intervals"); [] when no arm has intervals."""
    cols = [c for c in COLUMNS if any(c in a.get("intervals", {}) for a in arms)]
    if not cols:
        return []
    b = BOOTSTRAP
    lines = ["", f"Bootstrap intervals ({100 * b['level']:.0f}%, percentile bootstrap over the test trajectories, "
             f"{b['resamples']} resamples, seed {b['seed']}, the same resamples for every model seed): how far each "
             "figure could move with another test set of the same size; the seed spread is not in them.", "",
             "| " + " | ".join(["arm", *[c.replace("_", " ") for c in cols]]) + " |", "|" + " --- |" * (len(cols) + 1)]
    for a in arms:
        ci = a.get("intervals", {})
        cells = [f"{a[c]:.4f} [{ci[c][0]:.4f}, {ci[c][1]:.4f}]" if c in ci else "-" for c in cols]
        lines.append("| " + " | ".join([a["arm"], *cells]) + " |")
    return lines


def _number(value):
    """A stats figure for the tables: the number, or "" when absent or not measured (nan)."""
    return "" if value is None or value != value else value


def pacing_line(arms: list[dict], target="auto") -> str:
    """compare.md's line on the reservoir arms' pacing (``datasets.reservoir_pacer``) at the end of seed 0's run:
    the reuse target, what it was chosen from and what it left idle; "" when no arm was paced (a simulation
    budget's deterministic schedule, or --target-reuse off)."""
    parts = []
    for a in arms:
        st = a.get("stats") or {}
        if _number(st.get("target_reuse")) == "" or _number(st.get("step_s")) == "":
            continue
        solve = _number(st.get("solve_s_per_traj"))
        parts.append(f"{a['arm']} R {st['target_reuse']:.2f} (step {1e3 * st['step_s']:.1f} ms, solve "
                     + (f"{1e3 * solve:.2f} ms/trajectory" if solve != "" else "not measured")
                     + f", a solve slowing a step by k = {st['pace_slowdown']:.2f}"
                     + (f"; its probes measured {100 * st['pace_probe_cost']:.1f}% of the steps lost"
                        if _number(st.get("pace_probe_cost")) != "" else "")
                     + f"), {a['trajectories_solved']} "
                     f"solves for {a['steps']} steps, mean reuse {st.get('reuse_mean', 0):.2f}, producer idle "
                     f"{100 * st.get('producer_idle_share', 0):.0f}% of its time")
    if not parts:
        return ""
    rule = ("R = clip(b (s k / (1 + k) + i) / (per t 0.05), 1, max reuse), the least reuse at which solving costs "
            "training at most 5% of its steps, from rates re-measured as the run goes: b examples per batch, per "
            "examples per use of a trajectory, t the step's seconds, s and i the seconds per trajectory of solving and "
            "of inserting, k how much a running solve slows a step (the larger of a fit over the steps and the "
            f"probes' lower bound: in every {PROBE_CYCLE} windows of {PROBE_STEPS_MIN}-{PROBE_STEPS} steps (about "
            f"{PROBE_WINDOW_S:g} s each) the producer holds for the last, timed against the one before)"
            if target == "auto"
            else f"--target-reuse {target}")
    return f"Pacing of the reservoir's producer (seed 0, at the end; {rule}): " + "; ".join(parts) + "."


def gate_line(arms: list[dict], gate: bool = True) -> str:
    """compare.md's line on the steered arms' skill gate (``datasets.proposal``) at the end of seed 0's run: the
    measured skill and the share of steered draws it allowed (gate off: 1 - floor whatever the skill); "" when
    no arm steers."""
    parts = [f"{a['arm']} skill {a['stats']['proposal_skill']:.2f}{_lift(a['stats'])}, steered share "
             f"{a['stats']['proposal_steer']:.2f}" for a in arms if "proposal_skill" in (a.get("stats") or {})]
    if not parts:
        return ""
    rule = ("steered share = (1 - floor) x clip(max(skill / 0.5, lift / log 2), 0, 1), 0 when the lift's upper bound "
            "is below 0" if gate else "--proposal-gate off: steered share 1 - floor whatever the skill")
    return (f"Proposal skill gate (seed 0, at the end; {rule}; skill = the correlation of predicted and realized "
            "log-losses of fresh solves - 2 / sqrt(n - 1); lift = the lower bound of the steered draws' fresh "
            "log-loss over the uniform draws', datasets.proposal_lift): " + "; ".join(parts) + ".")


def _lift(stats: dict) -> str:
    """", lift L" from a steered arm's stats (the lift gate's lower bound), "" where it was not measured."""
    low = stats.get("proposal_lift")
    return "" if low is None or low != low else f", lift {low:.2f}"


def precompute_line(plan: dict, record: dict) -> str:
    """compare.md's sentence on how the precomputed arm sized and stored its dataset (seed 0)."""
    frames = (f"frames 0 and {plan['frames'] - 1} only of {plan['frames']} (what the operator view uses; solved "
              "with the stream's step, so the same values)" if plan["frames_stored"] < plan["frames"]
              else f"all {plan['frames']} frames (its view uses them)")
    size = f"{record['trajectories_solved']} trajectories"
    if "solve_per_s" in plan:
        size += (f" (rule: {plan['rule']}; measured {plan['solve_per_s']:.0f} trajectories/s solving and "
                 f"{1e3 * plan['step_s']:.1f} ms per training step: {100 * plan['solve_share']:.0f}% of the budget "
                 f"solving (capped at {100 * plan.get('solve_cap', 1):.0f}%), {plan['epochs_planned']:.1f} epochs planned)")
    else:
        size += f" ({plan['rule']})"
    return (f"Precomputed arm (seed 0): {size}; it stored {frames}: {record['cache_bytes'] / 2**20:.1f} MiB on "
            "disk.")


def verdicts(arms: list[dict], seeds: int) -> list[str]:
    """One line per error metric: which arm has the lowest mean over seeds, by how much it beats the runner-up,
    and whether that margin exceeds the seed spread (std of the winner + std of the runner-up); a tail metric (p99,
    cvar95, max) of a test set under TAIL_MIN trajectories says how many trajectories it rests on."""
    lines = []
    sizes = {k: len(v) for k, v in (arms[0].get("errors") or {}).items()}
    for c in COLUMNS:
        have = sorted((a for a in arms if c in a), key=lambda a: a[c])
        if len(have) < 2:
            continue
        win, second = have[0], have[1]
        margin, spread = second[c] - win[c], win.get(c + "_std", 0.0) + second.get(c + "_std", 0.0)
        head = (f"{c.replace('_', ' ')}: {win['arm']} {win[c]:.4f} vs {second['arm']} {second[c]:.4f} "
                f"(x{second[c] / max(win[c], 1e-300):.2f}, margin {margin:.4f})")
        if seeds < 2:
            line = f"{head}: one seed, no spread to judge by (--seeds 3 for a verdict)"
        elif margin > spread:
            line = f"{head}: {win['arm']} wins, outside the seed spread {spread:.4f}"
        else:
            line = f"{head}: within the seed spread {spread:.4f}, no clear winner"
        name, metric = c.split("_", 1)
        n = sizes.get(name)
        if n is not None and n < TAIL_MIN and metric in ("p99", "cvar95", "max"):
            line += (f" (rests on the worst {rests_on(n)[metric]} of {n} test trajectories: no tail claim below "
                     f"{TAIL_MIN})")
        lines.append(line)
    return lines


MIN_STEPS = 20  # below this an arm's errors are those of a barely trained network, whichever arm it is


def too_few_steps_note(arms: list[dict]) -> str:
    """A warning line naming the arms (records with "arm", "steps") that trained fewer than MIN_STEPS steps, or ""
    (a slow solver at a small --budget, e.g. grayscott2d --quick: 0-1 steps per arm, ranked as if compared)."""
    few = [f"{a['arm']} ({a['steps']})" for a in arms if a["steps"] < MIN_STEPS]
    if not few:
        return ""
    return (f"**Not a comparison:** {', '.join(few)} trained fewer than {MIN_STEPS} optimizer steps in the budget; "
            "their errors are those of nearly untrained networks. Raise --budget (or use a coarser grid).")
