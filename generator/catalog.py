"""The PDE catalog: every entry declared once in ENTRIES (name, class, fixed settings, group), and the lookup.

A class that serves several dimensions (``PDE.DIMENSIONS``) gets one entry per dimension; the entry's name
carries the dimension (diffusion1d, diffusion2d, ...) and its fixed ``ndim`` picks the class attributes and
setting defaults of that dimension. Each entry becomes a class of its own (``PDES[name]``), named like
``Diffusion2D`` and importable from this module (so a PDE pickles by reference, like any other class).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from pdestream.catalog_names import NAMES, unknown_pde  # the names without JAX (the CLI checks them)
from pdestream.recipes import RECIPES

from . import user
from .external.exponax import exponax_pde_class
from .finite_volume.diffusion_sorption import DiffusionSorption1D
from .finite_volume.problem import CompressibleNS1D, Euler1D
from .finite_volume.problem2d import CompressibleNS2D, Euler2D, ShallowWater2D
from .flow.entries import Cavity2D, Channel2D, Karman2D, Smoke2D, SmokeBox2D
from .flow.entries3d import Plume3D
from .spectral.advection import Advection
from .spectral.advection_diffusion import AdvectionDiffusion
from .spectral.allen_cahn import AllenCahn
from .spectral.base import PDE
from .spectral.burgers import Burgers
from .spectral.cahn_hilliard import CahnHilliard
from .spectral.diffusion import Diffusion
from .spectral.diffusion_reaction import DiffusionReaction
from .spectral.dispersion import Dispersion
from .spectral.fisher_kpp import FisherKPP
from .spectral.grayscott import GrayScott
from .spectral.hyper_diffusion import HyperDiffusion
from .spectral.kdv1d import KdV1D
from .spectral.ks import KS
from .spectral.ns2d import NS2D
from .spectral.swift_hohenberg import SwiftHohenberg
from .spectral.wave import Wave
from .steady.darcy2d import Darcy2D
from .steady.poisson import Helmholtz, Poisson

# How `pdestream list` and the README group the catalog.
GROUPS = ("linear", "nonlinear", "reaction-diffusion", "fluids", "steady")


@dataclass(frozen=True)
class Entry:
    """One catalog entry: its name, the class defining its equation, the settings fixed for this entry
    ({"ndim": d} for a class serving several dimensions; {} for a class of one dimension), and its group."""

    name: str
    pde: type[PDE]
    fixed: Mapping[str, Any]
    group: str


ENTRIES: tuple[Entry, ...] = (
    Entry("advection1d", Advection, {"ndim": 1}, "linear"),
    Entry("advection2d", Advection, {"ndim": 2}, "linear"),
    Entry("advection3d", Advection, {"ndim": 3}, "linear"),
    Entry("diffusion1d", Diffusion, {"ndim": 1}, "linear"),
    Entry("diffusion2d", Diffusion, {"ndim": 2}, "linear"),
    Entry("diffusion3d", Diffusion, {"ndim": 3}, "linear"),
    Entry("advection_diffusion1d", AdvectionDiffusion, {"ndim": 1}, "linear"),
    Entry("advection_diffusion2d", AdvectionDiffusion, {"ndim": 2}, "linear"),
    Entry("dispersion1d", Dispersion, {"ndim": 1}, "linear"),
    Entry("hyper_diffusion1d", HyperDiffusion, {"ndim": 1}, "linear"),
    Entry("hyper_diffusion2d", HyperDiffusion, {"ndim": 2}, "linear"),
    Entry("wave1d", Wave, {"ndim": 1}, "linear"),
    Entry("wave2d", Wave, {"ndim": 2}, "linear"),
    Entry("burgers1d", Burgers, {"ndim": 1}, "nonlinear"),
    Entry("kdv1d", KdV1D, {}, "nonlinear"),
    Entry("ks1d", KS, {"ndim": 1}, "nonlinear"),
    Entry("grayscott2d", GrayScott, {"ndim": 2}, "reaction-diffusion"),
    Entry("burgers2d", Burgers, {"ndim": 2}, "nonlinear"),
    Entry("burgers3d", Burgers, {"ndim": 3}, "nonlinear"),
    Entry("ks2d", KS, {"ndim": 2}, "nonlinear"),
    Entry("fisher_kpp1d", FisherKPP, {"ndim": 1}, "reaction-diffusion"),
    Entry("fisher_kpp2d", FisherKPP, {"ndim": 2}, "reaction-diffusion"),
    Entry("allen_cahn1d", AllenCahn, {"ndim": 1}, "reaction-diffusion"),
    Entry("allen_cahn2d", AllenCahn, {"ndim": 2}, "reaction-diffusion"),
    Entry("cahn_hilliard2d", CahnHilliard, {"ndim": 2}, "reaction-diffusion"),
    Entry("swift_hohenberg2d", SwiftHohenberg, {"ndim": 2}, "reaction-diffusion"),
    Entry("grayscott3d", GrayScott, {"ndim": 3}, "reaction-diffusion"),
    Entry("diffusion_reaction2d", DiffusionReaction, {"ndim": 2}, "reaction-diffusion"),
    Entry("diffusion_sorption1d", DiffusionSorption1D, {}, "reaction-diffusion"),
    Entry("ns2d", NS2D, {}, "fluids"),
    Entry("karman2d", Karman2D, {}, "fluids"),
    Entry("cavity2d", Cavity2D, {}, "fluids"),
    Entry("channel2d", Channel2D, {}, "fluids"),
    Entry("smoke2d", Smoke2D, {}, "fluids"),
    Entry("smoke_box2d", SmokeBox2D, {}, "fluids"),
    Entry("plume3d", Plume3D, {}, "fluids"),
    Entry("euler1d", Euler1D, {}, "fluids"),
    Entry("compressible_ns1d", CompressibleNS1D, {}, "fluids"),
    Entry("euler2d", Euler2D, {}, "fluids"),
    Entry("compressible_ns2d", CompressibleNS2D, {}, "fluids"),
    Entry("shallow_water2d", ShallowWater2D, {}, "fluids"),
    Entry("darcy2d", Darcy2D, {}, "steady"),
    Entry("poisson1d", Poisson, {"ndim": 1}, "steady"),
    Entry("poisson2d", Poisson, {"ndim": 2}, "steady"),
    Entry("helmholtz1d", Helmholtz, {"ndim": 1}, "steady"),
    Entry("helmholtz2d", Helmholtz, {"ndim": 2}, "steady"),
)


def entry_class(entry: Entry) -> type[PDE]:
    """The class of one entry: a dimension-generic class specialised to the entry's ndim (its defaults and
    dimension-dependent class attributes), or a one-dimension class as it is (named ``entry.name``)."""
    cls = entry.pde
    if entry.group not in GROUPS:
        raise TypeError(f"catalog entry {entry.name}: group {entry.group!r} is not one of {GROUPS}")
    if not cls.DIMENSIONS:
        if entry.fixed or cls.NAME != entry.name:
            raise TypeError(f"catalog entry {entry.name}: {cls.__name__} is the one-dimension PDE {cls.NAME!r} "
                            "and takes no fixed settings")
        return cls
    if set(entry.fixed) != {"ndim"} or entry.fixed["ndim"] not in cls.DIMENSIONS:
        raise TypeError(f"catalog entry {entry.name}: {cls.__name__} needs fixed={{'ndim': d}} with d in "
                        f"{sorted(cls.DIMENSIONS)}, got {dict(entry.fixed)}")
    ndim = entry.fixed["ndim"]
    defaults = dict(cls.DIMENSIONS[ndim])
    fields = {f.name: f for f in dataclasses.fields(cls)}
    name = f"{cls.__name__}{ndim}D"
    namespace = {"NAME": entry.name, "NDIM": ndim, **cls.for_dimension(ndim), **defaults,
                 "__annotations__": {k: fields[k].type for k in defaults},
                 "__module__": __name__, "__qualname__": name, "__doc__": cls.__doc__}
    return dataclass(frozen=True)(type(name, (cls,), namespace))


PDES: dict[str, type[PDE]] = {e.name: entry_class(e) for e in ENTRIES}
_clash = sorted(set(RECIPES) & set(PDES)) or [r.name for r in RECIPES.values() if r.entry not in PDES]
if _clash:
    raise TypeError(f"recipes {_clash}: a recipe's name must not be an entry's, and its entry must be in ENTRIES")
GROUP: dict[str, str] = {e.name: e.group for e in ENTRIES}
if GROUP != NAMES or list(GROUP) != list(NAMES):  # the JAX-free copy the CLI checks names against
    raise TypeError("catalog_names.NAMES differs from the catalog's ENTRIES: make it {name: group} of ENTRIES, in order")
# The specialised classes by their own names (Diffusion2D, ...), so pickle finds them in this module.
globals().update({cls.__name__: cls for cls in PDES.values() if cls.__module__ == __name__})


def register(name: str, cls: type) -> type:
    """Make your problem class ``cls`` known as ``name`` (get_pde, the CLI, ``pdestream list``); a catalog entry's
    name is refused. Returns the class (generator.user.register does the checks)."""
    return user.register(name, cls, taken=(*PDES, *RECIPES))


def get_pde(name: str, overrides: Mapping | None = None, **kwargs) -> PDE:
    """The catalog PDE ``name`` with its defaults, changed by ``overrides`` / keyword arguments.

    Values may be strings (parsed: domains like "loguniform(1e-3, 1e-1)", numbers, ic kinds). ``name`` may also
    be a user PDE (generator.user: registered, an entry point, or an import path "package.module:Class") or a
    recipe (pdestream.recipes: an entry with a published data set's settings, which ``overrides`` change further).
    """
    if isinstance(name, str) and name in RECIPES:  # a recipe: its entry with the published settings, labelled
        recipe = RECIPES[name]
        pde = dataclasses.replace(PDES[recipe.entry]().replace(recipe.settings), recipe=name)
    else:
        pde = pde_class(name)()
    return pde.replace(overrides, **kwargs) if (overrides or kwargs) else pde


def pde_class(name: str) -> type[PDE]:
    """The class of catalog entry, recipe (its entry's class) or user PDE ``name`` (one-line ValueError naming what
    is allowed)."""
    if isinstance(name, str) and name in PDES:
        return PDES[name]
    if isinstance(name, str) and name in RECIPES:
        return PDES[RECIPES[name].entry]
    if isinstance(name, str) and name.startswith("exponax:"):  # an Exponax stepper (the adapter imports exponax)
        return exponax_pde_class(name)
    found = user.lookup(name) if isinstance(name, str) and name else None
    if found is None:
        raise ValueError(unknown_pde(name, user.names()))
    return found
