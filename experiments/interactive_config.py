"""What every arm of ``compare --modes`` shares (``InteractiveConfig``) and each arm's mode settings, without
torch: ``InteractiveConfig.check`` refuses a bad value in one line before the comparison's modules (and torch)
are imported (``experiments.interactive_compare`` runs it)."""

from __future__ import annotations

from dataclasses import dataclass, field

from pdestream.surrogate.checks import check_count, check_number
from pdestream.surrogate.mode_table import (
    DEFAULTS,
    MODE_NAMES,
    MODE_SPECS,
    NETWORK_MODES,
    check_corrector_start,
    check_noise,
    mode_settings,
    parse_unroll_schedule,
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
    seed and the test set's; seeds: how many (seed, seed + 1, ...); resume: read back finished (arm, seed) runs;
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
    resume: bool = True
    device: str = "cpu"
    budget_s: float | None = None
    pairs_steps: int | None = None

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
        self.noise = check_noise(self.noise)  # a bad --noise is refused even without the noise arm
        check_corrector_start(self.corrector_start)  # (and a bad --corrector-start without the corrector arms)
        for name, value in (("--steps", self.steps), ("--batch-size", self.batch_size), ("--test-samples", self.n_test),
                            ("--k-in", self.k_in), ("--seeds", self.seeds)):
            check_count(name, value)
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
        longest = max([self.unroll, *(k for k, _ in self.schedule() or ())])
        if pde.n_frames < self.k_in + longest + 1:
            raise ValueError(f"--unroll {longest} needs trajectories of at least {self.k_in + longest + 1} "
                             f"frames; {pde.NAME} has n_frames={pde.n_frames}")
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
