"""The training modes' table: names, settings, defaults, checks and help, in one place (no torch: the CLI's
parser reads it for its choices and help without loading the models).

``surrogate.modes`` implements each mode (``MODES``, one class per row here); ``mode_settings`` turns what a
user gave (the CLI, a config, run.json) into a mode's complete settings or one line naming what is wrong.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from ..boundaries import kinds
from .checks import check_count

# a setting's default for every mode that takes it
DEFAULTS = {"unroll": 4, "coarse_n": 64, "noise": 0.01, "corrector_start": "random", "unroll_schedule": None,
            "clip": None, "remat": False, "restrict": "fourier"}
# how a correction network starts: "random" (the model's own initialisation) or "zero" (its output layer's weights and
# bias set to zero, so the corrected solver starts as the coarse solver alone: Mosaic's correctors start this way)
CORRECTOR_STARTS = ("random", "zero")
# how the corrector restricts a fine periodic field to its coarse grid: "fourier" (the modes the coarse grid holds,
# the coarse Nyquist mode zeroed: the mean kept, a resolved field mapped to itself) or "points" (every factor-th
# point: the fine modes beyond the coarse Nyquist alias; every run.json without "restrict" was restricted so)
RESTRICTS = ("fourier", "points")


@dataclass(frozen=True)
class ModeSpec:
    """One training mode: its settings (a subset of DEFAULTS' keys), whether it predicts with a network alone
    (False: a network corrects a coarse solver, which the comparisons set against that solver alone) and its
    help line."""

    name: str
    settings: tuple[str, ...]
    network: bool
    help: str
    defaults: tuple[tuple[str, object], ...] = ()  # (setting, default) where the mode's differs from DEFAULTS

    def default(self, key: str):
        """This mode's default for setting ``key``."""
        return dict(self.defaults).get(key, DEFAULTS[key])


MODE_SPECS = {spec.name: spec for spec in (
    ModeSpec("one-step", (), True, "frames -> next frames"),
    ModeSpec("pushforward", ("unroll",), True,
             "unroll the network K-1 steps without gradient, train the K-th"),
    ModeSpec("oracle", ("unroll",), True,
             "train on states the network reaches in 0..K steps, labelled by the solver"),
    ModeSpec("solver-in-the-loop", ("unroll", "coarse_n", "noise", "corrector_start", "unroll_schedule", "clip",
                                    "remat", "restrict"), False,
             "a correction network on a coarse differentiable solver, unrolled K steps, against the fine solve "
             "(--noise SIGMA: the coarse start state perturbed, the fine target clean; default 0; "
             "--corrector-start zero: the correction's output layer starts at zero)",
             defaults=(("noise", 0.0),)),
    ModeSpec("noise", ("noise",), True,
             "Gaussian noise on the input frames (random walk, the newest frame's std SIGMA x the data's std), "
             "target the clean next frames (Sanchez-Gonzalez et al. 2020)"),
)}
MODE_NAMES = tuple(MODE_SPECS)
NETWORK_MODES = tuple(name for name, spec in MODE_SPECS.items() if spec.network)
# run.json's words for the noise mode's rule (``surrogate.modes.Noise``), beside its scale
NOISE_RULE = ("x + eps, eps a Gaussian random walk over the k_in input frames whose newest frame has std noise x the "
              "data's std per channel (frame j of k_in: noise x sqrt(j / k_in)); target the clean next k_out frames")
# run.json's words for the noise on the corrector's start state (``surrogate.modes.SolverInTheLoop``, noise > 0)
SITL_NOISE_RULE = ("s0 + eps, s0 the coarse start state (the fine state restricted to the coarse grid), eps ~ N(0, "
                   "noise^2) per channel and point in normalized units (noise x the data's std); the coarse solver and "
                   "the correction step from s0 + eps, the fine targets clean")
# how the CLI spells each setting
OPTION = {"unroll": "--unroll", "coarse_n": "--coarse-n", "noise": "--noise", "corrector_start": "--corrector-start",
          "unroll_schedule": "--unroll-schedule", "clip": "--clip", "remat": "--remat",
          "restrict": "--restrict"}


def takes(setting: str) -> str:
    """The modes that take ``setting``, in words ("pushforward, oracle or solver-in-the-loop")."""
    names = [n for n, spec in MODE_SPECS.items() if setting in spec.settings]
    return ", ".join(names[:-1]) + " or " + names[-1] if len(names) > 1 else names[0]


def mode_settings(name: str, **given) -> dict:
    """The complete settings {"name", ...} of mode ``name`` from the settings given (None: the default);
    ValueError (one line) for an unknown mode, a setting it does not take, or a bad value."""
    if name not in MODE_SPECS:
        raise ValueError(f"unknown mode {name!r}; allowed: {', '.join(MODE_SPECS)}")
    spec = MODE_SPECS[name]
    unknown = sorted(k for k in given if k not in DEFAULTS)
    if unknown:
        raise ValueError(f"unknown mode setting(s) {unknown}; allowed: name, {', '.join(DEFAULTS)}")
    for key, value in given.items():
        if key not in spec.settings and value not in (None, False) and not (key == "unroll" and value == 1):
            raise ValueError(f"{OPTION[key]}={value} goes with {takes(key)}, not {name}")
    out = {"name": name}
    for key in spec.settings:
        value = spec.default(key) if given.get(key) is None else given[key]
        out[key] = CHECKS.get(key, lambda v: check_count(OPTION[key], v))(value)
    if out.get("unroll_schedule") and max(k for k, _ in out["unroll_schedule"]) != out["unroll"]:
        raise ValueError(f"--unroll-schedule's longest unroll {max(k for k, _ in out['unroll_schedule'])} must equal "
                         f"the mode's unroll {out['unroll']} (the frames each training window holds)")
    return out


def check_unroll_schedule(value) -> list | None:
    """A solver-in-the-loop unroll curriculum in optimizer steps: None (a fixed unroll) or [[unroll, steps], ...],
    each a positive integer, phases in order (after the last, its unroll goes on); else one line."""
    if value is None:
        return None
    try:
        phases = [[int(k), int(n)] for k, n in value]
        ok = bool(phases) and all(k == k0 and n == n0 and not isinstance(k0, bool) and k > 0 and n > 0
                                  for (k, n), (k0, n0) in zip(phases, value))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"unroll_schedule={value!r} not allowed; a list of [unroll, optimizer steps] pairs of "
                         "positive integers, e.g. [[1, 300], [4, 300], [16, 400]]")
    return phases


def parse_unroll_schedule(text: str, steps: int) -> list[list[int]]:
    """``--unroll-schedule`` "K1:S1,K2:S2,...": unroll Ki for the share Si of ``steps`` optimizer steps, in order
    (shares > 0 summing to 1; each phase gets round(cumulative share x steps) - the previous boundary, at least one
    step) -> [[K1, N1], ...] in steps (``check_unroll_schedule``); else one line naming the value."""
    rule = (f"--unroll-schedule {text!r} not allowed; allowed: UNROLL:SHARE pairs, comma-separated, each unroll a "
            "positive integer and each share of the optimizer steps > 0, the shares summing to 1, e.g. "
            "1:0.3,4:0.3,16:0.4")
    try:
        pairs = [part.split(":") for part in str(text).split(",")]
        phases = [(int(k), float(share)) for k, share in pairs]
    except ValueError:
        raise ValueError(rule) from None
    if not phases or any(k < 1 or not 0 < share <= 1 for k, share in phases) or abs(
            sum(share for _, share in phases) - 1) > 1e-6:
        raise ValueError(rule)
    out, done, total = [], 0, 0.0
    for k, share in phases:
        total += share
        end = round(min(total, 1.0) * steps)
        if end - done < 1:
            raise ValueError(f"--unroll-schedule {text!r}: the phase of unroll {k} gets no optimizer step of "
                             f"--steps {steps}; raise its share or --steps")
        out.append([k, end - done])
        done = end
    return out


def check_corrector_start(value) -> str:
    """The corrector's start, one of CORRECTOR_STARTS, else one line naming the value and what is allowed."""
    if value not in CORRECTOR_STARTS:
        raise ValueError(f"--corrector-start={value!r} not allowed; allowed: {', '.join(CORRECTOR_STARTS)} (random: the "
                         "model's own initialisation; zero: its output layer set to zero, the coarse solver at step 0)")
    return value


def check_noise(value) -> float:
    """The noise scale as a float: a finite number >= 0 (a fraction of the data's std; the CLI passes the text
    as typed, "0.05"), else one line naming the value and what is allowed."""
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            number = None
    else:
        number = value
    if (isinstance(number, bool) or not isinstance(number, numbers.Real) or not math.isfinite(number)
            or number < 0):
        raise ValueError(f"--noise={value!r} not allowed; must be a finite number >= 0: the std of the input noise "
                         f"as a fraction of the data's std (e.g. {DEFAULTS['noise']}; 0: no noise)")
    return float(number)


def check_clip(value) -> float | None:
    """The gradient clipping norm: None (no clipping) or a finite number > 0 (the CLI passes the text as typed),
    else one line naming the value and what is allowed."""
    if value is None:
        return None
    try:
        number = float(value) if isinstance(value, (str, numbers.Real)) and not isinstance(value, bool) else None
    except ValueError:
        number = None
    if number is None or not math.isfinite(number) or number <= 0:
        raise ValueError(f"--clip={value!r} not allowed; must be a finite number > 0: the largest global norm of "
                         "the gradient (clipped to it before each optimizer step), e.g. 1.0")
    return number


def check_restrict(value) -> str:
    """The fine -> coarse restriction of periodic axes, one of RESTRICTS, else one line naming the value."""
    if value not in RESTRICTS:
        raise ValueError(f"--restrict={value!r} not allowed; allowed: {', '.join(RESTRICTS)} (fourier: the coarse "
                         "grid's Fourier modes of the fine field; points: every factor-th fine point)")
    return value


def check_remat(value) -> bool:
    """Rematerialisation on or off: a bool, else one line."""
    if not isinstance(value, bool):
        raise ValueError(f"remat={value!r} not allowed; true or false")
    return value


CHECKS = {"noise": check_noise, "corrector_start": check_corrector_start, "unroll_schedule": check_unroll_schedule,
          "clip": check_clip, "remat": check_remat, "restrict": check_restrict}  # the settings that are not counts


def check_coarse_grid(pde, coarse_n) -> None:
    """Solver-in-the-loop's coarse grid against the fine PDE ``pde`` (a generator Problem, JAX-free to build): a
    proper divisor of its n, on a PDE without ``refine``, which the PDE itself accepts as n; else one line. No torch:
    ``compare --modes`` and ``train --mode`` refuse it before the corrector is built (``SolverInTheLoop.bind``)."""
    n = pde.n
    if getattr(pde, "refine", 1) > 1:  # the coarse solver would carry it: its grid n = coarse_n * refine
        raise ValueError(f"solver-in-the-loop: refine={pde.refine} not allowed: the coarse solver steps the fine "
                         f"states restricted to its own grid; allowed: refine=1 (--set n={n * pde.refine} "
                         "--set refine=1 trains on the fine grid itself)")
    if isinstance(coarse_n, bool) or not isinstance(coarse_n, int) or not (0 < coarse_n < n and n % coarse_n == 0):
        example = _coarse_example(pde)
        allowed = (f"allowed: a proper divisor of {n}, e.g. {example}" if example else
                   f"no proper divisor of {n} is a grid {pde.NAME} takes: choose a finer grid")
        raise ValueError(f"solver-in-the-loop: coarse n={coarse_n!r} does not fit the fine grid n={n}; {allowed}")
    try:
        pde.replace({"n": coarse_n})
    except ValueError as err:  # the PDE's refusal speaks of n, which the user set as --coarse-n
        raise ValueError(f"solver-in-the-loop: --coarse-n {coarse_n} not allowed: {err}") from None


# the target frames per window each mode reads from a next-step view (``surrogate.modes``' frames_ahead): the view's
# k_out ("k_out"), its unroll ("unroll"), or 1 (the oracle's targets come from the solver)
FRAMES_AHEAD = {"one-step": "k_out", "pushforward": "unroll", "oracle": 1, "solver-in-the-loop": "unroll",
                "noise": "k_out"}


def frames_ahead(name: str, unroll: int, k_out: int) -> int:
    """The target frames per window mode ``name`` reads (FRAMES_AHEAD) at this unroll and k_out."""
    ahead = FRAMES_AHEAD[name]
    return unroll if ahead == "unroll" else k_out if ahead == "k_out" else ahead


def check_mode_k_in(name: str, k_in) -> None:
    """One line for input frames a mode cannot take: solver-in-the-loop corrects one state at a time (k_in None:
    not given). No torch: train and compare say it before any work (``SolverInTheLoop.train_view`` again)."""
    if name == "solver-in-the-loop" and k_in not in (None, 1):
        raise ValueError(f"--mode solver-in-the-loop corrects one state at a time: --k-in={k_in} not allowed; use 1")


def check_window(name: str, unroll: int, k_in: int, frames_out: int, n_frames: int,
                 more: str = "--set n_frames={n}") -> None:
    """ValueError (one line) when mode ``name``'s window, ``k_in`` input frames and ``frames_out`` targets, is
    longer than trajectories of ``n_frames``, naming what would fit (``more``: how to get n frames, "--set
    n_frames={n}" on the stream, a cache of them). No torch: ``train --source CACHE`` checks it against the cache's
    frames before torch, ``surrogate.modes.check_fits`` against the data's."""
    if k_in + frames_out <= n_frames:
        return
    ahead = FRAMES_AHEAD.get(name, "k_out")
    what = {"unroll": f"--unroll {unroll} and --k-in {k_in}",
            "k_out": f"--k-in {k_in} and --k-out {frames_out}"}.get(ahead, f"--k-in {k_in}")
    raise ValueError(f"--mode {name} with {what} needs {k_in + frames_out} frames per window but the trajectories "
                     f"have {n_frames}; allowed: {_fits_hint(ahead, frames_out, n_frames, k_in, more)}")


def _fits_hint(ahead, frames_out: int, n_frames: int, k_in: int, more: str) -> str:
    """What would fit: a shorter unroll where the mode unrolls and one exists (it said "--unroll <= -2" when --k-in
    alone was too long, and offered --unroll to one-step and noise, which take none), else fewer input frames, else
    more frames."""
    if ahead == "unroll" and n_frames - k_in >= 1:
        return f"--unroll <= {n_frames - k_in}"
    if n_frames - frames_out >= 1:
        return f"--k-in <= {n_frames - frames_out} (or {more.format(n=k_in + frames_out)})"
    return f"{more.format(n=k_in + frames_out)} or more"


def _coarse_example(pde) -> int | None:
    """A coarse grid to offer on ``pde``'s fine grid: n/8 where that is a whole grid of >= 8, else the largest proper
    divisor, the first that the PDE itself accepts as n (it offered 15 on n=30 to a PDE of even n), or None."""
    n = pde.n
    first = [n // 8] if n % 8 == 0 and n // 8 >= 8 else []
    for d in first + [d for d in range(n // 2, 0, -1) if n % d == 0]:
        try:
            pde.replace({"n": d})
            return d
        except ValueError:
            continue
    return None


def restricts_periodic(bc, locations) -> bool:
    """Whether ``--restrict`` acts on a fine grid of per-axis ``bc`` (boundary words; None: periodic) whose fields
    sit at ``locations`` (a staggered grid's per-field locations; empty or None: none): a periodic axis and no
    staggered fields (these take cell / face means whatever ``--restrict`` says)."""
    return not locations and (bc is None or any(b.periodic for b in kinds(bc)))


def pde_restricts_periodic(pde) -> bool:
    """``restricts_periodic`` of a generator Problem (its grid's bc and FIELD_LOCATIONS; no JAX, no torch)."""
    return restricts_periodic(tuple(pde.grid.bc), getattr(pde, "FIELD_LOCATIONS", {}))


def check_restrict_acts(pde, restrict) -> None:
    """An explicit ``--restrict`` on a fine grid it does not act on (no periodic axis, or staggered fields: these
    take cell / face means) refused in one line naming what the grid does instead; None (not given) passes."""
    if restrict is not None and not pde_restricts_periodic(pde):
        why = "staggered (MAC) fields" if getattr(pde, "FIELD_LOCATIONS", {}) else "no periodic axis"
        raise ValueError(f"--restrict {restrict} does not act on {pde.NAME} ({why}: the corrector takes cell / face "
                         "means of the fine field whatever it says); drop --restrict")


def option_help() -> dict:
    """The CLI's help text of each mode setting, by setting (cli.py's --unroll, --coarse-n, --noise, ...): kept beside
    the settings they describe, so the parser stays a list of options."""
    return {
        "unroll": f"steps unrolled by {takes('unroll')} (default {DEFAULTS['unroll']})",
        "coarse_n": f"{takes('coarse_n')}: grid of the coarse solver, a divisor of the fine n (default "
                    f"{DEFAULTS['coarse_n']})",
        "noise": f"noise: std of the input noise on the newest input frame (default {DEFAULTS['noise']}); "
                 "solver-in-the-loop: std of the noise on the coarse start state, the fine target clean (train: "
                 "default 0; compare --modes: the arm 'pairs + noise'); a fraction of the data's std, a number >= 0",
        "corrector_start": f"{takes('corrector_start')}: how the correction network starts (default "
                           f"{DEFAULTS['corrector_start']}): random, the model's own initialisation; zero, its output "
                           "layer set to zero, so the corrected solver starts as the coarse solver (compare --modes: "
                           "every corrector arm)",
        "clip": "solver-in-the-loop: clip the gradient's global norm to NORM before each optimizer step (long "
                "unrolls; default: no clipping); recorded in run.json, the steps clipped in metrics.json",
        "remat": "solver-in-the-loop: rematerialise each unrolled step in the backward pass (memory of about two "
                 "steps' activations and solver residuals instead of K: long unrolls, large grids; each step's "
                 "forward runs twice)",
        "restrict": "solver-in-the-loop: how a fine field is restricted to the coarse grid on periodic axes (start "
                    "states, targets, references; compare --modes: every corrector arm and the coarse solver): fourier "
                    "(default: the Fourier modes the coarse grid holds, its Nyquist mode zeroed; keeps the mean) or "
                    "points (every factor-th point: aliases the fine modes beyond the coarse Nyquist; the runs "
                    "written before the option). Axes with walls and staggered fields: cell / face means either way",
        "unroll_schedule": "solver-in-the-loop arm: an unroll curriculum (Um et al. 2020), unroll Ki for the share Si "
                           "of --steps, in order (shares summing to 1), e.g. 1:0.3,4:0.3,16:0.4; recorded in run.json",
    }


def add_mode_options(group, unroll_default: int | None, compare: bool) -> None:
    """The training modes' settings as options of an argparse ``group`` (train and compare alike; compare also
    --unroll-schedule): each defaults to None (the mode's own default) and is checked by ``mode_settings``."""
    hint = option_help()
    group.add_argument("--unroll", type=int, default=unroll_default, metavar="K", help=hint["unroll"])
    group.add_argument("--coarse-n", type=int, metavar="N", help=hint["coarse_n"])
    group.add_argument("--noise", metavar="SIGMA", help=hint["noise"])
    group.add_argument("--corrector-start", metavar="|".join(CORRECTOR_STARTS), help=hint["corrector_start"])
    group.add_argument("--clip", metavar="NORM", help=hint["clip"])
    group.add_argument("--remat", action="store_true", help=hint["remat"])
    group.add_argument("--restrict", metavar="|".join(RESTRICTS), help=hint["restrict"])
    if compare:
        group.add_argument("--unroll-schedule", metavar="K1:S1,K2:S2,...", help=hint["unroll_schedule"])
