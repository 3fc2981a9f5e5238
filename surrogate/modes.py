"""Training modes: how one optimizer step of the training loop turns a batch into a loss.

Every mode trains on a stream or cache batch {"x": [B, k_in, C, *space], "y": [B, k_out, C, *space],
"params": [B, P], ...} and implements the same small interface (``Mode``), so the loop in ``train.py`` has no
per-mode branches:

- ``OneStep``: the model maps the input frames to the view's k_out next frames (any view; today's training).
- ``Pushforward(k)``: per example draw n ~ U{0..k-1}, unroll the network n steps without gradient from the
  input frames, train the next step against the frame n+1 ahead (Brandstetter et al. 2022, "Message passing
  neural PDE solvers", whose code draws the unroll count the same way). Always n = k-1 does not work: the
  network is then never trained on a true input, and learned a map whose 4th power is right and whose single
  steps alternate (burgers1d n=128, k=4, 5000 steps: rollout error 1.8 on odd frames, 0.06 on even ones).
- ``Oracle(k)``: per example draw j ~ U{0..k}, unroll the network j steps without gradient from the stream
  state, ask the PDE's solver (``datasets.SolverOracle``) for the true next frame from the state reached, and
  train on (reached state, solver answer): the network's own distribution, labelled by the solver. j = 0 (the
  stream state itself) is kept on purpose: with j >= 1 only, an untrained network's states collapse to nearly
  constant fields whose solver answer is the same field, and the network learns that fixed point (burgers1d
  n=32, 20 steps: training loss 7e-6, held-out rollout error 1.0).
- ``SolverInTheLoop(k, coarse_n)``: a correction network applied after each step of a coarse differentiable
  solver (``datasets.SolverStep`` on a coarse grid of the same PDE), unrolled k steps with gradients through
  the solver; the target is the fine solve of the same sample, restricted to the coarse grid (Um et al. 2020).
  With ``noise`` > 0 the coarse start state is perturbed (N(0, noise^2) in normalized units), the targets clean: at unroll 1 the
  noise baseline on the corrector (non-interacting pairs with SGGP+20's perturbed inputs).
- ``Noise(sigma)``: one-step training on perturbed inputs (Sanchez-Gonzalez et al. 2020, "Learning to simulate
  complex physics with graph networks"): Gaussian noise on the input frames, the target the clean next frames,
  so the network learns to undo an error in its input as well as to advance it (the error a rollout feeds it).

Modes that unroll predict one frame per network call and read ``frames_ahead`` frames from a next-step view
(``training_view`` sets k_out to that). All of them work in normalized units (``datasets.Normalization``).
Every mode takes ``loss``: "mse" (default: mean squared error over the batch) or "relative" (the mean of the
per-example relative L2 errors, the FNO paper's training loss): MSE spends nothing on a trajectory whose target
is small (a decayed flow), while the relative L2 the evaluation reports weighs every trajectory alike. Both are
taken in normalized units: "relative" is the evaluation's physical relative L2 for fields whose normalization
mean is about zero (velocities, vorticity, deviations); for a field with a large offset its denominator is the
deviation from that offset, not the field.
Randomness (pushforward's n, the oracle's j, the noise) is a pure function of (seed, step), so a resumed run draws what the
uninterrupted one drew.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

from pdestream import datasets
from pdestream.datasets.normalize import Normalization

from ..boundaries import kinds, periodic_words
from .mode_table import (
    DEFAULTS,
    MODE_NAMES,
    NOISE_RULE,
    SITL_NOISE_RULE,
    check_coarse_grid,
    check_mode_k_in,
    check_window,
    mode_settings,
    restricts_periodic,
)
from .models import zero_output
from .predict import model_channels, net_step, pairs, predict, relative_errors, rollout, stack_frames

LOSSES = ("mse", "relative")


def objective(loss: str, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The scalar training loss of pred against target [B, ...] (normalized units): "mse", or "relative", the
    mean over examples of ||pred - target|| / ||target|| (the norm of a target of zeros counted as 1e-12)."""
    if loss == "mse":
        return F.mse_loss(pred, target)
    return ((pred - target).flatten(1).norm(dim=1) / target.flatten(1).norm(dim=1).clamp_min(1e-12)).mean()


def _with_loss(settings: dict, loss: str) -> dict:
    """A mode's settings with its loss (left out when "mse": run.json files written before the setting existed
    compare equal)."""
    return settings if loss == "mse" else {**settings, "loss": loss}


class Mode(Protocol):
    """What the training loop and the evaluation need of a mode."""

    name: ClassVar[str]

    def settings(self) -> dict:
        """JSON-able settings (run.json's "mode"): {"name": ..., "unroll": k, ...}."""

    def bind(self, pde, seed: int = 0) -> "Mode":
        """Attach what the mode needs of the training PDE (a solver); returns self."""

    def frames_ahead(self, view) -> int:
        """Target frames per example the mode reads from a next-step view."""

    def train_view(self, view):
        """The view the mode trains on, made from the one asked for; ValueError (one line) when it cannot."""

    def channels(self, pde, view) -> tuple[int, int]:
        """(in_channels, out_channels) of the network."""

    def step_loss(self, model: nn.Module, batch: dict, norm: Normalization, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(scalar loss with graph, per-example relative L2 error float64 CPU [B]) for optimizer step ``step``."""

    def rollout(self, model: nn.Module | None, norm: Normalization, u: torch.Tensor, params: torch.Tensor,
                k_in: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Autoregressive prediction of whole trajectories u [B, T, C, *space] (physical units) from their first
        k_in frames: (prediction, truth), both [B, T - k_in, C, *space'] in physical units on the grid the mode
        predicts on."""

    def one_step(self, model: nn.Module, norm: Normalization, batch: dict, view) -> tuple[torch.Tensor, torch.Tensor]:
        """(prediction, truth) of every one-step pair of the whole trajectories in ``batch`` (physical units):
        the training view's pairs for one-step, (frame, next frame) for the modes that unroll."""


def _unrolling_view(mode, view):
    """A next-step ``view`` reading ``mode.frames_ahead`` frames ahead; ValueError for a view without windows."""
    if view.rollout_k_in is None:  # the view makes no windows of frames to unroll over
        raise ValueError(f"--mode {mode.name} needs the next_step view, not {view.name!r}; use --view next_step")
    if view.frames_out != 1:  # the mode predicts one frame per network call
        raise ValueError(f"--k-out={view.frames_out} goes with --mode one-step; --mode {mode.name} predicts one frame "
                         "per step and reads --unroll frames ahead")
    return view.ahead(mode.frames_ahead(view))


@torch.no_grad()
def _net_one_step(model: nn.Module, norm: Normalization, batch: dict, view, chunk: int = 256):
    """(prediction, truth) of every (x, y) pair ``view`` makes of the whole trajectories in ``batch``, physical
    units, predicted ``chunk`` pairs at a time."""
    p = pairs(view, batch)
    pred = [predict(model, norm, p["x"][s:s + chunk], p["params"][s:s + chunk], model.ndim, p["y"][s:s + chunk].shape)
            for s in range(0, len(p["x"]), chunk)]
    return torch.cat(pred), p["y"]


@torch.no_grad()
def _net_rollout(model: nn.Module, norm: Normalization, u: torch.Tensor, params: torch.Tensor, k_in: int):
    h = u.shape[1] - k_in
    pred = rollout(model, norm.normalize(u[:, :k_in]), norm.normalize_params(params), h)
    return norm.denormalize(pred), u[:, k_in:]


@dataclass
class OneStep:
    """The model maps k_in frames to the view's k_out frames (or an operator view's x to y) in one call."""

    name: ClassVar[str] = "one-step"
    unroll: int = 1
    loss: str = "mse"

    def settings(self) -> dict:
        return _with_loss({"name": self.name}, self.loss)

    def bind(self, pde, seed: int = 0) -> "OneStep":
        return self

    def frames_ahead(self, view) -> int:
        return view.frames_out

    def train_view(self, view):
        return view

    def channels(self, pde, view) -> tuple[int, int]:
        return model_channels(pde, view)

    def step_loss(self, model, batch, norm, step):
        target = stack_frames(norm.of_y.normalize(batch["y"]), model.ndim)  # [B, k_out*C, *space]
        pred = model(stack_frames(norm.of_x.normalize(batch["x"]), model.ndim), norm.normalize_params(batch["params"]))
        return objective(self.loss, pred, target), relative_errors(pred, target)

    def rollout(self, model, norm, u, params, k_in):
        return _net_rollout(model, norm, u, params, k_in)

    def one_step(self, model, norm, batch, view):
        return _net_one_step(model, norm, batch, view)


def _unrolled(model: nn.Module, window: torch.Tensor, p: torch.Tensor, j: torch.Tensor) -> torch.Tensor:
    """Example i's window after j[i] network steps without gradient: [B, k_in, C, *space] normalized."""
    out = window.clone()
    with torch.no_grad():
        for i in range(1, int(j.max()) + 1):
            window = torch.cat([window[:, 1:], net_step(model, window, p)], dim=1)
            out[j == i] = window[j == i]
    return out


def _draws(seed: int, step: int, batch: int, low: int, high: int) -> torch.Tensor:
    """int64 [batch] uniform in low..high, a pure function of (seed, step) (a resumed run draws the same)."""
    gen = torch.Generator().manual_seed(seed * 1_000_003 + step)
    return torch.randint(low, high + 1, (batch,), generator=gen)


@dataclass
class Pushforward:
    """Unroll n ~ U{0..k-1} network steps without gradient, train the next one against the frame n+1 ahead."""

    unroll: int = DEFAULTS["unroll"]
    seed: int = 0
    loss: str = "mse"
    name: ClassVar[str] = "pushforward"

    def settings(self) -> dict:
        return _with_loss({"name": self.name, "unroll": self.unroll}, self.loss)

    def bind(self, pde, seed: int = 0) -> "Pushforward":
        self.seed = seed
        return self

    def draws(self, step: int, batch: int) -> torch.Tensor:
        """Unrolled steps per example, int64 [batch] in 0..unroll-1."""
        return _draws(self.seed, step, batch, 0, self.unroll - 1)

    def frames_ahead(self, view) -> int:
        return self.unroll

    def train_view(self, view):
        return _unrolling_view(self, view)

    def channels(self, pde, view) -> tuple[int, int]:
        return view.rollout_k_in * len(pde.FIELDS), len(pde.FIELDS)

    def step_loss(self, model, batch, norm, step):
        p = norm.normalize_params(batch["params"])
        n = self.draws(step, len(p)).to(p.device)
        window = _unrolled(model, norm.normalize(batch["x"]), p, n)  # the unrolled steps carry no gradient
        pred = net_step(model, window, p)[:, 0]  # [B, C, *space]
        target = norm.normalize(batch["y"][torch.arange(len(n), device=n.device), n])
        return objective(self.loss, pred, target), relative_errors(pred, target)

    def rollout(self, model, norm, u, params, k_in):
        return _net_rollout(model, norm, u, params, k_in)

    def one_step(self, model, norm, batch, view):
        return _net_one_step(model, norm, batch, datasets.NextStep(view.rollout_k_in, 1))


@dataclass
class Oracle:
    """Train on states the network reaches (j ~ U{0..k} unrolled steps), labelled by the solver.

    solver: ``datasets.SolverOracle`` of the training PDE (or any callable (u [B, C, *space], params [B, P],
    frames) -> [B, C, *space] in physical units). Examples whose solver answer is not finite (the network
    reached a state the solver cannot advance) are left out of the loss and counted in ``dropped``.
    """

    unroll: int = DEFAULTS["unroll"]
    solver: object = None
    seed: int = 0
    dropped: int = 0
    loss: str = "mse"
    name: ClassVar[str] = "oracle"

    def settings(self) -> dict:
        return _with_loss({"name": self.name, "unroll": self.unroll}, self.loss)

    def bind(self, pde, seed: int = 0) -> "Oracle":
        """The solver of the training PDE; seed: the run's seed (the draws of j)."""
        self.solver, self.seed = datasets.SolverOracle(pde), seed
        return self

    def stats(self) -> dict:
        """What the mode did beyond the loss: examples left out because the solver's answer was not finite."""
        return {"oracle_dropped": self.dropped}

    def frames_ahead(self, view) -> int:
        return 1  # the targets come from the solver; the view only supplies start states

    def train_view(self, view):
        return _unrolling_view(self, view)

    def channels(self, pde, view) -> tuple[int, int]:
        return view.rollout_k_in * len(pde.FIELDS), len(pde.FIELDS)

    def draws(self, step: int, batch: int) -> torch.Tensor:
        """Unrolled steps per example, int64 [batch] in 0..unroll: a pure function of (seed, step)."""
        return _draws(self.seed, step, batch, 0, self.unroll)

    def reached(self, model, norm, batch, step) -> torch.Tensor:
        """The windows the network reaches, normalized [B, k_in, C, *space] (no gradient)."""
        p = norm.normalize_params(batch["params"])
        return _unrolled(model, norm.normalize(batch["x"]), p, self.draws(step, len(p)).to(p.device))

    def answer(self, u: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """The solver's next frame from each state u [B, C, *space] (physical units); NaN rows where the state is
        not finite or the solver blew up from it (then each state is solved alone, to keep the others)."""
        ok = torch.isfinite(u.flatten(1)).all(dim=1)
        out = torch.full_like(u, float("nan"))
        if not bool(ok.any()):
            return out
        try:
            out[ok] = self.solver(u[ok], params[ok], frames=1)
        except ValueError:  # BlowUpError is one: find the states it came from
            for i in torch.nonzero(ok).flatten().tolist():
                try:
                    out[i] = self.solver(u[i : i + 1], params[i : i + 1], frames=1)[0]
                except ValueError:
                    pass
        return out

    def step_loss(self, model, batch, norm, step):
        start = self.reached(model, norm, batch, step)
        answer = self.answer(norm.denormalize(start[:, -1]), batch["params"])  # [B, C, *space]
        ok = torch.isfinite(answer.flatten(1)).all(dim=1)
        if not bool(ok.all()):
            self.dropped += int((~ok).sum())
            if not bool(ok.any()):
                raise ValueError(f"oracle: at step {step} the solver blew up from every state the network reached; "
                                 "lower --lr or --unroll")
            start, answer, batch = start[ok], answer[ok], {**batch, "params": batch["params"][ok]}
        target = norm.normalize(answer)
        pred = net_step(model, start, norm.normalize_params(batch["params"]))[:, 0]
        per = relative_errors(pred, target)
        if not bool(ok.all()):  # report_losses wants a value per example: the dropped count as the worst kept
            full = torch.full((len(ok),), float(per.max()), dtype=torch.float64)
            full[ok.cpu()] = per
            per = full
        return objective(self.loss, pred, target), per

    def rollout(self, model, norm, u, params, k_in):
        return _net_rollout(model, norm, u, params, k_in)

    def one_step(self, model, norm, batch, view):
        return _net_one_step(model, norm, batch, datasets.NextStep(view.rollout_k_in, 1))


def subsample(u: torch.Tensor, factor: int, ndim: int, bc: tuple[str, ...] | None = None,
              locations: tuple[str, ...] | None = None, restrict: str = "points") -> torch.Tensor:
    """The fine field restricted to the coarse grid, [..., *fine] -> [..., *fine/factor] over the last ndim dims.
    On a periodic axis (x_i = i L / n), ``restrict`` "points": fine point factor*i is coarse point i exactly (the
    fine modes at and beyond the coarse Nyquist alias onto the coarse ones); "fourier": the Fourier truncation
    (``fourier_restrict``: the modes the coarse grid holds, its Nyquist mode zeroed). On an axis with walls the
    points are cell centres: coarse centre i is fine point factor*i + (factor-1)/2, which for an even factor lies
    midway between two fine points, whose mean is taken (second order in the fine spacing), whichever ``restrict``.
    ``locations``: per channel (the dim before space), a staggered grid's field locations (Problem.FIELD_LOCATIONS):
    cell and face means (``_restrict``), whichever ``restrict``."""
    if locations:
        return torch.stack([_restrict(u.select(-ndim - 1, c), factor, ndim, where)
                            for c, where in enumerate(locations)], dim=-ndim - 1)
    for axis, b in enumerate(kinds(bc or periodic_words(ndim))):
        dim = u.ndim - ndim + axis
        if b.periodic and restrict == "fourier":
            u = fourier_restrict(u, u.shape[dim] // factor, dim)
        elif b.periodic:
            u = u[(slice(None),) * dim + (slice(None, None, factor),)]
        else:
            lo, hi = (factor - 1) // 2, factor // 2  # the same point for an odd factor
            u = 0.5 * (u.unfold(dim, factor, factor).select(-1, lo) + u.unfold(dim, factor, factor).select(-1, hi))
    return u


def fourier_restrict(u: torch.Tensor, n_coarse: int, dim: int) -> torch.Tensor:
    """A real field periodic along ``dim`` (n fine points x_i = i L / n) on the coarse grid of ``n_coarse`` points
    there by Fourier truncation: [..., n, ...] -> [..., n_coarse, ...], u's real dtype and device.

    The coarse field is sum over |k| < n_coarse / 2 of the fine field's Fourier coefficients a_k exp(2 pi i k x / L)
    at the coarse points: the modes the coarse grid holds, its Nyquist mode (k = n_coarse / 2, even n_coarse)
    zeroed, every mode of the fine field beyond dropped instead of aliased. So the mean (a_0) is kept to rounding,
    and a field band-limited below the coarse Nyquist restricts to its own values at the coarse points (as
    point sampling gives). Computed in float64 (rfft with norm "forward": amplitudes a_k; irfft of length
    n_coarse, norm "forward"), returned in u's dtype."""
    n = u.shape[dim]
    keep = (n_coarse + 1) // 2  # k = 0 .. keep - 1 (|k| < n_coarse / 2)
    if not 0 < n_coarse <= n:
        raise ValueError(f"fourier_restrict: n_coarse={n_coarse} not allowed on an axis of {n} points; 1..{n}")
    a = torch.fft.rfft(u.double(), dim=dim, norm="forward").narrow(dim, 0, keep)
    if n_coarse % 2 == 0:  # the coarse Nyquist slot, zero
        a = torch.cat([a, torch.zeros_like(a.narrow(dim, 0, 1))], dim=dim)
    return torch.fft.irfft(a, n=n_coarse, dim=dim, norm="forward").to(u.dtype)


def _restrict(u: torch.Tensor, factor: int, ndim: int, where: str) -> torch.Tensor:
    """One staggered field [..., *fine] on the coarse cells [..., *fine/factor]: a cell average ("centre"), a
    coarse face's mean over the fine faces on it ("face_x", "face_y": the flux through it), or "mask": a coarse
    cell is in the set when any of its fine cells is."""
    face = {"face_x": 0, "face_y": 1}.get(where)
    for axis in range(ndim):
        dim = u.ndim - ndim + axis
        if axis == face:
            u = u.unfold(dim, factor, factor).select(-1, 0)  # the fine faces on the coarse faces' line
        else:
            blocks = u.unfold(dim, factor, factor)
            u = blocks.amax(-1) if where == "mask" else blocks.mean(-1)
    return u


@dataclass
class SolverInTheLoop:
    """A correction network after each step of a coarse differentiable solver, unrolled k steps.

    Built with ``bind(pde)`` from the fine training PDE: the coarse solver is the same PDE config with
    n = coarse_n (its own stable step), ``factor`` = n / coarse_n. A step is
    s <- S(s) + std * net(normalize(S(s)), params): the network outputs the correction in normalized units.
    The loss (``loss``) is over the k unrolled states against the fine trajectory restricted, gradients through
    the solver (``datasets.SolverStep``). unroll=1 is training on precomputed (coarse step, fine) pairs.

    ``noise`` = sigma > 0 (the noise baseline on the corrector, Sanchez-Gonzalez et al. 2020 applied to the
    start state): the coarse start state s0 (the fine state restricted to the coarse grid) becomes
    denormalize(normalize(s0) + eps), eps ~ N(0, sigma^2) independent per example, channel and point (so sigma is
    a fraction of the data's std per channel; a mask channel is left as it is); the coarse solver and the
    correction step from the perturbed state, the fine targets stay clean, so the correction learns to pull a
    perturbed coarse state back toward the fine trajectory. eps is a pure function of (seed, optimizer step);
    noise = 0 trains exactly as without it. The evaluation (rollout) is unperturbed.

    ``corrector_start`` "zero" (``init_model``): the network's output layer starts at zero, so before the first
    optimizer step the correction is exactly 0 and the corrected solver is the coarse solver; "random": the
    model's own initialisation (its correction starts as noise of the size of its random output).

    ``unroll_schedule`` [[k1, n1], [k2, n2], ...] (an unroll curriculum, Um et al. 2020): unroll k1 for the first
    n1 optimizer steps, then k2 for n2, ...; the last k after the schedule; ``unroll`` is the longest k (the
    window's frames). A pure function of the optimizer step, so a resumed run unrolls as the uninterrupted one.

    ``restrict`` (how a fine field reaches the coarse grid: start states, targets and the rollout's references):
    on a periodic axis "fourier" (``fourier_restrict``: the coarse grid's modes of the fine field, the mean kept)
    or "points" (every factor-th point: the fine modes beyond the coarse Nyquist alias, e.g. into the coarse
    mean, which the coarse solver then conserves); axes with walls and staggered fields: cell / face means either
    way (``subsample``). ``settings()`` records "restrict": "fourier" where it acts; its absence reads as points.

    ``clip`` (a norm, None: off): the training loop scales the gradient down to this global norm before each
    optimizer step (``surrogate.train``; the steps clipped go to metrics.json). ``remat``: each unrolled step
    after the first (solver step and correction) is rematerialised in the backward pass
    (``torch.utils.checkpoint``, reentrant): the forward keeps only the states between steps, and the backward
    recomputes one step at a time with its JAX residuals, so memory holds about two steps' activations instead
    of k. The forward then runs the solver's
    no-gradient program (the oracle's), equal to the differentiable one's to float32 rounding: the loss and
    gradients agree with ``remat`` off to that rounding, not bit for bit.
    """

    unroll: int = DEFAULTS["unroll"]
    coarse_n: int = DEFAULTS["coarse_n"]
    noise: float = 0.0
    corrector_start: str = DEFAULTS["corrector_start"]
    unroll_schedule: list | None = None
    clip: float | None = None
    remat: bool = False
    restrict: str = DEFAULTS["restrict"]
    seed: int = 0
    step: nn.Module | None = None
    factor: int = 0
    walls: tuple[str, ...] | None = None  # the PDE's per-axis bc (None: periodic), for the fine -> coarse points
    locations: tuple[str, ...] | None = None  # per channel, a staggered grid's field locations (FIELD_LOCATIONS)
    loss: str = "mse"
    name: ClassVar[str] = "solver-in-the-loop"

    def settings(self) -> dict:
        s = {"name": self.name, "unroll": self.unroll, "coarse_n": self.coarse_n}
        if self.noise > 0:  # (left out at 0: run.json files written before the setting existed compare equal)
            s.update(noise=self.noise, rule=SITL_NOISE_RULE)
        if self.corrector_start != DEFAULTS["corrector_start"]:  # (the same: older run.json files compare equal)
            s["corrector_start"] = self.corrector_start
        if self.unroll_schedule:  # (absent: a fixed unroll, as run.json files before the setting)
            s["unroll_schedule"] = [list(p) for p in self.unroll_schedule]
        if self.clip is not None:  # (absent when off: older run.json files compare equal)
            s["clip"] = self.clip
        if self.remat:
            s["remat"] = True
        if self.restrict == "fourier" and self.restricts_periodic():  # (absent: point sampling, every older run.json)
            s["restrict"] = "fourier"
        return _with_loss(s, self.loss)

    def restricts_periodic(self) -> bool:
        """Whether ``restrict`` acts on the PDE's grid: a periodic axis and no staggered fields (True before
        ``locate``, whose grid is not yet known)."""
        return restricts_periodic(self.walls, self.locations)

    def locate(self, pde) -> "SolverInTheLoop":
        """Take the fine PDE's per-axis bc and field locations (what the restriction needs; ``bind`` does it too);
        returns self."""
        self.walls = tuple(pde.grid.bc)
        where = getattr(pde, "FIELD_LOCATIONS", {})
        self.locations = tuple(where.get(f, "centre") for f in pde.FIELDS) if where else None
        return self

    def unroll_at(self, step: int) -> int:
        """The unroll length of optimizer step ``step`` (1-based, as the training loop counts): ``unroll``, or the
        schedule's phase holding it."""
        end = 0
        for k, n in self.unroll_schedule or ():
            end += n
            if step <= end:
                return k
        return self.unroll_schedule[-1][0] if self.unroll_schedule else self.unroll

    def init_model(self, model: nn.Module) -> None:
        """Set up a freshly built correction network for ``corrector_start`` (before its first step; a resumed run
        then loads its checkpoint over it)."""
        if self.corrector_start == "zero":
            zero_output(model)

    def frames_ahead(self, view) -> int:
        return self.unroll

    def train_view(self, view):
        check_mode_k_in(self.name, view.rollout_k_in)
        return _unrolling_view(self, view)

    def channels(self, pde, view) -> tuple[int, int]:
        return len(pde.FIELDS), len(pde.FIELDS)

    def bind(self, pde, seed: int = 0) -> "SolverInTheLoop":
        """The coarse solver of the fine PDE ``pde``; seed: the run's seed (the start-state noise); ValueError (one
        line) when the sizes do not fit."""
        self.seed = seed
        check_coarse_grid(pde, self.coarse_n)  # (the CLI's commands have run it before torch was imported)
        self.factor = pde.n // self.coarse_n
        self.locate(pde)
        try:
            self.step = datasets.SolverStep({**pde.config(), "n": self.coarse_n}, frames=1)
        except ValueError as err:  # the PDE's refusal speaks of n, which the user set as --coarse-n
            raise ValueError(f"solver-in-the-loop: --coarse-n {self.coarse_n} not allowed: {err}") from None
        return self

    def correct(self, model: nn.Module, norm: Normalization, s: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """The corrected state after a coarse solver step: s [B, C, *coarse] physical -> same."""
        z = norm.normalize(s)
        dz = model(z, p)
        if self.locations and "mask" in self.locations:  # the solver's geometry (an obstacle mask) is not learned
            keep = torch.tensor([w != "mask" for w in self.locations], dtype=dz.dtype, device=dz.device)
            dz = dz * keep.reshape(-1, *([1] * (dz.ndim - 2)))
        return norm.denormalize(z + dz)

    def perturbation(self, step: int, z: torch.Tensor) -> torch.Tensor:
        """eps (normalized units) for the coarse start states z [B, C, *coarse] at optimizer step ``step``:
        N(0, noise^2) per example, channel and point (zero on a mask channel), z's device and dtype."""
        eps = random_walk(self.seed, step, (z.shape[0], 1, *z.shape[1:]), self.noise)[:, 0]
        eps = eps.to(device=z.device, dtype=z.dtype)
        if self.locations and "mask" in self.locations:
            keep = torch.tensor([w != "mask" for w in self.locations], dtype=z.dtype, device=z.device)
            eps = eps * keep.reshape(-1, *([1] * (z.ndim - 2)))
        return eps

    def start(self, batch: dict, norm: Normalization, step: int) -> torch.Tensor:
        """The coarse start states of optimizer step ``step``, physical units [B, C, *coarse]: the newest input
        frame restricted to the coarse grid, perturbed when noise > 0."""
        ndim = batch["x"].ndim - 3
        s = subsample(batch["x"][:, -1], self.factor, ndim, self.walls, self.locations, self.restrict)
        if self.noise > 0:  # s + std * eps: denormalize(normalize(s) + eps), a channel without noise left bit for bit
            std = norm.std.to(device=s.device, dtype=s.dtype).reshape(-1, *([1] * ndim))
            s = s + std * self.perturbation(step, s)
        return s

    def step_loss(self, model, batch, norm, step):
        ndim = model.ndim
        params, p = batch["params"], norm.normalize_params(batch["params"])
        s = self.start(batch, norm, step)  # [B, C, *coarse]
        states, k = [], self.unroll_at(step)
        for i in range(k):
            # remat: from the second step on (a reentrant checkpoint needs an input that wants a gradient; the first
            # step's solver call from the constant start keeps no residuals anyway)
            if self.remat and i > 0:
                s = checkpoint(self._advance, s, params, p, model, norm, use_reentrant=True)
            else:
                s = self._advance(s, params, p, model, norm)
            states.append(s)
        pred = norm.normalize(torch.stack(states, dim=1))  # [B, k, C, *coarse]
        target = norm.normalize(subsample(batch["y"][:, :k], self.factor, ndim, self.walls, self.locations,
                                          self.restrict))
        return objective(self.loss, pred, target), relative_errors(pred, target)

    def _advance(self, s, params, p, model, norm):
        """One unrolled step: the coarse solver, then the correction (s [B, C, *coarse] physical -> same)."""
        return self.correct(model, norm, self.step(s, params), p)

    @torch.no_grad()
    def rollout(self, model, norm, u, params, k_in=1):
        """The corrected coarse solver (model=None: the coarse solver alone) from u[:, 0] restricted (``restrict``)."""
        ndim = u.ndim - 3
        truth = subsample(u, self.factor, ndim, self.walls, self.locations, self.restrict)  # [B, T, C, *coarse]
        p = norm.normalize_params(params) if model is not None else None
        s, out = truth[:, 0], []
        for _ in range(u.shape[1] - 1):
            s = self.step(s, params)
            if model is not None:
                s = self.correct(model, norm, s, p)
            out.append(s)
        return torch.stack(out, dim=1), truth[:, 1:]

    def one_step(self, model, norm, batch, view):
        """Each frame's corrected coarse step against the next frame, on the coarse grid."""
        u, params = batch["u"], batch["params"]
        B, T = u.shape[:2]
        starts = u[:, :-1].reshape(B * (T - 1), 1, *u.shape[2:])
        pred, truth = self.rollout(model, norm, torch.cat([starts, u[:, 1:].reshape(starts.shape)], 1),
                                   params.repeat_interleave(T - 1, 0))
        return pred[:, 0], truth[:, 0]


def random_walk(seed: int, step: int, shape: tuple, sigma: float) -> torch.Tensor:
    """The noise of optimizer step ``step``, float32 CPU ``shape`` = [B, k_in, C, *space]: a random walk over the
    k_in frames (oldest first) whose increments are N(0, sigma^2 / k_in), so frame j = 1..k_in has std
    sigma * sqrt(j / k_in) and the newest frame std sigma; independent across examples, channels and points. A pure
    function of (seed, step): a resumed run draws what the uninterrupted one drew."""
    gen = torch.Generator().manual_seed(seed * 1_000_003 + step)
    steps = torch.randn(shape, generator=gen) * (sigma / shape[1] ** 0.5)
    return steps.cumsum(dim=1)


@dataclass
class Noise:
    """One-step training on noisy inputs (Sanchez-Gonzalez et al. 2020, "SGGP+20").

    The rule, in normalized units (``datasets.Normalization``: each channel's std is 1, so ``noise`` = sigma is
    the fraction of the data's std per channel): the input window x = [x_{t-k_in+1}, ..., x_t] becomes x + eps,
    eps a random walk over the frames (``random_walk``): increments N(0, sigma^2 / k_in) per frame, so the newest
    frame x_t carries std sigma and frame j (1 = oldest) std sigma * sqrt(j / k_in), as SGGP+20 accumulate their
    noise over the input sequence so that its last step has the stated std. k_in = 1: eps ~ N(0, sigma^2).
    The target is corrected for the perturbation: the network outputs states, not increments, so the target that
    SGGP+20's correction gives (the one that lands on the true next state from the noisy input) is the clean
    next frames y = [x_{t+1}, ..., x_{t+k_out}], every one of the k_out frames unchanged; the network learns to
    remove eps while it advances the state, the error its own rollout will feed it. (The uncorrected target
    y + eps_t would teach it to carry the error along.)
    Channels that are geometry, not state (a flow's obstacle mask: ``FIELD_LOCATIONS`` "mask") get no noise.
    The noise is a pure function of (seed, optimizer step). noise = 0 trains exactly as ``OneStep``.
    Needs a next-step view (any k_in, any k_out); the rollout and one-step evaluation are one-step's.
    """

    noise: float = DEFAULTS["noise"]
    seed: int = 0
    keep: tuple[bool, ...] | None = None  # per channel: perturbed (False: a mask channel, left as it is)
    loss: str = "mse"
    unroll: ClassVar[int] = 1
    name: ClassVar[str] = "noise"

    def settings(self) -> dict:
        return _with_loss({"name": self.name, "noise": self.noise, "rule": NOISE_RULE}, self.loss)

    def bind(self, pde, seed: int = 0) -> "Noise":
        """seed: the run's seed (the noise draws); the PDE's mask channels are left unperturbed."""
        where = getattr(pde, "FIELD_LOCATIONS", {}) or {}
        self.seed, self.keep = seed, tuple(where.get(f) != "mask" for f in pde.FIELDS)
        return self

    def frames_ahead(self, view) -> int:
        return view.frames_out

    def train_view(self, view):
        if view.rollout_k_in is None:
            raise ValueError(f"--mode noise perturbs the input frames of the next_step view, not {view.name!r}; use "
                             "--view next_step")
        return view

    def channels(self, pde, view) -> tuple[int, int]:
        return model_channels(pde, view)

    def perturbation(self, step: int, x: torch.Tensor) -> torch.Tensor:
        """eps for the normalized window x [B, k_in, C, *space] at optimizer step ``step`` (x's device and dtype)."""
        eps = random_walk(self.seed, step, tuple(x.shape), self.noise).to(device=x.device, dtype=x.dtype)
        if self.keep is not None and not all(self.keep):
            keep = torch.tensor(self.keep, dtype=x.dtype, device=x.device)
            eps = eps * keep.reshape(-1, *([1] * (x.ndim - 3)))
        return eps

    def step_loss(self, model, batch, norm, step):
        x = norm.of_x.normalize(batch["x"])  # [B, k_in, C, *space]
        if self.noise > 0:
            x = x + self.perturbation(step, x)
        target = stack_frames(norm.of_y.normalize(batch["y"]), model.ndim)  # the clean frames: [B, k_out*C, *space]
        pred = model(stack_frames(x, model.ndim), norm.normalize_params(batch["params"]))
        return objective(self.loss, pred, target), relative_errors(pred, target)

    def rollout(self, model, norm, u, params, k_in):
        return _net_rollout(model, norm, u, params, k_in)

    def one_step(self, model, norm, batch, view):
        return _net_one_step(model, norm, batch, view)


MODES = {cls.name: cls for cls in (OneStep, Pushforward, Oracle, SolverInTheLoop, Noise)}  # one per MODE_SPECS row
assert tuple(MODES) == MODE_NAMES


def check_mode_settings(name: str, unroll: int | None = None, coarse_n: int | None = None, noise=None,
                        corrector_start: str | None = None) -> None:
    """ValueError (one line) naming a bad mode name, unroll, coarse grid, noise or corrector start
    (``mode_table.mode_settings``)."""
    mode_settings(name, unroll=unroll, coarse_n=coarse_n, noise=noise, corrector_start=corrector_start)


def make_mode(settings: dict | None, pde=None) -> Mode:
    """The mode of run.json's "mode" settings ({"name", "unroll", "coarse_n", "noise", "loss", ...}; None: one-step;
    a setting left out: its default, ``mode_table.DEFAULTS``, except solver-in-the-loop's "restrict", which
    left out reads "points": every run.json written before the setting restricted by point sampling, and a new
    run's settings (``mode_table.mode_settings``) carry it), not yet bound to a PDE: ``mode.bind(pde, seed)`` gives
    it its solver. ``pde``: the fine PDE, located (``SolverInTheLoop.locate``) so that ``settings()`` records what
    applies to its grid. ValueError (one line) for a bad name or setting."""
    s = dict(settings or {"name": "one-step"})
    loss = s.pop("loss", "mse")
    s.pop("rule", None)  # the noise mode's rule in words (run.json), not a setting
    if loss not in LOSSES:
        raise ValueError(f"--loss={loss!r} not allowed; allowed: {', '.join(LOSSES)}")
    if s.get("name") == SolverInTheLoop.name:
        s.setdefault("restrict", "points")
    s = mode_settings(s.pop("name", "one-step"), **s)
    mode = MODES[s.pop("name")](**s, loss=loss)
    return mode.locate(pde) if pde is not None and hasattr(mode, "locate") else mode


def training_view(mode: Mode, view):
    """The view a mode trains on (``mode.train_view``): one-step keeps ``view``; the others need a next-step view
    and get k_out = ``mode.frames_ahead``. ValueError (one line) for another view or a window that does not fit."""
    return mode.train_view(view)


def check_fits(mode: Mode, view, pde) -> None:
    """ValueError (one line) when the mode's window is longer than the PDE's trajectories."""
    if pde.STEADY:  # no frames to fit: the view's own check says what a steady PDE's samples allow
        datasets.for_sample(view, pde.n_frames, len(pde.INPUTS))
        return
    k_in = view.rollout_k_in
    if k_in is not None:
        check_window(mode.name, mode.unroll, k_in, view.frames_out, pde.n_frames)
