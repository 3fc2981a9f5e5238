"""The shifted test set's PDE: every random parameter's domain moved just outside its training range. Plain
settings work (no torch), so `compare` refuses a bad --shift / --shift-set before importing torch."""

from __future__ import annotations

import math


def shifted_pde(pde, frac: float = 0.25, overrides: dict | None = None):
    """The PDE with each random parameter's domain moved just outside its training range [a, b].

    frac > 0 (above): uniform(b, b + frac (b - a)), loguniform(b, b (b / a)^frac); frac < 0 (below):
    uniform(a - |frac| (b - a), a), loguniform(a (a / b)^|frac|, a). A parameter declared > 0 whose uniform shift
    below would reach 0 is shifted geometrically instead (uniform(a (a / b)^|frac|, a)); a parameter the problem
    refuses on that side (a bound of [0, 1], a source below the grid's resolution) is shifted to the other side,
    and one refused on both keeps its training domain. ``overrides`` ({name: domain string}) replaces the
    automatic choice. None when no parameter could be shifted.
    """
    if frac == 0:
        raise ValueError("shift=0 would test on the training domain; use a fraction like 0.25 or -0.25")
    changes = dict(overrides or {})
    for name, domain in changes.items():
        _check_override(pde, name, domain)
    for name, domain in pde.param_domains.items():
        if name in changes or type(domain).__name__ not in ("Uniform", "LogUniform"):
            continue
        for side in (frac, -frac):  # the asked side first, then the other
            candidate = _shifted_domain(domain, side, pde.PARAMS[name].positive)
            if candidate is None:
                raise ValueError(f"shift={frac:g} moves {name}'s domain {domain} past the largest float; use a "
                                 "fraction like 0.25 or -0.25")
            try:
                pde.replace({name: candidate})
            except ValueError:
                continue
            changes[name] = candidate
            break
    return pde.replace(changes) if changes else None


def _shifted_domain(domain, frac: float, positive: bool) -> str | None:
    """``domain`` (Uniform or LogUniform over [lo, hi]) moved by ``frac`` of its width (in log for loguniform, or
    for a positive uniform whose linear shift below would reach 0) above (frac > 0) or below its range; None when
    a bound would not be a finite float (--shift 1e300 raised OverflowError)."""
    kind, (lo, hi), f = type(domain).__name__, domain.bounds, abs(frac)
    geometric = kind == "LogUniform" or (positive and frac < 0 and lo - f * (hi - lo) <= 0)
    try:
        if geometric:
            a, b = (hi, hi * (hi / lo) ** f) if frac > 0 else (lo * (lo / hi) ** f, lo)
        else:
            a, b = (hi, hi + f * (hi - lo)) if frac > 0 else (lo - f * (hi - lo), lo)
    except OverflowError:
        return None
    if not (math.isfinite(a) and math.isfinite(b)):
        return None
    return f"{kind.lower()}({a:.6g}, {b:.6g})"


def _check_override(pde, name: str, domain) -> None:
    """One line for an explicit shifted domain that is not beyond the training range: a setting that is not one of
    the PDE's parameters (``n=32`` solved the set on another grid) or a domain inside the training one (the
    training domain itself was accepted and reported as "beyond the training range")."""
    if name not in pde.param_domains:
        raise ValueError(f"shift_set {name}={domain}: {name} is not a parameter of {pde.NAME}; allowed: "
                         f"{', '.join(pde.param_domains) or 'none (no parameters)'}")
    trained = pde.param_domains[name]
    lo, hi = pde.replace({name: domain}).param_domains[name].bounds
    a, b = trained.bounds
    if a <= lo and hi <= b:
        beyond = (_shifted_domain(trained, -0.25, pde.PARAMS[name].positive)
                  if type(trained).__name__ in ("Uniform", "LogUniform") else None)
        raise ValueError(f"shift_set {name}={domain} lies inside the training range {trained}; allowed: a domain "
                         f"beyond it{', e.g. ' + beyond if beyond else ''}")
