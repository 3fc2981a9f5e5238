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
