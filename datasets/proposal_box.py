"""The unit box of ``datasets.proposal.ParamProposal``: a PDE's random parameters <-> unit coordinates (uniform:
linear, loguniform: log, choice: equal-width bins per option, the bin's centre for a value), and the proposals'
density along its first coordinate; numpy only."""

from __future__ import annotations

import math

import numpy as np


def params_to_unit(domains: dict, names: list, random: list, values: np.ndarray) -> np.ndarray:
    """[N, P] values of every parameter (``names`` order) -> [N, R] unit coordinates of the ``random`` ones, clipped
    into [0, 1]. domains: {name: (kind, low, high, options)}."""
    cols = []
    for name in random:
        kind, low, high, options = domains[name]
        v = values[:, names.index(name)]
        if kind == "loguniform":
            z = (np.log(v) - math.log(low)) / (math.log(high) - math.log(low))
        elif kind == "choice":
            opts = np.asarray(options)
            z = (np.abs(v[:, None] - opts[None]).argmin(1) + 0.5) / len(opts)
        else:
            z = (v - low) / (high - low)
        cols.append(np.clip(z, 0.0, 1.0))
    return np.stack(cols, 1) if cols else np.zeros((len(values), 0))


def unit_to_params(domains: dict, random: list, z: np.ndarray) -> dict[str, np.ndarray]:
    """[N, R] unit coordinates -> {name: float64 [N]} values of the ``random`` parameters inside their domains (a
    choice: one of its options; otherwise no further out than float32 rounding allows: the solver checks in it)."""
    out = {}
    for j, name in enumerate(random):
        kind, low, high, options = domains[name]
        u = np.clip(z[:, j], 0.0, 1.0)
        if kind == "choice":  # the options as they are (a clip would move the end ones off the set)
            out[name] = np.asarray(options)[np.minimum((u * len(options)).astype(int), len(options) - 1)].astype(np.float64)
            continue
        v = np.exp(math.log(low) + u * (math.log(high) - math.log(low))) if kind == "loguniform" else low + u * (high - low)
        # float32 rounding must not step outside the domain the solver checks against
        out[name] = np.clip(v, np.nextafter(np.float32(low), np.float32(high)),
                            np.nextafter(np.float32(high), np.float32(low))).astype(np.float64)
    return out


def density(proposed: np.ndarray | None, points: np.ndarray, losses: np.ndarray, bins: int = 20) -> dict:
    """Along the first unit coordinate: bin edges [bins + 1], counts of the proposed unit points [P, D] (None: no
    random parameter, no counts) and the mean loss [bins] of the recorded points [W, D] with losses [W] per bin (NaN
    where none was recorded); plain lists, for plots and reports."""
    edges = np.linspace(0, 1, bins + 1)
    counts = np.histogram(proposed[:, 0] if proposed is not None and len(proposed) else np.zeros(0), edges)[0]
    loss = np.full(bins, np.nan)
    if len(losses):
        which = np.minimum((points[:, 0] * bins).astype(int), bins - 1)
        for b in range(bins):
            if (which == b).any():
                loss[b] = losses[which == b].mean()
    return {"edges": edges.tolist(), "counts": counts.tolist(), "loss": loss.tolist()}
