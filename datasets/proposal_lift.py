"""The lift gate: are a proposal's steered draws harder than its uniform ones, measured on the draws themselves?

``ParamProposal``'s correlation gate scores a loss *model*: how well its prediction at a fresh solve ranks that
solve's loss. The generative proposal draws from a kernel mixture around the hardest fresh solves, a local model
whose smooth summary (the gate's predictor) can miss what the mixture finds: on burgers1d its steered draws were
1.6x as hard as uniform ones on fresh solves while the summary's correlation was 0.1, so the gate stayed shut and the
proposal never steered (docs/results/active.md). The lift gate asks the question the issue asks, directly:

- **tags**: every draw the proposal makes for a known sample index (the reservoir passes its submissions'
  indices) is tagged steered or uniform; the tag waits until that sample's first training loss comes back;
- **lift**: difficulty = log-loss less the loss level at the time, the median of the last ``LEVEL_SPAN`` uniform
  fresh losses (the level falls as the model trains; the uniform draws are the reference, so a steered share of any
  size leaves the level the prior's); lift = mean difficulty of the last ``window`` steered fresh draws less that
  of the last ``window`` uniform ones, with a 2-standard-error interval (Welch): a lift of log 2 means the steered
  draws' losses are twice the uniform ones' at the same moment;
- **decided** only with at least ``LIFT_MIN`` fresh draws of each kind; before that the bounds are None.

The proposal opens its steered share by the interval's lower bound and closes it (share 0) when the upper bound is
below 0: steered draws measurably *easier* than uniform ones do harm, whatever the model's correlation says; that
veto is read from ``VETO_MIN`` draws of each kind on, the opening only from ``LIFT_MIN`` (harm stops sooner than a
benefit is believed). To be measured at all, a proposal with no other way to open (the generative one) *probes*: a
share ``probe`` of its draws is steered until ``LIFT_MIN`` steered fresh draws have been scored or the veto falls,
once per run; after that only the lift
and the correlation open it, so with no measured lift the draws are uniform again. numpy only; ``state`` /
``load`` carry it all, so a resumed stream continues exactly.
"""

from __future__ import annotations

import math

import numpy as np

from .proposal_fit import LEVEL_SPAN

LIFT_MIN = 16  # fresh draws of each kind (steered, uniform) before the lift is decided
VETO_MIN = 8  # of each kind before steered draws measurably easier close the share (harm stops sooner than a lift opens)
LIFT_FULL = math.log(2.0)  # the lift's lower bound at which the steered share is the whole 1 - floor
LEVEL_MIN = 8  # uniform draws scored before any draw's difficulty is measured
TAGS_MOST = 16384  # tags kept waiting for their loss (older ones: samples never trained on, dropped)


class LiftGate:
    """Tags of proposed draws by sample index and the difficulties of the tagged draws scored (``window``: the last
    scored draws of each kind kept)."""

    def __init__(self, window: int = 256):
        self.window = window
        self.tags: dict[int, bool] = {}  # sample index -> steered?, until its first loss is scored
        self.level = np.zeros(0)  # the last LEVEL_SPAN uniform log-losses (the level a draw is compared with)
        self.d_steered, self.d_uniform = np.zeros(0), np.zeros(0)  # difficulties of the last ``window`` of each kind
        self.probed = 0  # steered draws scored so far (the probe phase lasts LIFT_MIN of them)
        self.indexed = False  # any draw tagged: the caller reports sample indices (probing can be scored)

    def tag(self, indices: np.ndarray, steered: np.ndarray) -> None:
        """Sample indices [n] of proposed draws and whether each was steered [n]."""
        self.indexed = True
        self.tags.update(zip(np.asarray(indices, np.int64).tolist(), np.asarray(steered, bool).tolist()))
        while len(self.tags) > TAGS_MOST:  # dicts keep insertion order: the oldest go first
            self.tags.pop(next(iter(self.tags)))

    def score(self, indices: np.ndarray, log_losses: np.ndarray) -> None:
        """First-draw log-losses [m] of samples with indices [m], in arrival order; untagged ones (key draws) are
        ignored. A draw's difficulty is its log-loss less the median of the uniform draws' last LEVEL_SPAN (those
        scored before it: the level falls as the model trains, and both kinds arrive interleaved, so the lag of a
        trailing median is the same for both); none before LEVEL_MIN uniform draws were scored."""
        for i, y in zip(np.asarray(indices).tolist(), np.asarray(log_losses, np.float64).tolist()):
            steered = self.tags.pop(int(i), None)
            if steered is None:
                continue
            if len(self.level) >= LEVEL_MIN:
                d = y - float(np.median(self.level))
                if steered:
                    self.d_steered = np.append(self.d_steered, d)[-self.window:]
                else:
                    self.d_uniform = np.append(self.d_uniform, d)[-self.window:]
            if steered:
                self.probed += 1
            else:
                self.level = np.append(self.level, y)[-LEVEL_SPAN:]

    def bounds(self, least: int = LIFT_MIN) -> tuple[float, float] | None:
        """(lower, upper) 2-standard-error bounds of the lift (log-loss units): the steered draws' mean difficulty less
        the uniform ones' (Welch); None until ``least`` of each kind (LIFT_MIN; VETO_MIN for the veto)."""
        return lift_bounds(self.d_steered, self.d_uniform, least)

    def vetoed(self) -> bool:
        """The steered draws measurably easier than uniform ones: the upper bound below 0 from VETO_MIN draws of each
        kind on (asymmetric: opening the share waits for LIFT_MIN, closing it does not; on burgers2d the probes' 16
        easier draws cost the p99 6% where 8 had already shown the sign)."""
        early = self.bounds(VETO_MIN)
        return early is not None and early[1] < 0

    def state(self) -> dict:
        """Plain values (torch.load(weights_only=True) reads them)."""
        return {"window": self.window, "tags": [[i, s] for i, s in self.tags.items()], "level": self.level.tolist(),
                "steered": self.d_steered.tolist(), "uniform": self.d_uniform.tolist(), "probed": self.probed,
                "indexed": self.indexed}

    def load(self, state: dict | None) -> None:
        """Restore ``state()`` (None: a state saved before the lift gate; it starts empty)."""
        state = state or {}
        self.tags = {int(i): bool(s) for i, s in state.get("tags", [])}
        self.level = np.asarray(state.get("level", []), np.float64)
        self.d_steered = np.asarray(state.get("steered", []), np.float64)
        self.d_uniform = np.asarray(state.get("uniform", []), np.float64)
        self.probed, self.indexed = int(state.get("probed", 0)), bool(state.get("indexed", False))


def lift_bounds(steered: np.ndarray, uniform: np.ndarray, least: int = LIFT_MIN) -> tuple[float, float] | None:
    """The lift's (lower, upper) 2-standard-error bounds from the difficulties of steered draws [S] and uniform ones
    [U]: mean(steered) - mean(uniform) -+ 2 sqrt(var_S / S + var_U / U); None with fewer than ``least`` of either."""
    if len(steered) < least or len(uniform) < least:
        return None
    lift = float(steered.mean() - uniform.mean())
    se = math.sqrt(float(steered.var(ddof=1)) / len(steered) + float(uniform.var(ddof=1)) / len(uniform))
    return lift - 2.0 * se, lift + 2.0 * se
