"""One entry point for every benchmark family: ``python -m benchmarks [--quick] [--only generator,cache] [--json OUT.json]``.

Each family is a module ``benchmarks/<family>_bench.py`` with ``main(argv)``; the families present are run in
order (generator: pdestream vs Exponax; stream: TrajectoryStream delivered vs raw; cache: write/read;
dask: distributed generation; reservoir: reservoir vs FIFO; interactive: the solver as oracle
and differentiable step vs a plain solve; producer: external solvers vs a plain loop, workers and Dask). ``--json`` goes to the generator benchmark. Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from pathlib import Path

FAMILIES = ("generator", "stream", "cache", "dask", "reservoir", "interactive", "darcy", "producer")


def available() -> list[str]:
    return [f for f in FAMILIES if importlib.util.find_spec(f"benchmarks.{f}_bench") is not None]


# what a benchmark family imports beyond the base install, and the extra that provides it
NEEDS = {"generator": ("exponax", "bench"), "dask": ("distributed", "dask")}


def check_extras(families: list[str]) -> None:
    """ValueError naming the pip extra to install when a chosen family's optional package is missing."""
    missing = [(f, *NEEDS[f]) for f in families if f in NEEDS and importlib.util.find_spec(NEEDS[f][0]) is None]
    if missing:
        need = "; ".join(f"the {f} benchmark needs {pkg}: pip install -e '.[{extra}]'" for f, pkg, extra in missing)
        others = [f for f in families if f not in {m[0] for m in missing}]
        hint = f" (or run the others: python -m benchmarks --only {','.join(others)})" if others else ""
        raise ValueError(need + hint)


def check_json_target(json_out: str | None) -> None:
    """ValueError before any benchmark runs when --json names a directory or a file in a missing directory."""
    if json_out is None:
        return
    where = Path(json_out).absolute()
    if where.is_dir() or not where.parent.is_dir():
        raise ValueError(f"--json {json_out} not allowed: "
                         + ("it is a directory" if where.is_dir() else f"its directory {where.parent} does not exist")
                         + "; give a file in an existing directory")


def run(only: list[str] | None = None, quick: bool = False, json_out: str | None = None) -> None:
    """Run the chosen (default: all available) families, printing each one's table."""
    families = available()
    chosen = only or families
    bad = [f for f in chosen if f not in families]
    if bad:
        raise ValueError(f"unknown benchmark family {', '.join(bad)}; allowed: {', '.join(families)}")
    for family in chosen:
        argv = ["--quick"] if quick else []
        if family == "generator" and json_out:
            argv += ["--json", json_out]
        print(f"\n=== {family} benchmark ===", flush=True)
        importlib.import_module(f"benchmarks.{family}_bench").main(argv)
        sys.stdout.flush()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smaller, faster runs of every family")
    p.add_argument("--only", help=f"comma-separated families (default: all of {', '.join(available())})")
    p.add_argument("--json", metavar="OUT.json", help="write the generator figures as JSON")
    args = p.parse_args(argv)
    only = [f.strip() for f in args.only.split(",") if f.strip()] if args.only else None
    try:
        check_json_target(args.json)
        check_extras(only or available())
        run(only, args.quick, args.json)
    except ValueError as err:
        print(f"python -m benchmarks: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
