"""The numerics behind ``datasets.proposal.ParamProposal``: the "active" loss model and its uncertainty, the
"generative" model of the hard inputs, the loss-weighted picks, the skill gate's statistics; numpy (torch for the
normal CDF), seeded by the caller.

In ``"active"`` mode the loss signal is kept and an uncertainty signal added, both predicted over the whole box
(a candidate parameter has no solution yet, so neither its loss nor a model's disagreement on it can be measured):

- a **loss model**: a ridge regression of log(recent per-sample loss) on Gaussian bumps over the unit box (a
  lattice of centres, plus constant and linear terms), refitted every ``refit`` reported losses;
- its **uncertainty**: ``ensemble`` (>= 2) such regressions, each on a bootstrap resample of the window and
  with its own random prior; the spread (std) of their predictions is high where few or discordant losses were seen (AL4PDE's and OGAS's
  ensemble-disagreement signal, on the loss model instead of K surrogates, so it costs milliseconds);
- the **proposal**: ``candidates`` uniform points of the box, resampled with probability proportional to
  exp(power (mean + kappa spread)) of the predicted log-loss and jittered by about one candidate spacing, so
  its density follows the acquisition and can hold a sharp mode at one end of a parameter; with probability
  ``floor`` a uniform draw instead (no region starves).

In ``"generative"`` mode (OGAS's idea, a conditional generative model of the inputs given difficulty, at its
smallest) the proposal learns p(x | high difficulty) from the fresh solves and draws from it:

- **coordinates**: every unit coordinate as its normal score ndtri(z) (``normal_scores``): the prior becomes N(0, I)
  and a normal IC latent coordinate is the latent in standard deviations; a draw maps back by ndtr, which sends every
  real number into (0, 1), so no draw leaves the prior's support;
- **data**: the first-draw losses only (``fresh``: a solve the model has not trained on, the difficulty asked for; a
  replayed sample's loss falls as the model learns it), the last ``window`` of them; difficulty = log-loss less the
  running median of the 33 solves nearest in time (an early solve is not harder for having been scored by a worse
  model);
- **model** (``generative_fit``, every ``refit`` reported losses, milliseconds, in the loop): the top ``top`` share
  (25%) of the solves by difficulty, each weighted by prior / proposal density at it (recorded when it came in), so
  the model is of the *prior's* high-difficulty region, not of where earlier proposals went (the floor bounds the
  weights by 1 / floor); a diagonal Gaussian of that set, its per-coordinate mean and log variance soft-thresholded
  toward the prior's by the universal threshold (sqrt(2 ln 2D) null standard errors): a coordinate departs from the
  prior only where the set's moments do beyond noise, so in 171 dimensions with 64 hard solves the noise coordinates
  stay the prior. Why a diagonal Gaussian, not a flow or a mixture: 256 solves give a few dozen hard ones, which
  fix D means and variances but not a D x D covariance or a flow's weights, and a variance per coordinate is what
  an energy-driven difficulty (a mode's amplitude, either sign) needs; no library, a few dozen lines of numpy;
- **its predictor** for the skill gate: the log density ratio of the model to the prior at a point (by Bayes, the
  log odds that the point is of high difficulty, up to a constant).

**The skill statistic** (``correlation`` of log-losses less their ``running_median``): A correlation, not R^2: the
loss level falls as the model trains and the ridge fit shrinks, so an R^2 of the raw predictions is negative for a
model that places the high losses right; a correlation only asks whether the predictions go up where the losses do
(r^2 is the share of the log-loss variance the predictions explain once recalibrated). Of log-losses because per-
sample losses are heavy-tailed and the proposal works in log. Not a rank correlation: where a sharp region of high
loss sits in a bulk of noisy low losses (the case steering is for), the bulk's random order drowns Spearman's rho
(0.23 against r = 0.83 on the test suite's sharp-mode problem) although the model finds the region.

**IC latents in the loss model:** Beyond a few dimensions the loss model's lattice of bumps would have 3^D centres:
from LATTICE_MOST of them on it is constant + linear + per-axis quadratic terms instead, and the steered draws'
jitter stays that of a 4-D candidate set. The "active" loss model reads a normal latent coordinate as the latent
itself (0.5 + x / 6: +-3 standard deviations span [0, 1]), not as its unit coordinate (the CDF flattens the tails
where a size-driven loss grows): per-axis squares are then squared amplitudes, and a loss driven by a mode's energy
is in the model's span.
"""

from __future__ import annotations

import math

import numpy as np
import torch

LATTICE_MOST = 1024  # most bump centres of the loss model; beyond them, per-axis quadratic terms
LEVEL_SPAN = 33  # fresh solves whose median is the loss level at a time (the skill gate, the generative proposal)
UNIT_EDGE = 1e-7  # unit coordinates of a normal prior are kept this far inside (0, 1): its inverse CDF is finite


def ndtr(x: np.ndarray) -> np.ndarray:
    """The standard normal CDF, float64 (torch's: scipy is not a dependency)."""
    return torch.special.ndtr(torch.from_numpy(np.asarray(x, np.float64))).numpy()


def ndtri(u: np.ndarray) -> np.ndarray:
    """The standard normal inverse CDF of u in (0, 1), float64."""
    return torch.special.ndtri(torch.from_numpy(np.asarray(u, np.float64))).numpy()


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


def lattice(d: int, target: int = 64, most: int = 12) -> np.ndarray:
    """Centres of the loss model's bumps [M, D]: per axis m = clip(round(target ** (1 / D)), 3, most) evenly
    spaced points of [0, 1] (D = 1: 12, D = 2: 8 x 8, D = 3: 4 x 4 x 4), all their combinations; none ([0, D]) when
    they would be more than LATTICE_MOST (D >= 7: ``features`` then has per-axis quadratic terms)."""
    m = int(min(most, max(3, round(target ** (1.0 / d)))))
    if m**d > LATTICE_MOST:
        return np.zeros((0, d))
    axes = np.meshgrid(*[np.linspace(0, 1, m)] * d, indexing="ij")
    return np.stack([a.reshape(-1) for a in axes], 1)


def features(z: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """[N, D] unit points -> [N, 1 + D + M] features: constant, linear, and Gaussian bumps of width one lattice
    spacing at ``centres`` [M, D]; with no centres (a high D), [N, 1 + 2 D]: constant, linear and per-axis squares."""
    if not len(centres):
        return np.concatenate([np.ones((len(z), 1)), z - 0.5, 4.0 * (z - 0.5) ** 2], 1)
    m = round(len(centres) ** (1.0 / z.shape[1]))
    width = 1.0 / max(m - 1, 1)
    d2 = ((z[:, None, :] - centres[None]) ** 2).sum(-1)
    return np.concatenate([np.ones((len(z), 1)), z - 0.5, np.exp(-0.5 * d2 / width**2)], 1)


def loss_model(points: np.ndarray, losses: np.ndarray, at: np.ndarray, ensemble: int,
               rng: np.random.Generator, ridge: float = 1e-2, return_coef: bool = False) -> tuple:
    """Predicted log-loss at ``at`` [C, D] from recorded (points [W, D], losses [W]): the mean [C] and the spread
    (std, [C]) of ``ensemble`` ridge regressions, each fitted to a bootstrap resample of the window and shrunk
    toward its own random prior weights (Osband et al.'s randomized priors) rather than toward zero: where losses
    were seen the data outweigh the priors and the members agree; where none were, each keeps its prior and they
    disagree (plain bootstrapped ridge regressions would all shrink to the same value there, with no spread).
    The priors' scale is the spread of the log-losses. Losses <= 0 count as the smallest positive one (log of 0
    is not a number); inputs are finite (``record``). return_coef: also the members' mean weights [1 + D + M] (the
    mean prediction anywhere is ``features(z, lattice(D)) @ coef``: what the skill gate scores)."""
    positive = losses[losses > 0]
    y = np.log(np.maximum(losses, positive.min() if len(positive) else 1e-30))
    centres = lattice(points.shape[1])
    phi, phi_at = features(points, centres), features(at, centres)
    k = phi.shape[1]
    reg = ridge * np.eye(k)
    reg[0, 0] = 0.0  # the mean level is not shrunk
    scale = max(float(y.std()), 1e-3)
    preds, coef = np.empty((ensemble, len(at))), np.zeros(k)
    for e in range(ensemble):
        b = rng.integers(len(y), size=len(y))
        prior = scale * rng.standard_normal(k)
        prior[0] = 0.0
        a = phi[b]
        w = np.linalg.solve(a.T @ a / len(b) + reg, a.T @ y[b] / len(b) + reg @ prior)
        preds[e] = phi_at @ w
        coef += w / ensemble
    if return_coef:
        return preds.mean(0), preds.std(0, ddof=1), coef
    return preds.mean(0), preds.std(0, ddof=1)


def active_fit(points: np.ndarray, losses: np.ndarray, candidates: int, ensemble: int, kappa: float,
               power: float, rng: np.random.Generator, coords=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One refit of the "active" proposal: ``candidates`` uniform points of the unit box [C, D] and their
    probabilities [C], proportional to exp(power (mean + kappa spread)) of the loss model's predicted log-loss
    (``loss_model``): a resampling of uniform points, so the proposal's density follows that acquisition; and the
    mean model's weights (the skill gate's predictor). coords: unit points -> the model's coordinates (None: the
    unit points themselves; ``ParamProposal.model_coords``)."""
    cand = rng.random((candidates, points.shape[1]))
    if coords is not None:
        mean, spread, coef = loss_model(coords(points), losses, coords(cand), ensemble, rng, return_coef=True)
    else:
        mean, spread, coef = loss_model(points, losses, cand, ensemble, rng, return_coef=True)
    score = power * (mean + kappa * spread)
    w = np.exp(score - score.max())
    return cand, w / w.sum(), coef


def normal_scores(z: np.ndarray) -> np.ndarray:
    """Unit points [N, D] -> their normal scores ndtri(z) [N, D]: the prior (uniform on the box) becomes N(0, I), and a
    normal latent coordinate becomes the latent in standard deviations."""
    return ndtri(np.clip(z, UNIT_EDGE, 1 - UNIT_EDGE))


def gauss_ratio(w: np.ndarray, mean: np.ndarray, log_sd: np.ndarray) -> np.ndarray:
    """log N(w; mean, diag(exp(2 log_sd))) - log N(w; 0, I) at normal scores w [N, D] -> [N]."""
    return (-0.5 * ((w - mean) / np.exp(log_sd)) ** 2 - log_sd + 0.5 * w**2).sum(1)


def log_ratio(w: np.ndarray, centres: np.ndarray, log_v: np.ndarray, step: float) -> np.ndarray:
    """log of the generative model's density over the prior's, at normal scores w [N, D] -> [N]: the model is the
    mixture sum_k v_k N(sqrt(1 - step^2) c_k, step^2 I) over its centres c [K, D] (log weights log_v [K])."""
    rho, d = math.sqrt(1.0 - step**2), w.shape[1]
    d2 = (w**2).sum(1)[:, None] - 2 * rho * w @ centres.T + rho**2 * (centres**2).sum(1)[None]  # [N, K]
    logk = log_v[None] - 0.5 * np.maximum(d2, 0.0) / step**2 - d * math.log(step)
    peak = logk.max(1)
    return peak + np.log(np.exp(logk - peak[:, None]).sum(1)) + 0.5 * (w**2).sum(1)


def running_median(y: np.ndarray, at: np.ndarray, span: int) -> np.ndarray:
    """The median of y [G] over the ``span`` values nearest in ``at`` [G] order (centred, shorter at the ends): the
    level a value is compared with when the level drifts (a first-draw loss falls as the model trains, fast at first:
    no line fits it)."""
    order = np.argsort(at, kind="stable")
    ys = y[order]
    half, n = span // 2, len(ys)
    ends = [i for i in range(n) if i < half or i + half >= n]
    level = np.empty(n)
    level[ends] = [np.median(ys[max(0, i - half): i + half + 1]) for i in ends]
    if n > 2 * half:
        level[half: n - half] = np.median(np.lib.stride_tricks.sliding_window_view(ys, 2 * half + 1), axis=1)
    out = np.empty_like(y)
    out[order] = level
    return out


def generative_fit(w: np.ndarray, losses: np.ndarray, at: np.ndarray, log_iw: np.ndarray, top: float,
                   least: int = 8, span: int = LEVEL_SPAN) -> tuple[np.ndarray, np.ndarray] | None:
    """The generative proposal's model of the high-difficulty solves, or None with fewer than ``least`` of them.

    w: normal scores of fresh solves [G, D]; losses [G] (first-draw losses); at [G]: when each came in (reports);
    log_iw [G]: log prior / proposal density at each. Difficulty is the log-loss less the running median of the
    ``span`` solves nearest in time (the loss level falls as the model trains: an early solve is not harder for having
    been scored by a worse model). The
    high-difficulty set is the top ``top`` share of the solves by difficulty, counted in importance weight (so of the
    prior, not of where earlier proposals went). The model: that set and its normalized weights (centres [K, D], log
    weights [K]), drawn from as a kernel mixture (``ParamProposal.steered``); and its summary for the skill gate, the
    weighted per-coordinate mean [D] and log std [D], soft-thresholded toward the prior's (0, 0) by the universal
    threshold max(2, sqrt(2 ln 2D)) null standard errors (1 / sqrt(n), sqrt(2 / (n - 1)); n the set's effective
    size), so that only coordinates whose moments differ from the prior's beyond noise count (``gauss_ratio``)."""
    positive = losses[losses > 0]
    if len(positive) < least:
        return None
    y = np.log(np.maximum(losses, positive.min()))
    hard = y - running_median(y, at, span)
    iw = np.exp(log_iw - log_iw.max())
    order = np.argsort(-hard, kind="stable")
    keep = order[np.cumsum(iw[order]) - iw[order] < top * iw.sum()]  # the top share by weight
    # a steered draw near a centre in many dimensions has weight ~e^-300: no centre (it would cost time, not move a draw)
    keep = keep[iw[keep] > 1e-12 * iw[keep].max()]
    if len(keep) < least:
        return None
    v = iw[keep] / iw[keep].sum()
    n = 1.0 / float(v @ v)  # effective size
    mean = v @ w[keep]
    log_var = np.log(np.maximum(v @ (w[keep] - mean) ** 2 * n / max(n - 1.0, 1.0), 1e-12))
    cut = max(2.0, math.sqrt(2.0 * math.log(2.0 * w.shape[1])))
    mean = np.sign(mean) * np.maximum(np.abs(mean) - cut / math.sqrt(n), 0.0)
    log_var = np.sign(log_var) * np.maximum(np.abs(log_var) - cut * math.sqrt(2.0 / max(n - 1.0, 1.0)), 0.0)
    return w[keep].copy(), np.log(v), mean, 0.5 * np.clip(log_var, -2 * math.log(5.0), 2 * math.log(3.0))


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's correlation of a [N] and b [N]; 0 when either is constant (a flat prediction has no skill)."""
    a, b = a - a.mean(), b - b.mean()
    denom = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / denom if denom > 1e-300 else 0.0


def _fit_plain(fit):
    if fit is None:
        return None
    return {"candidates": fit[0].tolist(), "prob": fit[1].tolist(), **({"coef": fit[2].tolist()} if len(fit) > 2 else {})}


def _fit_array(fit, d: int):
    if fit is None:
        return None
    out = (np.asarray(fit["candidates"], np.float64).reshape(-1, d), np.asarray(fit["prob"], np.float64))
    return out + (np.asarray(fit["coef"], np.float64),) if "coef" in fit else out


def _plain(state):
    """numpy bit-generator state -> plain dict/int/str (no numpy scalars)."""
    if isinstance(state, dict):
        return {k: _plain(v) for k, v in state.items()}
    return int(state) if isinstance(state, (np.integer, int)) and not isinstance(state, bool) else state


