"""pdestream command line: generate, inspect, stream-train and compare datasets of randomized PDE solutions.

Each subcommand parses its arguments and makes one library call. User errors (bad names, values, paths)
print one line ``pdestream: error: ...`` and exit with status 2; no traceback.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading


def _parse_sets(pairs: list[str] | None) -> dict[str, str]:
    """["nu=0.1", "ic.alpha=2"] -> {"nu": "0.1", "ic.alpha": "2"}; values stay strings for the PDE to parse."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"bad --set {pair!r}: expected KEY=VALUE, e.g. --set nu=0.01")
        out[key.strip()] = value.strip()
    return out


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


def configure_solvers(args: argparse.Namespace) -> None:
    """--solver-workers / --solver-timeout for this process and the producers it starts (one line if bad)."""
    from pdestream.generator.external import solver as external

    external.configure(getattr(args, "solver_workers", None), getattr(args, "solver_timeout", None))


def settings_from_args(name: str | None, args: argparse.Namespace) -> tuple[str | None, dict]:
    """(PDE name, settings) from the command line: the --config file's keys, then --set overrides."""
    settings: dict = {}
    option = getattr(args, "pde_option", None)
    if name and option and name != option:
        raise ValueError(f"the command names PDE {name!r} and --pde {option!r}; give one")
    name = name or option
    if getattr(args, "config", None):
        data = read_config(args.config)
        # either a [pde] table (with name = NAME) or top-level keys (with pde = NAME)
        table = dict(data["pde"]) if isinstance(data.get("pde"), dict) else dict(data)
        file_name = table.pop("name", None) or table.pop("pde", None)
        if file_name is not None and not isinstance(file_name, str):
            raise ValueError(f"config {args.config}: the PDE name must be a string such as \"burgers1d\", "
                             f"got {file_name!r}")
        if name and file_name and name != file_name:
            raise ValueError(f"the command names PDE {name!r} but config {args.config} is for {file_name!r}")
        name = name or file_name
        ic = table.get("ic")
        if isinstance(ic, dict) and "kind" not in ic:  # TOML `ic.alpha = 2.5`: the same key as --set ic.alpha=2.5
            table.pop("ic")
            table.update({f"ic.{k}": v for k, v in ic.items()})
        settings.update(table)
    settings.update(_parse_sets(getattr(args, "set", None)))
    return name or getattr(args, "pde_default", None), settings  # compare's burgers1d when nothing names a PDE


def read_config(path: str) -> dict:
    """A TOML config file as a dict; one-line ValueError naming the file if unreadable, not UTF-8 or not TOML."""
    import tomllib

    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as err:
        raise ValueError(f"cannot read config {path}: {err.strerror}") from None
    except UnicodeDecodeError as err:  # tomllib decodes the whole file as UTF-8 first
        raise ValueError(f"config {path} is not UTF-8 text (byte {err.object[err.start]:#04x} at offset "
                         f"{err.start}); save it as UTF-8") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"config {path} is not valid TOML: {err}") from None


def pde_from_args(name: str | None, args: argparse.Namespace, named: tuple[str | None, dict] | None = None):
    """The PDE named on the command line with --config then --set applied (``named``: the result of
    ``settings_from_args`` when the caller has it already, so the config file is read once)."""
    from pdestream import generator

    name, settings = settings_from_args(name, args) if named is None else named
    if name is None:
        raise ValueError("no PDE named: give one (see `pdestream list`) or a config with pde = NAME")
    return generator.get_pde(name, settings)


def cmd_list(args: argparse.Namespace) -> None:
    from pdestream import generator

    if args.name is not None:
        return _list_entry(generator.get_pde(args.name), args.json)
    if args.json:
        raise ValueError("--json goes with an entry name: pdestream list NAME --json")

    for group in generator.GROUPS:  # the catalog's groups, in order; each entry says its dimension
        names = [name for name in generator.PDES if generator.GROUP[name] == group]
        if names:
            print(f"== {group} ({len(names)}) ==\n")
        for name in names:
            pde = generator.get_pde(name)
            offered = getattr(pde, "BOUNDARIES", pde.grid.bc[:1])  # what `--set bc=` takes (a steady grid: its own)
            walls = (f"  bc: {', '.join(offered)} (--set bc={offered[1]}, or one axis: --set bc.x={offered[-1]})"
                     if len(offered) > 1 else f"  bc: {pde.grid.bc[0]} on every axis (fixed)")
            print(f"[{pde.NDIM}D] {pde.describe()}\n{walls}\n")
    mine = generator.user.names()  # your own PDEs: registered by Python or installed entry points
    if mine:
        print(f"== user ({len(mine)}) ==\n")
    for name in mine:
        try:
            pde = generator.get_pde(name)
        except ValueError as err:  # one broken entry point does not hide the rest of the list
            print(f"[?] {name}: cannot be loaded: {err}\n")
            continue
        where = pde.config().get("origin") or {}
        print(f"[{pde.NDIM}D] {pde.describe()}\n  from {where.get('module')}:{where.get('class')}\n")


def _list_entry(pde, as_json: bool) -> None:
    """Every setting of one entry: its value (the default), and for parameters their domain, meaning and units."""
    import json

    config = pde.config()
    rows = {key: {"default": value} for key, value in config.items() if key not in ("pde", "ic", "origin")}
    for name, spec in pde.PARAMS.items():
        rows[name].update(meaning=spec.description, units=spec.units)  # the default is its domain
    rows.update({f"ic.{k}": {"default": v} for k, v in config["ic"].items() if k != "kind"})
    rows["ic"] = {"default": config["ic"]["kind"], "allowed": pde.fitting_ic_kinds()}
    units = getattr(pde, "FIELD_UNITS", {})
    fields = {f: units.get(f, "?") for f in (*getattr(pde, "INPUTS", ()), *pde.FIELDS)}
    offered = getattr(pde, "BOUNDARIES", None)
    if offered:
        rows.setdefault("bc", {"default": "periodic"})["allowed"] = list(offered)
    if as_json:
        where = {"origin": config["origin"]} if "origin" in config else {}  # a user's PDE: where its code is
        print(json.dumps({"pde": pde.NAME, "equation": pde.EQUATION, **where, "fields": fields, "settings": rows},
                         indent=2))
        return
    print(pde.describe())
    if "origin" in config:  # a user's PDE: where its code is (its identity in caches and runs)
        print("  from {module}:{class} version {version!r} source sha256 {source_sha256}".format(**config["origin"]))
    print("\nfields (units): " + ", ".join(f"{f} [{u}]" for f, u in fields.items()))
    print("\nsettings (--set KEY=VALUE; parameters take uniform(a, b), loguniform(a, b), choice(...)):")
    for key, row in rows.items():
        extra = "".join(f"  {k}: {', '.join(v) if isinstance(v, list) else v}" for k, v in row.items() if k != "default")
        print(f"  {key} = {row['default']}{extra}")


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Adds "(default: X)" to an option's help unless it has none (None, a flag off, no list) or says it already."""

    def _get_help_string(self, action):
        none = action.default is None or action.default is False or action.default == []
        if none or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose --help shows defaults; subcommand parsers are of this class too."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)


def _version() -> str:
    """The installed package's version (importlib.metadata), or a note when running from an uninstalled tree."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pdestream")
    except PackageNotFoundError:
        return "(not installed: pip install -e .)"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pdestream", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("list", help="every PDE with its equation, fields, parameters and domains; with a NAME, "
                                    "every setting of that entry")
    p.add_argument("name", nargs="?", help="one entry: all its settings with their defaults, domains and units")
    p.add_argument("--json", action="store_true", help="with NAME: the settings as JSON")
    p.set_defaults(func=cmd_list)

    for add in (add_generate, add_inspect, add_export, add_import, add_train, add_compare):
        add(sub)
    return parser


# --- generate / inspect (datasets.cache) -------------------------------------------------------------
def add_generate(sub) -> None:
    p = sub.add_parser("generate", help="solve N samples and write them to an HDF5 (.h5) or Zarr (.zarr) cache",
                       description="Solve samples 0..N-1 of a PDE under a seed and write them block by block to "
                                   "a cache readable by xarray (see datasets/schema.py for the layout).")
    p.add_argument("pde", nargs="?", help="PDE name (see `pdestream list`); may come from --config instead")
    p.add_argument("--n", type=int, required=True, help="number of samples (global indices 0..N-1)")
    p.add_argument("--seed", type=int, default=0, help="sample i is a pure function of (config, seed, i)")
    p.add_argument("--out", required=True, metavar="PATH.h5|PATH.zarr", help="cache to write; format by suffix")
    _add_pde_config_args(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true", help="finish an interrupted cache of the same set-up")
    mode.add_argument("--overwrite", action="store_true",
                      help="replace an existing pdestream cache (the new one is built beside it and swapped in "
                           "only when complete; anything else at PATH is refused)")
    p.add_argument("--block", type=int, help="samples solved and written per block (default: ~32 MiB)")
    p.add_argument("--on-blowup", choices=("raise", "redraw", "skip"), default="raise",
                   help="a NaN/Inf (or failed external) trajectory stops the run (raise) or is redrawn "
                        "deterministically (redraw); skip is refused: a cache holds every index")
    p.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="local: this process; dask: one task per block on a Dask cluster (Zarr output only)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask: address of a running scheduler, e.g. tcp://host:8786 "
                                                          "(default: an embedded LocalCluster)")
    p.add_argument("--workers", type=int, metavar="N", help="dask: worker processes of the embedded cluster (default 2)")
    _add_solver_args(p)
    p.set_defaults(func=cmd_generate)


def cmd_generate(args: argparse.Namespace) -> None:
    configure_solvers(args)
    pde = pde_from_args(args.pde, args)
    try:
        _generate(pde, args)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(_left_after_interrupt(args.out, args.resume)) from None


def _left_after_interrupt(out: str, resume: bool) -> str:
    """What an interrupted `generate` left at ``out``, in words (the writer has cleaned up by now)."""
    from pathlib import Path

    from pdestream.datasets.cache import is_complete, open_cache

    if not Path(out).exists():
        return "nothing was written"
    try:
        with open_cache(out) as ds:
            done, total, complete = int((ds["complete"].values == 1).sum()), ds.sizes["sample"], is_complete(ds)
    except (ValueError, OSError):
        return f"{out} is left as it was"
    if complete:  # --overwrite: the old cache, untouched (its replacement was removed)
        return f"{out} is unchanged"
    return f"{out} holds {done} of {total} samples; run the command with --resume{'' if resume else ' added'} to finish it"


def _snapshot(d) -> dict[str, tuple[int, int]] | None:
    """{name: (inode, mtime ns)} of the entries of directory ``d``, or None when there is no such directory (the
    command will create it): what was there before a command, so an interrupt removes only what it created."""
    from pathlib import Path

    d = Path(d)
    if not d.is_dir():
        return None
    return {e.name: (e.stat().st_ino, e.stat().st_mtime_ns) for e in os.scandir(d)}


def _remove_created(d, before: dict[str, tuple[int, int]] | None) -> None:
    """Remove what the command created in directory ``d``: ``d`` itself if it did not exist before (``before`` is
    None), else its new entries and the files replaced since (atomic writes make a new inode); entries that were
    there and are unchanged, or directories that were there, stay."""
    import shutil
    from pathlib import Path

    d = Path(d)
    if before is None:
        shutil.rmtree(d, ignore_errors=True)
        return
    for e in list(os.scandir(d)) if d.is_dir() else []:
        if e.name in before and (e.is_dir(follow_symlinks=False) or before[e.name] == (e.stat().st_ino,
                                                                                        e.stat().st_mtime_ns)):
            continue
        if e.is_dir(follow_symlinks=False):
            shutil.rmtree(e.path, ignore_errors=True)
        else:
            Path(e.path).unlink(missing_ok=True)


def check_disk_room(pde, out: str, n: int) -> None:
    """Refuse (one line) a new cache that cannot fit on its disk: --n x the bytes of one sample vs the free space
    where it goes (a huge --n would otherwise run until the disk is full)."""
    import shutil
    from pathlib import Path

    from pdestream.datasets import max_index

    parent = Path(out).absolute().parent
    if not parent.is_dir() or isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= max_index() + 1:
        return  # the writer names these
    frames = 1 if getattr(pde, "STEADY", False) else pde.n_frames
    channels = len(pde.FIELDS) + len(getattr(pde, "INPUTS", ()))
    need = n * (4 * channels * frames * math.prod(pde.grid.shape) + 4 * len(pde.PARAMS) + 2)
    free = shutil.disk_usage(parent).free
    if need > free:
        raise ValueError(f"--n {n} makes a cache of {need / 2**30:,.1f} GiB ({need / n / 2**10:,.1f} KiB per sample); "
                         f"the disk at {parent} has {free / 2**30:,.1f} GiB free: lower --n or write elsewhere")


def _generate(pde, args: argparse.Namespace) -> None:
    from pdestream import datasets

    if not args.resume:
        check_disk_room(pde, args.out, args.n)

    kw = dict(seed=args.seed, resume=args.resume, overwrite=args.overwrite, block=args.block, on_blowup=args.on_blowup)
    if args.executor == "dask":
        from pdestream.datasets.distributed import write_cache_dask

        if args.scheduler and args.workers is not None:
            raise ValueError("--workers sizes the embedded cluster; with --scheduler the cluster has its own workers")
        done = write_cache_dask(pde, args.out, args.n, scheduler=args.scheduler, workers=args.workers or 2, **kw)
    elif args.scheduler or args.workers is not None:
        raise ValueError("--scheduler and --workers go with --executor dask")
    else:
        done = datasets.write_cache(pde, args.out, args.n, **kw)
    if args.resume and done.written == 0:
        print(f"{args.out} is already complete: all {done.n_samples} samples were written; nothing to solve")
        return
    print(done.line())


def add_inspect(sub) -> None:
    p = sub.add_parser("inspect", help="what a cache holds: PDE, config, completeness, parameter ranges, statistics")
    p.add_argument("path", help="cache file (.h5/.hdf5) or directory (.zarr)")
    p.add_argument("--plot", metavar="FILE.png", help="also draw a few samples (space-time for 1D, snapshots for 2D)")
    p.set_defaults(func=cmd_inspect)


def cmd_inspect(args: argparse.Namespace) -> None:
    from pdestream.datasets import inspect

    print(inspect.summary(args.path))
    if args.plot:
        print(f"plot: {inspect.plot(args.path, args.plot)}")


# --- export / import (datasets.export) ------------------------------------------------------------
def add_export(sub) -> None:
    p = sub.add_parser("export", help="write a complete cache in The Well's or PDEBench's HDF5 layout",
                       description="Write a complete cache as one HDF5 file that The Well's WellDataset or "
                                   "PDEBench's loaders read (layouts in datasets/export.py); `pdestream import` "
                                   "reads it back.")
    p.add_argument("cache", help="cache file (.h5/.hdf5) or directory (.zarr), complete")
    p.add_argument("--to", required=True, metavar="the-well|pdebench", help="the layout to write")
    p.add_argument("--out", required=True, metavar="FILE.hdf5",
                   help="file to write (The Well: put it in DIR/data/train/ and load WellDataset(path=DIR, "
                        "well_split_name='train'))")
    p.add_argument("--overwrite", action="store_true", help="replace an existing export written by pdestream "
                                                            "(anything else at FILE is refused)")
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> None:
    from pdestream.datasets.export import export_cache

    out = export_cache(args.cache, args.to, args.out, overwrite=args.overwrite)
    print(f"exported {args.cache} to {out} ({args.to})")


def add_import(sub) -> None:
    p = sub.add_parser("import", help="turn a file written by `pdestream export` back into a cache "
                                      "(then `train --source CACHE`)")
    p.add_argument("path", help="a The Well or PDEBench HDF5 file written by `pdestream export`")
    p.add_argument("--out", required=True, metavar="PATH.h5|PATH.zarr", help="cache to write (must not exist)")
    p.set_defaults(func=cmd_import)


def cmd_import(args: argparse.Namespace) -> None:
    from pdestream.datasets.export import exported_as, import_export

    out = import_export(args.path, args.out)
    print(f"imported {args.path} ({exported_as(args.path)}) to {out}")


# --- train / compare (surrogate) ---------------------------------------------------------------------
def _add_model_args(p: argparse.ArgumentParser, steps: int | None, batch_size: int, lr: float, lr_note: str = "") -> None:
    p.add_argument("--model", default="fno", help="fno or unet (fno1d/fno2d/fno3d/unet1d/... pin the dimension), or "
                   "your own: package.module:Class (an nn.Module built from ndim, in_channels, out_channels, n_params "
                   "and the --model-set keys)")
    p.add_argument("--model-set", action="append", metavar="KEY=VALUE", default=[],
                   help="model setting, e.g. --model-set width=64 --model-set modes=16 (unet: channels, depth)")
    p.add_argument("--view", default=None, choices=["next_step", "operator"],
                   help="training pairs: next_step (frames k -> k+1) or operator (u(t=0) -> u(t_end); a steady "
                        "PDE: input field -> solution) (default: train next_step, operator on a steady PDE; compare "
                        "operator)")
    p.add_argument("--k-in", type=int, default=1, help="next_step: input frames stacked into channels")
    p.add_argument("--k-out", type=int, default=1, help="next_step: predicted frames")
    p.add_argument("--steps", type=int, default=steps, help="optimizer steps" if steps is not None else
                   f"optimizer steps (default: {TRAIN_STEPS}); with --resume RUN_DIR: the run's new total, which "
                   "extends it, finished or not (the schedule is re-planned for the new total)")
    p.add_argument("--batch-size", type=int, default=batch_size, help="examples per optimizer step")
    p.add_argument("--lr", type=float, default=lr, help=f"peak learning rate (Adam, cosine decay{lr_note})")
    p.add_argument("--threads", type=int, default=None,
                   help="torch CPU threads (default: train: all cores but one, so the stream's solver thread, or on "
                        "a cache the loader and the OS, keep a core; compare: 1)")
    p.add_argument("--device", default="cpu",
                   help="where the model trains: cpu, cuda or cuda:N (the stream's JAX solver uses the GPU when "
                        "JAX's CUDA build is installed, and hands batches to torch there without a host copy)")


def _add_reservoir_args(p: argparse.ArgumentParser, train: bool) -> None:
    g = p.add_argument_group("training reservoir (Melissa-style reuse of solves; see datasets/reservoir.py)")
    if train:
        g.add_argument("--reservoir", action="store_true",
                       help="train through a training reservoir between the solver and the loop (--source stream)")
    g.add_argument("--capacity", type=int, default=512, help="trajectories the reservoir holds")
    g.add_argument("--max-reuse", type=float, default=16.0,
                   help="bound on uses per trajectory (1 use = the examples a FIFO pass takes from it); the loop "
                        "waits rather than exceed it")
    g.add_argument("--reservoir-mode", choices=("async", "deterministic"), default="async",
                   help="async: insert solves as they arrive (fast, not reproducible); deterministic: a fixed "
                        "schedule, batches a pure function of the settings, exact --resume")
    g.add_argument("--target-reuse", type=float, metavar="R",
                   help="pace the solver so each trajectory pays for about R uses (<= --max-reuse): a solver "
                        "faster than training then leaves its core to training (default: solve flat out)")
    g.add_argument("--proposal-floor", type=float, default=0.25,
                   help="loss-driven sampling: share of uniform parameter draws (no region starves)")
    g.add_argument("--proposal-ensemble", type=int, default=5, metavar="K",
                   help="active sampling: bootstrap loss models whose disagreement is the uncertainty signal (>= 2)")
    g.add_argument("--proposal-kappa", type=float, default=1.0,
                   help="active sampling: weight of that disagreement against the predicted log-loss")
    g.add_argument("--priority-power", type=float, default=1.0, metavar="A",
                   help="prioritized replay (--draw priority; compare's reservoir_priority and reservoir_active arms): "
                        "a trajectory is drawn in proportion to its last training error (per-example relative L2) ** A "
                        "(0: uniform)")
    g.add_argument("--priority-floor", type=float, default=0.25,
                   help="prioritized replay: share of uniform draws, in (0, 1]")
    g.add_argument("--solve-batch", type=int, help=f"trajectories per solver job (default: {SOLVE_BATCH['cpu']}; "
                                                    f"{SOLVE_BATCH['cuda']} with --device cuda, where small batches "
                                                    "leave the GPU idle)")
    if not train:
        return
    g.add_argument("--warmup", type=int, help="trajectories held before the first batch (default: capacity/4)")
    g.add_argument("--eviction", choices=("fifo", "random"), default="fifo", help="which used trajectory makes way")
    g.add_argument("--draw", choices=("uniform", "least_used", "priority"), default="uniform",
                   help="which trajectories a batch draws: at random, the least used first, or by their last "
                        "training loss (prioritized replay: --priority-power, --priority-floor)")
    g.add_argument("--producer", choices=("thread", "process", "dask"), default="thread",
                   help="who solves: a background thread, spawned processes, or a Dask cluster")
    g.add_argument("--workers", type=int, default=1, help="solver processes (--producer process, or an embedded Dask cluster)")
    g.add_argument("--scheduler", metavar="ADDRESS", help="--producer dask: a running scheduler, e.g. tcp://host:8786")
    g.add_argument("--proposal", choices=("uniform", "loss", "active"), default="uniform",
                   help="parameters of the next solves: the domain's own draws, steered toward high training loss, "
                        "or active (a loss model + its ensemble's disagreement over the parameter box)")
    g.add_argument("--on-blowup", choices=("raise", "redraw", "skip"), default="raise",
                   help="a failed solve (NaN/Inf; an external solver's error, timeout, crash, wrong shape) stops "
                        "the run (raise), is redrawn (redraw) or left out with one warning line (skip)")


RESERVOIR_OPTIONS = ("capacity", "max_reuse", "reservoir_mode", "target_reuse", "proposal_floor", "solve_batch",
                     "warmup", "eviction", "draw", "producer", "workers", "scheduler", "proposal",
                     "proposal_ensemble", "proposal_kappa", "on_blowup", "priority_power", "priority_floor")


def _check_priority_options(args: argparse.Namespace, used: bool, needs: str) -> None:
    """--priority-power / --priority-floor given where no draw is prioritized: one line (they would do nothing)."""
    given = [name for name, default in (("--priority-power", 1.0), ("--priority-floor", 0.25))
             if getattr(args, name[2:].replace("-", "_")) != default]
    if given and not used:
        raise ValueError(f"{', '.join(given)} {'goes' if len(given) == 1 else 'go'} with {needs} (prioritized replay)")


def _check_priority_cap(args: argparse.Namespace, used: bool) -> None:
    """--priority-cap where no prioritized arm runs at a simulation budget: one line (it would do nothing)."""
    if args.priority_cap != 4.0 and not used:
        raise ValueError(f"--priority-cap={args.priority_cap:g} goes with --sim-budget and the arms reservoir_active or "
                         "reservoir_priority (their reuse bound at a simulation budget)")


def _active_kwargs(args: argparse.Namespace) -> dict:
    """--proposal-ensemble / --proposal-kappa as ParamProposal settings (an ensemble < 2 is refused there, in one
    line: one model has no disagreement)."""
    return {"ensemble": args.proposal_ensemble, "kappa": args.proposal_kappa}


# trajectories per solver job by where training runs: on an H100 the FNO Burgers set-up's solver gave 179 traj/s at
# 128 and 1102 at 1024 (README, "The reservoir on the training device"); 16 suits a 2-core CPU's cache
SOLVE_BATCH = {"cpu": 16, "cuda": 128}


def solve_batch(args: argparse.Namespace) -> int:
    """--solve-batch, or its default for the training device."""
    if args.solve_batch is not None:
        return args.solve_batch
    return SOLVE_BATCH["cuda" if str(getattr(args, "device", "cpu")).startswith("cuda") else "cpu"]


def reservoir_cfg(args: argparse.Namespace) -> dict | None:
    """data_cfg for train_run from `train --reservoir ...` (None without --reservoir; its options without it are
    refused, naming them: they were silently ignored)."""
    if not args.reservoir:
        defaults = vars(build_parser().parse_args(["train", "x"]))
        given = [k for k in RESERVOIR_OPTIONS if getattr(args, k) != defaults[k]]
        if given:
            names = ", ".join("--" + k.replace("_", "-") for k in given)
            raise ValueError(f"{names} {'goes' if len(given) == 1 else 'go'} with --reservoir (the training "
                             "reservoir's settings); add --reservoir or drop them")
        return None
    if args.workers < 1:
        raise ValueError(f"--workers={args.workers} not allowed; must be >= 1 (solver processes or Dask workers)")
    if args.source != "stream":
        raise ValueError(f"--reservoir goes with --source stream (got --source {args.source})")
    _check_priority_options(args, args.draw == "priority", "--draw priority")
    cfg = {"kind": "reservoir", "capacity": args.capacity, "max_reuse": args.max_reuse, "warmup": args.warmup,
           "eviction": args.eviction, "draw": args.draw, "mode": args.reservoir_mode, "producer": args.producer,
           "workers": args.workers, "scheduler": args.scheduler, "proposal": args.proposal,
           "proposal_kwargs": {"floor": args.proposal_floor, **_active_kwargs(args)}, "solve_batch": solve_batch(args),
           "target_reuse": args.target_reuse, "on_blowup": None if args.on_blowup == "raise" else args.on_blowup,
           "priority_power": args.priority_power, "priority_floor": args.priority_floor}
    return {k: v for k, v in cfg.items() if v is not None}


def _add_mode_args(p: argparse.ArgumentParser, train: bool) -> None:
    from pdestream.surrogate.mode_table import DEFAULTS, MODE_NAMES, MODE_SPECS, takes

    g = p.add_argument_group("interactive training modes (see surrogate/modes.py)")
    if train:
        g.add_argument("--mode", default="one-step", choices=MODE_NAMES,
                       help="; ".join(f"{name}: {spec.help}" for name, spec in MODE_SPECS.items()))
    else:
        g.add_argument("--modes", metavar="M1,M2,...",
                       help="compare training modes at equal steps (rollout error against time): a comma-separated "
                            f"subset of {', '.join(MODE_NAMES)}")
        g.add_argument("--fine-n", type=int, metavar="N",
                       help="solver-in-the-loop: the fine grid (default: the PDE's n)")
    g.add_argument("--loss", choices=("mse", "relative"), default="mse",
                   help="training loss: mse (in normalized units) or relative (the mean per-example relative L2, the "
                        "FNO paper's: a trajectory with a small target weighs as much as any)"
                        + ("" if train else "; with --budget / --sim-budget"))
    g.add_argument("--unroll", type=int, default=None, metavar="K",
                   help=f"steps unrolled by {takes('unroll')} (default {DEFAULTS['unroll']})")
    g.add_argument("--coarse-n", type=int, metavar="N",
                   help=f"{takes('coarse_n')}: grid of the coarse solver, a divisor of the fine n "
                        f"(default {DEFAULTS['coarse_n']})")


def mode_cfg(args: argparse.Namespace) -> dict:
    """The `train --mode` settings for train_run: the mode table's defaults, one line for an option the mode does
    not take (surrogate.mode_table.mode_settings); --k-out is checked with the view (surrogate.modes)."""
    from pdestream.surrogate.mode_table import mode_settings

    settings = mode_settings(args.mode, unroll=args.unroll, coarse_n=args.coarse_n)
    return settings if args.loss == "mse" else {**settings, "loss": args.loss}


def _interactive_compare(args: argparse.Namespace) -> None:
    """`compare PDE --modes ...`: training modes at equal steps (surrogate.interactive_compare)."""
    from pathlib import Path

    from pdestream.experiments.interactive_compare import InteractiveConfig, interactive_compare

    if args.budget is not None or args.sim_budget is not None:
        raise ValueError("--modes compares at equal --steps; --budget and --sim-budget go with the data-route comparison")
    modes = tuple(m.strip() for m in args.modes.split(",") if m.strip())
    if args.quick:  # a tiny scale for tests and a first look
        args.set = ["n=32", "n_frames=11"] + list(args.set)
    pde = pde_from_args(args.pde, args)
    _set_threads(1 if args.threads is None else args.threads)
    model_cfg = ({"width": 8, "modes": 4, "layers": 2} if args.quick else {"width": 32, "modes": 12, "layers": 3}) \
        if args.model.startswith("fno") else {}
    model_cfg.update(_parse_sets(args.model_set))
    quick = args.quick and args.steps == 1000  # --quick without --steps: a few steps
    given = {"unroll": args.unroll, "coarse_n": 16 if args.quick and args.coarse_n is None else args.coarse_n}
    cfg = InteractiveConfig(modes=modes, **{k: v for k, v in given.items() if v is not None},  # else the mode table's
                            steps=20 if quick else args.steps, batch_size=8 if quick else args.batch_size, lr=args.lr,
                            model=args.model, model_cfg=model_cfg, k_in=args.k_in, seed=0,
                            n_test=4 if args.quick and args.test_samples == 128 else args.test_samples,
                            fine_n=args.fine_n, device=args.device)
    if args.k_out != 1:
        raise ValueError(f"--k-out={args.k_out} not allowed with --modes: every mode predicts one frame per step")
    interactive_compare(pde, args.out, cfg)
    print((Path(args.out) / "compare.md").read_text(), end="")
    print(f"table: {args.out}/compare.md, compare.csv, compare.json; figure: {args.out}/compare.png")


def default_threads(source: str, ranks: int = 1) -> int:
    """torch CPU threads for `train` without --threads: the cores this process may use minus one (at least 1).
    On the stream the solver thread needs that core (torch's threads fighting it ran 6x slower on 2 cores). On a
    cache the loader, the OS and other programs do: torch's spinning OpenMP threads on both cores of a busy
    2-core machine trained 17-30x slower than one thread (50 FNO steps of the README's command: 72.4 s vs 4.2 s,
    41.9 s vs 1.5 s), same losses. ``source`` ("stream" or a cache path) is kept for callers; both get this.
    ranks: processes training on this machine (--ddp N), which share its cores."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cores // ranks - 1)


def _set_threads(threads: int | None) -> None:
    import torch

    if threads is not None:
        if threads < 1:
            raise ValueError(f"--threads={threads} not allowed; must be >= 1")
        torch.set_num_threads(threads)


def _view_from_args(args, default: str):
    from pdestream import datasets

    name = args.view or default
    return datasets.make_view(name, k_in=args.k_in, k_out=args.k_out) if name == "next_step" else datasets.make_view(name)


def add_train(sub) -> None:
    p = sub.add_parser("train", help="train a surrogate (FNO / U-Net) on the stream or on a cache; --resume a run")
    p.add_argument("pde", nargs="?", help="PDE name (see `pdestream list`); may come from --config instead")
    p.add_argument("--source", default="stream", metavar="stream|PATH",
                   help="'stream' (solve on the fly), a cache written by `pdestream generate`, or a file written by "
                        "`pdestream export` (read through a temporary cache)")
    p.add_argument("--out", metavar="RUN_DIR", help="run directory (required for a new run; a resumed run keeps its own): run.json, "
                   "checkpoint.pt, metrics.csv/json, model.pt")
    p.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run from its checkpoint.pt, with the "
                                                       "settings of its run.json (only --threads, --steps and --ddp may go with it)")
    p.add_argument("--seed", type=int, default=0, help="model initialization and data seed")
    p.add_argument("--test-samples", type=int, default=32, help="held-out trajectories for the test errors")
    p.add_argument("--checkpoint-every", type=int, default=100, metavar="N",
                   help="write RUN_DIR/checkpoint.pt every N steps (0: only at the end)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run in RUN_DIR")
    p.add_argument("--ddp", type=int, metavar="N",
                   help="train on N ranks (processes started here; gloo on the CPU, nccl with --device cuda), each "
                        "with its own data (disjoint samples; --reservoir: a reservoir per rank), gradients averaged; "
                        "--batch-size is per rank. Under torchrun the ranks come from WORLD_SIZE instead. A run "
                        "resumes with the same N")
    _add_model_args(p, steps=None, batch_size=32, lr=1e-3)  # None: --steps given or not, known with --resume
    p.add_argument("--schedule", default="cosine", help="learning rate over the run: cosine (decay to 1%% of "
                   "--lr), onecycle (warm-up, then anneal) or constant (a run extended by --resume --steps "
                   "then equals one of that length)")
    _add_reservoir_args(p, train=True)
    _add_mode_args(p, train=True)
    _add_pde_config_args(p)
    _add_solver_args(p)
    p.set_defaults(func=cmd_train)


RUN_MARKERS = ("run.json", "checkpoint.pt", "model.pt", "metrics.json")  # any of them: the directory holds a run
# what may go with --resume: --threads (how, not what) and --steps (a new total, which extends the run)
RESUME_ALLOWED = {"resume", "threads", "steps", "ddp", "command", "func", "solver_workers", "solver_timeout"}
TRAIN_STEPS = 1000  # train's --steps for a new run (its default is None, so that --resume knows if it was given)


def _settings_given_with_resume(args: argparse.Namespace) -> list[str]:
    """The options (and PDE name) set on the command line besides --resume and --threads."""
    defaults = vars(build_parser().parse_args(["train", "--resume", "x"]))
    given = [k for k, v in vars(args).items() if k not in RESUME_ALLOWED and v != defaults.get(k)]
    return ["PDE name" if k == "pde" else "--pde" if k == "pde_option" else "--" + k.replace("_", "-") for k in given]


def _train_ranks(args: argparse.Namespace) -> int:
    """The ranks this `train` runs on: --ddp N, or torchrun's WORLD_SIZE (they must agree when both are set)."""
    from pdestream.surrogate.ddp import env_world

    env = env_world()
    if args.ddp is not None:
        if args.ddp < 1:
            raise ValueError(f"--ddp={args.ddp} not allowed; must be an integer >= 1 (ranks)")
        if env > 1 and args.ddp != env:
            raise ValueError(f"--ddp {args.ddp} but torchrun started {env} ranks (WORLD_SIZE={env}); drop --ddp or "
                             "make them agree")
    return env if env > 1 else (args.ddp or 1)


def cmd_train(args: argparse.Namespace) -> None:
    from pdestream.surrogate import ddp

    configure_solvers(args)  # (environment variables: spawned ranks and their producers inherit them)
    ranks = _train_ranks(args)
    if ranks > 1 and ddp.env_world() == 1:  # --ddp N: check here, then start the N ranks
        return _launch_train(args, ranks)
    try:
        _resume_train(args, ranks) if args.resume is not None else _new_train(args, ranks)
    finally:
        ddp.finish()


def _check_new_train(args: argparse.Namespace, ranks: int):
    """(pde, named settings, held run files) of a new `train`, after its checks (ValueError: one line)."""
    from pathlib import Path

    if args.out is None:
        raise ValueError("give --out RUN_DIR for a new run (or --resume RUN_DIR to continue one)")
    held = [name for name in RUN_MARKERS if (Path(args.out) / name).exists()]
    if held and not args.overwrite:
        raise FileExistsError(f"{args.out} already holds a run ({', '.join(held)}); pass --resume {args.out} to "
                              "continue it, --overwrite to replace it, or choose another --out")
    if args.source != "stream" and not Path(args.source).exists():
        raise FileNotFoundError(f"--source {args.source}: no such cache (or use --source stream)")
    named = settings_from_args(args.pde, args)  # the --config file, read once
    pde = pde_from_args(args.pde, args, named)
    if pde.STEADY and args.mode != "one-step":  # the modes' own refusal would send the user to --view next_step
        raise ValueError(f"--mode {args.mode} unrolls over frames and {pde.NAME} is steady (no frames); allowed: "
                         "--mode one-step")
    if args.test_samples < 1:
        raise ValueError(f"--test-samples={args.test_samples} not allowed; must be >= 1")
    if args.checkpoint_every < 0:
        raise ValueError(f"--checkpoint-every={args.checkpoint_every} not allowed; must be >= 0 (0: only at the end)")
    if ranks > 1 and args.source != "stream":
        raise ValueError(f"--ddp goes with --source stream (with or without --reservoir); a cache ({args.source}) is "
                         "not sharded across ranks")
    reservoir_cfg(args)  # its one-line refusals before any rank starts
    return pde, named, held


def _new_train(args: argparse.Namespace, ranks: int) -> None:
    from pathlib import Path

    from pdestream.surrogate import ddp
    from pdestream.surrogate.runs import remove_staging, replace_run, staging_dir, train_run

    pde, named, held = _check_new_train(args, ranks)
    _set_threads(default_threads(args.source, ranks) if args.threads is None else args.threads)
    ddp.init_from_env(args.device)  # several ranks: every rank has passed the checks once all have joined
    out = Path(args.out)
    kw = dict(model=args.model, model_cfg=_parse_sets(args.model_set),
              view=_view_from_args(args, "operator" if pde.STEADY else "next_step"),  # steady: no frames
              steps=TRAIN_STEPS if args.steps is None else args.steps, batch_size=args.batch_size, lr=args.lr,
              schedule=args.schedule, seed=args.seed, n_test=args.test_samples, explicit=named[1],
              checkpoint_every=args.checkpoint_every, data_cfg=reservoir_cfg(args), device=args.device,
              mode=mode_cfg(args))
    if ddp.world()[0] > 0:  # another rank than 0: trains, writes nothing, leaves the files and their clean-up to 0
        train_run(pde, args.source, out, **kw)
        return
    # --overwrite over a run: the new run is built beside it and moves in only when it finishes (or is interrupted
    # with a checkpoint, which is then worth resuming); a refusal, a divergence or an early Ctrl-C leave the old one
    target = staging_dir(out) if held else out
    before = _snapshot(target)
    try:
        s = train_run(pde, args.source, target, **kw)
    except KeyboardInterrupt:
        if target != out:
            raise KeyboardInterrupt(_overwrite_left(target, out)) from None
        raise KeyboardInterrupt(_train_left(out, before)) from None
    except BaseException:  # refused or failed: the old run stays as it was, and a new one without a checkpoint goes
        if target != out:
            remove_staging(target)
        else:
            _train_left(out, before)
        raise
    if target != out:
        replace_run(target, out)
    _print_run(s, args.model, args.source, args.test_samples, args.out)


def _overwrite_left(staging, out) -> str:
    """What an interrupted `train --overwrite` leaves, in words: the new run in place of the old one if it has a
    checkpoint to resume from, else the old run untouched (and the new one's files removed)."""
    from pdestream.surrogate.runs import CHECKPOINT, remove_staging, replace_run

    if (staging / CHECKPOINT).is_file():
        replace_run(staging, out)
        return f"{out} now holds the new run's checkpoint; pdestream train --resume {out} continues from it"
    remove_staging(staging)
    return f"nothing of the new run was kept (no checkpoint yet); {out} still holds the earlier run, untouched"


def _train_left(out, before) -> str:
    """What an interrupted fresh `train` leaves, in words. With a checkpoint the run stays for --resume. Without
    one nothing of the training is saved, so what the command created (run.json, the directory) is removed
    rather than kept for a resume from step 0: the same command then starts again, with no --overwrite."""
    if (out / "metrics.json").is_file():  # finished before the interrupt (or an old finished run, untouched)
        return f"{out} holds a finished run"
    if (out / "checkpoint.pt").is_file():
        return f"{out} holds a checkpoint; pdestream train --resume {out} continues from it"
    _remove_created(out, before)
    return "nothing was kept (no checkpoint yet); run the command again to start over"


def _resume_train(args: argparse.Namespace, ranks: int = 1) -> None:
    """`train --resume RUN_DIR`: everything from RUN_DIR/run.json; other settings are refused (one line)."""
    from pdestream.surrogate import ddp
    from pdestream.surrogate.runs import resume_run

    run = _check_resume(args, ranks)
    settings = run[0]
    _set_threads(default_threads(settings["source"], ranks) if args.threads is None else args.threads)
    steps = settings["steps"] if args.steps is None else args.steps
    ddp.init_from_env(settings.get("device", "cpu"))
    ddp.barrier()  # every rank has read run.json before rank 0 may rewrite it (an extension)
    writes = ddp.world()[0] == 0
    if steps != settings["steps"] and writes:
        print(f"extending {args.resume} from {settings['steps']} to {steps} steps at its step {run[1]['step']}; "
              f"the {settings.get('schedule', 'cosine')} schedule is re-planned for {steps} steps")
    s, step = resume_run(args.resume, run, steps)
    if writes:
        print(f"resumed {args.resume} at step {step} of {steps}")
        _print_run(s, settings["model"], settings["source"], settings["n_test"], args.resume)


def _check_resume(args: argparse.Namespace, ranks: int) -> tuple[dict, dict]:
    """read_run's (settings, checkpoint) of `train --resume RUN_DIR`, after its checks (ValueError: one line)."""
    from pathlib import Path

    from pdestream.surrogate.runs import RUN_FILE, check_ranks, read_run

    given = _settings_given_with_resume(args)
    if given:
        raise ValueError(f"--resume takes the run's settings from {Path(args.resume) / RUN_FILE}; "
                         f"drop {', '.join(given)} (only --threads, --steps and --ddp may go with it)")
    run = read_run(Path(args.resume), args.steps)  # refuse a non-run or a finished run before anything else
    check_ranks(args.resume, run[0], ranks)
    return run


def _launch_train(args: argparse.Namespace, ranks: int) -> None:
    """`train --ddp N`: the checks here (one line, before anything starts), then N spawned ranks that meet through
    a file; rank 0's output is shown, and the first failure's one line is raised here after the others are stopped.
    A reservoir with --producer dask and no --scheduler gets one embedded cluster here that every rank submits to."""
    import contextlib
    import multiprocessing as mp
    import tempfile
    from multiprocessing.connection import wait
    from pathlib import Path

    if args.resume is not None:
        data_cfg = _check_resume(args, ranks)[0]["data_cfg"] or {}
    else:
        _check_new_train(args, ranks)
        data_cfg = reservoir_cfg(args) or {}
    with tempfile.TemporaryDirectory(prefix="pdestream-ddp-") as tmp, contextlib.ExitStack() as stack:
        env = {}
        if data_cfg.get("producer") == "dask" and not data_cfg.get("scheduler"):
            # one pool for every rank: a cluster of --workers processes here, which all ranks' reservoirs submit to
            from pdestream.datasets.distributed import dask_client
            from pdestream.datasets.ranks import SHARED_SCHEDULER

            env[SHARED_SCHEDULER] = stack.enter_context(dask_client(None, data_cfg.get("workers", 1))).scheduler.address
        ctx = mp.get_context("spawn")  # JAX is not fork-safe
        procs = [ctx.Process(target=_train_rank, args=(r, ranks, args, tmp, env), daemon=False) for r in range(ranks)]
        for proc in procs:
            proc.start()
        interrupted = False
        try:
            while any(p.exitcode is None for p in procs) and all(p.exitcode in (None, 0) for p in procs):
                wait([p.sentinel for p in procs if p.exitcode is None], timeout=1.0)
        except KeyboardInterrupt:  # the terminal's Ctrl-C reached the ranks too: they leave as one process would
            interrupted = True
        for proc in procs:  # a failed rank leaves the others waiting in a collective: stop them
            proc.join(60 if interrupted else 0.5)
            if proc.exitcode is None:
                proc.terminate()
                proc.join()
        failed = [r for r, p in enumerate(procs) if p.exitcode != 0]
        if not failed and not interrupted:
            return
        said = [(Path(tmp) / f"rank{r}.err") for r in range(ranks)]
        said = [f.read_text() for f in said if f.is_file()]
        if interrupted or any(procs[r].exitcode == 130 for r in failed):
            raise KeyboardInterrupt(said[0] if said else "")
        if said:
            raise ValueError(said[0])
        log = Path(tmp) / f"rank{failed[0]}.log"
        tail = log.read_text().strip().splitlines()[-1:] if log.is_file() else []
        raise RuntimeError(f"rank {failed[0]} of {ranks} failed (exit code {procs[failed[0]].exitcode})"
                           + (f": {tail[0]}" if tail else ""))


def _train_rank(rank: int, ranks: int, args: argparse.Namespace, tmp: str, env: dict) -> None:
    """One rank of `train --ddp N` (a spawned process): the environment torchrun would give it (and ``env``: the
    shared Dask cluster's address), then `train`. Its user error goes to TMP/rank{rank}.err for the launcher to
    show once; ranks other than 0 print nothing."""
    from pathlib import Path

    from pdestream.surrogate.ddp import INIT_ENV

    os.environ.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(ranks), LOCAL_WORLD_SIZE=str(ranks),
                      **{INIT_ENV: f"file://{tmp}/rendezvous"}, **env)
    if rank > 0:  # their output would repeat rank 0's; a crash's traceback is kept for the launcher
        sys.stdout = open(os.devnull, "w")
        sys.stderr = open(Path(tmp) / f"rank{rank}.log", "w", buffering=1)
    try:
        cmd_train(args)
    except USER_ERRORS as err:
        (Path(tmp) / f"rank{rank}.err").write_text(str(err))
        sys.exit(2)
    except KeyboardInterrupt as err:
        (Path(tmp) / f"rank{rank}.err").write_text(str(err))
        sys.exit(130)


def _print_run(s: dict, model: str, source: str, n_test: int, out) -> None:
    mode = s.get("mode") or {"name": "one-step"}
    shown = {k: v for k, v in mode.items() if k != "name"}  # (unroll, coarse_n, loss when not mse)
    how = f" ({', '.join(f'{k} {v}' for k, v in shown.items())})" if shown else ""
    if mode["name"] != "one-step":
        how = f" --mode {mode['name']}{how}"
    on = f" on {s['ranks']} ranks" if s.get("ranks") else ""  # (each rank its own data; the counts are all ranks')
    print(f"trained {model}{how} on {source}{on} for {s['steps']} steps in {s['wall']:.1f} s "
          f"(waiting for data {s['t_data']:.1f} s = {100 * s['data_share']:.1f}% of the loop, normalization draw "
          f"included; computing {s['t_compute']:.1f} s); "
          f"{s['trajectories_seen']} trajectories, final loss {s['final_loss']:.4g}")
    t = s["test"]["test"]
    if mode["name"] == "solver-in-the-loop":  # the corrected coarse solver against the fine solution subsampled
        print(f"(errors on the coarse grid n={mode['coarse_n']}, against the fine solution subsampled)")
    print(f"test ({n_test} held-out trajectories): rel L2 {t['rel_l2']:.4f}, nRMSE {t['nrmse']:.4f}"
          + (f", rollout rel L2 at the last frame {t['rollout_final']:.4f}" if "rollout_final" in t else ""))
    if "data_stats" in s and "reuse_mean" in s["data_stats"]:
        d = s["data_stats"]
        who = f"rank 0's reservoir (of {s['ranks']} ranks)" if s.get("ranks") else "reservoir"
        print(f"{who}: {d['inserted']} trajectories solved, {d['evicted']} evicted, reuse mean {d['reuse_mean']:.2f} "
              f"(max {d['reuse_max']:.2f}); waiting for solves {100 * d['wait_share']:.1f}% of the time since the "
              "first batch (the reservoir's own clock: the loop's waiting share above also counts the normalization "
              "draw and handing batches over)")
    extra = ", reservoir.json, reservoir.png" if "data_stats" in s and "reuse_mean" in s["data_stats"] else ""
    print(f"run: {out}/metrics.csv, metrics.json, model.pt, checkpoint.pt{extra}")


def add_compare(sub) -> None:
    p = sub.add_parser("compare", help="the same model trained on a fixed cache vs the on-the-fly stream")
    p.add_argument("pde", nargs="?", help="PDE name (default burgers1d)")
    p.set_defaults(pde_default="burgers1d")
    p.add_argument("--out", required=True, metavar="DIR", help="output: compare.md/csv/json/png, cache, runs")
    p.add_argument("--cache-samples", type=int, default=32, metavar="M", help="size of the fixed cached set")
    p.add_argument("--seeds", type=int, help="model and data seeds per arm: mean, spread and, with a budget, a "
                   "verdict per metric (default: 3; a budget with --quick: 1)")
    p.add_argument("--test-samples", type=int, default=128, help="held-out trajectories per test set")
    p.add_argument("--shift", type=float, default=-0.25,
                   help="shifted test set: parameter domains moved this fraction of their width beyond the "
                        "training range (< 0: below the lower bound, > 0: above the upper bound)")
    p.add_argument("--shift-set", action="append", metavar="PARAM=DOMAIN", default=[],
                   help="explicit shifted domain, e.g. --shift-set nu='loguniform(0.1,0.2)'")
    p.add_argument("--format", default="h5", choices=["h5", "zarr"], help="cache format")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier compare output in DIR")
    b = p.add_argument_group("budget-matched comparison (precomputed / fifo / reservoir / reservoir_loss / "
                             "reservoir_active / reservoir_priority)")
    b.add_argument("--budget", type=float, metavar="SECONDS",
                   help="every arm gets this wall-clock time (solving, caching and training all count)")
    b.add_argument("--sim-budget", type=int, metavar="N",
                   help="every arm gets N solved trajectories and --steps optimizer steps")
    b.add_argument("--arms", default=",".join(BUDGET_ARMS), help="comma-separated subset of the arms (default: all "
                   "but the steered reservoir_active and reservoir_priority: add them by name)")
    b.add_argument("--priority-cap", type=float, default=4.0, metavar="C",
                   help="--sim-budget: the reuse bound of the prioritized-replay arms, in multiples of the mean reuse "
                        "(>= 1; their solves are paced at the mean)")
    b.add_argument("--precompute-share", type=float, default=None,
                   help="--budget: share of the precomputed arm's time spent solving its dataset (default: sized "
                        "as a careful user would: as many trajectories as it can solve and train on --max-reuse "
                        "times each in the budget, from the solver and training rates it measures)")
    b.add_argument("--sim-warmup-share", type=float, default=0.5,
                   help="--sim-budget: share of a reservoir arm's solves made before training starts (the rest are "
                        "paced over the run and, for reservoir_loss, steered)")
    b.add_argument("--quick", action="store_true",
                   help="a small scale for tests and a first look (n=64, 11 frames, small FNO, 20 s per arm)")
    _add_model_args(p, steps=1000, batch_size=32, lr=3e-3,
                    lr_note="; three times train's 1e-3, for the comparisons' small models and short runs")
    _add_reservoir_args(p, train=False)
    _add_mode_args(p, train=False)
    _add_pde_config_args(p)
    p.set_defaults(func=cmd_compare)


BUDGET_ARMS = ("precomputed", "fifo", "reservoir", "reservoir_loss")


COMPARE_DEFAULTS = {"n": "64", "n_frames": "11"}  # small enough for ~10 min on 2 CPU cores


def compare_sets(args: argparse.Namespace) -> list[str]:
    """COMPARE_DEFAULTS as --set items ahead of the user's own: never a finer grid than the entry's default (a 3D
    entry keeps its n=32; n=64 was 8x the points and a reservoir past the machine's memory) and only the settings
    the entry has (a steady one has no frames: darcy2d was refused for an n_frames the user never set)."""
    from pdestream import generator

    name, _ = settings_from_args(args.pde, args)
    try:
        base = generator.pde_class(name)()
    except (ValueError, TypeError):
        return list(args.set)  # pde_from_args refuses the name in its own words
    fields = base.config_fields()
    defaults = {k: (str(min(int(v), base.n)) if k == "n" else v) for k, v in COMPARE_DEFAULTS.items() if k in fields}
    return [f"{k}={v}" for k, v in defaults.items()] + list(args.set)


COMPARE_OUTPUTS = ("compare.md", "compare.csv", "compare.json", "compare.png", "cache.h5", "cache.zarr")
RUN_FILES = ("model.pt", "metrics.json", "arm.json", "run.json", "checkpoint.pt")


def check_compare_out(out: str, overwrite: bool) -> None:
    """Refuse an --out DIR that already holds compare output (tables, cache, run directories) unless
    --overwrite: like `train`, a second run must not silently replace the first one's results."""
    from pathlib import Path

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


def cmd_compare(args: argparse.Namespace) -> None:
    check_compare_out(args.out, args.overwrite)
    before = _snapshot(args.out)
    try:
        _compare(args)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(_compare_left(args.out, before)) from None


def _compare_left(out: str, before) -> str:
    """What an interrupted `compare` leaves, in words. Finished runs (and tables) are kept; without them nothing
    of value was written (a rerun rewrites the cache too), so what the command created in --out is removed."""
    from pathlib import Path

    d = Path(out)
    if not d.is_dir():
        return "nothing was written"
    tables = [n for n in ("compare.md", "compare.json") if (d / n).is_file()]
    runs = sorted(p.name for p in d.iterdir() if p.is_dir() and ((p / "metrics.json").is_file()
                                                                 or (p / "arm.json").is_file()))
    if tables or runs:
        kept = ", ".join(tables + [f"{r}/" for r in runs][:4]) + (", ..." if len(runs) > 4 else "")
        return (f"{out} keeps {len(runs)} finished run{'' if len(runs) == 1 else 's'} ({kept}); "
                "pass --overwrite to run the comparison again")
    _remove_created(d, before)
    return "nothing was kept (no run had finished)"


def _compare(args: argparse.Namespace) -> None:
    from pathlib import Path

    from pdestream.experiments.compare import CompareConfig, compare

    budget = args.budget is not None or args.sim_budget is not None or args.quick
    if args.loss != "mse" and (args.modes is not None or not budget):
        raise ValueError(f"--loss {args.loss} goes with --budget or --sim-budget (and with train), not with "
                         f"{'--modes' if args.modes is not None else 'the stream/cache comparison'}")
    if args.modes is not None or not budget:
        _check_priority_options(args, False, "compare --budget / --sim-budget")
        _check_priority_cap(args, False)
    if args.modes is not None:
        return _interactive_compare(args)
    if args.unroll is not None or args.coarse_n is not None or args.fine_n is not None:
        raise ValueError("--unroll, --coarse-n and --fine-n go with --modes (compare training modes)")
    if args.budget is not None or args.sim_budget is not None or args.quick:
        return _budget_compare(args)
    args.set = compare_sets(args)
    pde = pde_from_args(args.pde, args)
    _check_shift(pde, args)
    _set_threads(1 if args.threads is None else args.threads)
    from pdestream.surrogate.fno import COMPARE_FNO

    model_cfg = dict(COMPARE_FNO) if args.model.startswith("fno") else {}
    model_cfg.update(_parse_sets(args.model_set))
    args.seeds = 3 if args.seeds is None else args.seeds
    cfg = CompareConfig(model=args.model, model_cfg=model_cfg, view=_view_from_args(args, "operator"),
                        steps=args.steps, batch_size=args.batch_size, lr=args.lr, cache_samples=args.cache_samples,
                        seeds=tuple(range(args.seeds)), n_test=args.test_samples, shift=args.shift,
                        cache_format=args.format, device=args.device)
    compare(pde, args.out, cfg, shift_overrides=_parse_sets(args.shift_set))
    print((Path(args.out) / "compare.md").read_text(), end="")
    print(f"table: {args.out}/compare.md, compare.csv; figure: {args.out}/compare.png")


def _check_shift(pde, args: argparse.Namespace) -> None:
    """--shift and --shift-set checked (one line) before any cache or run is written: the shifted PDE is built
    once here the way the comparison builds it later (--shift 0 wrote a 256-sample cache before its refusal)."""
    from pdestream.experiments.compare import shifted_pde

    if args.shift != args.shift or args.shift in (float("inf"), float("-inf")):
        raise ValueError(f"--shift {args.shift} not allowed: a finite fraction like 0.25 or -0.25")
    try:
        shifted_pde(pde, args.shift, _parse_sets(args.shift_set))
    except ValueError as err:
        raise ValueError(str(err).replace("shift=0", "--shift 0")) from None


def _budget_compare(args: argparse.Namespace) -> None:
    """`compare --budget S | --sim-budget N [--quick]`: every arm at the same cost (surrogate.budget)."""
    from pathlib import Path

    from pdestream.experiments.budget import BudgetConfig, budget_compare

    if args.quick:
        args.set = compare_sets(args)
        if args.budget is None and args.sim_budget is None:
            args.budget = 20.0
            print("compare --quick: the budget comparison of the data routes (--arms) at --budget 20 seconds per "
                  "arm; --sim-budget N for equal solves, --modes M1,M2 for the training modes, no --quick for cache "
                  "vs stream", flush=True)
    pde = pde_from_args(args.pde, args)
    _check_shift(pde, args)
    _set_threads(1 if args.threads is None else args.threads)
    from pdestream.surrogate.fno import COMPARE_FNO

    small = dict(COMPARE_FNO)
    model_cfg = (small if args.quick else {"width": 64, "modes": 16, "layers": 4}) if args.model.startswith("fno") else {}
    model_cfg.update(_parse_sets(args.model_set))
    arms = tuple(a.strip() for a in args.arms.split(",") if a.strip())
    steered = bool({"reservoir_active", "reservoir_priority"} & set(arms))
    _check_priority_options(args, steered, "the arms reservoir_active or reservoir_priority")
    _check_priority_cap(args, steered and args.sim_budget is not None)
    cfg = BudgetConfig(budget_s=args.budget, sim_budget=args.sim_budget, arms=arms, model=args.model,
                       model_cfg=model_cfg, view=_view_from_args(args, "operator"), batch_size=args.batch_size,
                       lr=args.lr, steps=args.steps, precompute_share=args.precompute_share, capacity=args.capacity,
                       max_reuse=args.max_reuse, target_reuse=args.target_reuse, reservoir_mode=args.reservoir_mode,
                       sim_warmup_share=args.sim_warmup_share,
                       proposal_floor=args.proposal_floor, proposal_kwargs=_active_kwargs(args),
                       priority_power=args.priority_power, priority_floor=args.priority_floor,
                       priority_cap=args.priority_cap, solve_batch=solve_batch(args), n_test=32 if args.quick and args.test_samples == 128 else args.test_samples, shift=args.shift,
                       seeds=(1 if args.quick else 3) if args.seeds is None else args.seeds, device=args.device,
                       mode=None if args.loss == "mse" else {"name": "one-step", "loss": args.loss})
    budget_compare(pde, args.out, cfg, shift_overrides=_parse_sets(args.shift_set))
    print((Path(args.out) / "compare.md").read_text(), end="")
    print(f"table: {args.out}/compare.md, compare.csv, compare.json; figure: {args.out}/compare.png")


USER_ERRORS = (ValueError, FileExistsError, FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError)


def _first_interrupt(signum, frame) -> None:
    """SIGINT handler: the first Ctrl-C raises KeyboardInterrupt; later ones are ignored, so the clean-up it
    starts (removing a half-made cache, stopping solver threads) runs to its end and a second Ctrl-C cannot
    tear the interpreter down inside a JAX call ("terminate called ...", exit 134)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def _redeliver_interrupt(unraisable) -> None:
    """sys.unraisablehook: a Ctrl-C whose KeyboardInterrupt was raised where Python cannot raise (inside a gc
    callback of JAX's, a __del__) is sent again, instead of being printed and lost while the SIGINTs after it
    are ignored (a compare kept training); other unraisable errors go to the default hook."""
    if issubclass(unraisable.exc_type, KeyboardInterrupt):
        signal.signal(signal.SIGINT, _first_interrupt)
        # from another thread, a little later: sent from here it would be handled in this hook, and dropped again
        threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT)).start()
        return
    sys.__unraisablehook__(unraisable)


def _leave(code: int) -> None:
    """The command's exit after an interrupt's clean-up (caches, producers and clusters closed by then): at
    once, since a solver thread may still be inside a call or a compile, which interpreter shutdown would wait
    for (seconds) or tear down inside JAX (an abort). multiprocessing's exit hook still runs, so semaphores
    and child processes are released."""
    import multiprocessing.util

    multiprocessing.util._exit_function()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, _first_interrupt) if in_main else None
    hook = sys.unraisablehook
    if in_main:
        sys.unraisablehook = _redeliver_interrupt
    interrupted = False
    try:
        args.func(args)
    except USER_ERRORS as err:
        print(f"pdestream: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:
        interrupted = True
        print(f"pdestream: interrupted{f'; {err}' if str(err) else ''}", file=sys.stderr)
        if argv is None:  # the command itself, not an in-process call (tests)
            _leave(130)
        return 130
    except BrokenPipeError:  # output piped into `head`
        sys.stderr.close()
        return 0
    finally:
        # the command keeps ignoring SIGINT after an interrupt until it has exited (a Ctrl-C during interpreter
        # shutdown would kill it or abort it); an in-process caller gets its handler back
        if in_main and not (interrupted and argv is None):
            signal.signal(signal.SIGINT, previous if previous is not None else signal.default_int_handler)
            sys.unraisablehook = hook
    return 0


if __name__ == "__main__":
    sys.exit(main())
