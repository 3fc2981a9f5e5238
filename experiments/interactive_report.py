"""What an interactive comparison reports (``experiments.interactive_compare``): one arm's record from its rollout
errors, the seeds combined, the corrector arms scored against the coarse solver, compare.md / compare.csv /
curves.csv and the two figures (compare.png, corrector.png)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from pdestream.surrogate.evaluate import error_stats
from pdestream.surrogate.mode_table import NETWORK_MODES

SEED_FIGURES = ("end_mean", "end_p95", "end_max", "rollout_mean", "rollout_p95", "wall_s", "final_loss")


def combine_seeds(runs: list[dict]) -> dict:
    """One arm's record over its seeds: each figure of SEED_FIGURES the mean over seeds with its std in
    FIGURE_std (0 for one seed), the curves (mean and p95 over trajectories per frame) averaged over seeds, and
    every seed's figures under "per_seed"."""
    out = dict(runs[0])
    out["seeds"] = [r["seed"] for r in runs]
    out["per_seed"] = [{"seed": r["seed"], **{c: r[c] for c in SEED_FIGURES}} for r in runs]
    for c in SEED_FIGURES:
        values = np.array([np.nan if r[c] is None else r[c] for r in runs], np.float64)
        out[c] = None if runs[0][c] is None else float(values.mean())
        out[c + "_std"] = float(values.std(ddof=1)) if len(runs) > 1 and runs[0][c] is not None else 0.0
    for c in ("curve", "curve_p95"):
        out[c] = np.mean([r[c] for r in runs], axis=0).tolist()
    return out


def verdict(win: dict, other: dict, key: str, name: str) -> str:
    """One line: arm ``win`` against arm ``other`` on figure ``key`` (means over seeds): the ratio other / win (> 1:
    ``win`` lower), the margin other - win and whether it exceeds the seed spread (the two arms' stds added; one
    seed: no spread to judge by)."""
    a, b = win[key], other[key]
    margin, spread = b - a, win.get(key + "_std", 0.0) + other.get(key + "_std", 0.0)
    head = (f"{name}: {win['arm']} {a:.4f} vs {other['arm']} {b:.4f} (x{b / max(a, 1e-300):.2f}, margin "
            f"{margin:+.4f})")
    if len(win.get("seeds", [0])) < 2 or len(other.get("seeds", [0])) < 2:
        return f"{head}: one seed, no spread to judge by (--seeds 3 for a verdict)"
    if abs(margin) > spread:
        return f"{head}: {win['arm'] if margin > 0 else other['arm']} better, outside the seed spread {spread:.4f}"
    return f"{head}: within the seed spread {spread:.4f}, no clear winner"


CORRECTOR_MODES = ("none", "solver-in-the-loop")  # the coarse solver alone and its corrector arms
SCORED = (("rollout_mean", "rollout mean"), ("rollout_p95", "rollout p95"), ("end_mean", "end mean"))


def score_against_coarse(arms: list[dict]) -> None:
    """Each corrector arm's ``vs_coarse``: per figure e of SCORED, the improvement e_coarse / e_arm (> 1: better
    than the coarse solver alone) and the share of the coarse solver's gap to the fine reference the correction
    closes, 1 - e_arm / e_coarse (1: the fine solution, 0: no better than the coarse solver, < 0: worse)."""
    base = next(a for a in arms if a["mode"] == "none")
    for a in arms:
        if a["mode"] in CORRECTOR_MODES:
            a["vs_coarse"] = {key: {"improvement": _ratio(base[key], a[key]), "gap_closed": 1 - _ratio(a[key], base[key])}
                              for key, _ in SCORED}


def _times(arm: dict, other: dict, key: str) -> str:
    """'2.00x lower than', '2.00x higher than' or 'the same (x1.00) as': ``arm``'s figure ``key`` against
    ``other``'s, the factor always >= 1 (a ratio below 1 read "0.18x lower" for an error 5.5 times higher; a tie to
    the digits shown read "1.00x lower")."""
    ratio = _ratio(other[key], arm[key])
    factor = ratio if ratio >= 1 else _ratio(arm[key], other[key])
    if f"{factor:.2f}" == "1.00":
        return "the same (x1.00) as"
    return f"{factor:.2f}x {'lower' if ratio >= 1 else 'higher'} than"


def _ratio(num: float, den: float) -> float:
    return float(num / den) if den > 0 else float("inf") if num > 0 else 1.0


def write_curves(path: Path, result: dict) -> None:
    """curves.csv: error against time per arm, one row per (arm, frame): t (from the first frame), mean and p95
    of the relative L2 over the test trajectories."""
    dt = result["frame_dt"]
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["arm", "mode", "n", "frame", "t", "mean", "p95"])
        for a in result["arms"]:
            for i, (mean, p95) in enumerate(zip(a["curve"], a["curve_p95"])):
                writer.writerow([a["arm"], a["mode"], a["n"], i + 1, f"{dt * (i + 1):.6g}", f"{mean:.6g}", f"{p95:.6g}"])


def record(label: str, mode: str, errors: np.ndarray, wall: float, summary: dict | None, n: int) -> dict:
    """One arm's figures from its per-trajectory, per-frame errors [N, h]; n: the grid it predicts on."""
    end = error_stats(errors[:, -1])
    per_trajectory = errors.mean(1)  # each trajectory's error averaged over the whole rollout
    return {"arm": label, "mode": mode, "n": n, "seed": None, "seeds": [], "wall_s": wall, "steps": summary["steps"] if summary else 0,
            "final_loss": summary["final_loss"] if summary else None,
            "end_mean": end["mean"], "end_p95": end["p95"], "end_max": end["max"],
            "rollout_mean": float(errors.mean()), "rollout_p95": float(np.percentile(per_trajectory, 95)),
            "curve": errors.mean(0).tolist(),
            "curve_p95": np.percentile(errors, 95, axis=0).tolist(), "frames": errors.shape[1]}


COLUMNS = ("end_mean", "end_p95", "end_max", "rollout_mean", "rollout_p95", "wall_s", "steps", "final_loss")


def restriction_words(restrict: str, pde) -> str:
    """compare.md's words for the corrector arms' fine -> coarse restriction (``--restrict``) on ``pde``'s grid: on
    one without a periodic axis, or of staggered fields, the flag does not act (it said "Fourier truncation" there,
    of arms that may have run with points)."""
    from pdestream.surrogate.mode_table import pde_restricts_periodic

    if not pde_restricts_periodic(pde):
        return ("fine -> coarse restriction: means of the fine cells and faces (no periodic axis, or staggered "
                "fields: --restrict does not act)")
    return "fine -> coarse restriction on periodic axes: " + (
        "Fourier truncation (the coarse grid's modes, its Nyquist mode zeroed)" if restrict == "fourier" else
        "point sampling (every factor-th point)")


def write_tables(out: Path, result: dict, pde, cfg) -> None:
    """compare.md and compare.csv of an interactive comparison: one row per arm (mean ± std over seeds), the
    network modes against one-step, the corrector arms against the coarse solver and solver-in-the-loop's verdicts."""
    rows = _rows(result["arms"])
    with open(out / "compare.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    frames = result["arms"][0]["frames"]
    noise = (f", noise: input noise of std {cfg.noise:g} x the data's std on the newest frame, clean targets"
             if "noise" in cfg.modes else "")
    if "solver-in-the-loop" in cfg.modes:
        noise += (f", pairs + noise: the corrector's coarse start state perturbed by N(0, {cfg.noise:g}^2) in "
                  "normalized units (x the data's std), the fine target clean")
        noise += f", corrector start: {cfg.corrector_start}" + (" (every corrector's output layer zero at step 0)"
                                                                 if cfg.corrector_start == "zero" else "")
        clip, remat = getattr(cfg, "clip", None), getattr(cfg, "remat", False)
        if clip is not None or remat:  # (compare.json's config alone had them)
            noise += ", every corrector arm" + (f"'s gradient clipped to global norm {clip:g}" if clip is not None
                                                else "") + (" and" if clip is not None and remat else "") + \
                (" rematerialised (--remat)" if remat else "")
        noise += ", " + restriction_words(getattr(cfg, "restrict", "points"), pde)
    seeds = list(range(cfg.seed, cfg.seed + cfg.seeds))
    pairs = getattr(cfg, "pairs_steps", None)
    per_arm = (f"{cfg.steps} optimizer steps" + (f" (the two pairs arms: {pairs})" if pairs else "")
               if cfg.budget_s is None else
               f"equal wall clock: {cfg.budget_s:g} s of training (the steps each arm reached: steps column)")
    if cfg.unroll_schedule and "solver-in-the-loop" in cfg.modes:
        noise += (f", solver-in-the-loop unroll curriculum {cfg.unroll_schedule} (unroll:share of the steps; in steps "
                  f"{cfg.schedule()})")
    takes = {"pushforward", "oracle"} & set(cfg.modes) or ("solver-in-the-loop" in cfg.modes and not cfg.unroll_schedule)
    unroll = (f"unroll {cfg.unroll}" if takes else "the curriculum's unrolls" if "solver-in-the-loop"
              in cfg.modes else "no unroll")  # (it said "unroll 4", which no arm took)
    spread = (f"; {len(seeds)} model and data seeds {seeds} per trained arm, each figure the mean ± std over seeds "
              "(the coarse solver: no seed)" if len(seeds) > 1 else f"; one model and data seed ({cfg.seed})")
    lines = [f"{pde.NAME} ({', '.join(f'{k} ~ {v}' for k, v in pde.param_domains.items())}), {cfg.model} "
             f"{cfg.model_cfg}, {per_arm} x batch {cfg.batch_size} per trained arm, lr {cfg.lr}, "
             f"{unroll}{noise}{spread}; errors: relative L2 per trajectory over {cfg.n_test} held-out trajectories "
             f"(Latin hypercube over the parameters), rolled out {frames} frames from the first; end: the last "
             "frame (mean, p95, max over trajectories); rollout mean: over all frames and trajectories; rollout "
             "p95: the 95th percentile over trajectories of each trajectory's error averaged over all frames; wall: "
             "training time of the arm (solver calls included); error against time per arm: curves.csv", ""]
    lines += _arms_lines(result["arms"])
    beyond = result.get("beyond")
    if beyond:
        lines += ["", f"## Beyond the training range ({beyond['domains']})", "",
                  f"The same trained models (every seed's) and the coarse solver, rolled out on {cfg.n_test} held-out "
                  "trajectories whose parameters lie beyond the training range (a Latin hypercube over the shifted "
                  "domains):", ""]
        lines += _arms_lines(beyond["arms"])
    (out / "compare.md").write_text("\n".join(lines) + "\n")


def _rows(arms: list[dict]) -> list[dict]:
    return [{"arm": a["arm"], "mode": a["mode"], "n": a["n"], "seeds": len(a["seeds"]), **{c: a[c] for c in COLUMNS},
             **{f"{c}_std": a.get(f"{c}_std", 0.0) for c in SEED_FIGURES}} for a in arms]


def _arms_lines(arms: list[dict]) -> list[str]:
    """compare.md's table of ``arms`` (mean ± std over seeds), the network modes against one-step, and the corrector
    arms against the coarse solver with solver-in-the-loop's verdicts."""
    lines = ["| arm | grid n | end mean | end p95 | end max | rollout mean | rollout p95 | wall s | steps | "
             "final train loss |",
             "|" + " --- |" * 10]
    for r in _rows(arms):
        several = r["seeds"] > 1

        def cell(c, fmt=".4f"):  # the mean, ± the std over seeds where there are several
            return f"{r[c]:{fmt}}" + (f" ± {r[c + '_std']:{fmt}}" if several else "")

        loss = "-" if r["final_loss"] is None else cell("final_loss", ".3g")
        lines.append(f"| {r['arm']} | {r['n']} | {cell('end_mean')} | {cell('end_p95')} | {cell('end_max')} | "
                     f"{cell('rollout_mean')} | {cell('rollout_p95')} | {r['wall_s']:.0f} | {r['steps']} | {loss} |")
    by = {a["mode"]: a for a in arms if a["mode"] in NETWORK_MODES}
    if "one-step" in by:
        for name in ("pushforward", "oracle", "noise"):
            if name in by:
                lines.append(f"\n{name}: end error {_times(by[name], by['one-step'], 'end_mean')} one-step; "
                             + verdict(by[name], by["one-step"], "end_mean", "end mean"))
    sitl = [a for a in arms if a["mode"] in CORRECTOR_MODES]
    if len(sitl) == 4:
        base, pairs, noisy, loop = sitl
        lines += ["", "Against the coarse solver alone (n=" f"{base['n']}" "): improvement e_coarse / e_arm (> 1: "
                  "better) and share of the coarse-to-fine gap closed 1 - e_arm / e_coarse (1: the fine solution, 0: "
                  "no better than the coarse solver, < 0: worse), e per arm over the same test trajectories:", "",
                  "| arm | " + " | ".join(f"{name}: improvement | {name}: gap closed" for _, name in SCORED) + " |",
                  "|" + " --- |" * (1 + 2 * len(SCORED))]
        for a in sitl[1:]:
            v = a["vs_coarse"]
            lines.append(f"| {a['arm']} | " + " | ".join(f"{v[key]['improvement']:.2f}x | {v[key]['gap_closed']:+.1%}"
                                                          for key, _ in SCORED) + " |")
        lines.append(f"\nsolver-in-the-loop rollout mean error: {_times(loop, base, 'rollout_mean')} the coarse "
                     f"solver alone, {_times(loop, pairs, 'rollout_mean')} the correction trained on pairs, "
                     f"{_times(loop, noisy, 'rollout_mean')} pairs + noise; end error: "
                     f"{_times(loop, base, 'end_mean')} the coarse solver alone, {_times(loop, pairs, 'end_mean')} "
                     "the correction trained on pairs")
        lines += ["", "Solver-in-the-loop against each non-interacting corrector arm per metric (x: the other arm's "
                  "error / solver-in-the-loop's, > 1: solver-in-the-loop better; outside the seed spread when the "
                  "margin exceeds the two arms' stds over seeds added):", ""]
        lines += [f"- {verdict(loop, other, key, name)}" for other in (pairs, noisy) for key, name in SCORED]
    return lines


def plot(path: Path, result: dict) -> None:
    """Rollout error (mean over trajectories) against time, one panel per group (network modes, solver-in-the-loop)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [[a for a in result["arms"] if a["mode"] in NETWORK_MODES],
              [a for a in result["arms"] if a["mode"] not in NETWORK_MODES]]
    groups = [g for g in groups if g]
    fig, axes = plt.subplots(1, len(groups), figsize=(5.5 * len(groups), 4), squeeze=False)
    dt = result["frame_dt"]
    for ax, group in zip(axes[0], groups):
        for a in group:
            t = dt * (1 + np.arange(a["frames"]))
            k = f", k={a['unroll']}" if a["mode"] in ("pushforward", "oracle") else \
                f", sigma={a['noise']:g}" if a.get("noise") else ""
            ax.plot(t, a["curve"], label=f"{a['arm']}{k} (end {a['end_mean']:.3f})")
        ax.set(yscale="log", xlabel="time (rolled out from t=0)", ylabel="relative L2 error (mean over trajectories)")
        fine = result["fine_pde"]["n"] if result["fine_pde"] else None
        steps = max(a["steps"] for a in group)
        ax.set_title(f"network modes, {steps} steps each" if group[0]["mode"] in NETWORK_MODES else
                     f"coarse solver n={group[0]['n']} vs fine n={fine} ({_restriction(result)})")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _restriction(result: dict) -> str:
    """The fine -> coarse restriction of a comparison in a figure's words (compare.json without it: points); on a
    fine grid --restrict does not act on (walls only, staggered fields), the means it takes there (it said
    "Fourier-restricted" of walls)."""
    try:
        from pdestream.datasets import pde_from_config
        from pdestream.surrogate.mode_table import pde_restricts_periodic

        acts = pde_restricts_periodic(pde_from_config(result["fine_pde"]))
    except Exception:  # no fine PDE recorded (no corrector arm) or one this cannot build: the setting's words
        acts = True
    if not acts:
        return "cell / face means"
    return "Fourier-restricted" if (result.get("config") or {}).get("restrict", "points") == "fourier" else "subsampled"


def plot_corrector(path: Path, result: dict) -> None:
    """corrector.png: the coarse solver and its corrector arms, relative L2 error against time (log y): the mean
    over the test trajectories (solid) and their p95 (dashed, the same colour), one line pair per arm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    arms = [a for a in result["arms"] if a["mode"] in CORRECTOR_MODES]
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    dt = result["frame_dt"]
    for i, a in enumerate(arms):
        t = dt * (1 + np.arange(a["frames"]))
        colour = f"C{i}"
        sigma = f", sigma={a['noise']:g}" if a.get("noise") else ""
        gap = f", gap closed {a['vs_coarse']['rollout_mean']['gap_closed']:+.0%}" if "vs_coarse" in a and \
            a["mode"] != "none" else ""
        ax.plot(t, a["curve"], color=colour, label=f"{a['arm']}{sigma} (rollout mean {a['rollout_mean']:.3g}{gap})")
        ax.plot(t, a["curve_p95"], color=colour, ls="--", lw=0.9)
    ax.plot([], [], color="grey", ls="--", lw=0.9, label="dashed: p95 over trajectories")
    ax.set(yscale="log", xlabel="time (rolled out from t=0)", ylabel="relative L2 error (solid: mean over trajectories)")
    fine = result["fine_pde"]["n"] if result["fine_pde"] else None
    ax.set_title(f"corrector arms: coarse n={arms[0]['n']} vs fine n={fine} ({_restriction(result)}), "
                 f"{max(a['steps'] for a in arms)} steps each", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
