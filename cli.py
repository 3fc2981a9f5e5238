"""pdestream command line: generate, inspect, stream-train and compare datasets of randomized PDE solutions.

Each subcommand parses its arguments and makes one library call. User errors (bad names, values, paths)
print one line ``pdestream: error: ...`` and exit with status 2; no traceback.
"""

from __future__ import annotations

import argparse
import sys


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


def pde_from_args(name: str, args: argparse.Namespace):
    """The PDE named on the command line with --config then --set applied."""
    import generator

    settings: dict = {}
    if getattr(args, "config", None):
        import tomllib

        try:
            with open(args.config, "rb") as f:
                data = tomllib.load(f)
        except OSError as err:
            raise ValueError(f"cannot read config {args.config}: {err.strerror}") from None
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"config {args.config} is not valid TOML: {err}") from None
        data = data.get("pde", data)
        name = data.pop("name", data.pop("pde", name)) if name is None else name
        ic = data.pop("ic", None)
        if isinstance(ic, dict):
            settings["ic"] = ic
        elif ic is not None:
            settings["ic"] = ic
        settings.update(data)
    settings.update(_parse_sets(getattr(args, "set", None)))
    if name is None:
        raise ValueError("no PDE named: give one (see `pdestream list`) or a config with pde = NAME")
    return generator.get_pde(name, settings)


def cmd_list(args: argparse.Namespace) -> None:
    import generator

    for name in generator.PDES:
        print(generator.get_pde(name).describe())
        print()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pdestream", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("list", help="every PDE with its equation, fields, parameters and domains")
    p.set_defaults(func=cmd_list)

    for add in (add_generate, add_inspect, add_train, add_compare, add_bench):
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
    mode.add_argument("--overwrite", action="store_true", help="replace an existing cache")
    p.add_argument("--block", type=int, help="samples solved and written per block (default: ~32 MiB)")
    p.add_argument("--on-blowup", choices=("raise", "redraw"), default="raise",
                   help="a NaN/Inf trajectory stops the run (raise) or is redrawn deterministically (redraw)")
    p.set_defaults(func=cmd_generate)


def cmd_generate(args: argparse.Namespace) -> None:
    import datasets

    pde = pde_from_args(args.pde, args)
    done = datasets.write_cache(pde, args.out, args.n, seed=args.seed, resume=args.resume, overwrite=args.overwrite,
                                block=args.block, on_blowup=args.on_blowup)
    print(done.line())


def add_inspect(sub) -> None:
    p = sub.add_parser("inspect", help="what a cache holds: PDE, config, completeness, parameter ranges, statistics")
    p.add_argument("path", help="cache file (.h5/.hdf5) or directory (.zarr)")
    p.add_argument("--plot", metavar="FILE.png", help="also draw a few samples (space-time for 1D, snapshots for 2D)")
    p.set_defaults(func=cmd_inspect)


def cmd_inspect(args: argparse.Namespace) -> None:
    from datasets import inspect

    print(inspect.summary(args.path))
    if args.plot:
        print(f"plot: {inspect.plot(args.path, args.plot)}")


# --- train / compare (surrogate) ---------------------------------------------------------------------
def add_train(sub) -> None:
    pass


def add_compare(sub) -> None:
    pass


# --- bench (benchmarks) ------------------------------------------------------------------------------
def add_bench(sub) -> None:
    pass


USER_ERRORS = (ValueError, FileExistsError, FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except USER_ERRORS as err:
        print(f"pdestream: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pdestream: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head`
        sys.stderr.close()
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
