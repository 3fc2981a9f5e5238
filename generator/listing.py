"""``pdestream list``: the catalog and the user's PDEs in words, or every setting of one entry (text or JSON)."""

from __future__ import annotations

import json

from ..boundaries import PERIODIC
from . import user
from .catalog import GROUP, GROUPS, PDES, get_pde


def listing(name: str | None = None, as_json: bool = False) -> str:
    """Every PDE with its equation, fields, parameters and boundaries, by group (then the user's); with ``name``,
    every setting of that entry (``as_json``: as JSON)."""
    if name is not None:
        return entry_settings(get_pde(name), as_json)
    if as_json:
        raise ValueError("--json goes with an entry name: pdestream list NAME --json")
    out = []
    for group in GROUPS:  # the catalog's groups, in order; each entry says its dimension
        names = [n for n in PDES if GROUP[n] == group]
        if names:
            out.append(f"== {group} ({len(names)}) ==\n")
        for n in names:
            pde = get_pde(n)
            offered = getattr(pde, "BOUNDARIES", pde.grid.bc[:1])  # what `--set bc=` takes (a steady grid: its own)
            walls = (f"  bc: {', '.join(offered)} (--set bc={offered[1]}, or one axis: --set bc.x={offered[-1]})"
                     if len(offered) > 1 else f"  bc: {pde.grid.bc[0]} on every axis (fixed)")
            out.append(f"[{pde.NDIM}D] {pde.describe()}\n{walls}\n")
    mine = user.names()  # your own PDEs: registered by Python or installed entry points
    if mine:
        out.append(f"== user ({len(mine)}) ==\n")
    for n in mine:
        try:
            pde = get_pde(n)
        except ValueError as err:  # one broken entry point does not hide the rest of the list
            out.append(f"[?] {n}: cannot be loaded: {err}\n")
            continue
        where = pde.config().get("origin") or {}
        out.append(f"[{pde.NDIM}D] {pde.describe()}\n  from {where.get('module')}:{where.get('class')}\n")
    return "\n".join(out)


def entry_settings(pde, as_json: bool = False) -> str:
    """Every setting of one entry: its value (the default), and for parameters their domain, meaning and units."""
    config = pde.config()
    rows = {}
    # in the class's order; a setting its config leaves out at its default (refine, t_start, points: so the hashes
    # of caches written before it existed hold) is still one to list
    for key in (*getattr(pde, "config_fields", list)(), *config):
        if key not in rows and key not in ("pde", "ic", "origin", "recipe"):  # a recipe is named, not --set
            rows[key] = {"default": config[key] if key in config else getattr(pde, key)}
    for name, spec in pde.PARAMS.items():
        rows[name].update(meaning=spec.description, units=spec.units)  # the default is its domain
    rows.update({f"ic.{k}": {"default": v} for k, v in config["ic"].items() if k != "kind"})
    rows["ic"] = {"default": config["ic"]["kind"], "allowed": pde.fitting_ic_kinds()}
    units = getattr(pde, "FIELD_UNITS", {})
    fields = {f: units.get(f, "?") for f in (*getattr(pde, "INPUTS", ()), *pde.FIELDS)}
    offered = getattr(pde, "BOUNDARIES", None)
    if offered:
        rows.setdefault("bc", {"default": PERIODIC.value})["allowed"] = list(offered)
    if as_json:
        where = {"origin": config["origin"]} if "origin" in config else {}  # a user's PDE: where its code is
        recipe = {"recipe": config["recipe"]} if config.get("recipe") else {}
        return json.dumps({"pde": pde.NAME, "equation": pde.EQUATION, **recipe, **where, "fields": fields,
                           "settings": rows}, indent=2)
    out = [pde.describe()]
    if config.get("recipe"):  # the entry with a published set's settings (the defaults below)
        out.append(f"  recipe: {config['recipe']} (pdestream recipes show {config['recipe']}: its source and splits)")
    if "origin" in config:  # a user's PDE: where its code is (its identity in caches and runs)
        out.append("  from {module}:{class} version {version!r} source sha256 {source_sha256}".format(**config["origin"]))
    out.append("\nfields (units): " + ", ".join(f"{f} [{u}]" for f, u in fields.items()))
    out.append("\nsettings (--set KEY=VALUE; parameters take uniform(a, b), loguniform(a, b), choice(...)):")
    for key, row in rows.items():
        extra = "".join(f"  {k}: {', '.join(v) if isinstance(v, list) else v}" for k, v in row.items() if k != "default")
        out.append(f"  {key} = {row['default']}{extra}")
    return "\n".join(out)
