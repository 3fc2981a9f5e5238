"""Where the next simulations go: uniform over the parameter domain, or steered toward high training loss.

``ParamProposal`` works in the unit box of the random parameters (uniform: linear, loguniform: log, choice:
equal-width bins per option). In ``"loss"`` mode it keeps the last ``window`` per-sample training losses
reported by the training loop (``record``) and proposes (``propose``) a mixture:

- with probability ``floor``, a uniform draw over the box (no region ever starves);
- otherwise a recent training sample picked with probability proportional to ``loss ** power`` divided by how
  crowded its neighbourhood is among the recent samples, moved by a Gaussian kernel of width ``bandwidth``
  (unit-box units) and reflected back into the box: a draw whose density follows the recent loss over the box
  (not loss x where earlier proposals went, which would pile every solve into one corner).

Everything is numpy and seeded: the sequence of proposals is a pure function of (seed, the losses recorded
and the order of calls), so a deterministic reservoir stays deterministic. ``state_dict`` captures it all.
"""

from __future__ import annotations

import math

import numpy as np

MODES = ("uniform", "loss")


class ParamProposal:
    """Proposes explicit parameter values {name: float64 [n]} for the next solves.

    domains: {name: (kind, low, high, options)} for every PDE parameter in PARAMS order (``_bridge.param_domains``);
    "fixed" ones are left to the solver. mode: "uniform" (propose() returns None: the solver draws from the
    key as usual) or "loss". floor: share of uniform draws in "loss" mode, in (0, 1]. window: recent losses kept.
    """

    def __init__(self, domains: dict, mode: str = "loss", floor: float = 0.25, window: int = 2048,
                 bandwidth: float = 0.05, power: float = 1.0, seed: int = 0):
        if mode not in MODES:
            raise ValueError(f"proposal={mode!r} not allowed; allowed: {', '.join(MODES)}")
        if not (isinstance(floor, (int, float)) and 0 < floor <= 1):
            raise ValueError(f"proposal floor={floor!r} not allowed; must be in (0, 1] (uniform share)")
        if not (isinstance(bandwidth, (int, float)) and 0 < bandwidth <= 1):
            raise ValueError(f"proposal bandwidth={bandwidth!r} not allowed; must be in (0, 1] (unit-box units)")
        if not (isinstance(power, (int, float)) and 0 <= power <= 8):
            raise ValueError(f"proposal power={power!r} not allowed; must be in [0, 8]")
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"proposal window={window!r} not allowed; must be an integer >= 1")
        self.mode, self.floor, self.window, self.bandwidth, self.power = mode, float(floor), window, float(bandwidth), float(power)
        self.names = list(domains)  # every PDE parameter, PARAMS order (the columns of batch["params"])
        self.domains = {k: tuple(v) for k, v in domains.items()}
        self.random = [k for k, (kind, *_rest) in self.domains.items() if kind != "fixed"]
        self.rng = np.random.default_rng(seed)
        self.points = np.zeros((0, len(self.random)))  # recent training samples, unit box [W, D]
        self.losses = np.zeros(0)  # their losses [W]
        self.proposed = []  # every proposed unit point (for the plot), list of [D] lists
        self.reports = 0
        self.dropped = 0  # recorded rows refused for a non-finite loss or parameter
        self._w, self._w_at = None, 0  # pick probabilities of the recorded points, as of self._w_at reports

    # --- unit box <-> parameter values -------------------------------------------------------------
    def to_unit(self, values: np.ndarray) -> np.ndarray:
        """[N, P] parameter values (all PDE parameters, PARAMS order) -> [N, D] unit coordinates of the random ones."""
        values = np.asarray(values, np.float64).reshape(len(values), len(self.names))
        cols = []
        for name in self.random:
            kind, low, high, options = self.domains[name]
            v = values[:, self.names.index(name)]
            if kind == "loguniform":
                z = (np.log(v) - math.log(low)) / (math.log(high) - math.log(low))
            elif kind == "choice":
                opts = np.asarray(options)
                z = (np.abs(v[:, None] - opts[None]).argmin(1) + 0.5) / len(opts)
            else:
                z = (v - low) / (high - low)
            cols.append(np.clip(z, 0.0, 1.0))
        return np.stack(cols, 1) if cols else np.zeros((len(values), 0))

    def from_unit(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """[N, D] unit coordinates -> {name: float64 [N]} values inside each domain."""
        out = {}
        for j, name in enumerate(self.random):
            kind, low, high, options = self.domains[name]
            u = np.clip(z[:, j], 0.0, 1.0)
            if kind == "loguniform":
                v = np.exp(math.log(low) + u * (math.log(high) - math.log(low)))
            elif kind == "choice":
                v = np.asarray(options)[np.minimum((u * len(options)).astype(int), len(options) - 1)]
            else:
                v = low + u * (high - low)
            # float32 rounding must not step outside the domain the solver checks against
            out[name] = np.clip(v, np.nextafter(np.float32(low), np.float32(high)),
                                np.nextafter(np.float32(high), np.float32(low))).astype(np.float64)
        return out

    # --- the loop's feedback and the proposals -----------------------------------------------------
    def record(self, params: np.ndarray, losses: np.ndarray) -> None:
        """Per-sample training losses [B] of samples with parameters [B, P] (PARAMS order). A row whose loss or
        parameters are not finite (a diverged step, a NaN parameter) is dropped and counted in ``dropped``: one
        such row would otherwise turn the pick weights, and then the proposals sent to the solver, into NaN."""
        losses = np.asarray(losses, np.float64).reshape(-1)
        params = np.asarray(params, np.float64).reshape(len(losses), len(self.names))
        ok = np.isfinite(losses) & np.isfinite(params).all(axis=1)
        self.dropped += int((~ok).sum())
        if not ok.any() or not self.random:
            return
        self.points = np.concatenate([self.points, self.to_unit(params[ok])])[-self.window :]
        self.losses = np.concatenate([self.losses, losses[ok]])[-self.window :]
        self.reports += int(ok.sum())

    def propose(self, n: int) -> dict[str, np.ndarray] | None:
        """Explicit values {name: float64 [n]} for the next n solves; None in "uniform" mode (key draws)."""
        if self.mode == "uniform" or not self.random:
            return None
        d = len(self.random)
        z = self.rng.random((n, d))  # the uniform part
        steer = self.rng.random(n) >= self.floor
        if steer.any() and len(self.losses):
            # The recorded points were drawn from earlier proposals, so they crowd where the loss was high; weighting
            # them by loss alone would compound that (loss x crowding) and pile every solve into one corner. Divide
            # by the points' own kernel density so that the steered draws follow the loss, not the crowding.
            w = self._weights()
            pick = self.rng.choice(len(w), size=int(steer.sum()), p=w)
            moved = self.points[pick] + self.bandwidth * self.rng.standard_normal((len(pick), d))
            moved = np.abs(moved)  # reflect at 0 ...
            moved = 1.0 - np.abs(1.0 - moved)  # ... and at 1
            z[steer] = np.clip(moved, 0.0, 1.0)
        self.proposed.extend(z.tolist())
        return self.from_unit(z)

    def _weights(self) -> np.ndarray:
        """Pick probabilities of the recorded points [W]; recomputed once ``window // 2`` new losses have come
        in (the O(128 W) density would otherwise cost a cheap solver's loop a sixth of its time)."""
        if self._w is None or len(self._w) != len(self.losses) or self.reports - self._w_at >= max(1, self.window // 2):
            self._w = pick_weights(self.losses, self._crowding(), self.power)
            self._w_at = self.reports
        return self._w

    def _crowding(self) -> np.ndarray:
        """Kernel density of the recorded points at each of them [W] (Gaussian, width ``bandwidth``), estimated
        against an evenly spaced subset of at most 128 of them (O(128 W D): a few ms)."""
        ref = self.points[:: max(1, len(self.points) // 128)]
        diff = self.points[:, None, :] - ref[None, :, :]  # [W, R, D]
        return np.exp(-0.5 * (diff**2).sum(-1) / self.bandwidth**2).mean(1)

    def density(self, bins: int = 20) -> dict:
        """For plots and reports, along the first random parameter: bin edges (unit box), proposal counts
        and mean recent loss per bin (NaN where no loss was recorded)."""
        edges = np.linspace(0, 1, bins + 1)
        prop = np.asarray(self.proposed)[:, 0] if self.proposed and self.random else np.zeros(0)
        counts = np.histogram(prop, edges)[0]
        loss = np.full(bins, np.nan)
        if len(self.losses):
            which = np.minimum((self.points[:, 0] * bins).astype(int), bins - 1)
            for b in range(bins):
                if (which == b).any():
                    loss[b] = self.losses[which == b].mean()
        return {"edges": edges.tolist(), "counts": counts.tolist(), "loss": loss.tolist()}

    # --- state -------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything the next proposals depend on (plain values; loads with torch.load(weights_only=True))."""
        return {"mode": self.mode, "rng": _plain(self.rng.bit_generator.state), "points": self.points.tolist(),
                "losses": self.losses.tolist(), "proposed": list(self.proposed), "reports": self.reports, "dropped": self.dropped,
                "weights": None if self._w is None else self._w.tolist(), "weights_at": self._w_at}

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict()`` output (the same domains and mode are required)."""
        if state.get("mode") != self.mode:
            raise ValueError(f"proposal state has mode {state.get('mode')!r}, this proposal {self.mode!r}")
        self.rng.bit_generator.state = state["rng"]
        self.points = np.asarray(state["points"], np.float64).reshape(-1, len(self.random))
        self.losses = np.asarray(state["losses"], np.float64)
        self.proposed = [list(p) for p in state["proposed"]]
        self.reports = int(state["reports"])
        self.dropped = int(state.get("dropped", 0))  # states saved before the count existed have none
        self._w = None if state.get("weights") is None else np.asarray(state["weights"], np.float64)
        self._w_at = int(state.get("weights_at", 0))


def pick_weights(losses: np.ndarray, crowding: np.ndarray, power: float) -> np.ndarray:
    """Probabilities [W] proportional to max(loss, 0) ** power / crowding, computed in log space so that losses
    of 1e300 (or 1e-300) neither overflow nor vanish; uniform when no loss is positive. Inputs are finite
    (``record`` drops the rest); crowding > 0 (every point counts itself)."""
    positive = losses > 0 if power > 0 else np.ones(len(losses), bool)  # loss ** 0 == 1, even for loss 0
    if not positive.any():
        return np.full(len(losses), 1.0 / len(losses))
    logw = np.full(len(losses), -np.inf)
    logw[positive] = -np.log(crowding[positive])
    if power > 0:
        logw[positive] += power * np.log(losses[positive])
    w = np.exp(logw - logw.max())
    return w / w.sum()


def _plain(state):
    """numpy bit-generator state -> plain dict/int/str (no numpy scalars)."""
    if isinstance(state, dict):
        return {k: _plain(v) for k, v in state.items()}
    return int(state) if isinstance(state, (np.integer, int)) and not isinstance(state, bool) else state
