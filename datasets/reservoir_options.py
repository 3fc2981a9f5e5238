"""The training reservoir's command-line options (``train --reservoir``, ``compare``'s reservoir arms) and the
reservoir settings they give (``reservoir_cfg``: train_run's data_cfg). argparse only: no torch, no JAX.
"""

from __future__ import annotations

import argparse

from .reservoir_config import DEFAULTS as R
from .reservoir_config import DRAWS, EVICTIONS, MODES, PROPOSAL_SPACES, PROPOSALS


def add_reservoir_args(p: argparse.ArgumentParser, train: bool) -> None:
    g = p.add_argument_group("training reservoir (Melissa-style reuse of solves; see datasets/reservoir.py)")
    if train:
        g.add_argument("--reservoir", action="store_true",
                       help="train through a training reservoir between the solver and the loop (--source stream)")
    g.add_argument("--capacity", type=int, default=R.capacity, help="trajectories the reservoir holds")
    g.add_argument("--max-reuse", type=float, default=R.max_reuse,
                   help="bound on uses per trajectory (1 use = the examples a FIFO pass takes from it); the loop "
                        "waits rather than exceed it")
    g.add_argument("--reservoir-mode", choices=MODES, default=R.mode,
                   help="async: insert solves as they arrive (fast, not reproducible); deterministic: a fixed "
                        "schedule, batches a pure function of the settings, exact --resume")
    g.add_argument("--target-reuse", type=_target, default=R.target_reuse, metavar="auto|off|R",
                   help="async mode: pace the solver so each trajectory pays for about R uses (<= --max-reuse), so a "
                        "solver faster than training leaves its core to training; auto: R chosen, and re-chosen as "
                        "the run goes, from measured rates so that solving costs training at most 5%% of its steps "
                        "(datasets/reservoir_pacer.py); off: solve flat out (default: auto)")
    g.add_argument("--proposal-floor", type=float, default=0.25,
                   help="steered sampling (loss, active, generative): share of uniform draws (no region starves)")
    g.add_argument("--proposal-gate", choices=("on", "off"), default="on",
                   help="steered sampling (loss, active, generative): steer only as far as the loss model's measured skill on "
                        "fresh solves allows (no skill: uniform draws); off: always steer 1 - floor of the draws")
    g.add_argument("--proposal-space", default="params", metavar="params|params+ic",
                   help="steered sampling (loss, active, generative): what the proposal steers, the PDE parameters alone or "
                        "jointly with the initial condition's latent coordinates (Fourier amplitudes and phases, a "
                        "GRF's leading white-noise modes, spot centres: generator.ics.LatentIC); default: params")
    g.add_argument("--proposal-ensemble", type=int, default=5, metavar="K",
                   help="active sampling: bootstrap loss models whose disagreement is the uncertainty signal (2-100)")
    g.add_argument("--proposal-kappa", type=float, default=1.0,
                   help="active sampling: weight of that disagreement against the predicted log-loss")
    g.add_argument("--priority-power", type=float, default=R.priority_power, metavar="A",
                   help="prioritized replay (--draw priority; compare's reservoir_priority and reservoir_active arms): "
                        "a trajectory is drawn in proportion to its last training error (per-example relative L2) ** A "
                        "(0: uniform)")
    g.add_argument("--priority-floor", type=float, default=R.priority_floor,
                   help="prioritized replay: share of uniform draws, in (0, 1]")
    g.add_argument("--solve-batch", type=int, help=f"trajectories per solver job (default: {R.solve_batch}; "
                                                    f"{SOLVE_BATCH_CUDA} with --device cuda, where small batches "
                                                    "leave the GPU idle)")
    if not train:
        return
    g.add_argument("--warmup", type=int, help="trajectories held before the first batch (default: the larger of "
                   "capacity/4 and --solve-batch)")
    g.add_argument("--eviction", choices=EVICTIONS, default=R.eviction, help="which used trajectory makes way")
    g.add_argument("--draw", choices=DRAWS, default=R.draw,
                   help="which trajectories a batch draws: at random, the least used first, or by their last "
                        "training loss (prioritized replay: --priority-power, --priority-floor)")
    g.add_argument("--producer", choices=("thread", "process", "dask"), default=R.producer,
                   help="who solves: a background thread, spawned processes, or a Dask cluster")
    g.add_argument("--workers", type=int, default=R.workers, help="solver processes (--producer process, or an embedded Dask cluster)")
    g.add_argument("--scheduler", metavar="ADDRESS", help="--producer dask: a running scheduler, e.g. tcp://host:8786")
    g.add_argument("--proposal", choices=PROPOSALS, default=R.proposal,
                   help="parameters of the next solves: the domain's own draws, steered toward high training loss, "
                        "active (a loss model + its ensemble's disagreement over the parameter box) or generative "
                        "(a Gaussian model of the high-difficulty fresh solves, drawn from)")
    g.add_argument("--on-blowup", choices=("raise", "redraw", "skip"), default=R.on_blowup,
                   help="a failed solve (NaN/Inf; an external solver's error, timeout, crash, wrong shape) stops "
                        "the run (raise), is redrawn (redraw) or left out with one warning line (skip)")


RESERVOIR_OPTIONS = ("capacity", "max_reuse", "reservoir_mode", "target_reuse", "proposal_floor", "proposal_gate",
                     "proposal_space",
                     "solve_batch", "warmup", "eviction", "draw", "producer", "workers", "scheduler", "proposal",
                     "proposal_ensemble", "proposal_kappa", "on_blowup", "priority_power", "priority_floor")


def _target(text: str):
    """--target-reuse: "auto", "off" or a number (checked against --max-reuse by ReservoirConfig)."""
    if text in ("auto", "off"):
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not auto, off or a number") from None


def _refuse_unused(args: argparse.Namespace, used: dict[str, bool], needs: str, why: str) -> None:
    """Options {dest: whether something uses it} given off their defaults where nothing uses them: one line naming
    them and what they go with (they were silently ignored)."""
    default = defaults(train=False)
    unused = ["--" + name.replace("_", "-") for name, u in used.items() if not u and getattr(args, name) != default[name]]
    if unused:
        raise ValueError(f"{', '.join(unused)} {'goes' if len(unused) == 1 else 'go'} with {needs}{why}")


def check_priority_options(args: argparse.Namespace, used: bool, needs: str) -> None:
    """--priority-power / --priority-floor given where no draw is prioritized: one line (they would do nothing)."""
    _refuse_unused(args, {"priority_power": used, "priority_floor": used}, needs, " (prioritized replay)")


def check_proposal_options(args: argparse.Namespace, floor_used: bool, active_used: bool, needs: str,
                           active_needs: str | None = None) -> None:
    """--proposal-floor, --proposal-gate, --proposal-space (the steered proposals: ``needs`` says which) /
    --proposal-ensemble, --proposal-kappa (active only: ``active_needs``, None: ``needs``) given where nothing uses
    them: one line naming each group with what it goes with (it named both groups' words for every option)."""
    default = defaults(train=False)
    groups = ((("proposal_floor", "proposal_gate", "proposal_space"), floor_used, needs),
              (("proposal_ensemble", "proposal_kappa"), active_used, active_needs or needs))
    parts, count = [], 0
    for names, used, where in groups:
        unused = ["--" + n.replace("_", "-") for n in names if not used and getattr(args, n) != default[n]]
        if unused:
            parts.append(f"{', '.join(unused)} {'goes' if len(unused) == 1 else 'go'} with {where}")
            count += len(unused)
    if parts:
        raise ValueError(f"{'; '.join(parts)}; nothing here uses {'it: drop it' if count == 1 else 'them: drop them'}")


def active_kwargs(args: argparse.Namespace) -> dict:
    """--proposal-ensemble / --proposal-kappa / --proposal-gate / --proposal-space as the proposal's settings (an
    ensemble < 2 is refused there, in one line: one model has no disagreement; a space other than params or
    params+ic here)."""
    space = getattr(args, "proposal_space", "params")
    if space not in PROPOSAL_SPACES:
        raise ValueError(f"--proposal-space={space!r} not allowed; allowed: {', '.join(PROPOSAL_SPACES)}")
    return {"ensemble": args.proposal_ensemble, "kappa": args.proposal_kappa,
            "gate": getattr(args, "proposal_gate", "on") == "on", **({"space": space} if space != "params" else {})}


# trajectories per solver job by where training runs: on an H100 the FNO Burgers set-up's solver gave 179 traj/s at
# 128 and 1102 at 1024 (README, "The reservoir on the training device"); 16 suits a 2-core CPU's cache
SOLVE_BATCH_CUDA = 128  # (on the CPU: ReservoirConfig's solve_batch)


def solve_batch(args: argparse.Namespace) -> int:
    """--solve-batch, or its default for the training device."""
    if args.solve_batch is not None:
        return args.solve_batch
    return SOLVE_BATCH_CUDA if str(getattr(args, "device", "cpu")).startswith("cuda") else R.solve_batch


def reservoir_cfg(args: argparse.Namespace) -> dict | None:
    """data_cfg for train_run from `train --reservoir ...` (None without --reservoir; its options without it are
    refused, naming them: they were silently ignored)."""
    if not args.reservoir:
        default = defaults()
        given = [k for k in RESERVOIR_OPTIONS if getattr(args, k) != default[k]]
        if given:
            names = ", ".join("--" + k.replace("_", "-") for k in given)
            raise ValueError(f"{names} {'goes' if len(given) == 1 else 'go'} with --reservoir (the training "
                             "reservoir's settings); add --reservoir or drop them")
        return None
    if args.workers < 1:
        raise ValueError(f"--workers={args.workers} not allowed; must be >= 1 (solver processes or Dask workers)")
    if args.source != "stream":
        raise ValueError(f"--reservoir goes with --source stream (got --source {args.source})")
    check_priority_options(args, args.draw == "priority", "--draw priority")
    check_proposal_options(args, args.proposal != "uniform", args.proposal == "active",
                           "--proposal loss / active / generative",
                           f"--proposal active (not {args.proposal})")
    check_numbers(args)
    cfg = {"kind": "reservoir", "capacity": args.capacity, "max_reuse": args.max_reuse, "warmup": args.warmup,
           "eviction": args.eviction, "draw": args.draw, "mode": args.reservoir_mode, "producer": args.producer,
           "workers": args.workers, "scheduler": args.scheduler, "proposal": args.proposal,
           "proposal_kwargs": {"floor": args.proposal_floor, **active_kwargs(args)}, "solve_batch": solve_batch(args),
           "target_reuse": args.target_reuse, "on_blowup": None if args.on_blowup == "raise" else args.on_blowup,
           "priority_power": args.priority_power, "priority_floor": args.priority_floor}
    return {k: v for k, v in cfg.items() if v is not None}


def check_numbers(args: argparse.Namespace) -> None:
    """`train --reservoir`'s numbers, one line each before torch is imported (they were refused when the reservoir
    and its proposal were built, after it): ``ReservoirConfig.checked`` against --batch-size (per rank), and the
    steered proposal's floor, ensemble and kappa by ``reservoir_config.PROPOSAL_RANGES`` (the table the proposal
    itself checks by)."""
    from .reservoir_config import ReservoirConfig, check_proposal_settings

    ReservoirConfig(capacity=args.capacity, max_reuse=args.max_reuse, warmup=getattr(args, "warmup", None),
                    eviction=getattr(args, "eviction", "fifo"), draw=getattr(args, "draw", "uniform"),  # (compare's)
                    priority_power=args.priority_power, priority_floor=args.priority_floor,
                    solve_batch=solve_batch(args), mode=args.reservoir_mode,
                    target_reuse=args.target_reuse).checked(getattr(args, "batch_size", 1))  # (none: a library's)
    check_proposal_settings(floor=args.proposal_floor, ensemble=args.proposal_ensemble, kappa=args.proposal_kappa)


def defaults(train: bool = True) -> dict:
    """The reservoir options' defaults {dest: value}, as `train` (or `compare`: ``train=False``) parses them."""
    p = argparse.ArgumentParser()
    add_reservoir_args(p, train=train)
    return vars(p.parse_args([]))
