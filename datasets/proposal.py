"""Where the next simulations go: uniform over the parameter domain, or steered toward high training loss.

``ParamProposal`` works in the unit box of the random parameters (uniform: linear, loguniform: log, choice:
equal-width bins per option). In ``"loss"`` mode it keeps the last ``window`` per-sample training losses
reported by the training loop (``record``) and proposes (``propose``) a mixture:

- with probability ``floor``, a uniform draw over the box (no region ever starves);
- otherwise a recent training sample picked with probability proportional to ``loss ** power`` divided by how
  crowded its neighbourhood is among the recent samples, moved by a Gaussian kernel of width ``bandwidth``
  (unit-box units) and reflected back into the box: a draw whose density follows the recent loss over the box
  (not loss x where earlier proposals went, which would pile every solve into one corner).

In ``"active"`` mode the loss signal is kept and an uncertainty signal added (a loss model over the box, its
ensemble spread as the uncertainty, candidates resampled by the acquisition; ``proposal_fit``'s docstring says how).

In ``"generative"`` mode (OGAS's idea, a conditional generative model of the inputs given difficulty, at its
smallest) the proposal learns p(x | high difficulty) from the fresh solves and draws from it (``proposal_fit``'s
docstring: its coordinates, data, model and predictor). Breed-style importance sampling (Melissa's Breed: resample
past inputs by their loss, perturb them, keep a uniform share) is the ``"loss"`` mode above.

The "active" fit runs in a background thread, off the training loop: it starts in ``record`` on a snapshot of the
window and is used from the next refit on (one refit interval later, ``refit`` losses), by which time it is
done, so the loop does not wait for it. Which fit a proposal uses is therefore fixed by the count of losses
reported, not by timing: the proposals stay a pure function of (seed, losses, call order).

**The skill gate (never do harm).** A steered draw only helps if the loss model can tell where the loss will be
high; on a problem whose error lives in the initial condition, not in the parameters, it cannot, and steering
then only thins the draws elsewhere. So in every steered mode the proposal measures its own skill on
fresh solves and moves its weight between the steered and the uniform draw by it (in "generative" mode too):

- **skill pairs**: when ``record`` gets the loss of a sample trained on for the first time (``fresh``; the
  reservoir marks a trajectory's first draw), the proposal's loss model predicts the log-loss at its parameters
  *before* the loss joins the window (out of sample: the model never saw that solve) -- "active": the mean of the
  ensemble fit in use, "loss": a kernel (Nadaraya-Watson, width ``bandwidth``) average of the recent log-losses.
  The last ``skill_window`` (prediction, realized log-loss) pairs are kept.
- **skill** = the correlation (Pearson) of those predicted and realized log-losses, each less its running median over
  the ``LEVEL_SPAN`` (33) pairs nearest in arrival (the loss level falls as the model trains: a predictor that only
  follows the level, such as the "loss" mode's kernel average far from every recorded point, would otherwise
  correlate through it alone, with no idea where the loss is high), minus its null standard error,
  r - 2 / sqrt(n - 1) (a lower confidence bound: with no structure r scatters around 0 by about 1 / sqrt(n - 1),
  whatever the losses' distribution, and the bound keeps that scatter from opening the gate), floored at 0; no
  skill (0) until ``skill_min`` pairs exist. (why a correlation, of log-losses, not a rank one:
  ``proposal_fit``'s docstring).
- **the steered share** w = (1 - floor) * clip(skill / skill_full, 0, 1): each draw is steered with probability
  w and uniform otherwise. No skill: w = 0, the draws are uniform; skill >= ``skill_full``: w = 1 - floor, the
  ungated proposal. ``gate=False`` keeps w = 1 - floor always (the proposal before the gate). ``skill`` and
  ``steer`` (w) are in the reservoir's ``stats()`` (metrics.csv: ``proposal_skill``, ``proposal_steer``, and the
  lift's lower bound ``proposal_lift``) and in ``state_dict``.
- **the lift** (``proposal_lift``; where the caller passes sample indices, as the reservoir does): the steered
  draws' fresh losses against the uniform draws' at the same moment, on the draws themselves. Its lower bound opens
  the share too, w = (1 - floor) * clip(max(skill / skill_full, lift_low / log 2), 0, 1); its upper bound below 0
  (steered draws measurably easier) closes it (w = 0) whatever the correlation says; the generative proposal (its
  correlation predictor a smooth summary of a local model) probes, w >= ``probe``, until its lift is measured (or vetoed).

**The initial condition too** (``latent_prior``, the reservoir's ``proposal_space="params+ic"``): where the entry's IC
has latent coordinates (``generator.ics.LatentIC``: Fourier amplitudes and phases, a GRF's leading white-noise modes,
spot centres), the unit box grows by those L coordinates, mapped onto the latent by its prior's inverse CDF (a
uniform unit point is a draw of the prior, as the key would make it), and every proposal above runs over
(parameters, latent) jointly: ``propose`` adds the latents [n, L] under LATENT, ``record`` takes each sample's.
How the loss
model reads the latent coordinates: ``proposal_fit``'s docstring.

Everything is numpy and seeded: the sequence of proposals is a pure function of (seed, the losses recorded
and the order of calls), so a deterministic reservoir stays deterministic. ``state_dict`` captures it all.
"""

from __future__ import annotations

import inspect
import math
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from ._bridge import LATENT  # propose()'s key for the IC latents [n, L] (no parameter can be named so)
from .proposal_box import density, params_to_unit, unit_to_params
from .proposal_fit import (
    LEVEL_SPAN,
    UNIT_EDGE,
    _fit_array,
    _fit_plain,
    _plain,
    active_fit,
    correlation,
    features,
    gauss_ratio,
    generative_fit,
    lattice,
    log_ratio,
    ndtr,
    ndtri,
    normal_scores,
    pick_weights,
    running_median,
)
from .proposal_lift import LIFT_FULL, LIFT_MIN, LiftGate
from .reservoir_config import PROPOSALS, check_proposal_settings, check_proposal_uses

MODES = ("uniform", "loss", "active", "generative")
if MODES != PROPOSALS:
    raise ImportError(f"reservoir_config.PROPOSALS {PROPOSALS} and the proposal's modes {MODES} disagree")


class ParamProposal:
    """Proposes explicit parameter values {name: float64 [n]} for the next solves.

    domains: {name: (kind, low, high, options)} for every PDE parameter in PARAMS order (``_bridge.param_domains``);
    "fixed" ones are left to the solver. mode: "uniform" (propose() returns None: the solver draws from the
    key as usual), "loss", "active" or "generative" (the module docstring). floor: share of uniform draws in "loss" and
    "active" mode, in (0, 1]. window: recent losses kept. "active" only: ensemble (2-100) bootstrap loss models,
    kappa (>= 0) the weight of their spread against their mean (log-loss units), refit: losses between fits,
    candidates: uniform points of the box the proposal resamples. The skill gate ("loss" and "active", the module
    docstring): gate (False: always steer 1 - floor), skill_window: fresh (prediction, loss) pairs kept,
    skill_min: pairs before any steering, skill_full: the skill at which the steered share is 1 - floor.
    latent_prior: None, or the IC latent's law ("normal" | "uniform", a [L], b [L]) (``LatentIC.latent_prior``):
    the proposals then draw (parameters, latent) jointly (the module docstring). "generative" only: top, the share of
    the fresh solves (by importance weight) its model is of; step, its move in prior standard deviations; refit, the
    losses between fits; probe, its steered share until its lift is measured (``proposal_lift``).
    """

    def __init__(self, domains: dict, mode: str = "loss", floor: float = 0.25, window: int = 2048,
                 bandwidth: float = 0.05, power: float = 1.0, seed: int = 0, ensemble: int = 5, kappa: float = 1.0,
                 refit: int = 256, candidates: int = 2048, gate: bool = True, skill_window: int = 256,
                 skill_min: int = 32, skill_full: float = 0.5, latent_prior: tuple | None = None, top: float = 0.25,
                 step: float = 0.25, probe: float = 0.25):
        settings = dict(floor=floor, bandwidth=bandwidth, power=power, window=window, ensemble=ensemble, kappa=kappa,
                        top=top, step=step, gate=gate, skill_full=skill_full, skill_min=skill_min, refit=refit,
                        candidates=candidates, skill_window=skill_window, probe=probe)
        check_proposal_settings(mode, **settings)
        check_proposal_uses(mode, {k: v for k, v in settings.items() if v != _DEFAULTS[k]})
        self.mode, self.floor, self.window, self.bandwidth, self.power = mode, float(floor), window, float(bandwidth), float(power)
        self.ensemble, self.kappa, self.refit, self.candidates = ensemble, float(kappa), refit, candidates
        self.gate, self.skill_window, self.skill_min, self.skill_full = gate, skill_window, skill_min, float(skill_full)
        self.seed, self.top, self.step, self.probe = seed, float(top), float(step), float(probe)
        self.names = list(domains)  # every PDE parameter, PARAMS order (the columns of batch["params"])
        self.domains = {k: tuple(v) for k, v in domains.items()}
        self.random = [k for k, (kind, *_rest) in self.domains.items() if kind != "fixed"]
        self.latent_prior = None
        if latent_prior is not None:
            kind, a, b = latent_prior
            if kind not in ("normal", "uniform") or np.shape(a) != np.shape(b) or np.ndim(a) != 1:
                raise ValueError(f"proposal latent_prior kind={kind!r} not allowed; allowed: 'normal' or 'uniform' "
                                 "with two [L] arrays")
            self.latent_prior = (kind, np.asarray(a, np.float64), np.asarray(b, np.float64))
        self.n_latent = 0 if self.latent_prior is None else len(self.latent_prior[1])
        self.dims = len(self.random) + self.n_latent  # D: the unit box's dimensions (parameters, then latent)
        self.rng = np.random.default_rng(seed)
        self.points = np.zeros((0, self.dims))  # recent training samples, unit box [W, D]
        self.losses = np.zeros(0)  # their losses [W]
        self.proposed = []  # every proposed unit point (for the plot), list of [D] lists
        self.reports = 0
        self.dropped = 0  # recorded rows refused for a non-finite loss or parameter
        self._w, self._w_at = None, 0  # pick probabilities of the recorded points, as of self._w_at reports
        # "active": the fit in use, the one running in the background (started at the last refit), and how many
        # fits were started; a fit is (candidates [C, D], probabilities [C]) or None (no fit yet: uniform)
        self._fit, self._next, self.fits = None, None, 0
        self._fit_at = 0  # reports when the last fit was started
        self._pool = None
        # the skill gate: out-of-sample (predicted, realized) log-losses of fresh solves, the last skill_window
        self.skill_pred, self.skill_real = np.zeros(0), np.zeros(0)
        # "generative": the fresh solves it learns from (unit points [G, D], losses [G], the report count when each came
        # in [G], log prior / proposal density at each [G]) and its model (the hard solves' normal scores [K, D] and
        # their log weights [K])
        self.g_points, self.g_losses = np.zeros((0, self.dims)), np.zeros(0)
        self.g_at, self.g_logiw = np.zeros(0), np.zeros(0)
        self._gen = None
        self.lift = LiftGate(skill_window)  # the steered draws' fresh losses against the uniform ones'

    # --- unit box <-> parameter values -------------------------------------------------------------
    def to_unit(self, values: np.ndarray, latent: np.ndarray | None = None) -> np.ndarray:
        """[N, P] parameter values (all PDE parameters, PARAMS order) and, with a latent prior, [N, L] IC latents ->
        [N, D] unit coordinates of the random ones (then the latent's)."""
        values = np.asarray(values, np.float64).reshape(len(values), len(self.names))
        params = params_to_unit(self.domains, self.names, self.random, values)
        if not self.n_latent:
            return params
        kind, a, b = self.latent_prior
        x = np.asarray(latent, np.float64).reshape(len(values), self.n_latent)
        z = ndtr((x - a) / b) if kind == "normal" else (x - a) / (b - a)
        return np.concatenate([params, np.clip(z, 0.0, 1.0)], 1)

    def from_unit(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """[N, D] unit coordinates -> {name: float64 [N]} values inside each domain (and LATENT: float64 [N, L],
        the IC latents, with a latent prior)."""
        out = {}
        if self.n_latent:
            kind, a, b = self.latent_prior
            u = z[:, len(self.random):]
            out[LATENT] = (a + b * ndtri(np.clip(u, UNIT_EDGE, 1 - UNIT_EDGE)) if kind == "normal"
                           else a + np.clip(u, 0.0, 1.0) * (b - a))
        out.update(unit_to_params(self.domains, self.random, z[:, : len(self.random)]))
        return out

    # --- the loop's feedback and the proposals -----------------------------------------------------
    def record(self, params: np.ndarray, losses: np.ndarray, fresh: np.ndarray | None = None,
               latent: np.ndarray | None = None, indices: np.ndarray | None = None) -> None:
        """Per-sample training losses [B] of samples with parameters [B, P] (PARAMS order). A row whose loss or
        parameters are not finite (a diverged step, a NaN parameter) is dropped and counted in ``dropped``: one
        such row would otherwise turn the pick weights, and then the proposals sent to the solver, into NaN.
        fresh: bool [B], which rows are samples trained on for the first time (their losses measure the skill
        gate, before they join the window); None: every row (a caller that reports each sample once). latent:
        [B, L], the samples' IC latents (with a latent prior; None or a NaN row: unknown, the row is dropped). indices: [B],
        the samples' indices (the lift gate scores the fresh rows of draws ``propose`` tagged; None: none)."""
        losses = np.asarray(losses, np.float64).reshape(-1)
        params = np.asarray(params, np.float64).reshape(len(losses), len(self.names))
        if self.n_latent:
            latent = (np.full((len(losses), self.n_latent), np.nan) if latent is None
                      else np.asarray(latent, np.float64).reshape(len(losses), self.n_latent))
        ok = np.isfinite(losses) & np.isfinite(params).all(axis=1)
        if self.n_latent:
            ok &= np.isfinite(latent).all(axis=1)
        self.dropped += int((~ok).sum())
        if not ok.any() or not self.dims:
            return
        fresh = np.ones(len(losses), bool) if fresh is None else np.asarray(fresh, bool).reshape(len(losses))
        unit = self.to_unit(params[ok], None if latent is None else latent[ok])
        if self.mode != "uniform" and fresh[ok].any():
            self._score(unit[fresh[ok]], losses[ok][fresh[ok]])
            if indices is not None:
                f = fresh[ok]
                self.lift.score(np.asarray(indices).reshape(len(losses))[ok][f], self._log(losses[ok][f]))
        if self.mode == "generative" and fresh[ok].any():
            # first-draw losses only: the loss of a solve the model has not trained on is the difficulty the
            # proposal is asked to find (a replayed sample's loss falls as the model learns it)
            new = unit[fresh[ok]]
            self.g_points = np.concatenate([self.g_points, new])[-self.window :]
            self.g_losses = np.concatenate([self.g_losses, losses[ok][fresh[ok]]])[-self.window :]
            self.g_at = np.concatenate([self.g_at, np.full(len(new), float(self.reports))])[-self.window :]
            self.g_logiw = np.concatenate([self.g_logiw, self._log_iw(new)])[-self.window :]
        self.points = np.concatenate([self.points, unit])[-self.window :]
        self.losses = np.concatenate([self.losses, losses[ok]])[-self.window :]
        self.reports += int(ok.sum())
        if self.mode == "active" and self.reports - self._fit_at >= self.refit:
            self._start_fit()
        elif self.mode == "generative" and self.reports - self._fit_at >= self.refit:
            # milliseconds (a sort and a running median of at most ``window`` losses): in the loop, no thread
            self._gen = generative_fit(normal_scores(self.g_points), self.g_losses, self.g_at, self.g_logiw, self.top)
            self.fits += 1
            self._fit_at = self.reports

    def _log_iw(self, z: np.ndarray) -> np.ndarray:
        """log(prior density / proposal density) at unit points z [N, D] under the proposal in use now: the
        importance weights that let the generative fit target the prior's own high-difficulty region, not where
        earlier proposals went. The proposal is (1 - steer) prior + steer model, so the weight is at most
        1 / (1 - steer) <= 1 / floor (defensive importance sampling: the floor bounds the weights)."""
        if self._gen is None or self.steer == 0.0:
            return np.zeros(len(z))
        llr = log_ratio(normal_scores(z), *self._gen[:2], self.step)
        return -np.logaddexp(math.log1p(-self.steer), math.log(self.steer) + llr)

    def _start_fit(self) -> None:
        """Refit point: the fit started at the previous refit goes into use (waiting for it only if it has not
        finished in a whole refit interval), and a new one starts in the background on a copy of the window."""
        if self._next is not None:
            self._fit = self._next.result()
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="proposal-fit")
        args = (self.points.copy(), self.losses.copy(), self.candidates, self.ensemble, self.kappa, self.power,
                np.random.default_rng([self.seed, 7, self.fits]))
        more = {"coords": self.model_coords} if self.n_latent else {}  # (a parameters-only fit: as before)
        self._next = self._pool.submit(active_fit, *args, **more)
        self.fits += 1
        self._fit_at = self.reports

    def _score(self, z: np.ndarray, losses: np.ndarray) -> None:
        """The skill gate's pairs: the loss model's out-of-sample log-loss prediction at fresh unit points z [F, D]
        against their realized losses [F] (nothing while there is no model: no fit yet, an empty window)."""
        pred = self.predict(z)
        if pred is None:
            return
        real = self._log(losses)
        self.skill_pred = np.concatenate([self.skill_pred, pred])[-self.skill_window :]
        self.skill_real = np.concatenate([self.skill_real, real])[-self.skill_window :]

    def _log(self, losses: np.ndarray) -> np.ndarray:
        """log of losses [F], a loss <= 0 counted as the smallest positive one recorded (log of 0 is no number)."""
        positive = np.concatenate([self.losses, losses])
        positive = positive[positive > 0]
        return np.log(np.maximum(losses, positive.min() if len(positive) else 1e-30))

    def predict(self, z: np.ndarray) -> np.ndarray | None:
        """The loss model's predicted log-loss at unit points z [N, D], or None without one: "active", the mean
        of the ensemble fit in use; "loss", the kernel average (width ``bandwidth``) of the recorded log-losses;
        "generative", a score that rises with it, the model's log density ratio to the prior (Bayes: the log odds of
        high difficulty, up to a constant; the gate's correlation asks no more)."""
        if self.mode == "active":
            if self._fit is None or len(self._fit) < 3:  # no fit yet (or one restored from before the gate)
                return None
            return features(self.model_coords(z), lattice(z.shape[1])) @ self._fit[2]
        if self.mode == "generative":
            if self._gen is None:
                return None
            # the hard set's smooth summary (a diagonal Gaussian), not the kernel mixture drawn from: the mixture is
            # local, ~0 at any uniform draw, and would keep the gate shut for want of a prediction
            return gauss_ratio(normal_scores(z), *self._gen[2:])
        if self.mode == "loss" and len(self.losses):
            y = self._log(self.losses)
            k = np.exp(-0.5 * ((z[:, None, :] - self.points[None]) ** 2).sum(-1) / self.bandwidth**2)  # [N, W]
            total = k.sum(1)
            return np.where(total > 1e-12, (k @ y) / np.maximum(total, 1e-300), y.mean())
        return None

    def model_coords(self, z: np.ndarray) -> np.ndarray:
        """Unit points [N, D] -> the coordinates the "active" loss model reads [N, D]: a normal latent coordinate as
        0.5 + x / 6 (x: the latent in standard deviations), every other one as it is."""
        if not self.n_latent or self.latent_prior[0] != "normal":
            return z
        out = z.copy()
        u = np.clip(z[:, len(self.random):], UNIT_EDGE, 1 - UNIT_EDGE)
        out[:, len(self.random):] = 0.5 + ndtri(u) / 6.0
        return out

    @property
    def skill(self) -> float:
        """The correlation of the fresh (predicted, realized) log-losses, each less its running median over the
        ``LEVEL_SPAN`` pairs nearest in arrival, minus 2 / sqrt(n - 1), floored at 0; 0 below ``skill_min`` pairs."""
        n = len(self.skill_pred)
        if n < self.skill_min:
            return 0.0
        # Where the pairs came in: the loss level falls as the model trains, and a predictor that follows the level
        # (a kernel average of recent losses far from any point, a refitted intercept) correlates with the realized
        # losses through it alone, with no idea where in the box the loss is high (kdv1d: "skill" 0.64, the steered
        # draws 0.69x as hard as uniform ones). Only the departures from the level at the time count.
        at = np.arange(n, dtype=np.float64)
        pred = self.skill_pred - running_median(self.skill_pred, at, LEVEL_SPAN)
        real = self.skill_real - running_median(self.skill_real, at, LEVEL_SPAN)
        return max(0.0, correlation(pred, real) - 2.0 / math.sqrt(n - 1))

    @property
    def steer(self) -> float:
        """The share of steered draws (the module docstring's w; 1 - floor without the gate; 0 in "uniform" mode)."""
        if self.mode == "uniform":
            return 0.0
        if not self.gate:
            return 1.0 - self.floor
        if self.lift.vetoed():  # the steered draws are measurably easier than uniform ones: never do harm
            return 0.0
        opened = self.skill / self.skill_full
        lift = self.lift.bounds()
        if lift is not None:
            opened = max(opened, lift[0] / LIFT_FULL)
        w = (1.0 - self.floor) * min(1.0, max(0.0, opened))
        if self.mode == "generative" and self.lift.indexed and self.lift.probed < LIFT_MIN and self._gen is not None:
            w = max(w, min(self.probe, 1.0 - self.floor))  # probing: its lift can only be measured on steered draws
        return w

    def propose(self, n: int, indices: np.ndarray | None = None) -> dict[str, np.ndarray] | None:
        """Explicit values {name: float64 [n]} for the next n solves; None in "uniform" mode (key draws). indices:
        the n solves' sample indices (the lift gate tags each draw steered or uniform by them; None: no tags)."""
        if self.mode == "uniform" or not self.dims:
            return None
        if indices is not None:
            self.lift.indexed = True  # (before the share is read: a generative proposal may probe from this draw on)
        z = self.rng.random((n, self.dims))  # the uniform part
        steer = self.rng.random(n) >= 1.0 - self.steer  # ungated (steer = 1 - floor): the draws of before the gate
        if steer.any():
            moved = self.steered(int(steer.sum()), self.rng)
            if moved is not None:
                z[steer] = moved
            else:
                steer[:] = False  # nothing to steer by yet: these draws are uniform
        if indices is not None:
            self.lift.tag(indices, steer)
        self.proposed.extend(z.tolist())
        return self.from_unit(z)

    def steered(self, n: int, rng: np.random.Generator) -> np.ndarray | None:
        """n draws of the steered part alone (no uniform floor, no gate), unit points [n, D] inside the box, drawn
        with ``rng``; None while there is nothing to steer by (no fit, no loss yet)."""
        d = self.dims
        if self.mode == "active":
            if self._fit is None:
                return None
            cand, prob = self._fit[:2]
            pick = rng.choice(len(prob), size=n, p=prob)
            # about one candidate spacing: the density is continuous, yet as sharp as the candidates resolve
            # (beyond 4 dimensions, a 4-D set's spacing: a high-dimensional spacing would undo the steering)
            width = 0.5 * len(prob) ** (-1.0 / min(d, 4))
            moved = np.abs(cand[pick] + width * rng.standard_normal((len(pick), d)))
            return np.clip(1.0 - np.abs(1.0 - moved), 0.0, 1.0)
        if self.mode == "generative":
            if self._gen is None:
                return None
            centres, log_v = self._gen[:2]
            pick = rng.choice(len(log_v), size=n, p=np.exp(log_v))
            # a prior-preserving move (pCN): a draw of N(0, I) moved so stays one, whatever the step
            w = math.sqrt(1.0 - self.step**2) * centres[pick] + self.step * rng.standard_normal((n, d))
            # normal scores -> unit coordinates: ndtr maps every real onto (0, 1), the prior's support by construction
            return np.clip(ndtr(w), UNIT_EDGE, 1 - UNIT_EDGE)
        if self.mode == "loss" and len(self.losses):
            # The recorded points were drawn from earlier proposals, so they crowd where the loss was high; weighting
            # them by loss alone would compound that (loss x crowding) and pile every solve into one corner. Divide
            # by the points' own kernel density so that the steered draws follow the loss, not the crowding.
            w = self._weights()
            pick = rng.choice(len(w), size=n, p=w)
            moved = self.points[pick] + self.bandwidth * rng.standard_normal((len(pick), d))
            moved = np.abs(moved)  # reflect at 0 ...
            moved = 1.0 - np.abs(1.0 - moved)  # ... and at 1
            return np.clip(moved, 0.0, 1.0)
        return None

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
        # floored at the smallest positive float: in many dimensions (an IC latent) a point outside the subset has no
        # neighbour within the kernel's reach, and a density of 0 made its weight NaN (in a few dimensions no density
        # comes near the floor: their weights are as before)
        return np.maximum(np.exp(-0.5 * (diff**2).sum(-1) / self.bandwidth**2).mean(1), np.finfo(np.float64).tiny)

    def density(self, bins: int = 20) -> dict:
        """For plots and reports (``proposal_box.density``): along the first random parameter, the proposals' counts
        and the mean recent loss per bin."""
        return density(np.asarray(self.proposed).reshape(-1, self.dims) if self.random else None, self.points,
                       self.losses, bins)

    # --- state -------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything the next proposals depend on (plain values; loads with torch.load(weights_only=True))."""
        return {"mode": self.mode, "rng": _plain(self.rng.bit_generator.state), "points": self.points.tolist(),
                "losses": self.losses.tolist(), "proposed": list(self.proposed), "dims": self.dims, "reports": self.reports, "dropped": self.dropped,
                "weights": None if self._w is None else self._w.tolist(), "weights_at": self._w_at,
                "fit": _fit_plain(self._fit), "next_fit": _fit_plain(None if self._next is None else self._next.result()),
                "fits": self.fits, "fit_at": self._fit_at, "skill_pred": self.skill_pred.tolist(),
                "skill_real": self.skill_real.tolist(), "top": self.top,
                "generative": {"points": self.g_points.tolist(), "losses": self.g_losses.tolist(),
                               "at": self.g_at.tolist(), "log_iw": self.g_logiw.tolist(),
                               "model": None if self._gen is None else [x.tolist() for x in self._gen]},
                "lift": self.lift.state()}

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict()`` output (the same domains and mode are required)."""
        if state.get("mode") != self.mode:
            raise ValueError(f"proposal state has mode {state.get('mode')!r}, this proposal {self.mode!r}")
        if state.get("dims", len(self.random)) != self.dims:  # (states saved before the latent: parameters only)
            raise ValueError(f"proposal state has {state.get('dims')} dimensions, this proposal {self.dims} (another "
                             "proposal space: params or params+ic)")
        self.rng.bit_generator.state = state["rng"]
        self.points = np.asarray(state["points"], np.float64).reshape(-1, self.dims)
        self.losses = np.asarray(state["losses"], np.float64)
        self.proposed = [list(p) for p in state["proposed"]]
        self.reports = int(state["reports"])
        self.dropped = int(state.get("dropped", 0))  # states saved before the count existed have none
        self._w = None if state.get("weights") is None else np.asarray(state["weights"], np.float64)
        self._w_at = int(state.get("weights_at", 0))
        self._fit = _fit_array(state.get("fit"), self.dims)
        following = _fit_array(state.get("next_fit"), self.dims)
        self._next = None
        if following is not None:
            self._next = Future()
            self._next.set_result(following)
        self.fits, self._fit_at = int(state.get("fits", 0)), int(state.get("fit_at", 0))
        # states saved before the gate have no pairs: the gate starts closed and opens on measured skill
        self.skill_pred = np.asarray(state.get("skill_pred", []), np.float64)
        self.skill_real = np.asarray(state.get("skill_real", []), np.float64)
        gen = state.get("generative") or {}  # (states saved before the generative mode: none)
        self.g_points = np.asarray(gen.get("points", []), np.float64).reshape(-1, self.dims)
        self.g_losses = np.asarray(gen.get("losses", []), np.float64)
        self.g_at = np.asarray(gen.get("at", []), np.float64)
        self.g_logiw = np.asarray(gen.get("log_iw", []), np.float64)
        model = gen.get("model")
        self._gen = None if model is None else tuple(np.asarray(x, np.float64) for x in model)
        self.lift.load(state.get("lift"))  # (states saved before the lift gate: none, it starts empty)

    def __getstate__(self):
        # copy.deepcopy / pickle: the background fit is resolved into its result, the thread pool is not copied
        state = dict(self.__dict__)
        state["_pool"] = None
        state["_next"] = None if self._next is None else self._next.result()
        return state

    def __setstate__(self, state):
        following = state.pop("_next")
        self.__dict__.update(state)
        self._next = None
        if following is not None:
            self._next = Future()
            self._next.set_result(following)

    def close(self) -> None:
        """Let the background fit finish and the thread end (a later refit starts a new one)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


_DEFAULTS = {k: p.default for k, p in inspect.signature(ParamProposal.__init__).parameters.items() if p.default is not p.empty}
