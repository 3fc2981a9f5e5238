"""Interactive training modes compared at equal optimizer steps: rollout error against time per mode.

Network modes (``one-step``, ``pushforward``, ``oracle``, ``noise``): the same model, from the same initial
weights, trained on the same stream (next-step windows of the PDE) for the same number of steps, each with its own mode
(``surrogate.modes``); then rolled out autoregressively from the first frame of held-out trajectories (a Latin
hypercube over the parameter box, ICs from a held-out seed: ``budget.stratified_test_set``) over all their
frames. Reported per mode: relative L2 per frame (mean over trajectories), the error at the last frame (mean,
p95, max over trajectories) and the training wall time.

``solver-in-the-loop``: the PDE on a coarse grid (``coarse_n``) against the same PDE on a fine grid (``fine_n``,
default the PDE's own n), four arms rolled out over the whole trajectory from the fine IC restricted to the coarse
grid and compared with the fine solution restricted alike (``--restrict``: Fourier truncation or point sampling on
periodic axes, ``surrogate.modes.subsample``): the coarse solver alone, the coarse solver with a correction trained
on (coarse step, fine) pairs (unroll 1: no unrolling, the precomputed-pairs baseline), the same with the coarse
start state perturbed by N(0, noise^2) in normalized units and the fine target clean ("pairs + noise", the noise
baseline on the corrector, Sanchez-Gonzalez et al. 2020), and with a correction trained unrolled ``unroll``
steps through the differentiable coarse solver. Each corrector arm is also scored against the coarse solver
alone (``vs_coarse``): improvement e_coarse / e_arm and share of the gap closed 1 - e_arm / e_coarse, for e the
rollout mean (the mean over trajectories of each trajectory's relative L2 averaged over all frames), the
rollout p95 (the 95th percentile over trajectories of the same) and the end mean.

Seeds (``seeds``): every trained arm is trained with model and data seeds seed .. seed + seeds - 1 on the same
test trajectories (those of ``seed``); each figure is reported as the mean over seeds with its std, and
compare.md says per metric whether solver-in-the-loop's margin over each corrector arm exceeds the seed spread
(the two arms' stds added, as ``budget_report.verdicts``). Resumable arm by arm: an (arm, seed) whose run
directory holds a finished run (metrics.json) with the same settings is read back, not retrained, so the same
command rerun on the same out goes on where a killed one stopped: an unfinished run of the same settings goes on
from its last checkpoint (every 5% of the steps; bit for bit the run it would have been, on the CPU), one of
other settings starts over; a finished run with other settings is refused (one line) unless ``resume`` is False
(``--overwrite``: every arm is retrained).

Outputs in out_dir: compare.md, compare.csv, compare.json, curves.csv (error against time per arm: mean and p95
over trajectories per frame), compare.png (errors against time), corrector.png (solver-in-the-loop: error
against time per corrector arm, mean and p95, log y), rollouts.png (solver-in-the-loop: one held-out
trajectory, reference / coarse / corrected; vorticity for a flow) and one run directory per arm.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

from pdestream import datasets
from pdestream.surrogate.checkpoint import load_checkpoint
from pdestream.surrogate.data import check_device
from pdestream.surrogate.evaluate import rollout_errors
from pdestream.surrogate.mode_table import NETWORK_MODES
from pdestream.surrogate.modes import make_mode
from pdestream.surrogate.phases import phase
from pdestream.surrogate.runs import resume_run, train_run

from .budget import stratified_test_set
from .interactive_config import CHECKPOINTS, InteractiveConfig, check_arms
from .interactive_config import arm_differs as _differ
from .interactive_config import arm_settings as _settings
from .interactive_config import arm_steps as _arm_steps
from .interactive_config import corrector_arms as _corrector_arms
from .interactive_config import finished_run as _finished
from .interactive_config import seed_dir as _run_dir
from .interactive_config import seeds as _seeds
from .interactive_report import (
    combine_seeds,
    plot,
    plot_corrector,
    record,
    score_against_coarse,
    write_curves,
    write_tables,
)
from .rollout_figure import plot_rollouts
from .shift import shifted_pde


def interactive_compare(pde, out_dir, cfg: InteractiveConfig, log=print) -> dict:
    """Train and roll out every arm; write compare.md/csv/json and compare.png; return the result dict."""
    cfg.check(pde)
    out = Path(out_dir)
    net_modes = [m for m in cfg.modes if m in NETWORK_MODES]
    sitl = "solver-in-the-loop" in cfg.modes
    # the coarse grid, another comparison in out, a finished run of other settings: refused before any work (the
    # CLI has run this before importing torch)
    fine, plan = check_arms(pde, out, cfg)
    for name in net_modes:  # the oracle's solver refuses this PDE (refine, steady, external) before any work
        make_mode(_settings(cfg, name)).bind(pde)
    if sitl:
        make_mode(_settings(cfg, "solver-in-the-loop", unroll=1)).bind(fine)  # the coarse solver builds?
    out.mkdir(parents=True, exist_ok=True)
    arms = []
    if net_modes:
        t0 = time.perf_counter()
        with phase(f"building the test set ({cfg.n_test} trajectories)", total=cfg.n_test, solves=-(-cfg.n_test // 32)):
            test = stratified_test_set(pde, cfg.n_test, cfg.seed)
        log(f"test set: {cfg.n_test} trajectories of {pde.n_frames} frames in {time.perf_counter() - t0:.1f} s")
        for name, arm_pde, settings, run_dir in plan[:len(net_modes)]:
            if cfg.trains(run_dir):
                arms.append(_train_seeds(name, arm_pde, settings, test, cfg, run_dir, log))
    if sitl and not (net_modes and fine is pde):  # (the network modes' test set is the fine one: not solved twice)
        with phase(f"building the fine test set ({cfg.n_test} trajectories, n={fine.n})", total=cfg.n_test,
                   solves=-(-cfg.n_test // 32)):  # stratified_test_set's chunks of 32
            test = stratified_test_set(fine, cfg.n_test, cfg.seed)
    if sitl:
        coarse = make_mode(_settings(cfg, "solver-in-the-loop", unroll=1)).bind(fine)
        t0 = time.perf_counter()
        errors = rollout_errors(None, _identity_norm(fine), test, datasets.NextStep(1, 1), coarse).relative()
        arms.append(record("coarse solver", "none", errors, 0.0, None, cfg.coarse_n))
        log(f"coarse solver (n={cfg.coarse_n}): end error {arms[-1]['end_mean']:.4f} ({time.perf_counter() - t0:.1f} s)")
        for label, arm_pde, settings, run_dir in plan[len(net_modes):]:
            if cfg.trains(run_dir):
                arms.append(_train_seeds(label, arm_pde, settings, test, cfg, run_dir, log))
        if not cfg.partial():
            score_against_coarse(arms)
            _plot_sitl_rollouts(out / "rollouts.png", fine, coarse, test[0], [p[3] for p in plan[len(net_modes):]], cfg)
    if cfg.partial():
        return {"arms": arms}  # some seeds or arms of several: the tables wait for the run that reads every seed back
    result = {"pde": pde.config(), "fine_pde": fine.config() if sitl else None, "config": asdict(cfg),
              "frame_dt": pde.frame_dt, "arms": arms}
    if cfg.shift is not None:
        result["beyond"] = _beyond(pde, fine, plan, net_modes, cfg, log)
    (out / "compare.json").write_text(json.dumps(result, indent=2))
    write_tables(out, result, pde, cfg)
    write_curves(out / "curves.csv", result)
    plot(out / "compare.png", result)
    if sitl:
        plot_corrector(out / "corrector.png", result)
    return result


def _beyond(pde, fine, plan: list, net_modes: list, cfg: InteractiveConfig, log) -> dict | None:
    """Every trained arm (each seed's saved model) and the coarse solver rolled out on a held-out set beyond the
    training range: {"pde": the shifted PDE's config (the corrector's where it runs), "domains": its parameter
    domains in words, "arms": records as the main set's}; None when no parameter could be shifted (logged)."""
    arms, shifted, domains = [], None, ""
    for base, part, corrector in ((pde, plan[:len(net_modes)], False), (fine, plan[len(net_modes):], True)):
        if not part:
            continue
        shifted = shifted_pde(base, cfg.shift, dict(cfg.shift_set))
        if shifted is None:
            log("beyond the training range: no parameter could be shifted; no such set")
            return None
        domains = ", ".join(f"{k} ~ {v}" for k, v in shifted.param_domains.items())
        with phase(f"building the test set beyond the training range ({domains}; {cfg.n_test} trajectories)",
                   total=cfg.n_test, solves=-(-cfg.n_test // 32)):
            test = stratified_test_set(shifted, cfg.n_test, cfg.seed)
        found = []
        if corrector:  # the coarse solver of the shifted config (it refuses parameters outside its own domains)
            coarse = make_mode(_settings(cfg, "solver-in-the-loop", unroll=1)).bind(shifted)
            errors = rollout_errors(None, _identity_norm(shifted), test, datasets.NextStep(1, 1), coarse).relative()
            found.append(record("coarse solver", "none", errors, 0.0, None, cfg.coarse_n))
        for label, _arm_pde, settings, run_dir in part:
            runs = [_evaluate(label, shifted, settings, test, cfg, _run_dir(run_dir, cfg, seed), seed,
                              json.loads((_run_dir(run_dir, cfg, seed) / "metrics.json").read_text()))
                    for seed in _seeds(cfg)]
            found.append(combine_seeds(runs))
            log(f"{label:32s} beyond the range: end error mean {found[-1]['end_mean']:.4f}; rollout mean "
                f"{found[-1]['rollout_mean']:.4f}")
        if corrector:
            score_against_coarse(found)
        arms += found
    return {"pde": shifted.config(), "domains": domains,
            "arms": arms}


def _unfinished(run_dir: Path, pde, settings: dict, cfg: InteractiveConfig, seed: int) -> bool:
    """True when ``run_dir`` holds an interrupted run (run.json and checkpoint.pt, no metrics.json) of the settings
    this arm and seed train with: it goes on from its checkpoint instead of starting over."""
    return (cfg.resume and (run_dir / "checkpoint.pt").is_file() and not (run_dir / "metrics.json").is_file()
            and not _differ(run_dir, pde, settings, cfg, seed))


def _train_seeds(label: str, pde, settings: dict, test, cfg: InteractiveConfig, run_dir: Path, log) -> dict:
    """Train (or read back) one arm for every seed; its record with each figure's mean and std over seeds."""
    runs = []
    for seed in _seeds(cfg) if cfg.only_seed is None else (cfg.only_seed,):
        rec = _train_arm(label, pde, settings, test, cfg, _run_dir(run_dir, cfg, seed), log, seed)
        runs.append(rec)
    return combine_seeds(runs)


def _plot_sitl_rollouts(path: Path, fine, coarse, test: dict, runs: list[Path], cfg: InteractiveConfig) -> None:
    """rollouts.png: the first held-out trajectory as the reference (fine, restricted to the coarse grid), the
    coarse solver alone, the pairs-trained and the solver-in-the-loop corrections (the first seed's), over time.
    runs: the corrector arms' run directories (``_corrector_arms``' order)."""
    device = check_device(cfg.device)
    u, params = test["u"][:1].to(device), test["params"][:1].to(device)
    rows = {}
    arms = _corrector_arms(cfg, _settings(cfg, "solver-in-the-loop")["unroll"])  # (0 here labelled it "unroll 0")
    for label, run in (("coarse solver", None), (arms[0][0], runs[0]), (arms[2][0], runs[2])):
        run = None if run is None else _run_dir(run, cfg, cfg.seed)
        model, norm = (None, _identity_norm(fine)) if run is None else load_checkpoint(run / "model.pt")[:2]
        if model is not None:
            model.to(device)
        pred, truth = (x.cpu() for x in coarse.rollout(model, norm, u, params))
        rows.setdefault(f"reference (n={fine.n} restricted)", truth[0])
        rows[label] = pred[0]
    where = getattr(fine, "FIELD_LOCATIONS", {})
    solid = truth[0, 0, fine.FIELDS.index("solid")] if where.get("solid") == "mask" else None
    h = fine.grid.length / cfg.coarse_n
    plot_rollouts(path, fine, rows, h, fine.frame_dt, solid=solid)


def _identity_norm(pde) -> datasets.Normalization:
    """A do-nothing normalization (mean 0, std 1) for rolling out the coarse solver alone."""
    import torch

    c, p = len(pde.FIELDS), len(pde.PARAMS)
    return datasets.Normalization(tuple(pde.FIELDS), torch.zeros(c), torch.ones(c), tuple(pde.PARAMS),
                                  torch.zeros(p), torch.ones(p), pde.NDIM)


def _evaluate(label: str, pde, settings: dict, test: list[dict], cfg: InteractiveConfig, run_dir: Path, seed: int,
              summary: dict) -> dict:
    """One seed's record of an arm: its saved model (run_dir/model.pt) rolled out on ``test`` of ``pde``."""
    model, norm, _ = load_checkpoint(run_dir / "model.pt")
    model.to(check_device(cfg.device))
    mode = make_mode(settings).bind(pde, seed)
    with phase(f"{label}: rolling out {sum(len(t['u']) for t in test)} test trajectories"):
        errors = rollout_errors(model, norm, test, datasets.NextStep(cfg.k_in, 1), mode).relative()  # [N, T - k_in]
    rec = record(label, settings["name"], errors, summary["wall"], summary, settings.get("coarse_n", pde.n))
    rec["unroll"] = settings.get("unroll", 1)
    if "noise" in settings:
        rec["noise"] = settings["noise"]
    if settings.get("unroll_schedule"):
        rec["unroll_schedule"] = settings["unroll_schedule"]
    rec["mode_stats"] = summary.get("mode_stats", {})
    rec["seed"] = seed
    return rec


def _train_arm(label: str, pde, settings: dict, test: list[dict], cfg: InteractiveConfig, run_dir: Path, log,
               seed: int) -> dict:
    """Train one arm through ``train_run`` (stream, model and data seed ``seed``: every arm of a seed starts from
    the same initial weights) and roll it out on ``test``; a finished run of the same settings is read back."""
    summary = _finished(run_dir, pde, settings, cfg, seed)
    if summary is not None:
        log(f"{label} seed {seed}: finished in {run_dir}, read back (not retrained)")
    elif _unfinished(run_dir, pde, settings, cfg, seed):
        summary, at = resume_run(run_dir, tests={})
        log(f"{label} seed {seed}: interrupted in {run_dir}, went on from its checkpoint at step {at} of "
            f"{_arm_steps(cfg, settings)}")
    else:
        steps = _arm_steps(cfg, settings)
        summary = train_run(pde, "stream", run_dir, model=cfg.model, model_cfg=cfg.model_cfg,
                            view=datasets.NextStep(cfg.k_in, 1), steps=steps, batch_size=cfg.batch_size,
                            lr=cfg.lr, seed=seed, data_seed=seed, tests={}, label=label,
                            checkpoint_every=max(1, steps // CHECKPOINTS), device=cfg.device, mode=settings,
                            seconds=cfg.budget_s)
    rec = _evaluate(label, pde, settings, test, cfg, run_dir, seed, summary)
    log(f"{label:32s} seed {seed}: end error mean {rec['end_mean']:.4f} p95 {rec['end_p95']:.4f} max {rec['end_max']:.4f}; "
        f"rollout mean {rec['rollout_mean']:.4f}; train loss {summary['final_loss']:.3g}; {summary['wall']:.0f} s")
    return rec

