"""pdestream command line: generate, inspect, stream-train and compare datasets of randomized PDE solutions.

Each subcommand parses its arguments into its library config and makes one library call: generate
(datasets.generate), inspect / export / import (datasets.inspect, datasets.export), train (surrogate.launch with a
TrainConfig), compare (experiments.command), list (generator.listing), recipes (pdestream.recipes: no JAX). Options
take their defaults from those configs. Nothing heavy (JAX, torch) is imported before the arguments are checked.
User errors print one line ``pdestream: error: ...`` and exit with status 2; no traceback (interrupts.run).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from pdestream.datasets.generate import GenerateConfig
from pdestream.datasets.reservoir_options import add_reservoir_args, reservoir_cfg
from pdestream.experiments.command import CompareCommand
from pdestream.interrupts import run
from pdestream.recipes import cli_command as recipes_command
from pdestream.settings import Parser, parse_sets, settings_from_args
from pdestream.surrogate.config import RESUME_ALLOWED, TRAIN_STEPS, TrainConfig

GENERATE, TRAIN, COMPARE = GenerateConfig(), TrainConfig(), CompareCommand()  # the options' defaults


def _version() -> str:
    """The installed package's version (importlib.metadata), or a note when running from an uninstalled tree."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("pdestream")
    except PackageNotFoundError:
        return "(not installed: pip install -e .)"


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="pdestream", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("list", help="every PDE with its equation, fields, parameters and domains; NAME: its settings")
    p.add_argument("name", nargs="?", help="one entry: all its settings with their defaults, domains and units")
    p.add_argument("--json", action="store_true", help="with NAME: the settings as JSON")
    p.set_defaults(func=cmd_list)
    p = sub.add_parser("recipes", help="published datasets (FNO, PDEBench) by name and source; show NAME: one")
    p.add_argument("args", nargs="*", metavar="show NAME", help="show NAME: a recipe's settings, splits, source")
    p.set_defaults(func=recipes_command)
    for add in (add_generate, add_inspect, add_export, add_import, add_train, add_compare):
        add(sub)
    return parser


def _add_pde_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override a PDE setting, e.g. --set nu='loguniform(1e-3,1e-2)' --set n=512 --set ic.alpha=2.5")
    p.add_argument("--config", metavar="FILE.toml", help="TOML file of settings (a [pde] table or top-level keys)")
    p.add_argument("--pde", dest="pde_option", metavar="NAME|package.module:Class",
                   help="the PDE, as the positional name does: a catalog entry, a registered or entry-point PDE, or "
                   "your own class by import path (see README 'Your own PDE')")


def _add_solver_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("external solvers (generator.ExternalSolver: your own solve() or command)")
    g.add_argument("--solver-workers", type=int, metavar="N",
                   help="worker processes that run an external solver's solves in parallel, per solving process "
                        "(default 1; 0: in the calling process, no timeout)")
    g.add_argument("--solver-timeout", type=float, metavar="SECONDS",
                   help="an external solve running longer fails (its worker is stopped), under --on-blowup")


# --- generate / inspect / export / import (datasets) ------------------------------------------------
def add_generate(sub) -> None:
    p = sub.add_parser("generate", help="solve N samples and write them to an HDF5 (.h5) or Zarr (.zarr) cache",
                       description="Solve samples 0..N-1 under a seed, block by block, into a cache (see schema.py)")
    p.add_argument("pde", nargs="?", help="PDE name (see `pdestream list`); may come from --config instead")
    p.add_argument("--n", type=int, help="number of samples (indices 0..N-1); with --split: its first N (default all)")
    p.add_argument("--seed", type=int, help="sample i is a pure function of (config, seed, i) (default: 0, or the --split's)")
    p.add_argument("--split", choices=("train", "valid", "test"), help="a recipe's split (its seed and size)")
    p.add_argument("--out", required=True, metavar="PATH.h5|PATH.zarr", help="cache to write; format by suffix")
    _add_pde_config_args(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true", help="finish an interrupted cache of the same set-up")
    mode.add_argument("--overwrite", action="store_true",
                      help="replace an existing pdestream cache (the new one is built beside it and swapped in "
                           "only when complete; anything else at PATH is refused)")
    p.add_argument("--block", type=int, default=GENERATE.block,
                   help="samples solved and written per block (default: ~32 MiB)")
    p.add_argument("--on-blowup", choices=("raise", "redraw", "skip"), default=GENERATE.on_blowup,
                   help="a NaN/Inf (or failed external) trajectory stops the run (raise) or is redrawn "
                        "deterministically (redraw); skip is refused: a cache holds every index")
    p.add_argument("--executor", choices=("local", "dask"), default=GENERATE.executor,
                   help="local: this process; dask: one task per block on a Dask cluster (Zarr output only)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask: address of a running scheduler, e.g. tcp://host:8786 "
                                                          "(default: an embedded LocalCluster)")
    p.add_argument("--workers", type=int, metavar="N", help="dask: worker processes of the embedded cluster (default 2)")
    _add_solver_args(p)
    p.set_defaults(func=cmd_generate)


def add_inspect(sub) -> None:
    p = sub.add_parser("inspect", help="what a cache holds: PDE, config, completeness, parameter ranges, statistics")
    p.add_argument("path", help="cache file (.h5/.hdf5) or directory (.zarr)")
    p.add_argument("--plot", metavar="FILE.png", help="also draw a few samples (space-time for 1D, snapshots for 2D, mid-slices for 3D)")
    p.add_argument("--stats", action="store_true", help="write the normalization statistics to CACHE.stats.yaml")
    p.set_defaults(func=cmd_inspect)


def add_export(sub) -> None:
    p = sub.add_parser("export", help="write a complete cache in The Well's or PDEBench's HDF5 layout",
                       description="Write a complete cache as one HDF5 file that The Well's WellDataset or PDEBench's "
                                   "loaders read (layouts in datasets/export.py); `pdestream import` reads it back.")
    p.add_argument("cache", help="cache file (.h5/.hdf5) or directory (.zarr), complete")
    p.add_argument("--to", required=True, metavar="the-well|pdebench", help="the layout to write")
    p.add_argument("--out", required=True, metavar="FILE.hdf5",
                   help="file to write (The Well: put it in DIR/data/train/ and load WellDataset(path=DIR, "
                        "well_split_name='train'))")
    p.add_argument("--overwrite", action="store_true", help="replace an existing export written by pdestream "
                                                            "(anything else at FILE is refused)")
    p.set_defaults(func=cmd_export)


def add_import(sub) -> None:
    p = sub.add_parser("import", help="a file written by `pdestream export` back into a cache (then train --source)")
    p.add_argument("path", help="a The Well or PDEBench HDF5 file written by `pdestream export`")
    p.add_argument("--out", required=True, metavar="PATH.h5|PATH.zarr", help="cache to write (must not exist)")
    p.set_defaults(func=cmd_import)


def cmd_list(args: argparse.Namespace) -> None:
    from pdestream.generator.listing import listing

    print(listing(args.name, args.json))


def cmd_generate(args: argparse.Namespace) -> None:
    name, settings = settings_from_args(args.pde, args)
    from pdestream.datasets.generate import generate

    print(generate(GenerateConfig(
        pde=name, n=args.n, out=args.out, settings=settings, seed=args.seed, resume=args.resume,
        overwrite=args.overwrite, block=args.block, on_blowup=args.on_blowup, executor=args.executor,
        scheduler=args.scheduler, workers=args.workers, solver_workers=args.solver_workers,
        solver_timeout=args.solver_timeout, split=args.split)))


def cmd_inspect(args: argparse.Namespace) -> None:
    from pdestream.datasets import inspect, stats

    print(inspect.summary(args.path, args.plot))  # (a bad --plot refused first)
    if args.plot:
        print(f"plot: {inspect.plot(args.path, args.plot)}")
    if args.stats:
        print(f"stats: {stats.write_stats(args.path)}")


def cmd_export(args: argparse.Namespace) -> None:
    from pdestream.datasets.export import export_cache

    print(f"exported {args.cache} to {export_cache(args.cache, args.to, args.out, args.overwrite)} ({args.to})")


def cmd_import(args: argparse.Namespace) -> None:
    from pdestream.datasets.export import exported_as, import_export

    out = import_export(args.path, args.out)
    print(f"imported {args.path} ({exported_as(args.path)}) to {out}")


# --- train / compare (surrogate, experiments) ----------------------------------------------------------
def _add_model_args(p: argparse.ArgumentParser, d, lr_note: str = "") -> None:
    """The model and optimizer options, their defaults from ``d`` (a TrainConfig or a CompareCommand)."""
    p.add_argument("--model", default=d.model, help="fno or unet (fno1d/fno2d/fno3d/unet1d/... pin the dimension), "
                   "or your own: package.module:Class (an nn.Module built from ndim, in_channels, out_channels, "
                   "n_params and the --model-set keys)")
    p.add_argument("--model-set", action="append", metavar="KEY=VALUE", default=[],
                   help="model setting, e.g. --model-set width=64 --model-set modes=16 (unet: channels, depth)")
    p.add_argument("--view", default=d.view, choices=["next_step", "operator"],
                   help="training pairs: next_step (frames k -> k+1) or operator (u(t=0) -> u(t_end); a steady "
                        "PDE: input field -> solution) (default: train next_step, operator on a steady PDE; compare "
                        "operator)")
    p.add_argument("--k-in", type=int, default=d.k_in, help="next_step: input frames (default 1; train: a recipe's)")
    p.add_argument("--k-out", type=int, default=d.k_out, help="next_step: predicted frames")
    p.add_argument("--steps", type=int, default=d.steps, help="optimizer steps" if d.steps is not None else
                   f"optimizer steps (default: {TRAIN_STEPS}); with --resume RUN_DIR: the run's new total, which "
                   "extends it, finished or not (the schedule is re-planned for the new total)")
    p.add_argument("--batch-size", type=int, default=d.batch_size, help="examples per optimizer step")
    p.add_argument("--lr", type=float, default=d.lr, help=f"peak learning rate (Adam, cosine decay{lr_note})")
    p.add_argument("--threads", type=int, default=d.threads,
                   help="torch CPU threads (default: train: all cores but one, so the stream's solver thread, or on "
                        "a cache the loader and the OS, keep a core; compare: 1)")
    p.add_argument("--device", default=d.device,
                   help="where the model trains: cpu, cuda or cuda:N (the stream's JAX solver uses the GPU when "
                        "JAX's CUDA build is installed, and hands batches to torch there without a host copy)")


def _add_mode_args(p: argparse.ArgumentParser, d) -> None:
    from pdestream.surrogate.mode_table import MODE_NAMES, MODE_SPECS, add_mode_options

    g = p.add_argument_group("interactive training modes (see surrogate/modes.py)")
    if isinstance(d, TrainConfig):
        g.add_argument("--mode", default=d.mode, choices=MODE_NAMES,
                       help="; ".join(f"{name}: {spec.help}" for name, spec in MODE_SPECS.items()))
    else:
        g.add_argument("--modes", metavar="M1,M2,...", help="compare training modes at equal steps (rollout error "
                       f"against time): a comma-separated subset of {', '.join(MODE_NAMES)}")
        g.add_argument("--fine-n", type=int, metavar="N", help="solver-in-the-loop: the fine grid (default: the PDE's n)")
    g.add_argument("--loss", choices=("mse", "relative"), default=d.loss,
                   help="training loss: mse (in normalized units) or relative (the mean per-example relative L2, the "
                        "FNO paper's: a trajectory with a small target weighs as much as any)"
                        + ("" if isinstance(d, TrainConfig) else "; with --budget / --sim-budget"))
    add_mode_options(g, d.unroll, compare=not isinstance(d, TrainConfig))  # the values: checked by the mode table
    if not isinstance(d, TrainConfig):
        g.add_argument("--pairs-steps", type=int, metavar="N", help="the corrector's pairs arms' steps (default --steps)")


def add_train(sub) -> None:
    d = TRAIN
    p = sub.add_parser("train", help="train a surrogate (FNO / U-Net) on the stream or on a cache; --resume a run")
    p.add_argument("pde", nargs="?", help="PDE name (see `pdestream list`); may come from --config or --source PATH")
    p.add_argument("--source", default=d.source, metavar="stream|PATH",
                   help="'stream' (solve on the fly), a cache written by `pdestream generate`, or a file written by "
                        "`pdestream export` (read through a temporary cache)")
    p.add_argument("--out", metavar="RUN_DIR", help="run directory (required for a new run; a resumed run keeps its "
                   "own): run.json, checkpoint.pt, metrics.csv/json, model.pt")
    p.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run from its checkpoint.pt, with the "
                   "settings of its run.json (only --threads, --steps and --ddp may go with it)")
    p.add_argument("--seed", type=int, default=d.seed, help="model initialization and data seed")
    p.add_argument("--test-samples", type=int, default=d.test_samples, help="held-out trajectories for the test errors")
    p.add_argument("--checkpoint-every", type=int, default=d.checkpoint_every, metavar="N",
                   help="write RUN_DIR/checkpoint.pt every N steps (0: only at the end)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run in RUN_DIR")
    p.add_argument("--ddp", type=int, metavar="N",
                   help="train on N ranks (processes started here; gloo on the CPU, nccl with --device cuda), each "
                        "with its own data (disjoint samples; --reservoir: a reservoir per rank), gradients averaged; "
                        "--batch-size is per rank. Under torchrun the ranks come from WORLD_SIZE instead. A run "
                        "resumes with the same N")
    _add_model_args(p, d)  # steps None: --steps given or not, known with --resume
    p.add_argument("--schedule", default=d.schedule, help="learning rate over the run: cosine (decay to 1%% of "
                   "--lr), onecycle (warm-up, then anneal) or constant (a run extended by --resume --steps "
                   "then equals one of that length)")
    add_reservoir_args(p, train=True)
    _add_mode_args(p, d)
    _add_pde_config_args(p)
    _add_solver_args(p)
    p.set_defaults(func=cmd_train)


def add_compare(sub) -> None:
    d = COMPARE
    p = sub.add_parser("compare", help="the same model trained on a fixed cache vs the on-the-fly stream")
    p.add_argument("pde", nargs="?", help=f"PDE name (default {d.pde})")
    p.set_defaults(pde_default=d.pde)
    p.add_argument("--out", required=True, metavar="DIR", help="output: compare.md/csv/json/png, cache, runs")
    p.add_argument("--cache-samples", type=int, default=d.cache_samples, metavar="M", help="size of the fixed cached set")
    p.add_argument("--seeds", type=int, default=d.seeds, help="model and data seeds per arm: mean, spread and, with a "
                   "budget or --modes, a verdict per metric (default: 3; a budget with --quick and --modes: 1)")
    p.add_argument("--only-seed", type=int, metavar="S", help="--modes: train (or read back) seed S of every arm and "
                   "stop, no tables: one process or machine per seed; the same command without it then reads every "
                   "seed back and writes them")
    p.add_argument("--only-arm", metavar="NAME[,NAME]", help="--modes: train (or read back) only these arms (their "
                   "directories in DIR, e.g. sitl_unroll1,sitl_unroll8) and stop, no tables; with --only-seed, that "
                   "seed of them")
    p.add_argument("--test-samples", type=int, default=d.test_samples, help="held-out trajectories per test set")
    p.add_argument("--shift", type=float, default=d.shift,
                   help="shifted test set (--modes: every arm rolled out on it too; not with --quick): parameter domains "
                        "moved this fraction of their width beyond the training range (< 0: below, > 0: above)")
    p.add_argument("--shift-set", action="append", metavar="PARAM=DOMAIN", default=[],
                   help="explicit shifted domain, e.g. --shift-set nu='loguniform(0.1,0.2)'")
    p.add_argument("--format", default=d.format, choices=["h5", "zarr"], help="cache format")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier compare output in DIR (--modes: "
                   "without it a rerun goes on, reading back each finished (arm, seed); with it every arm retrains)")
    b = p.add_argument_group("budget-matched comparison (precomputed / fifo / reservoir / reservoir_loss / "
                             "reservoir_active / reservoir_priority / reservoir_generative)")
    b.add_argument("--budget", type=float, metavar="SECONDS",
                   help="every arm gets this wall-clock time (solving, caching and training all count; --modes: each trained arm)")
    b.add_argument("--sim-budget", type=int, metavar="N",
                   help="every arm gets N solved trajectories and --steps optimizer steps")
    b.add_argument("--arms", default=",".join(d.arms), help="comma-separated subset of the arms (default: all "
                   "but the steered reservoir_active, reservoir_priority and reservoir_generative: add them by name)")
    b.add_argument("--priority-cap", type=float, default=d.priority_cap, metavar="C",
                   help="--sim-budget: the reuse bound of the prioritized-replay arms, in multiples of the mean reuse "
                        "(>= 1; their solves are paced at the mean)")
    b.add_argument("--precompute-share", type=float, default=d.precompute_share,
                   help="--budget: share of the precomputed arm's time spent solving its dataset (default: sized "
                        "as a careful user would: as many trajectories as it can solve and train on --max-reuse "
                        "times each in the budget, from the solver and training rates it measures)")
    b.add_argument("--sim-warmup-share", type=float, default=d.sim_warmup_share,
                   help="--sim-budget: share of a reservoir arm's solves made before training starts (the rest are "
                        "paced over the run and, for reservoir_loss, steered)")
    b.add_argument("--quick", action="store_true",
                   help="a small scale for tests and a first look (n=64, 11 frames, small FNO, 20 s per arm)")
    _add_model_args(p, d, lr_note="; three times train's 1e-3, for the comparisons' small models and short runs")
    add_reservoir_args(p, train=False)
    _add_mode_args(p, d)
    _add_pde_config_args(p)
    p.set_defaults(func=cmd_compare)


def _given_with_resume(args: argparse.Namespace) -> list[str]:
    """The options (and PDE name) set on the command line besides those that may go with --resume."""
    defaults = vars(build_parser().parse_args(["train", "--resume", "x"]))
    allowed = {*RESUME_ALLOWED, "command", "func"}
    given = [k for k, v in vars(args).items() if k not in allowed and v != defaults.get(k)]
    return ["PDE name" if k == "pde" else "--pde" if k == "pde_option" else "--" + k.replace("_", "-") for k in given]


def train_config(args: argparse.Namespace) -> TrainConfig:
    """The TrainConfig of `train`'s arguments (one line for options that do not go together)."""
    if args.resume is not None:
        given = _given_with_resume(args)
        if given:
            raise ValueError(f"--resume takes the run's settings from {Path(args.resume) / 'run.json'}; drop "
                             f"{', '.join(given)} (only --threads, --steps and --ddp may go with it" + (
                                 "; the run restricts as it started: a run.json without \"restrict\" by points"
                                 if "--restrict" in given else "") + ")")
        cfg = TrainConfig(resume=args.resume, threads=args.threads, steps=args.steps, ddp=args.ddp,
                          solver_workers=args.solver_workers, solver_timeout=args.solver_timeout)
        cfg.check_resume()
        return cfg
    if args.out is None:
        raise ValueError("give --out RUN_DIR for a new run (or --resume RUN_DIR to continue one)")
    name, settings = settings_from_args(args.pde, args)  # the --config file, read once
    cfg = TrainConfig(
        pde=name, settings=settings, source=args.source, out=args.out, overwrite=args.overwrite, seed=args.seed,
        test_samples=args.test_samples, checkpoint_every=args.checkpoint_every, ddp=args.ddp, model=args.model,
        model_cfg=parse_sets(args.model_set, "--model-set"), view=args.view, k_in=args.k_in, k_out=args.k_out, steps=args.steps,
        batch_size=args.batch_size, lr=args.lr, schedule=args.schedule, threads=args.threads, device=args.device,
        mode=args.mode, loss=args.loss, unroll=args.unroll, coarse_n=args.coarse_n, noise=args.noise,
        corrector_start=args.corrector_start, clip=args.clip, remat=args.remat, restrict=args.restrict,
        solver_workers=args.solver_workers, solver_timeout=args.solver_timeout)
    cfg.check()  # its own values first (a cache with --ddp is named as such, not as a cache with --reservoir)
    cfg.reservoir = reservoir_cfg(args)
    return cfg


def cmd_train(args: argparse.Namespace) -> None:
    cfg = train_config(args)
    from pdestream.surrogate.launch import train

    train(cfg)


def compare_command(args: argparse.Namespace) -> CompareCommand:
    """The CompareCommand of `compare`'s arguments."""
    name, settings = settings_from_args(args.pde, args)
    reservoir = {k: getattr(args, k) for k in ("capacity", "max_reuse", "reservoir_mode", "target_reuse",
                                               "proposal_floor", "proposal_gate", "proposal_space", "proposal_ensemble",
                                               "proposal_kappa", "priority_power", "priority_floor", "solve_batch")}
    return CompareCommand(
        pde=name, out=args.out, settings=settings, overwrite=args.overwrite, cache_samples=args.cache_samples,
        seeds=args.seeds, only_seed=args.only_seed,
        only_arms=tuple(a.strip() for a in (args.only_arm or "").split(",") if a.strip()), test_samples=args.test_samples, shift=args.shift, shift_set=parse_sets(args.shift_set, "--shift-set"),
        format=args.format, budget=args.budget, sim_budget=args.sim_budget,
        arms=tuple(a.strip() for a in args.arms.split(",") if a.strip()), priority_cap=args.priority_cap,
        precompute_share=args.precompute_share, sim_warmup_share=args.sim_warmup_share, quick=args.quick,
        model=args.model, model_cfg=parse_sets(args.model_set, "--model-set"), view=args.view, k_in=args.k_in, k_out=args.k_out,
        steps=args.steps, batch_size=args.batch_size, lr=args.lr, threads=args.threads, device=args.device,
        modes=None if args.modes is None else tuple(args.modes.split(",")), fine_n=args.fine_n, loss=args.loss,
        unroll=args.unroll, coarse_n=args.coarse_n, noise=args.noise, corrector_start=args.corrector_start,
        unroll_schedule=args.unroll_schedule, pairs_steps=args.pairs_steps, clip=args.clip, remat=args.remat,
        restrict=args.restrict, reservoir=reservoir)


def cmd_compare(args: argparse.Namespace) -> None:
    cmd = compare_command(args)
    from pdestream.experiments.command import run_compare

    print(run_compare(cmd))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if argv is None:  # the `pdestream` command: a plug-in's import path (mypdes.damped:Damped) resolves in the
        importable_here()  # current directory, as with `python -m` (the console script's sys.path lacks it)
    return run(lambda: args.func(args), standalone=argv is None)


def importable_here() -> None:
    """The current directory at the end of sys.path (the only sys.path edit of the package), if not there."""
    here = os.getcwd()
    if not any((p or ".") in (here, ".") or os.path.abspath(p or ".") == here for p in sys.path):
        sys.path.append(here)


if __name__ == "__main__":
    sys.exit(main())
