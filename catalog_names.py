"""The catalog's entry names without the catalog: a command refuses an unknown PDE before it imports JAX.

``NAMES`` is generator.catalog's entries in their order, with their groups (generator/catalog.py checks at import
that its ENTRIES give exactly this, so the two never drift). User PDEs are known here without importing them:
entry points by their metadata (importlib.metadata), import paths ``package.module:Class`` and Exponax steppers
``exponax:Name`` by their form (loading them is the catalog's job, which says in one line what went wrong).
"""

from __future__ import annotations

import difflib
import sys

ENTRY_POINT_GROUP = "pdestream.pdes"  # generator.user's group

# {entry name: group}, in the catalog's order
NAMES: dict[str, str] = {
    "advection1d": "linear",
    "advection2d": "linear",
    "advection3d": "linear",
    "diffusion1d": "linear",
    "diffusion2d": "linear",
    "diffusion3d": "linear",
    "advection_diffusion1d": "linear",
    "advection_diffusion2d": "linear",
    "dispersion1d": "linear",
    "hyper_diffusion1d": "linear",
    "hyper_diffusion2d": "linear",
    "wave1d": "linear",
    "wave2d": "linear",
    "burgers1d": "nonlinear",
    "kdv1d": "nonlinear",
    "ks1d": "nonlinear",
    "grayscott2d": "reaction-diffusion",
    "burgers2d": "nonlinear",
    "burgers3d": "nonlinear",
    "ks2d": "nonlinear",
    "fisher_kpp1d": "reaction-diffusion",
    "fisher_kpp2d": "reaction-diffusion",
    "allen_cahn1d": "reaction-diffusion",
    "allen_cahn2d": "reaction-diffusion",
    "cahn_hilliard2d": "reaction-diffusion",
    "swift_hohenberg2d": "reaction-diffusion",
    "grayscott3d": "reaction-diffusion",
    "diffusion_reaction2d": "reaction-diffusion",
    "diffusion_sorption1d": "reaction-diffusion",
    "ns2d": "fluids",
    "karman2d": "fluids",
    "cavity2d": "fluids",
    "channel2d": "fluids",
    "smoke2d": "fluids",
    "smoke_box2d": "fluids",
    "plume3d": "fluids",
    "euler1d": "fluids",
    "compressible_ns1d": "fluids",
    "euler2d": "fluids",
    "compressible_ns2d": "fluids",
    "shallow_water2d": "fluids",
    "darcy2d": "steady",
    "poisson1d": "steady",
    "poisson2d": "steady",
    "helmholtz1d": "steady",
    "helmholtz2d": "steady",
}


def entry_point_names() -> list[str]:
    """The names of installed entry points in group ``pdestream.pdes`` (read from metadata, nothing imported)."""
    from importlib.metadata import entry_points

    return [ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)]


def unknown_pde(name, mine: list[str]) -> str:
    """The one-line refusal of PDE ``name``: a near name if any, and what is allowed (``mine``: user PDE names)."""
    from pdestream.recipes import RECIPES, refuse_not_expressible

    refused = refuse_not_expressible(name)
    if refused:
        return refused
    names = [*NAMES, *RECIPES]
    near = [n for n in names if isinstance(name, str) and name and n.startswith(name)]
    near = near or (difflib.get_close_matches(name, names, n=3) if isinstance(name, str) else [])
    hint = f"; did you mean {' or '.join(near)}" if near else ""
    more = ", ".join(mine)
    return (f"unknown PDE {name!r}{hint}; allowed: {', '.join(NAMES)}{', ' + more if more else ''} "
            f"or an import path package.module:Class, or an Exponax stepper exponax:Name, or a recipe: "
            f"{', '.join(RECIPES)}")


def check_name(name: str | None) -> None:
    """One-line ValueError if ``name`` cannot name a PDE (None passes: the caller says no PDE was named). Once
    generator is imported, PDEs registered by Python count too (it decides then)."""
    from pdestream.recipes import RECIPES  # a recipe names its entry (no JAX either)

    if name is None or (isinstance(name, str) and (name in NAMES or name in RECIPES or ":" in name)):
        return
    if "pdestream.generator" in sys.modules:  # registered PDEs live there: ask it
        sys.modules["pdestream.generator"].pde_class(name)
        return
    mine = entry_point_names()
    if name not in mine:
        raise ValueError(unknown_pde(name, mine))
