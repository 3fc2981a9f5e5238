"""``pdestream compare`` as a library call: ``run_compare(CompareCommand(pde="burgers1d", out="cmp", quick=True))``.

One command, three comparisons: cache vs stream (experiments.compare), every data route at an equal budget
(``budget`` / ``sim_budget`` / ``quick``: experiments.budget) and training modes at equal steps (``modes``:
experiments.interactive_compare). This module imports nothing heavy until called (the CLI reads its defaults).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

from pdestream.interrupts import check_not_in_zarr, check_writable_dir, remove_created, snapshot

BUDGET_ARMS = ("precomputed", "fifo", "reservoir", "reservoir_loss")  # experiments.budget.DEFAULT_ARMS
COMPARE_DEFAULTS = {"n": "64", "n_frames": "11"}  # small enough for ~10 min on 2 CPU cores
COMPARE_OUTPUTS = ("compare.md", "compare.csv", "compare.json", "compare.png", "cache.h5", "cache.zarr")
RUN_FILES = ("model.pt", "metrics.json", "arm.json", "run.json", "checkpoint.pt")


@dataclass
class CompareCommand:
    """Everything ``pdestream compare`` takes. settings: the PDE's --config/--set values; model_cfg: the user's
    model settings over the comparison's own; reservoir: the reservoir options given (datasets.reservoir_options'
    names; the rest take their defaults); seeds None: 3 (1 for a quick budget run and for --modes)."""

    pde: object = "burgers1d"
    out: str = ""
    settings: dict = field(default_factory=dict)
    overwrite: bool = False
    cache_samples: int = 32
    seeds: int | None = None
    only_seed: int | None = None  # --modes: train this seed of every arm and stop (no tables)
    only_arms: tuple = ()  # --modes: train these arms (their directory names) and stop (no tables)
    test_samples: int = 128
    shift: float = -0.25
    shift_set: dict = field(default_factory=dict)
    format: str = "h5"
    budget: float | None = None
    sim_budget: int | None = None
    arms: tuple = BUDGET_ARMS
    priority_cap: float = 4.0
    precompute_share: float | None = None
    sim_warmup_share: float = 0.5
    quick: bool = False
    model: str = "fno"
    model_cfg: dict = field(default_factory=dict)
    view: str | None = None
    k_in: int | None = None  # next_step's frames (None: 1); refused with the operator view, which has none
    k_out: int | None = None
    steps: int = 1000
    batch_size: int = 32
    lr: float = 3e-3
    threads: int | None = None
    device: str = "cpu"
    modes: tuple | None = None
    fine_n: int | None = None
    loss: str = "mse"
    unroll: int | None = None
    coarse_n: int | None = None
    noise: float | str | None = None
    corrector_start: str | None = None
    unroll_schedule: str | None = None
    pairs_steps: int | None = None  # --modes: the corrector's pairs arms' steps (equal wall clock), None: steps
    clip: float | str | None = None  # --modes: the corrector arms' gradient clipping norm
    remat: bool = False  # --modes: the corrector arms' rematerialisation
    restrict: str | None = None  # --modes: the corrector arms' fine -> coarse restriction (None: the mode table's)
    reservoir: dict = field(default_factory=dict)


def run_compare(cmd: CompareCommand, log=None) -> str:
    """Run the comparison of ``cmd`` into ``cmd.out``; returns compare.md's text and the files' line. A Ctrl-C is
    raised again as a KeyboardInterrupt saying what was kept (finished runs stay; else what it created goes)."""
    log = log or (lambda line: print(line, flush=True))  # (said before a long run: flushed)
    check_numbers(cmd)
    if cmd.modes is None or not _modes_out(cmd.out):  # --modes resumes in its own out: (arm, seed) runs are kept
        check_compare_out(cmd.out, cmd.overwrite)
    check_writable_dir(cmd.out)
    check_not_in_zarr(cmd.out)
    if isinstance(cmd.pde, str):
        from pdestream.settings import build_pde

        pde = build_pde(cmd.pde, cmd.settings)  # the name and --set checked before torch (and JAX) are imported
        if cmd.modes is None or not cmd.quick:
            check_shift(pde, cmd)  # and --shift / --shift-set (checked again on the comparison's own settings)
    before = snapshot(cmd.out)
    try:
        return _compare(cmd, log)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(compare_left(cmd.out, before, resumes=cmd.modes is not None)) from None


def check_numbers(cmd: CompareCommand) -> None:
    """The numbers of ``cmd`` that need no PDE, one line each before torch is imported (the budget comparison's and
    the cache/stream comparison's were refused after it, 4-7 s at load 5-8; ``--modes`` checks its own in
    ``InteractiveConfig.check``), in the words of ``BudgetConfig.check`` / ``compare``. ``--cache-samples`` goes with
    the cache/stream comparison alone (elsewhere it went unread, -1 too)."""
    from pdestream.surrogate.checks import check_count, check_number  # (no torch)

    budget = cmd.budget is not None or cmd.sim_budget is not None or cmd.quick
    if cmd.cache_samples != CompareCommand.cache_samples and (budget or cmd.modes is not None):
        raise ValueError(f"--cache-samples {cmd.cache_samples} goes with the cache/stream comparison (no --budget, "
                         "--sim-budget, --quick or --modes): the others write no cache of that size")
    for flag, given, what in (("--only-seed", cmd.only_seed, "one seed of every training mode's arm"),
                              ("--only-arm", ",".join(cmd.only_arms) or None, "the training modes' arms")):
        if given is not None and cmd.modes is None:
            raise ValueError(f"{flag} {given} goes with --modes ({what})")
    if cmd.modes is not None:
        return
    check_count("--cache-samples", cmd.cache_samples)
    for name, value in (("--steps", cmd.steps), ("--batch-size", cmd.batch_size), ("--test-samples", cmd.test_samples),
                        ("--seeds", cmd.seeds)):
        if value is not None:
            check_count(name, value)
    check_number("--lr", cmd.lr, 0)
    if not budget:
        return
    if cmd.budget is not None and cmd.sim_budget is not None:
        raise ValueError("give exactly one budget: --budget SECONDS or --sim-budget N")
    if cmd.budget is not None:
        check_number("--budget", cmd.budget, 0, unit="seconds")
    if cmd.sim_budget is not None:
        check_count("--sim-budget", cmd.sim_budget, note=" (trajectories)")
    check_number("sim warm-up share", cmd.sim_warmup_share, 0, 1, closed="both")
    check_number("--priority-cap", cmd.priority_cap, 1, closed="low")
    if cmd.precompute_share is not None:
        check_number("precompute share", cmd.precompute_share, 0, 1)
    from pdestream.datasets.reservoir_options import check_numbers as check_reservoir  # (no torch)

    check_reservoir(argparse.Namespace(**{**vars(_options(cmd)), "batch_size": cmd.batch_size}))  # the reservoir arms'


def check_compare_out(out: str, overwrite: bool) -> None:
    """Refuse an out DIR that already holds compare output (tables, cache, run directories) unless overwrite:
    like `train`, a second run must not silently replace the first one's results."""
    d = Path(out)
    if d.exists() and not d.is_dir():
        raise NotADirectoryError(f"--out {out} is a file; compare writes a directory")
    if overwrite or not d.is_dir():
        return
    found = [n for n in COMPARE_OUTPUTS if (d / n).exists()]
    found += [f"{p.name}/" for p in sorted(d.iterdir()) if p.is_dir() and any((p / f).exists() for f in RUN_FILES)]
    if found:
        raise FileExistsError(f"{out} already holds compare output ({', '.join(found[:4])}"
                              f"{', ...' if len(found) > 4 else ''}); pass --overwrite or choose another --out")


def _modes_out(out: str) -> bool:
    """Whether ``out`` holds nothing but what a `compare --modes` writes (its compare.json, if any, is one): the
    place to go on from, where another comparison's output is refused as before."""
    table = Path(out) / "compare.json"
    if not table.is_file():
        return not any((Path(out) / n).exists() for n in COMPARE_OUTPUTS)
    try:
        import json

        return "modes" in json.loads(table.read_text()).get("config", {})
    except (ValueError, AttributeError):
        return False


def compare_left(out: str, before, resumes: bool = False) -> str:
    """What an interrupted `compare` leaves, in words. Finished runs (and tables) are kept; without them nothing
    of value was written (a rerun rewrites the cache too), so what the command created in out is removed.
    resumes: the comparison goes on from its finished runs when rerun (``--modes``)."""
    d = Path(out)
    if not d.is_dir():
        return "nothing was written"
    tables = [n for n in ("compare.md", "compare.json") if (d / n).is_file()]
    runs = sorted(p.name for p in d.iterdir() if p.is_dir() and ((p / "metrics.json").is_file()
                                                                 or (p / "arm.json").is_file()))
    # --modes: an arm cut short goes on from its checkpoint when the command is rerun, so it is kept too
    cut = sorted(p.name for p in d.iterdir() if resumes and p.is_dir() and (p / "checkpoint.pt").is_file()
                 and p.name not in runs)
    if tables or runs or cut:
        kept = ", ".join(tables + [f"{r}/" for r in runs][:4]) + (", ..." if len(runs) > 4 else "")
        again = ("rerun the same command to go on from them" if resumes else
                 "pass --overwrite to run the comparison again")
        part = f" and {len(cut)} interrupted one{'' if len(cut) == 1 else 's'} at a checkpoint ({cut[0]}/)" if cut else ""
        return (f"{out} keeps {len(runs)} finished run{'' if len(runs) == 1 else 's'}"
                f"{f' ({kept})' if kept else ''}{part}; {again}")
    remove_created(d, before)
    return "nothing was kept (no run had finished)"


def compare_settings(name, settings: dict) -> dict:
    """COMPARE_DEFAULTS under the user's settings: never a finer grid than the entry's default (a 3D entry keeps
    its n=32; n=64 was 8x the points and a reservoir past the machine's memory) and only the settings the entry
    has (a steady one has no frames: darcy2d was refused for an n_frames the user never set)."""
    from pdestream import generator

    try:
        base = generator.get_pde(name) if isinstance(name, str) else name  # a recipe: its settings
    except (ValueError, TypeError):
        return dict(settings)  # build_pde refuses the name in its own words
    fields = base.config_fields()
    defaults = {k: (str(min(int(v), base.n)) if k == "n" else v) for k, v in COMPARE_DEFAULTS.items() if k in fields}
    return {**defaults, **settings}


def _options(cmd: CompareCommand) -> argparse.Namespace:
    """The reservoir options of ``cmd`` over their defaults (datasets.reservoir_options), with device and priority cap."""
    from pdestream.datasets.reservoir_options import defaults

    return argparse.Namespace(**{**defaults(train=False), **cmd.reservoir, "device": cmd.device,
                                 "priority_cap": cmd.priority_cap})


def check_priority_cap(cmd: CompareCommand, used: bool) -> None:
    """priority_cap where no prioritized arm runs at a simulation budget: one line (it would do nothing)."""
    if cmd.priority_cap != 4.0 and not used:
        raise ValueError(f"--priority-cap={cmd.priority_cap:g} goes with --sim-budget and the arms reservoir_active or "
                         "reservoir_priority (their reuse bound at a simulation budget)")


def check_shift(pde, cmd: CompareCommand) -> None:
    """shift and shift_set checked (one line) before any cache or run is written: the shifted PDE is built once
    here the way the comparison builds it later (--shift 0 wrote a 256-sample cache before its refusal)."""
    from pdestream.experiments.shift import shifted_pde

    if cmd.shift != cmd.shift or cmd.shift in (float("inf"), float("-inf")):
        raise ValueError(f"--shift {cmd.shift} not allowed: a finite fraction like 0.25 or -0.25")
    try:
        shifted_pde(pde, cmd.shift, dict(cmd.shift_set))
    except ValueError as err:
        raise ValueError(str(err).replace("shift=", "--shift ", 1).replace("shift_set ", "--shift-set ", 1)) from None


def _compare(cmd: CompareCommand, log) -> str:
    from pdestream.datasets.reservoir_options import check_priority_options, check_proposal_options

    budget = cmd.budget is not None or cmd.sim_budget is not None or cmd.quick
    if cmd.loss != "mse" and (cmd.modes is not None or not budget):
        raise ValueError(f"--loss {cmd.loss} goes with --budget or --sim-budget (and with train), not with "
                         f"{'--modes' if cmd.modes is not None else 'the stream/cache comparison'}")
    if cmd.modes is not None or not budget:
        check_priority_options(_options(cmd), False, "compare --budget / --sim-budget")
        check_proposal_options(_options(cmd), False, False, "compare --budget / --sim-budget (the steered arms)")
        check_priority_cap(cmd, False)
    if cmd.modes is not None:
        return _interactive(cmd)
    if (cmd.view or "operator") == "operator" and (cmd.k_in is not None or cmd.k_out is not None):
        given = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in (("k_in", cmd.k_in), ("k_out", cmd.k_out))
                         if v is not None)
        raise ValueError(f"{given} goes with --view next_step; compare trains the operator view by default "
                         "(u(t=0) -> u(t_end), no frames to stack)")
    if (cmd.unroll is not None or cmd.coarse_n is not None or cmd.fine_n is not None or cmd.noise is not None
            or cmd.corrector_start is not None or cmd.unroll_schedule is not None or cmd.pairs_steps is not None
            or cmd.clip is not None or cmd.remat or cmd.restrict is not None):
        raise ValueError("--unroll, --unroll-schedule, --coarse-n, --fine-n, --pairs-steps, --corrector-start, --noise, "
                         "--clip, --remat and --restrict go with --modes (compare training modes)")
    if budget:
        return _budget(cmd, log)
    from pdestream.experiments import compare as module
    from pdestream.settings import build_pde
    from pdestream.surrogate.fno import COMPARE_FNO
    from pdestream.surrogate.launch import make_view, set_threads

    pde = build_pde(cmd.pde, compare_settings(cmd.pde, cmd.settings))
    check_shift(pde, cmd)
    set_threads(1 if cmd.threads is None else cmd.threads)
    model_cfg = {**(COMPARE_FNO if cmd.model.startswith("fno") else {}), **cmd.model_cfg}
    seeds = 3 if cmd.seeds is None else cmd.seeds
    view = make_view(cmd.view or "operator", 1 if cmd.k_in is None else cmd.k_in, 1 if cmd.k_out is None else cmd.k_out)
    cfg = module.CompareConfig(model=cmd.model, model_cfg=model_cfg, view=view,
                               steps=cmd.steps, batch_size=cmd.batch_size, lr=cmd.lr, cache_samples=cmd.cache_samples,
                               seeds=tuple(range(seeds)), n_test=cmd.test_samples, shift=cmd.shift,
                               cache_format=cmd.format, device=cmd.device)
    module.compare(pde, cmd.out, cfg, shift_overrides=dict(cmd.shift_set))
    return (Path(cmd.out) / "compare.md").read_text() + \
        f"table: {cmd.out}/compare.md, compare.csv; figure: {cmd.out}/compare.png"


def _budget(cmd: CompareCommand, log) -> str:
    """budget / sim_budget [/ quick]: every arm at the same cost (experiments.budget)."""
    from pdestream.experiments import budget as module

    pde, cfg = budget_setup(cmd, log)
    module.budget_compare(pde, cmd.out, cfg, shift_overrides=dict(cmd.shift_set))
    return (Path(cmd.out) / "compare.md").read_text() + \
        f"table: {cmd.out}/compare.md, compare.csv, compare.json; figure: {cmd.out}/compare.png"


def budget_setup(cmd: CompareCommand, log=print):
    """(pde, BudgetConfig) of a budget / sim_budget [/ quick] ``cmd``, every option checked (one line each) and
    torch's threads set, as ``compare`` runs it: what a harness running single (arm, seed) units through
    ``experiments.budget.run_arm`` builds (benchmarks/active_suite.py)."""
    from pdestream.datasets.reservoir_options import (
        active_kwargs,
        check_priority_options,
        check_proposal_options,
        solve_batch,
    )
    from pdestream.experiments import budget as module
    from pdestream.settings import build_pde
    from pdestream.surrogate.fno import COMPARE_FNO
    from pdestream.surrogate.launch import make_view, set_threads

    settings, budget_s = dict(cmd.settings), cmd.budget
    if cmd.quick:
        settings = compare_settings(cmd.pde, settings)
        if cmd.budget is None and cmd.sim_budget is None:
            budget_s = 20.0
            log("compare --quick: the budget comparison of the data routes (--arms) at --budget 20 seconds per "
                "arm; --sim-budget N for equal solves, --modes M1,M2 for the training modes, no --quick for cache "
                "vs stream")
    pde = build_pde(cmd.pde, settings)
    check_shift(pde, cmd)
    set_threads(1 if cmd.threads is None else cmd.threads)
    small = dict(COMPARE_FNO)
    model_cfg = (small if cmd.quick else {"width": 64, "modes": 16, "layers": 4}) if cmd.model.startswith("fno") else {}
    model_cfg = {**model_cfg, **cmd.model_cfg}
    arms = tuple(cmd.arms)
    steered = bool({"reservoir_active", "reservoir_priority"} & set(arms))
    o = _options(cmd)
    check_priority_options(o, steered, "the arms reservoir_active or reservoir_priority")
    check_proposal_options(o, bool({"reservoir_loss", "reservoir_active", "reservoir_generative"} & set(arms)),
                           "reservoir_active" in arms, "the arms reservoir_loss / reservoir_active / reservoir_generative",
                           "the arm reservoir_active")
    check_priority_cap(cmd, steered and cmd.sim_budget is not None)
    cfg = module.BudgetConfig(
        budget_s=budget_s, sim_budget=cmd.sim_budget, arms=arms, model=cmd.model, model_cfg=model_cfg,
        view=make_view(cmd.view or "operator", 1 if cmd.k_in is None else cmd.k_in,
                       1 if cmd.k_out is None else cmd.k_out), batch_size=cmd.batch_size, lr=cmd.lr,
        steps=cmd.steps, precompute_share=cmd.precompute_share, capacity=o.capacity, max_reuse=o.max_reuse,
        target_reuse=o.target_reuse, reservoir_mode=o.reservoir_mode, sim_warmup_share=cmd.sim_warmup_share,
        proposal_floor=o.proposal_floor, proposal_kwargs=active_kwargs(o), priority_power=o.priority_power,
        priority_floor=o.priority_floor, priority_cap=cmd.priority_cap, solve_batch=solve_batch(o),
        n_test=32 if cmd.quick and cmd.test_samples == 128 else cmd.test_samples, shift=cmd.shift,
        seeds=(1 if cmd.quick else 3) if cmd.seeds is None else cmd.seeds, device=cmd.device,
        mode=None if cmd.loss == "mse" else {"name": "one-step", "loss": cmd.loss})
    return pde, cfg


def _interactive(cmd: CompareCommand) -> str:
    """modes: training modes at equal steps (experiments.interactive_compare)."""
    from pdestream.experiments.interactive_config import InteractiveConfig, check_arms
    from pdestream.settings import build_pde
    from pdestream.surrogate.mode_table import (
        MODE_SPECS,
        check_clip,
        check_corrector_start,
        check_noise,
        check_restrict,
        check_restrict_acts,
    )

    if cmd.sim_budget is not None:
        raise ValueError("--modes compares at equal --steps or, with --budget SECONDS, at equal wall clock; "
                         "--sim-budget goes with the data-route comparison")
    if cmd.view not in (None, "next_step"):  # (it ran rc 0 on the next-step view, the option unread)
        raise ValueError(f"--view {cmd.view} not allowed with --modes: every mode trains on the next-step view and is "
                         "rolled out frame by frame; drop --view")
    if cmd.noise is not None:
        check_noise(cmd.noise)  # before the PDE (and JAX) is built
    if cmd.corrector_start is not None:
        check_corrector_start(cmd.corrector_start)
    clip = check_clip(cmd.clip)
    modes = tuple(m.strip() for m in cmd.modes if m.strip())
    if cmd.restrict is not None:
        check_restrict(cmd.restrict)
        if "solver-in-the-loop" not in modes:
            raise ValueError(f"--restrict {cmd.restrict} goes with the corrector's arms (--modes ...,solver-in-the-loop)")
    if "solver-in-the-loop" not in modes:  # (they ran, rc 0, the option unread)
        given = [f"{o} {v}" for o, v in (("--fine-n", cmd.fine_n), ("--coarse-n", cmd.coarse_n),
                                         ("--corrector-start", cmd.corrector_start)) if v is not None]
        if given:
            raise ValueError(f"{', '.join(given)} {'goes' if len(given) == 1 else 'go'} with the corrector's arms "
                             "(--modes ...,solver-in-the-loop)")
        if cmd.noise is not None and "noise" not in modes:
            raise ValueError(f"--noise {cmd.noise} goes with the noise mode or the corrector's arms (--modes ...,noise "
                             "or ...,solver-in-the-loop)")
    if cmd.unroll is not None and not any("unroll" in MODE_SPECS[m].settings for m in modes if m in MODE_SPECS):
        raise ValueError(f"--unroll {cmd.unroll} goes with the modes that unroll (--modes ...,pushforward, oracle or "
                         "solver-in-the-loop)")
    settings = {"n": "32", "n_frames": "11", **cmd.settings} if cmd.quick else dict(cmd.settings)  # tiny: tests
    pde = build_pde(cmd.pde, settings)
    check_restrict_acts(pde, cmd.restrict)  # (given only with the corrector's arms: checked above)
    if not cmd.quick:
        check_shift(pde, cmd)  # the set beyond the training range (not with --quick, a smoke run)
    model_cfg = ({"width": 8, "modes": 4, "layers": 2} if cmd.quick else {"width": 32, "modes": 12, "layers": 3}) \
        if cmd.model.startswith("fno") else {}
    model_cfg = {**model_cfg, **cmd.model_cfg}
    quick = cmd.quick and cmd.steps == 1000  # quick without steps: a few steps
    given = {"unroll": cmd.unroll, "coarse_n": 16 if cmd.quick and cmd.coarse_n is None else cmd.coarse_n,
             "noise": cmd.noise, "corrector_start": cmd.corrector_start, "restrict": cmd.restrict}
    cfg = InteractiveConfig(
        modes=modes, **{k: v for k, v in given.items() if v is not None},  # else the mode table's
        steps=20 if quick else cmd.steps, batch_size=8 if quick else cmd.batch_size, lr=cmd.lr, model=cmd.model,
        model_cfg=model_cfg, k_in=(1 if cmd.k_in is None else cmd.k_in), seed=0, seeds=1 if cmd.seeds is None else cmd.seeds,
        only_seed=cmd.only_seed, only_arms=cmd.only_arms,
        unroll_schedule=cmd.unroll_schedule, resume=not cmd.overwrite, n_test=4 if cmd.quick and cmd.test_samples == 128 else
        cmd.test_samples, fine_n=cmd.fine_n, device=cmd.device, budget_s=cmd.budget, pairs_steps=cmd.pairs_steps,
        clip=clip, remat=cmd.remat, shift=None if cmd.quick else cmd.shift, shift_set=dict(cmd.shift_set))
    if cmd.k_out not in (None, 1):
        raise ValueError(f"--k-out={cmd.k_out} not allowed with --modes: every mode predicts one frame per step")
    cfg.check(pde)  # every bad value in one line before torch is imported (3-6 s under load)
    check_arms(pde, cmd.out, cfg)  # the coarse grid, a finished arm of other settings: as well
    from pdestream.experiments import interactive_compare as module
    from pdestream.surrogate.launch import set_threads

    set_threads(1 if cmd.threads is None else cmd.threads)
    module.interactive_compare(pde, cmd.out, cfg)
    if cfg.partial():
        which = f"{', '.join(cfg.only_arms) if cfg.only_arms else 'every arm'}" + \
            ("" if cfg.only_seed is None else f", seed {cfg.only_seed}")
        return (f"trained ({which}) in {cmd.out}; the same command without --only-seed / --only-arm reads it back "
                "with the rest and writes the tables")
    corrector = ", corrector.png (corrector arms)" if "solver-in-the-loop" in modes else ""
    return (Path(cmd.out) / "compare.md").read_text() + \
        f"table: {cmd.out}/compare.md, compare.csv, compare.json, curves.csv (error against time per arm); " \
        f"figures: {cmd.out}/compare.png{corrector}"
