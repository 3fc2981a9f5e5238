"""pdestream: randomized-parameter PDE data solved on demand (JAX) and streamed into PyTorch, or cached.

    pdestream.generator     the solvers, by family (spectral, steady, flow, external) behind one Problem protocol;
                            the catalog, parameter domains, initial conditions, the sampler. JAX only.
    pdestream.datasets      the torch data side: TrajectoryStream, the reservoir, HDF5/Zarr caches, views.
    pdestream.surrogate     models (FNO, U-Net, yours) and the training loop. torch only.
    pdestream.experiments   compare, the time and simulation budgets, the interactive-mode comparison.
    pdestream.cli           the ``pdestream`` command: parses and hands each command to the library.
    pdestream.settings      a command's PDE settings (--config, --set); pdestream.catalog_names: the catalog's
                            names without JAX; pdestream.interrupts: Ctrl-C and the exit status of a command;
                            pdestream.meter: solves' progress reports and the count / rate / time-left lines.
    pdestream.boundaries    the boundary kinds (periodic, dirichlet, neumann) declared once, below JAX and torch:
                            what each is asked (periodic, bc_type, pad_mode, ...), the ``bc`` setting's parsing.

This module imports nothing heavy (no JAX, no torch), so ``pdestream --help`` and a refused command answer fast.
The repository's folders are these packages (pyproject maps ``pdestream`` to the repository root); ``datasets/``
has no ``__init__.py`` on purpose: a top-level regular package of that name would shadow HuggingFace's
``datasets`` whenever the repository root is on ``sys.path``, so its public names are given to it here.
"""

from __future__ import annotations

import importlib

__version__ = "0.2.0"

# Module paths written before the pdestream namespace (0.1: top-level generator / datasets / surrogate / cli, the
# spectral family in generator.pdes) -> today's, so that a "module:Class" string saved in a config, a run or a
# script still resolves. Longest prefix first.
LEGACY_MODULES = {
    "generator.spectral": "pdestream.generator.spectral.fourier",
    "generator.rollout": "pdestream.generator.spectral.rollout",
    "generator.bounded": "pdestream.generator.spectral.bounded",
    "generator.interactive": "pdestream.generator.spectral.interactive",
    "generator.pdes.steady": "pdestream.generator.steady.base",
    "generator.pdes.poisson": "pdestream.generator.steady.poisson",
    "generator.pdes.darcy2d": "pdestream.generator.steady.darcy2d",
    "generator.pdes.flows": "pdestream.generator.flow.entries",
    "generator.pdes": "pdestream.generator.spectral",
    "generator.elliptic": "pdestream.generator.steady.elliptic",
    "generator.external": "pdestream.generator.external.solver",
    "generator._solver_worker": "pdestream.generator.external.worker",
    "generator.adapters.exponax": "pdestream.generator.external.exponax",
    "surrogate.budget": "pdestream.experiments.budget",
    "surrogate.compare": "pdestream.experiments.compare",
    "surrogate.interactive_compare": "pdestream.experiments.interactive_compare",
    "surrogate.rollout_figure": "pdestream.experiments.rollout_figure",
    "generator": "pdestream.generator",
    "datasets": "pdestream.datasets",
    "surrogate": "pdestream.surrogate",
    "cli": "pdestream.cli",
}


def current_module(name: str) -> str:
    """Today's path of module ``name`` ("generator.pdes.burgers" -> "pdestream.generator.spectral.burgers"); a name
    that is not one of pdestream's old paths comes back unchanged."""
    for old in sorted(LEGACY_MODULES, key=len, reverse=True):
        if name == old or name.startswith(old + "."):
            return LEGACY_MODULES[old] + name[len(old):]
    return name


def load_object(spec: str, what: str = "object"):
    """The object at import path ``spec`` = "package.module:Qualified.Name" (a path of pdestream's own written
    before its namespace still resolves); ValueError in one line, naming ``what`` it was for, if it cannot be had."""
    module_name, _, qualname = spec.partition(":") if isinstance(spec, str) else ("", "", "")
    if not module_name or not qualname:
        raise ValueError(f"{what} {spec!r} not allowed: an import path is 'package.module:Class'")
    try:
        obj = importlib.import_module(current_module(module_name))
    except Exception as err:  # any error of the user's module: say which module and why, no traceback
        raise ValueError(f"{what} {spec!r}: module {module_name!r} does not import: {type(err).__name__}: {err}") from None
    for part in qualname.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"{what} {spec!r}: module {module_name!r} has no {qualname!r}")
        obj = getattr(obj, part)
    return obj


def _give_datasets_its_names() -> None:
    """Load pdestream.datasets' public names (datasets/api.py) on first use, as a package __init__ would."""
    namespace = importlib.import_module(".datasets", __name__)
    api = importlib.import_module(".datasets.api", __name__)

    def __getattr__(name: str):
        if name in api.WHERE:
            return getattr(importlib.import_module(f".{api.WHERE[name]}", namespace.__name__), name)
        try:  # a submodule, as `package.module` works after the module was imported anywhere
            return importlib.import_module(f".{name}", namespace.__name__)
        except ModuleNotFoundError as err:
            if err.name != f"{namespace.__name__}.{name}":
                raise
        raise AttributeError(f"module {namespace.__name__!r} has no attribute {name!r}")

    namespace.__getattr__ = __getattr__
    namespace.__all__ = api.__all__
    namespace.__doc__ = api.__doc__


# Only as pdestream: pytest collects the repository root as a package and imports this file under the folder's name
# (a clone in a folder named like "pdestream-ci" gives "__init__"), where there is no package to give names to.
if __name__ == "pdestream":
    _give_datasets_its_names()
