"""The argument checks of the surrogate side, one of each kind: a bad value gets one line naming it and what
is allowed (``ValueError``; the CLI prints it). No torch: the mode table uses them too."""

from __future__ import annotations

import math
import numbers


def check_count(name: str, value, low: int = 1, note: str = "") -> int:
    """``value`` when it is an integer >= ``low`` (a bool is not one), else "NAME=VALUE not allowed; must be an
    integer >= LOW NOTE"."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise ValueError(f"{name}={value!r} not allowed; must be an integer >= {low}{note}")
    return int(value)


def check_number(name: str, value, low: float | None = None, high: float | None = None, *, closed: str = "",
                 unit: str = "") -> float:
    """``value`` when it is a finite number within the bounds, else one line. low / high: exclusive bounds
    unless named in ``closed`` ("low", "high" or "both"); unit: what the number counts ("seconds")."""
    lo_ok = low is None or value > low or (closed in ("low", "both") and value == low) if _real(value) else False
    hi_ok = high is None or value < high or (closed in ("high", "both") and value == high) if _real(value) else False
    if not (_real(value) and lo_ok and hi_ok):
        if low is not None and high is not None:
            what = f"in {'[' if closed in ('low', 'both') else '('}{low:g}, {high:g}{']' if closed in ('high', 'both') else ')'}"
        elif low is not None:
            what = f"a number{' of ' + unit if unit else ''} {'>=' if closed in ('low', 'both') else '>'} {low:g}"
        elif high is not None:
            what = f"a number{' of ' + unit if unit else ''} {'<=' if closed in ('high', 'both') else '<'} {high:g}"
        else:
            what = "a finite number"
        raise ValueError(f"{name}={value!r} not allowed; must be {what}")
    return float(value)


def _real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def check_cache_matches(path, config: dict, pde, explicit: dict | None = None) -> None:
    """ValueError (one line) when the cache at ``path`` (its stored PDE ``config``) holds another PDE than ``pde``,
    or differs from settings the user set explicitly (``explicit``: the --set dict). No torch: `train --source`
    checks it before torch is imported, the loader again when it opens the cache."""
    name = config.get("pde")
    if name != pde.NAME:
        raise ValueError(f"cache {path} holds {name!r} samples, not {pde.NAME!r}; "
                         f"train on {name} or generate a {pde.NAME} cache")
    wanted = pde.config()
    # a setting the cache recorded counts too when the asked PDE leaves it out of its config (bc=periodic is the
    # default, so a periodic entry records no bc: asked on a Dirichlet cache, it trained on the Dirichlet data)
    differ = [k for k in (explicit or {}) if (k.split(".")[0] in wanted or k.split(".")[0] in config)
              and _lookup(wanted, k) != _lookup(config, k)]
    differ = [k for k in differ if k.split(".")[0] == k or k.split(".")[0] not in differ]  # (ic, not ic.max_mode too)
    if differ:
        # a setting a config leaves out is at its default (bc: periodic, refine: 1): shown as that, not as None
        shown = [(k, *(_default(pde, k) if v is None else v for v in (_lookup(config, k), _lookup(wanted, k))))
                 for k in differ]
        detail = ", ".join(f"{k}: cache {_said(k, c)} vs asked {_said(k, w)}" for key, c0, w0 in shown
                           for k, c, w in _entries(key, c0, w0))
        raise ValueError(f"cache {path} was written with other settings ({detail})")


def _said(key: str, value) -> str:
    """A setting's value in the refusal: None (a default that is no value) in words, the step's "automatic" (the
    PDE's stable step; it said "cache None")."""
    if value is None:
        return "automatic (the stable step)" if key == "dt" else "unset"
    return repr(value)


def _entries(key: str, cache, asked) -> list[tuple]:
    """The differing entries of one setting as (name, cache's, asked): two dicts (an initial condition's settings)
    by their differing keys, only "kind" where that differs (it said both whole dicts); else the setting itself."""
    if not (isinstance(cache, dict) and isinstance(asked, dict)):
        return [(key, cache, asked)]
    keys = ["kind"] if cache.get("kind") != asked.get("kind") else sorted(cache.keys() | asked.keys())
    return [(f"{key}.{k}", cache.get(k), asked.get(k)) for k in keys if cache.get(k) != asked.get(k)]


def _default(pde, key: str):
    """The default of the setting ``key`` that a config leaves out (bc: periodic; a field of ``pde``'s dataclass:
    its default), or None."""
    import dataclasses

    from ..boundaries import PERIODIC

    if key.split(".")[0] == "bc":
        return PERIODIC.value
    field = next((f for f in dataclasses.fields(pde) if f.name == key), None) if dataclasses.is_dataclass(pde) else None
    return None if field is None or field.default is dataclasses.MISSING else field.default


def _lookup(config: dict, key: str):
    head, _, rest = key.partition(".")
    value = config.get(head)
    return _lookup(value, rest) if rest and isinstance(value, dict) else value
