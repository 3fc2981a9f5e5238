"""The generative proposal (``ParamProposal(mode="generative")``): a kernel model of the high-difficulty fresh solves
in the prior's normal scores. Its draws stay inside the prior's support, go where the loss is high when the loss has
structure, stay uniform when it has none (the skill gate), and a stream steered by it resumes exactly."""

import numpy as np

from pdestream import generator
from pdestream.datasets.proposal import LATENT, ParamProposal
from pdestream.datasets.proposal_fit import generative_fit, normal_scores

PDE = generator.get_pde("burgers1d", n=32, n_frames=4)
DOMAINS = {"nu": ("loguniform", 0.01, 0.1, ()), "c": ("choice", 0.0, 0.0, (1.0, 2.0, 4.0)), "k": ("fixed", 1.0, 1.0, ())}


def feed(p, rounds, loss_of, rng, n=64):
    """rounds of propose -> losses (loss_of(draws) [n]) -> record, as the reservoir does for fresh solves."""
    for _ in range(rounds):
        d = p.propose(n)
        params = np.c_[d["nu"], d["c"], np.ones(n)]
        p.record(params, loss_of(d, rng), latent=d[LATENT])


def test_draws_stay_in_the_prior_support_and_go_where_the_loss_is_high():
    prior = PDE.latent_prior()
    sd = prior[2][0]
    # the loss grows with the first latent coordinate's size and with low viscosity: a steep structure that pulls
    # a proposal toward the edges of the box
    def loss_of(d, rng):
        return np.exp(3 * np.abs(d[LATENT][:, 0] / sd) - 5 * np.log10(d["nu"]) + 0.3 * rng.standard_normal(len(d["nu"])))

    p = ParamProposal(DOMAINS, mode="generative", seed=1, latent_prior=prior, refit=64, floor=0.25)
    feed(p, 16, loss_of, np.random.default_rng(0))
    assert p.fits > 0 and p.skill > 0.3 and p.steer > 0.4, (p.fits, p.skill, p.steer)
    out = p.propose(4000)
    assert (out["nu"] >= 0.01).all() and (out["nu"] <= 0.1).all() and set(np.unique(out["c"])) <= {1.0, 2.0, 4.0}
    assert np.isfinite(out[LATENT]).all() and "k" not in out
    hard = p.from_unit(p.steered(4000, np.random.default_rng(1)))
    uniform = p.from_unit(np.random.default_rng(2).random((4000, p.dims)))
    # the steered draws: a wider first coordinate (|x| drives the loss), lower viscosity, the other coordinates as
    # the prior's (nothing drives them)
    assert np.std(hard[LATENT][:, 0]) > 1.3 * np.std(uniform[LATENT][:, 0])
    assert np.median(hard["nu"]) < 0.8 * np.median(uniform["nu"])
    assert abs(np.std(hard[LATENT][:, 5:]) / sd - 1) < 0.05
    # a uniform-law latent (spot centres in [0, length)): every draw inside, even pushed against an edge
    spots = ("uniform", np.zeros(3), np.full(3, 2.0))
    q = ParamProposal(DOMAINS, mode="generative", seed=1, latent_prior=spots, refit=64, gate=False)
    feed(q, 12, lambda d, rng: np.exp(8 * d[LATENT][:, 0]), np.random.default_rng(0))
    edge = q.from_unit(q.steered(4000, np.random.default_rng(3)))[LATENT]
    assert (edge >= 0).all() and (edge <= 2).all() and np.mean(edge[:, 0]) > 1.3


def test_with_no_structure_in_the_loss_the_draws_are_uniform():
    prior = PDE.latent_prior()
    p = ParamProposal(DOMAINS, mode="generative", seed=2, latent_prior=prior, refit=64)
    feed(p, 16, lambda d, rng: np.exp(rng.standard_normal(len(d["nu"]))), np.random.default_rng(0))
    assert p.fits > 0 and len(p.skill_pred) >= p.skill_min  # the gate was measured, not just empty
    assert p.skill == 0.0 and p.steer == 0.0
    twin = np.random.default_rng()
    twin.bit_generator.state = p.rng.bit_generator.state
    z = p.to_unit(np.c_[(d := p.propose(2000))["nu"], d["c"], np.ones(2000)], d[LATENT])
    # gate shut: every draw is the uniform part (the same numbers a plain uniform draw of the box gives)
    expect = twin.random((2000, p.dims))
    assert np.allclose(z[:, 0], expect[:, 0]) and np.allclose(z[:, 2:], expect[:, 2:], atol=1e-6)


def test_the_model_of_a_random_hard_set_draws_the_prior():
    # the move is prior-preserving (pCN): centres drawn from the prior give draws of the prior (a plain Gaussian
    # jitter of step 0.25 would widen every coordinate by 3%)
    rng = np.random.default_rng(0)
    w = rng.standard_normal((2000, 50))
    p = ParamProposal({"x": ("uniform", 0.0, 1.0, ())}, mode="generative", seed=0,
                      latent_prior=("normal", np.zeros(49), np.ones(49)))
    p._gen = generative_fit(w, np.exp(rng.standard_normal(2000)), np.arange(2000.0), np.zeros(2000), 0.25)
    drawn = normal_scores(p.steered(20000, rng))
    assert abs(drawn.std() - 1) < 0.015 and abs(drawn.mean()) < 0.02, (drawn.std(), drawn.mean())


def test_the_fit_targets_the_prior_not_where_earlier_draws_went():
    # half the solves piled at w0 = 2 by an earlier proposal (its density there 10x the prior's); difficulty grows
    # with w0. Weighted back to the prior, the hard set's w0 mean is the prior's top-quarter mean (~1.27), not the
    # pile's 2
    rng = np.random.default_rng(0)
    w = np.r_[rng.standard_normal((400, 1)), 2 + 0.1 * rng.standard_normal((400, 1))]
    log_iw = np.r_[np.zeros(400), np.full(400, np.log(0.1))]
    at = rng.permutation(800).astype(float)  # the two kinds of solves interleaved in time
    mean, plain = (np.exp(v) @ c[:, 0] for c, v, *_ in (generative_fit(w, np.exp(w[:, 0]), at, iw, 0.25)
                                                   for iw in (log_iw, np.zeros(800))))
    assert 1.0 < mean < 1.6 < plain, (mean, plain)


def test_the_loss_proposal_over_a_long_latent_draws_no_nan():
    # Breed-style resampling over 171 coordinates: no recorded point has a neighbour within the kernel's reach, and
    # the crowding of one outside the reference subset was 0 (its pick weight NaN: a crash in the reservoir's loop)
    prior = generator.get_pde("burgers1d").latent_prior()
    p = ParamProposal({"nu": ("loguniform", 0.01, 0.1, ())}, mode="loss", seed=0, latent_prior=prior, gate=False)
    for _ in range(8):
        d = p.propose(64)
        p.record(np.c_[d["nu"]], np.exp(d[LATENT][:, 0] / prior[2][0]), latent=d[LATENT])
    hard = p.from_unit(p.steered(2000, np.random.default_rng(0)))
    assert np.isfinite(hard[LATENT]).all() and np.mean(hard[LATENT][:, 0]) > 0.3 * prior[2][0]


def feed_indexed(p, rounds, loss_of, rng, n=64, first=0):
    """As ``feed``, the reservoir's way: each draw proposed for a sample index, its loss reported with it."""
    for r in range(rounds):
        idx = np.arange(first + r * n, first + (r + 1) * n)
        d = p.propose(n, idx)
        p.record(np.c_[d["nu"], d["c"], np.ones(n)], loss_of(d, rng), latent=d[LATENT], indices=idx)
    return first + rounds * n


class NoCorrelation(ParamProposal):
    """A proposal whose loss model predicts nothing: its correlation gate stays shut, only the lift can open it."""

    def predict(self, z):
        return None


def steep(d, rng, sd=PDE.latent_prior()[2][0]):
    return np.exp(3 * np.abs(d[LATENT][:, 0] / sd) - 5 * np.log10(d["nu"]) + 0.3 * rng.standard_normal(len(d["nu"])))


def test_the_lift_opens_the_gate_where_the_correlation_cannot():
    from pdestream.datasets.proposal_lift import LIFT_MIN

    p = NoCorrelation(DOMAINS, mode="generative", seed=1, latent_prior=PDE.latent_prior(), refit=64, probe=0.25)
    feed_indexed(p, 1, steep, np.random.default_rng(0))  # the first fit: nothing to steer by before it
    assert p.fits == 1 and p.skill == 0.0 and p.lift.probed == 0 and p.steer == 0.25  # probing: no lift measured yet
    feed_indexed(p, 20, steep, np.random.default_rng(1), first=64)
    low, high = p.lift.bounds()
    assert p.skill == 0.0 and p.lift.probed >= LIFT_MIN and low > 0.3, (p.lift.probed, low)
    assert p.steer > 0.3, p.steer  # opened by the steered draws' own losses, past the probe share


def test_with_no_structure_the_probes_stop_and_the_draws_are_uniform():
    from pdestream.datasets.proposal_lift import LIFT_MIN

    p = NoCorrelation(DOMAINS, mode="generative", seed=2, latent_prior=PDE.latent_prior(), refit=64, probe=0.25)
    flat = lambda d, rng: np.exp(rng.standard_normal(len(d["nu"])))  # noqa: E731
    first = feed_indexed(p, 30, flat, np.random.default_rng(0))
    assert p.lift.probed >= LIFT_MIN and p.lift.bounds() is not None and p.steer == 0.0
    waiting = dict(p.lift.tags)
    probed = p.lift.probed
    feed_indexed(p, 4, flat, np.random.default_rng(1), first=first)
    assert p.lift.probed == probed and p.steer == 0.0  # after the probes: uniform draws only
    assert not waiting  # every tagged draw was scored (nothing left waiting)


def test_steered_draws_measurably_easier_close_the_gate_whatever_the_correlation():
    p = ParamProposal(DOMAINS, mode="generative", seed=1, latent_prior=PDE.latent_prior(), refit=64)
    feed(p, 16, steep, np.random.default_rng(0))
    assert p.skill > 0.3 and p.steer > 0.4
    rng = np.random.default_rng(3)
    idx = np.arange(10**6, 10**6 + 64)
    p.lift.tag(idx, np.arange(64) % 2 == 0)
    p.lift.score(idx, np.where(np.arange(64) % 2 == 0, -3.0, 0.0) + 0.1 * rng.standard_normal(64))
    assert p.lift.bounds()[1] < 0 and p.steer == 0.0


def test_easier_steered_draws_end_the_probe_after_veto_min_not_lift_min():
    # burgers2d: the probes drew 16 measurably easier fields before the veto fell (the p99 6% worse); the veto reads
    # the sign from VETO_MIN draws of each kind, the opening still waits for LIFT_MIN
    from pdestream.datasets.proposal_lift import LIFT_MIN, VETO_MIN

    p = NoCorrelation(DOMAINS, mode="generative", seed=1, latent_prior=PDE.latent_prior(), refit=64, probe=0.25)
    feed_indexed(p, 1, steep, np.random.default_rng(0))
    assert p.steer == 0.25 and p.lift.probed == 0
    rng = np.random.default_rng(3)
    for k in range(LIFT_MIN):  # one steered and one uniform draw scored at a time: steered ones e^-2 as hard
        idx = np.array([10**6 + 2 * k, 10**6 + 2 * k + 1])
        p.lift.tag(idx, np.array([True, False]))
        p.lift.score(idx, np.median(p.lift.level) + np.array([-2.0, 0.0]) + 0.3 * rng.standard_normal(2))
        scored = len(p.lift.d_steered)
        if scored < VETO_MIN:
            assert p.steer == 0.25, k  # still probing: too few to read a sign from
        elif scored < LIFT_MIN:
            assert p.lift.bounds() is None and p.steer == 0.0, k  # vetoed before the lift is decided
    # a lift never opens from VETO_MIN draws: harder steered draws leave the probe share until LIFT_MIN
    q = NoCorrelation(DOMAINS, mode="generative", seed=1, latent_prior=PDE.latent_prior(), refit=64, probe=0.25)
    feed_indexed(q, 1, steep, np.random.default_rng(0))
    for k in range(LIFT_MIN - 1):
        idx = np.array([10**6 + 2 * k, 10**6 + 2 * k + 1])
        q.lift.tag(idx, np.array([True, False]))
        q.lift.score(idx, np.median(q.lift.level) + np.array([2.0, 0.0]) + 0.3 * rng.standard_normal(2))
    assert len(q.lift.d_steered) >= VETO_MIN and q.lift.bounds() is None and q.steer == 0.25


def test_the_lift_resumes_exactly():
    p = NoCorrelation(DOMAINS, mode="generative", seed=4, latent_prior=PDE.latent_prior(), refit=64)
    first = feed_indexed(p, 12, steep, np.random.default_rng(0))
    q = NoCorrelation(DOMAINS, mode="generative", seed=4, latent_prior=PDE.latent_prior(), refit=64)
    q.load_state_dict(p.state_dict())
    assert q.lift.state() == p.lift.state() and q.steer == p.steer
    idx = np.arange(first, first + 64)
    a, b = p.propose(64, idx), q.propose(64, idx)
    assert all(np.array_equal(a[k], b[k]) for k in a) and q.lift.tags == p.lift.tags
