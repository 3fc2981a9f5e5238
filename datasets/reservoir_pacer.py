"""The training reservoir's pacing: how far ahead of training the producer may solve (async mode).

Every surplus solve on shared cores is a training step lost, so by default (``target_reuse="auto"``) the producer
solves what training consumes at a reuse target R (each trajectory drawn about R uses before it makes way), with R
chosen from rates ``Pacer`` keeps re-measuring while the run goes on (a rate measured once under load misleads):

- ``s``: the solver's seconds per trajectory (a job's own wall time, measured where it runs, over its samples);
- ``i``: the training thread's seconds per trajectory inserting solves into the store (a cost training pays);
- ``t``: the training step's seconds (the loop's time outside the stream: forward, backward, optimizer);
- ``k``: how much a running solve slows a training step (t while solving = t alone x (1 + k)): "cores free",
  measured by its effect rather than counted (a core free by count may be another program's, or the GIL's);
  fitted by least squares of each step's time on the share of it a solve was running, over about the last
  1 / (1 - DECAY) steps, and taken at the fit's upper bound (slope + K_Z standard errors): on cores that other
  programs load, step times scatter and a plain fit often says "free" (k = 0) when it is not, which let the solver
  run flat out and cost training half its steps (docs/results/compare.md, equal wall clock). K_PRIOR before steps
  with and without solves have been seen; with no spread in the solve share (the producer always or never
  running, so nothing can be fitted) k relaxes toward K_PRIOR, which changes R and so brings the spread back;
- ``b``: examples per batch, ``per``: examples per use of a trajectory (the view's).

The rule: solving at reuse R keeps a solve running a share ``D = b s / (per R t)`` of the wall clock, which costs
training ``D k / (1 + k)`` of its steps, and inserting costs ``b i / (per R t)`` more; R is the smallest reuse at
which that cost is at most ``cost`` (PACE_COST, 5% of the steps training would make without solves)::

    R = clip(b (s k / (1 + k) + i) / (per t cost), 1, max_reuse)

and the producer holds its next solve job while (trajectories submitted) >= warmup + (uses drawn, each counted
at the R in force when it was drawn) / R + solve_batch. A solver that costs training nothing (k = 0: a free core, or
a GPU trainer) is paced at R = 1 (each trajectory drawn once); one that shares training's core is held back to
reuse each trajectory more; a solver slower than that (the bottleneck) is never held: when nothing held is
drawable (the loop would wait) the producer solves regardless. Pacing changes only *when* jobs are submitted,
never which samples they solve (sample identity). ``target_reuse=R`` fixes R, ``None`` ("off") solves flat out.

The share fit may under-read k: the share is measured with error (a solve's CPU use is not even over its wall
time; a step's cost need not end when the job's future does), and an error in the regressor pulls a slope toward
zero. So the pacer also measures the cost directly, by **probes**. Training runs in cycles of PROBE_CYCLE windows
of w steps, w chosen at each cycle's start so that a window lasts about PROBE_WINDOW_S seconds (from PROBE_STEPS_MIN
to PROBE_STEPS steps; the first cycle's is PROBE_STEPS_MIN, the step time unknown yet): a fast 1D step gets 32-step
windows, a 2D step of a quarter second 8, so a 90-second 2D run is probed too. In each cycle's last window (auto
mode) the producer holds, unless it is behind the draws (a solver that is the bottleneck is never held). The steps
of that probe that no solve touched (share 0) give the step time alone, t_0; the window just before it, the time
with the producer at its pace, t_1, and the share D of its time a solve ran. Training lost ``1 - t_0 / t_1`` of
those steps (``probe_cost``: what pacing cost, measured rather than modelled) to a producer busy ``D`` of the time,
so each busy second costs ``q = (1 - t_0 / t_1) / D`` of a step-second, i.e. ``k = q / (1 - q)``. The probes are
pooled (each weighted PROBE_DECAY per later probe) by the ratio of their sums, and q is taken at the pool's **lower**
bound (the ratio minus K_Z of its standard errors, from the probes' scatter about it): a window of a few steps
scatters, and a point estimate that reads high by chance held the producer at the reuse bound for nothing (on
fisher_kpp1d probes read k 0.7-5.1 where the fit read 0.9-1.0: docs/results/compare.md). The probes correct the
fit only where they are sure: from PROBES_MIN probes on, k is the larger of the fit's upper bound and the probes'
lower bound (at most K_MAX). Adjacent windows a second apart cancel the drift of a shared machine's speed (10-20%
over minutes on the 2 cores here). A probe delays solves, never skips them: after it the producer catches up to
the draws.
"""

from __future__ import annotations

import math

PACE_COST = 0.05  # the share of training's steps that solving may cost (the rule above)
K_PRIOR = 1.0  # k before it is measured: a solve halves a training step (two threads on one core)
K_MAX = 8.0  # (a fitted k is clipped to [0, K_MAX]: one slow step must not stop the producer)
DECAY = 0.98  # the regression's weight per step: about the last 50 steps count
MIN_STEPS = 8.0  # weighted steps, and a spread of the solve share, before k is fitted
MIN_SPREAD = 0.01  # (variance of the per-step solve share below this: no fit, k relaxes toward K_PRIOR)
K_Z = 2.0  # k is the fit's slope plus this many standard errors (an overestimate costs reuse, an underestimate steps)
RELAX = 0.02  # per step without spread, the share of the way k moves back toward K_PRIOR
PROBE_CYCLE = 10  # windows per cycle: the last is the probe, the one before it what the probe is compared with
PROBE_WINDOW_S = 1.0  # seconds a window should last (the probe's, and the one before it)
PROBE_STEPS_MIN = 8  # steps per window at least (fewer would scatter too much to bound)
PROBE_STEPS = 32  # and at most (a fast step's probe need not hold the producer longer)
PROBE_DECAY = 0.8  # a probe's weight in the pool per later probe: about the last 5 count
PROBES_MIN = 3  # probes before their k is used


class Pacer:
    """The reuse target of an async reservoir's producer, from the rates it is fed (the module docstring's rule).

    batch_size, per_trajectory: b and per; max_reuse: the bound (R's ceiling); target: "auto" (the rule), a
    number (fixed R) or None (off: flat out, ``target()`` is None); cost: the share of training steps solving
    may cost. Feed it ``solved`` (each finished job), ``inserted`` (each insertion into the store) and ``step``
    (each training step); it reads no clock itself, so a test drives it with made-up times.
    """

    def __init__(self, batch_size: int, per_trajectory: int, max_reuse: float, target="auto", cost: float = PACE_COST):
        self.b, self.per, self.max_reuse, self.mode, self.cost = batch_size, per_trajectory, max_reuse, target, cost
        self.s = self.i = None  # seconds per trajectory: solving (the job's own wall time), inserting
        self.k = K_PRIOR
        # decayed sums of 1, f, f^2, t, f t, t^2 and of the squared weights (f: the share of a step a solve ran, t: its
        # seconds)
        self.sums = [0.0] * 7
        self.steps = self.solved_n = 0
        self.solve_s = 0.0  # seconds of solving in all (the jobs' own), for the producer's idle time
        # probes: the cycle's first step and window length w; its window before the probe (sum of seconds, of seconds
        # a solve ran, steps) and the probe's clean steps (sum of seconds, steps); the pool: decayed sums of the lost
        # share, the busy share and the weight, and of their squares and product with squared weights (the scatter)
        self._cycle_at, self._w = 0, PROBE_STEPS_MIN
        self._before, self._alone = [0.0, 0.0, 0], [0.0, 0]
        self._pool = [0.0] * 7  # w lost, w busy, w, w^2 lost^2, w^2 lost busy, w^2 busy^2, w^2
        self.probes = 0
        self.k_probe = None

    def probing(self) -> bool:
        """Whether the next steps are a probe's, for which the producer holds (auto mode; the module docstring)."""
        return self.mode == "auto" and self.steps - self._cycle_at >= (PROBE_CYCLE - 1) * self._w

    def solved(self, n: int, seconds: float) -> None:
        """A job of ``n`` trajectories took ``seconds`` (where it ran)."""
        if n > 0 and seconds >= 0:
            self.solve_s += seconds
            self.solved_n += n
            self.s = _ewma(self.s, seconds / n, 0.2)

    def inserted(self, n: int, seconds: float) -> None:
        """Inserting ``n`` trajectories took the training thread ``seconds``."""
        if n > 0 and seconds >= 0:
            self.i = _ewma(self.i, seconds / n, 0.2)

    def step(self, seconds: float, share: float) -> None:
        """A training step took ``seconds`` with a solve running ``share`` (in [0, 1]) of it."""
        if not seconds > 0 or not 0 <= share <= 1:
            return
        s0, sf, sff, st, sft, stt, sww = self.sums
        if s0 >= MIN_STEPS:  # a step held up by something else (a checkpoint, a snapshot) does not pass for a solve's cost
            seconds = min(seconds, 4 * st / s0)
        self._probe_step(seconds, share)
        self.steps += 1
        self.sums = [DECAY * s0 + 1, DECAY * sf + share, DECAY * sff + share * share, DECAY * st + seconds,
                     DECAY * sft + share * seconds, DECAY * stt + seconds * seconds, DECAY * DECAY * sww + 1]
        s0, sf, sff, st, sft, stt, sww = self.sums
        spread = sff / s0 - (sf / s0) ** 2
        if s0 < MIN_STEPS:
            return
        if spread < MIN_SPREAD:
            self.k += RELAX * (K_PRIOR - self.k)
            return
        cov = sft / s0 - (sf / s0) * (st / s0)
        slope = cov / spread
        alone = st / s0 - slope * sf / s0  # t with no solve running
        # the slope's standard error over the weighted steps (n: their effective number)
        resid = max(stt / s0 - (st / s0) ** 2 - slope * cov, 0.0)
        n = s0 * s0 / sww
        se = math.sqrt(resid / (max(n - 2.0, 1.0) * spread))
        if alone > 0:
            self.k = min(max((slope + K_Z * se) / alone, 0.0), K_MAX)

    def _probe_step(self, seconds: float, share: float) -> None:
        """Step number ``self.steps`` (about to be counted) into this cycle's windows; a probe ending is pooled."""
        if self.mode != "auto":
            return
        at, w = self.steps - self._cycle_at, self._w
        if (PROBE_CYCLE - 2) * w <= at < (PROBE_CYCLE - 1) * w:  # the window before the probe
            b = self._before
            b[0], b[1], b[2] = b[0] + seconds, b[1] + share * seconds, b[2] + 1
        elif at >= (PROBE_CYCLE - 1) * w and share == 0:  # the probe's clean steps
            self._alone[0], self._alone[1] = self._alone[0] + seconds, self._alone[1] + 1
        if at != PROBE_CYCLE * w - 1:
            return
        (t_sum, f_sum, n1), (t0_sum, n0) = self._before, self._alone
        self._before, self._alone = [0.0, 0.0, 0], [0.0, 0]
        self._cycle_at = self.steps + 1
        t = self.step_s
        self._w = PROBE_STEPS_MIN if not t else min(max(round(PROBE_WINDOW_S / t), PROBE_STEPS_MIN), PROBE_STEPS)
        if n1 < w // 2 or n0 < w // 2 or f_sum <= 0:  # (no probe held, or nothing solved before)
            return
        lost, busy = 1 - (t0_sum / n0) / (t_sum / n1), f_sum / t_sum  # (busy: the share of the window's time)
        d, d2 = PROBE_DECAY, PROBE_DECAY * PROBE_DECAY
        a, b, n, ll, lb, bb, n2 = self._pool
        self._pool = [d * a + lost, d * b + busy, d * n + 1, d2 * ll + lost * lost, d2 * lb + lost * busy,
                      d2 * bb + busy * busy, d2 * n2 + 1]
        self.probes += 1
        if self.probes >= PROBES_MIN:
            q = max(self._probe_q_low(), 0.0)
            self.k_probe = K_MAX if q >= K_MAX / (1 + K_MAX) else q / (1 - q)

    def _probe_q_low(self) -> float:
        """The pool's q (lost share per busy share, the ratio of the weighted sums) minus K_Z standard errors, the
        error from the probes' residuals about it (weighted, with the small-sample factor n / (n - 1))."""
        a, b, n, ll, lb, bb, n2 = self._pool
        q = a / b
        resid = max(ll - 2 * q * lb + q * q * bb, 0.0)
        n_eff = n * n / n2
        return q - K_Z * math.sqrt(resid * n_eff / max(n_eff - 1, 1e-9)) / b

    @property
    def probe_cost(self) -> float | None:
        """The share of steps the producer's pace cost, as the probes measured it (decayed mean; None before one)."""
        return self._pool[0] / self._pool[2] if self._pool[2] else None

    @property
    def slowdown(self) -> float:
        """k in force: the share fit's, or the probes' where they measured more (module docstring)."""
        return self.k if self.k_probe is None else max(self.k, self.k_probe)

    @property
    def step_s(self) -> float | None:
        """Training step seconds (the decayed mean; None before a step)."""
        return self.sums[3] / self.sums[0] if self.sums[0] else None

    def target(self) -> float | None:
        """R now: the fixed one, None when off, else the rule's (max_reuse until a solve and a step were measured)."""
        if self.mode is None:
            return None
        if self.mode != "auto":
            return float(self.mode)
        t = self.step_s
        if self.s is None or t is None:
            return self.max_reuse
        k = self.slowdown
        cost = self.s * k / (1 + k) + (self.i or 0.0)
        r = self.b * cost / (self.per * t * self.cost)
        return min(max(r, 1.0), self.max_reuse) if math.isfinite(r) else self.max_reuse

    def stats(self) -> dict:
        """What pacing chose and measured (flat numbers for metrics.csv; nan where not measured yet)."""
        nan = float("nan")
        r = self.target()
        return {"target_reuse": nan if r is None else r, "pace_slowdown": self.slowdown, "pace_fit_k": self.k,
                "pace_probe_k": nan if self.k_probe is None else self.k_probe, "pace_probes": self.probes,
                "pace_probe_cost": nan if self.probe_cost is None else self.probe_cost,
                "solve_s_per_traj": nan if self.s is None else self.s,
                "step_s": nan if self.step_s is None else self.step_s}


def _ewma(old, new: float, weight: float) -> float:
    return new if old is None else (1 - weight) * old + weight * new
