"""What every arm of ``compare --modes`` shares (``InteractiveConfig``) and each arm's mode settings, without
torch: ``InteractiveConfig.check`` refuses a bad value in one line before the comparison's modules (and torch)
are imported (``experiments.interactive_compare`` runs it); the arms' run directories and what a rerun finds in
them (``check_arms``: a finished run of other settings, a coarse grid that does not fit, refused before torch)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from pdestream.surrogate.checks import check_count, check_number
from pdestream.surrogate.config import check_checkpoint_file
from pdestream.surrogate.mode_table import (
    DEFAULTS,
    MODE_NAMES,
    MODE_SPECS,
    NETWORK_MODES,
    check_coarse_grid,
    check_corrector_start,
    check_mode_k_in,
    check_noise,
    mode_settings,
    parse_unroll_schedule,
    pde_restricts_periodic,
)


@dataclass
class InteractiveConfig:
    """What every arm shares. unroll: k of pushforward, oracle and solver-in-the-loop (sitl_unroll overrides the
    last); coarse_n / fine_n: the solver-in-the-loop grids (fine_n None: the PDE's n); noise: the noise arms'
    std as a fraction of the data's std (``surrogate.modes.Noise`` on the network's input frames; the corrector's
    "pairs + noise" arm on its coarse start state, ``surrogate.modes.SolverInTheLoop``); corrector_start: how every
    corrector arm's network starts ("random" or "zero", ``SolverInTheLoop.init_model``); unroll_schedule: the
    solver-in-the-loop arm's unroll curriculum, "K1:S1,K2:S2,..." (unroll Ki for the share Si of the steps,
    ``mode_table.parse_unroll_schedule``; its longest unroll replaces sitl_unroll); clip / remat: every corrector
    arm's gradient clipping norm and rematerialisation (``SolverInTheLoop``); restrict: how every corrector arm,
    the coarse solver and the references restrict a fine periodic field to the coarse grid ("fourier" or
    "points", ``surrogate.modes.subsample``); shift / shift_set: every arm rolled
    out again on a second held-out set beyond the training range (``experiments.shift.shifted_pde``: the parameter
    domains moved by this fraction of their width, or as shift_set names them; None: no such set); seed: the
    first model and data
    seed and the test set's; seeds: how many (seed, seed + 1, ...); only_seed: train (or read back) this one of them
    in every arm and stop before the tables (seeds spread over processes, read back by a run without it);
    only_arms: the same for these arms (their run directories' names; empty: every arm); resume: read back finished
    (arm, seed) runs;
    budget_s: equal wall clock instead of equal steps: every trained arm trains this many seconds (solver calls
    included; the steps it reaches are in the table), None: ``steps`` each; pairs_steps: the corrector's two pairs
    arms' steps (None: ``steps``), for equal wall clock with solver-in-the-loop, whose unrolled steps cost more
    (read off a run at equal steps: ``steps`` x its wall / theirs)."""

    modes: tuple = NETWORK_MODES
    unroll: int = DEFAULTS["unroll"]
    sitl_unroll: int | None = None
    steps: int = 2000
    batch_size: int = 32
    lr: float = 1e-3
    model: str = "fno"
    model_cfg: dict = field(default_factory=lambda: {"width": 32, "modes": 12, "layers": 3})
    k_in: int = 1
    seed: int = 0
    n_test: int = 32
    coarse_n: int = DEFAULTS["coarse_n"]
    fine_n: int | None = None
    noise: float = DEFAULTS["noise"]
    corrector_start: str = DEFAULTS["corrector_start"]
    unroll_schedule: str | None = None
    clip: float | None = None
    remat: bool = False
    restrict: str = DEFAULTS["restrict"]
    shift: float | None = None
    shift_set: dict = field(default_factory=dict)
    seeds: int = 1
    only_seed: int | None = None
    only_arms: tuple = ()
    resume: bool = True
    device: str = "cpu"
    budget_s: float | None = None
    pairs_steps: int | None = None

    def partial(self) -> bool:
        """Only some seeds or arms trained (``only_seed`` / ``only_arms``): no tables."""
        return self.only_seed is not None or bool(self.only_arms)

    def trains(self, arm_dir: Path) -> bool:
        """Whether this run trains (or reads back) the arm whose run directory is ``arm_dir``."""
        return not self.only_arms or arm_dir.name in self.only_arms

    def schedule(self) -> list | None:
        """The solver-in-the-loop arm's unroll curriculum in optimizer steps ([[k, steps], ...]) or None."""
        return None if self.unroll_schedule is None else parse_unroll_schedule(self.unroll_schedule, self.steps)

    def check(self, pde) -> None:
        """ValueError (one line) naming the bad setting, before any work."""
        unknown = [m for m in self.modes if m not in MODE_NAMES]
        if unknown or not self.modes:
            raise ValueError(f"--modes {','.join(self.modes)} not allowed; choose from {', '.join(MODE_NAMES)}")
        for name in self.modes:
            arm_settings(self, name)
            check_mode_k_in(name, self.k_in)  # (the other arms trained first, then the corrector refused it)
        self.noise = check_noise(self.noise)  # a bad --noise is refused even without the noise arm
        check_corrector_start(self.corrector_start)  # (and a bad --corrector-start without the corrector arms)
        for name, value in (("--steps", self.steps), ("--batch-size", self.batch_size), ("--test-samples", self.n_test),
                            ("--k-in", self.k_in), ("--seeds", self.seeds)):
            check_count(name, value)
        if self.only_seed is not None and self.only_seed not in seeds(self):
            raise ValueError(f"--only-seed {self.only_seed} not among the seeds trained ({self.seed}..."
                             f"{self.seed + self.seeds - 1}: --seeds {self.seeds})")
        if self.pairs_steps is not None:
            check_count("--pairs-steps", self.pairs_steps)
            if "solver-in-the-loop" not in self.modes or self.budget_s is not None:
                raise ValueError(f"--pairs-steps {self.pairs_steps} goes with the corrector's arms (--modes "
                                 "...,solver-in-the-loop) at equal steps (not with --budget)")
        if self.budget_s is not None:
            check_number("--budget", self.budget_s, 0, unit="seconds")
            if self.unroll_schedule is not None:
                raise ValueError(f"--unroll-schedule {self.unroll_schedule} is in shares of --steps; with --budget "
                                 f"{self.budget_s:g} the steps an arm reaches are not known before it trains")
        if (self.clip is not None or self.remat) and "solver-in-the-loop" not in self.modes:
            raise ValueError(f"{'--clip' if self.clip is not None else '--remat'} goes with the corrector's arms "
                             "(--modes ...,solver-in-the-loop)")
        if self.unroll_schedule is not None:
            if "solver-in-the-loop" not in self.modes:
                raise ValueError(f"--unroll-schedule {self.unroll_schedule} goes with the solver-in-the-loop arm "
                                 "(--modes ...,solver-in-the-loop)")
            self.schedule()  # one line for a bad value, before any work
        check_number("--lr", self.lr, 0)
        unrolled = [m for m in self.modes if "unroll" in MODE_SPECS[m].settings]  # (one-step, noise: one frame)
        longest = max([self.unroll, *(k for k, _ in self.schedule() or ())]) if unrolled else 1
        if pde.n_frames < self.k_in + longest + 1:
            raise ValueError(f"{f'--unroll {longest}' if unrolled else f'--k-in {self.k_in}'} needs trajectories of "
                             f"at least {self.k_in + longest + 1} frames; {pde.NAME} has n_frames={pde.n_frames}")
        if self.device != "cpu":  # (torch only for another device: every refusal above comes without it)
            from pdestream.surrogate.data import check_device

            check_device(self.device)


def arm_settings(cfg: InteractiveConfig, name: str, **override) -> dict:
    """Mode ``name``'s settings in this comparison: the config's unroll (sitl_unroll for solver-in-the-loop) and
    coarse grid where the mode takes them (the mode table decides), ``override`` on top."""
    unroll = cfg.sitl_unroll if name == "solver-in-the-loop" and cfg.sitl_unroll else cfg.unroll
    schedule = cfg.schedule() if name == "solver-in-the-loop" else None
    if schedule:
        unroll = max(k for k, _ in schedule)
    noise = 0.0 if name == "solver-in-the-loop" else cfg.noise  # (the corrector's noise arm overrides it)
    given = {"unroll": unroll, "coarse_n": cfg.coarse_n, "noise": noise, "corrector_start": cfg.corrector_start,
             "unroll_schedule": schedule, "clip": cfg.clip, "remat": cfg.remat,
             "restrict": cfg.restrict, **override}
    if given.get("unroll") == 1:  # the pairs arms: no curriculum
        given["unroll_schedule"] = None
    return mode_settings(name, **{k: v for k, v in given.items() if k in MODE_SPECS[name].settings})


# --- the arms and their run directories: what a rerun finds there (no torch) -----------------------------
CHECKPOINTS = 20  # per arm: an interrupted arm loses at most 5% of its steps
RESUME_KEYS = ("model", "model_cfg", "k_in", "steps", "seconds", "batch_size", "lr", "seed", "mode", "pde")


def corrector_arms(cfg: InteractiveConfig, k: int) -> list[tuple]:
    """(label, unroll, noise, run directory name) of the three trained corrector arms."""
    schedule = cfg.schedule()
    name = "->".join(str(u) for u, _ in schedule) if schedule else str(k)
    return [("pairs (unroll 1)", 1, 0.0, "sitl_unroll1"),
            ("pairs + noise (unroll 1)", 1, cfg.noise, "sitl_unroll1_noise"),
            (f"solver-in-the-loop (unroll {name})", k, 0.0,
             f"sitl_unroll{'-'.join(str(u) for u, _ in schedule)}" if schedule else f"sitl_unroll{k}")]


def plan_arms(pde, out: Path, cfg: InteractiveConfig) -> tuple[object, list[tuple]]:
    """(the corrector's fine PDE, [(label, arm's PDE, mode settings, arm directory)] of every trained arm, the
    network modes first)."""
    net_modes = [m for m in cfg.modes if m in NETWORK_MODES]
    sitl = "solver-in-the-loop" in cfg.modes
    try:
        fine = pde.replace({"n": cfg.fine_n}) if sitl and cfg.fine_n not in (None, pde.n) else pde
    except ValueError as err:  # the PDE's refusal speaks of n, which the user set as --fine-n
        raise ValueError(f"--fine-n {cfg.fine_n} not allowed: {err}") from None
    plan = [(name, pde, arm_settings(cfg, name), out / name) for name in net_modes]
    if sitl:
        k = arm_settings(cfg, "solver-in-the-loop")["unroll"]
        plan += [(label, fine, arm_settings(cfg, "solver-in-the-loop", unroll=unroll, noise=noise), out / run)
                 for label, unroll, noise, run in corrector_arms(cfg, k)]
    return fine, plan


def check_arms(pde, out, cfg: InteractiveConfig) -> tuple[object, list[tuple]]:
    """``plan_arms``, after what can be refused without torch: the corrector's coarse grid against the fine one, a
    finished comparison of other arms in ``out``, a finished (arm, seed) run of other settings (one line each)."""
    out = Path(out)
    fine, plan = plan_arms(pde, out, cfg)
    names = [arm_dir.name for *_, arm_dir in plan]
    unknown = [a for a in cfg.only_arms if a not in names]
    if unknown:
        raise ValueError(f"--only-arm {','.join(unknown)} not an arm of this comparison; its arms: {', '.join(names)}")
    if "solver-in-the-loop" in cfg.modes:
        check_coarse_grid(fine, cfg.coarse_n)
    check_same_comparison(out, pde, cfg)
    for _label, arm_pde, settings, arm_dir in plan:
        for seed in seeds(cfg):
            finished_run(seed_dir(arm_dir, cfg, seed), arm_pde, settings, cfg, seed)
    return fine, plan


def arm_steps(cfg: InteractiveConfig, settings: dict) -> int:
    """The optimizer steps of the arm with mode ``settings``: pairs_steps for the corrector's pairs arms (unroll
    1), when given, else steps."""
    pairs = settings["name"] == "solver-in-the-loop" and settings.get("unroll") == 1
    return cfg.pairs_steps if pairs and cfg.pairs_steps is not None else cfg.steps


def seeds(cfg: InteractiveConfig) -> range:
    return range(cfg.seed, cfg.seed + cfg.seeds)


def seed_dir(arm_dir: Path, cfg: InteractiveConfig, seed: int) -> Path:
    """One seed's run directory: the arm's own with one seed (as before seeds), ARM_seedS with several; with several,
    a seed that a one-seed run on the same out trained (the arm's own directory, its run.json of that seed) is
    found there, so ``--seeds 1`` then ``--seeds 3`` reads seed 0 back instead of training it again."""
    if cfg.seeds == 1:
        return arm_dir
    named = arm_dir.with_name(f"{arm_dir.name}_seed{seed}")
    if not named.exists() and (arm_dir / "run.json").is_file():
        if json.loads((arm_dir / "run.json").read_text()).get("seed") == seed:
            return arm_dir
    return named


def comparable_mode(mode, pde=None):
    """A mode's settings (as given, or run.json's "mode") in one form: every setting of the mode with its default
    filled in and the loss, without the rule in words (what ``surrogate.modes.make_mode`` reads of it); the value
    itself when it is not a mode's settings. Solver-in-the-loop's "restrict" left out reads "points" (run.json
    files before the setting), as make_mode reads it; on the fine ``pde``'s grid where it does not act (walls
    only, staggered fields: ``mode_table.pde_restricts_periodic``) it is left out of the form."""
    if mode is None:  # run.json of runs before modes: one-step
        mode = {"name": "one-step"}
    if not isinstance(mode, dict):
        return mode
    s = {k: v for k, v in mode.items() if k not in ("loss", "rule")}
    name = s.pop("name", "one-step")
    if name == "solver-in-the-loop":
        s.setdefault("restrict", "points")
    try:
        form = {**mode_settings(name, **s), "loss": mode.get("loss", "mse")}
    except (ValueError, TypeError):
        return mode
    if name == "solver-in-the-loop" and pde is not None and not pde_restricts_periodic(pde):
        form.pop("restrict", None)
    return form


def arm_differs(run: Path, pde, settings: dict, cfg: InteractiveConfig, seed: int, said: bool = False) -> list[str]:
    """The RESUME_KEYS in which the run.json in ``run`` differs from what this arm and seed train with (said: each
    as "KEY: the run's X, asked Y", a dict's differing entries named, as the refusal says them)."""
    want = json.loads(json.dumps({"model": cfg.model, "model_cfg": cfg.model_cfg, "k_in": cfg.k_in,
                                  "steps": arm_steps(cfg, settings),
                                  "seconds": cfg.budget_s, "batch_size": cfg.batch_size, "lr": cfg.lr, "seed": seed,
                                  "mode": comparable_mode(settings, pde), "pde": pde.config()}))
    try:
        have = json.loads((run / "run.json").read_text())
    except (OSError, ValueError):
        have = {}
    # k_in: the next-step view's input frames (run.json's view_args; a model of 1 read back for 2 failed in the
    # rollout on its input channels)
    have = {**have, "mode": comparable_mode(have.get("mode"), pde), "model_cfg": comparable_model_cfg(have),
            "k_in": _view_k_in(have.get("view_args"))} if isinstance(have, dict) else {}
    want["model_cfg"] = comparable_model_cfg(want)
    keys = [key for key in RESUME_KEYS if have.get(key) != want[key]]
    return [_said(key, have.get(key), want[key]) for key in keys] if said else keys


def comparable_model_cfg(run: dict):
    """A run's model settings (run.json's "model_cfg", or an arm's) in one form: a built-in model's integers as
    ints, so that --model-set width=08 (kept as the string "08" for the model to parse) and a run of width=8 read as
    the same model; your own model's settings (a "package.module:Class" model) as given."""
    cfg = run.get("model_cfg")
    if not isinstance(cfg, dict) or ":" in str(run.get("model")):
        return cfg
    return {k: _as_int(v) for k, v in cfg.items()}


def _as_int(value):
    try:
        return int(value) if isinstance(value, (int, str)) and not isinstance(value, bool) else value
    except ValueError:
        return value


def _view_k_in(view_args) -> int | None:
    """The input frames run.json's ``view_args`` record (1 where it records none), None for a damaged entry."""
    if view_args is None:
        return 1
    return view_args.get("k_in", 1) if isinstance(view_args, dict) else None


def _said(key: str, have, want) -> str:
    """One difference in words: "steps: the run's 3, asked 2"; for dicts, "mode: clip the run's 1.0, asked 0.5"
    (a rerun with another --clip was refused as "other settings (mode)")."""
    if not (isinstance(have, dict) and isinstance(want, dict)):
        return f"{key}: the run's {have}, asked {want}"
    parts = [f"{k} the run's {have.get(k, 'its default')}, asked {want.get(k, 'its default')}"
             for k in sorted(set(have) | set(want)) if have.get(k) != want.get(k) and k != "restrict"]
    if key == "mode" and have.get("restrict") != want.get("restrict"):  # first: the flag to pass
        parts.insert(0, f"restrict the run's {have.get('restrict', 'points')}, asked "
                        f"{want.get('restrict', 'points')}: pass --restrict {have.get('restrict', 'points')}")
    return f"{key}: {', '.join(parts[:3])}{' ...' if len(parts) > 3 else ''}"


def finished_run(run: Path, pde, settings: dict, cfg: InteractiveConfig, seed: int) -> dict | None:
    """The summary (metrics.json) of a finished run in ``run`` trained with the settings this arm and seed would
    train with, None when there is none (or cfg.resume is False); ValueError (one line) for a finished run with
    other settings."""
    if not (cfg.resume and (run / "metrics.json").is_file() and (run / "model.pt").is_file()):
        return None
    again = "pass --overwrite (retrains every arm) or another --out"
    try:  # (a damaged one read as "other settings", every key None)
        readable = isinstance(json.loads((run / "run.json").read_text()), dict)
    except (OSError, ValueError):
        readable = False
    if not readable:
        raise ValueError(f"{run / 'run.json'} is damaged (not a JSON object); {again}")
    differ = arm_differs(run, pde, settings, cfg, seed, said=True)
    if differ:  # (first: what to pass to read it back, before whether its weights can be)
        raise ValueError(f"{run} holds a finished run with other settings ({'; '.join(differ)}); rerun with its "
                         "own settings to go on, or pass --overwrite (retrains every arm) or another --out")
    check_checkpoint_file(run / "model.pt", again)  # (torch's UnpicklingError, a traceback, after the test set)
    return json.loads((run / "metrics.json").read_text())


def _pde_differs(have, want: dict) -> list[str]:
    """How a comparison's PDE config (compare.json's "pde") differs from ``want`` in words: [] (the same), ["PDE
    (the comparison's NAME, asked NAME)"] or ["PDE settings (KEY: the comparison's A, asked B, ...)"] (it said
    "other the PDE", naming nothing)."""
    if have == want:
        return []
    if not isinstance(have, dict) or have.get("pde") != want.get("pde"):
        name = have.get("pde") if isinstance(have, dict) else have
        return [f"PDE (the comparison's {name}, asked {want.get('pde')})"]
    keys = [k for k in (*have, *(k for k in want if k not in have)) if have.get(k) != want.get(k)]
    parts = [f"{k}: the comparison's {have.get(k)}, asked {want.get(k)}" for k in keys]
    return [f"PDE settings ({'; '.join(parts[:3])}{' ...' if len(parts) > 3 else ''})"]


def check_same_comparison(out: Path, pde, cfg: InteractiveConfig) -> None:
    """ValueError (one line) when ``out`` holds a finished comparison (compare.json) of another PDE or other arms:
    going on there would replace its tables with those of a different comparison. More seeds are allowed (the
    finished ones are read back); --overwrite retrains in place."""
    done = out / "compare.json"
    if not (cfg.resume and done.is_file()):
        return
    have = json.loads(done.read_text())
    differ = ["--modes"] if list(have.get("config", {}).get("modes", [])) != list(cfg.modes) else []
    differ += _pde_differs(have.get("pde"), json.loads(json.dumps(pde.config())))
    if differ:
        raise ValueError(f"{out} holds a comparison with other {' and '.join(differ)}; rerun with its own settings to "
                         "go on, or pass --overwrite (retrains every arm) or another --out")
