"""Active sampling (ParamProposal mode "active"): loss model + ensemble disagreement, sharp proposal, uniform floor,
background fit that never changes what is proposed."""

import copy
import time

import numpy as np
import pytest
import torch
from test_reservoir import same, stream, take

from pdestream.datasets import proposal as proposal_module
from pdestream.datasets.proposal import ParamProposal
from pdestream.datasets.proposal_fit import loss_model, running_median

DOMAINS = {"nu": ("loguniform", 0.01, 0.1, ()), "c": ("fixed", 1.0, 1.0, ()), "a": ("uniform", -1.0, 1.0, ())}


def fed(seed=0, n=2048, refit=256, **kw):
    """An active proposal fed ``n`` losses that are high in the lowest tenth of log(nu) (a sharp region at one end
    of the box), in batches of 32 with a proposal call after each, as the reservoir does."""
    prop = ParamProposal(DOMAINS, mode="active", seed=seed, refit=refit, **kw)
    rng = np.random.default_rng(seed)
    for _ in range(n // 32):
        z = rng.random(32)
        params = np.stack([np.exp(np.log(0.01) + z * np.log(10)), np.ones(32), rng.uniform(-1, 1, 32)], 1)
        prop.record(params, np.where(z < 0.1, 1.0, 0.02) * rng.uniform(0.8, 1.2, 32))
        prop.propose(16)
    return prop


def unit(prop, out):
    return prop.to_unit(np.stack([out["nu"], np.ones(len(out["nu"])), out["a"]], 1))


def test_active_proposal_holds_a_sharp_mode_inside_the_box_and_keeps_its_floor():
    prop = fed(floor=0.25)
    assert prop.fits == 8 and prop._fit is not None
    out = prop.propose(8000)
    assert set(out) == {"nu", "a"}  # the fixed parameter stays the solver's
    assert out["nu"].min() >= 0.01 and out["nu"].max() <= 0.1 and np.abs(out["a"]).max() <= 1.0
    z = unit(prop, out)[:, 0]
    assert (z < 0.12).mean() > 0.5  # uniform: 0.12; the steered three quarters go to the sharp region
    # the floor: a quarter of the draws are uniform, so every tenth of the box keeps at least ~0.025 of them
    assert min(((z >= a) & (z < a + 0.1)).mean() for a in np.arange(0.1, 1.0, 0.1)) > 0.8 * 0.25 * 0.1
    everything = ParamProposal(DOMAINS, mode="active", floor=1.0, seed=0)
    everything.__dict__.update({k: v for k, v in prop.__dict__.items() if k in ("_fit", "points", "losses")})
    z = unit(everything, everything.propose(8000))[:, 0]
    assert abs((z < 0.1).mean() - 0.1) < 0.02  # floor 1: uniform, whatever the fit says


def test_ensemble_spread_is_high_where_no_loss_was_seen_and_kappa_sends_draws_there():
    rng = np.random.default_rng(0)
    points = rng.uniform(0.0, 0.6, (400, 1))  # nothing seen above 0.6
    losses = np.exp(rng.normal(0, 0.3, 400))  # the same loss level everywhere it was seen
    at = np.array([[0.3], [0.95]])
    mean, spread = loss_model(points, losses, at, ensemble=8, rng=np.random.default_rng(1))
    assert spread[1] > 3 * spread[0]
    shares = []
    for kappa in (0.0, 4.0):
        # gate off: this tests the acquisition; the losses have no structure, so the skill gate would (rightly) make
        # both proposals uniform (test_the_gate_makes_a_proposal_without_skill_uniform)
        prop = ParamProposal({"x": ("uniform", 0.0, 1.0, ())}, mode="active", kappa=kappa, floor=0.1, refit=200, seed=0,
                             gate=False)
        for lo in range(0, 400, 100):
            prop.record(points[lo: lo + 100], losses[lo: lo + 100])
        prop._start_fit()  # the second fit's predecessor goes into use
        shares.append((prop.propose(4000)["x"] > 0.6).mean())
    assert shares[1] > shares[0] + 0.1


@pytest.mark.parametrize("ensemble", [1, 0, -3, True, 2.5, 101, 10**8])
def test_an_ensemble_below_two_or_above_a_hundred_is_refused_in_one_line(ensemble):
    # adv52: 10**8 was accepted and failed at the second refit (a MemoryError from the fit thread, a traceback)
    with pytest.raises(ValueError) as err:
        ParamProposal(DOMAINS, mode="active", ensemble=ensemble)
    assert str(err.value) == (f"proposal ensemble={ensemble!r} not allowed; must be an integer >= 2 (the uncertainty "
                              "signal is the disagreement of its members) and <= 100 (each member is a loss model "
                              "refitted at every refit)")


def test_cli_train_refuses_an_ensemble_of_one(capsys, tmp_path):
    from pdestream import cli

    out = tmp_path / "run"
    assert cli.main(["train", "burgers1d", "--reservoir", "--proposal", "active", "--proposal-ensemble", "1",
                     "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "proposal ensemble=1 not allowed; must be an integer >= 2" in err and err.count("\n") == 1
    assert not out.exists()


def test_non_finite_rows_are_dropped_with_a_count_and_never_reach_the_proposals():
    prop = ParamProposal(DOMAINS, mode="active", seed=0, refit=29)
    rng = np.random.default_rng(0)
    for _i in range(4):
        params = np.stack([np.exp(rng.uniform(np.log(0.01), np.log(0.1), 32)), np.ones(32), rng.uniform(-1, 1, 32)], 1)
        losses = rng.uniform(0.1, 1.0, 32)
        params[3, 0], losses[5], losses[6] = np.nan, np.inf, -np.inf
        losses[7] = 0.0  # finite: kept (counts as the smallest positive loss in the loss model)
        prop.record(params, losses)
    assert prop.dropped == 12 and len(prop.losses) == 4 * 29 and prop.fits == 4
    out = prop.propose(1000)
    assert all(np.isfinite(v).all() for v in out.values())
    assert out["nu"].min() >= 0.01 and out["nu"].max() <= 0.1


def test_state_dict_round_trip_continues_the_same_proposals(tmp_path):
    prop = fed(n=640)
    assert prop._next is not None  # a fit is in flight (or done) in the background
    path = tmp_path / "p.pt"
    torch.save(prop.state_dict(), path)
    again = ParamProposal(DOMAINS, mode="active", seed=0)
    again.load_state_dict(torch.load(path, weights_only=True))
    copied = copy.deepcopy(prop)  # the reservoir checks a state on a deep copy: the thread pool is not copied
    # the skill gate's pairs travel with the state: the resumed proposal steers the same share
    assert len(prop.skill_pred) > 32 and prop.steer > 0
    for p in (again, copied):
        assert np.array_equal(p.skill_pred, prop.skill_pred) and np.array_equal(p.skill_real, prop.skill_real)
        assert p.skill == prop.skill and p.steer == prop.steer
    rng = np.random.default_rng(5)
    for _ in range(20):  # across further refits: the resumed fits follow the same sequence
        params = np.stack([np.exp(rng.uniform(np.log(0.01), np.log(0.1), 32)), np.ones(32), rng.uniform(-1, 1, 32)], 1)
        losses = rng.uniform(0.1, 1.0, 32)
        outs = []
        for p in (prop, again, copied):
            p.record(params, losses)
            outs.append(p.propose(8))
        assert all(np.array_equal(o["nu"], outs[0]["nu"]) and np.array_equal(o["a"], outs[0]["a"]) for o in outs)
        assert prop.steer == again.steer == copied.steer
    for p in (prop, again, copied):
        p.close()
    with pytest.raises(ValueError, match="proposal state has mode 'active', this proposal 'loss'"):
        ParamProposal(DOMAINS, mode="loss").load_state_dict(prop.state_dict())


def test_a_slow_background_fit_changes_nothing(monkeypatch):
    fast = fed(n=1024, refit=64)
    slow_fit = proposal_module.active_fit

    def slow(*args):
        time.sleep(0.02)
        return slow_fit(*args)

    monkeypatch.setattr(proposal_module, "active_fit", slow)
    slow_prop = fed(n=1024, refit=64)
    assert np.array_equal(np.asarray(fast.proposed), np.asarray(slow_prop.proposed))


def test_active_reservoir_is_bit_reproducible_in_deterministic_mode():
    def run():
        s = stream(proposal="active", proposal_kwargs={"floor": 0.3, "refit": 8})
        batches = []
        for batch in torch.utils.data.DataLoader(s, batch_size=None):
            s.report_losses(batch, torch.where(batch["params"][:, 0] < 0.02, 1.0, 0.001).double())
            batches.append(batch)
            if len(batches) == 40:
                break
        state = s.state_dict()
        s.close()
        return batches, state

    (first, state), (second, _) = run(), run()
    assert state["proposal"]["fits"] >= 10 and same(first, second)
    nu = torch.cat([b["params"][:, 0] for b in first[20:]])
    assert nu.min() >= 0.01 and nu.max() <= 0.1
    assert (nu < 0.02).float().mean() > 0.4  # uniform in log: 0.30
    # resuming from the state continues the same batches
    resumed = stream(proposal="active", proposal_kwargs={"floor": 0.3, "refit": 8})
    resumed.load_state_dict(state)
    assert len(take(resumed, 3)) == 3


# --- the skill gate: never do harm -------------------------------------------------------------------------
BOX = {"x": ("uniform", 0.0, 1.0, ()), "y": ("uniform", 0.0, 1.0, ())}


def noise(z, rng):
    return rng.lognormal(0.0, 1.0, len(z))  # i.i.d. losses, independent of the parameters: nothing to steer by


def smooth(z, rng):
    return np.exp(3 * np.cos(np.pi * z[:, 0])) * rng.lognormal(0.0, 0.3, len(z))  # high at x = 0, none in y


def fed_by(loss, mode="active", gate=True, seed=0, n=4096):
    """A proposal fed ``n`` fresh losses of its own proposals (batches of 32, as the reservoir does); returns it and
    the steered share after each batch."""
    prop = ParamProposal(BOX, mode=mode, seed=seed, refit=256, gate=gate)
    rng = np.random.default_rng(seed + 100)
    z, steer = rng.random((32, 2)), []
    for _ in range(n // 32):
        prop.record(z, loss(z, rng))
        out = prop.propose(32)
        z = np.stack([out["x"], out["y"]], 1)
        steer.append(prop.steer)
    return prop, steer


def ks(u):
    """Kolmogorov-Smirnov statistic against uniform(0, 1), times sqrt(n) (1.63: the 1% critical value)."""
    u, n = np.sort(u), len(u)
    i = np.arange(1, n + 1)
    return max((i / n - u).max(), (u - (i - 1) / n).max()) * np.sqrt(n)


def chi2(z, bins=5):
    """Pearson's chi-square of a bins x bins histogram of z [N, 2] against uniform (24 dof: 43.0 at 1%)."""
    h = np.histogram2d(z[:, 0], z[:, 1], bins=bins, range=[[0, 1], [0, 1]])[0].ravel()
    return float(((h - len(z) / bins**2) ** 2 / (len(z) / bins**2)).sum())


@pytest.mark.parametrize("mode", ["active", "loss"])
def test_the_gate_makes_a_proposal_without_skill_uniform(mode):
    prop, steer = fed_by(noise, mode)
    assert len(prop.skill_pred) == 256 and prop.skill < 0.05 and prop.steer == 0.0
    assert np.mean(steer) < 0.02 and max(steer) < 0.2  # uniform throughout, bar a rare blip of chance skill
    out = prop.propose(20000)
    z = np.stack([out["x"], out["y"]], 1)
    assert ks(z[:, 0]) < 1.63 and ks(z[:, 1]) < 1.63 and chi2(z) < 43.0
    # without the gate the same proposal steers by a loss model of noise: its draws are far from uniform
    ungated, _ = fed_by(noise, mode, gate=False)
    out = ungated.propose(20000)
    z = np.stack([out["x"], out["y"]], 1)
    assert max(ks(z[:, 0]), ks(z[:, 1])) > 1.63 and chi2(z) > 100.0


@pytest.mark.parametrize("mode", ["active", "loss", "generative"])
def test_a_falling_loss_level_is_no_skill(mode):
    # no structure in the box, but the level falls as a trained model's does: a predictor that follows the level
    # (the kernel average of recent losses, a refitted intercept) correlated with the fresh losses through it alone
    # and opened the gate (kdv1d: "skill" 0.64, the steered draws 0.69x as hard as uniform ones)
    calls = iter(range(10**6))

    def falling(z, rng):
        return np.exp(-next(calls) / 20) * rng.lognormal(0.0, 0.5, len(z))

    prop, steer = fed_by(falling, mode)
    assert len(prop.skill_pred) == 256 and prop.steer == 0.0 and np.mean(steer) < 0.05, (prop.skill, np.mean(steer))


@pytest.mark.parametrize("mode", ["active", "loss"])
def test_the_gate_opens_on_skill_and_the_draws_go_where_the_loss_is_high(mode):
    prop, steer = fed_by(smooth, mode)
    assert prop.skill > 0.6 and prop.steer == steer[-1] == 1.0 - prop.floor
    out = prop.propose(20000)
    assert (out["x"] < 0.2).mean() > 0.35  # uniform: 0.2
    assert abs((out["y"] < 0.2).mean() - 0.2) < 0.03  # y carries no loss: left uniform


def test_the_steered_share_rule():
    prop = ParamProposal(BOX, mode="active", floor=0.2, skill_full=0.5, skill_min=8)
    assert prop.skill == 0.0 and prop.steer == 0.0  # nothing measured: uniform
    rng = np.random.default_rng(0)
    x = rng.normal(size=400)
    for r, expected in ((0.3, None), (0.95, 0.8)):
        prop.skill_pred, prop.skill_real = x, r * x + np.sqrt(1 - r**2) * rng.normal(size=400)
        at = np.arange(400.0)  # each less its running level (the 33 pairs nearest in arrival)
        skill = np.corrcoef(prop.skill_pred - running_median(prop.skill_pred, at, 33),
                            prop.skill_real - running_median(prop.skill_real, at, 33))[0, 1] - 2 / np.sqrt(399)
        assert prop.skill == pytest.approx(skill)
        assert prop.steer == pytest.approx(expected if expected is not None else 0.8 * skill / 0.5)
    assert ParamProposal(BOX, mode="active", floor=0.2, gate=False).steer == pytest.approx(0.8)
    assert ParamProposal(BOX, mode="uniform").steer == 0.0
    with pytest.raises(ValueError, match="proposal skill_full=0 not allowed"):
        ParamProposal(BOX, skill_full=0)


def test_the_reservoir_scores_only_first_draws():
    s = stream(proposal="loss", proposal_kwargs={"floor": 0.5}, max_reuse=4)
    seen, marks = set(), []
    record = s.proposal.record

    def spy(params, losses, fresh=None, latent=None, indices=None):
        marks.append(fresh.copy())
        record(params, losses, fresh=fresh, latent=latent, indices=indices)

    s.proposal.record = spy
    for batch in torch.utils.data.DataLoader(s, batch_size=None):
        index = batch["index"].tolist()
        s.report_losses(batch, torch.ones(len(index), dtype=torch.float64))
        assert marks[-1].tolist() == [i not in seen for i in index]
        seen.update(index)
        if len(marks) == 30:
            break
    s.close()
    fresh = np.concatenate(marks)
    assert 0 < fresh.sum() < len(fresh)  # trajectories come back (reuse) and are not scored again
    assert set(s.stats()) >= {"proposal_skill", "proposal_steer"}


def test_a_state_saved_before_the_gate_loads_with_the_gate_closed():
    prop, _ = fed_by(smooth, n=1024)
    old = prop.state_dict()
    for key in ("skill_pred", "skill_real"):
        del old[key]
    for key in ("fit", "next_fit"):
        old[key] = {k: v for k, v in old[key].items() if k != "coef"}  # fits had no mean weights then
    again = ParamProposal(BOX, mode="active", seed=0, refit=256)
    again.load_state_dict(old)
    assert len(again.skill_pred) == 0 and again.steer == 0.0 and again.predict(np.zeros((1, 2))) is None
    out = again.propose(100)
    assert np.isfinite(out["x"]).all()
    prop.close()


def test_the_cli_and_the_proposal_refuse_by_one_table(capsys):
    """reservoir_options.check_numbers (before torch) and ParamProposal (when built) read one table
    (reservoir_config.PROPOSAL_RANGES): each setting's bad value is refused in the same words by both."""
    from pdestream import cli
    from pdestream.datasets.proposal import ParamProposal
    from pdestream.datasets.reservoir_config import PROPOSAL_RANGES

    bad = {"floor": 0.0, "bandwidth": 1.5, "power": 9.0, "window": 0, "ensemble": 1, "kappa": -1.0, "top": 1.0,
           "step": 0.0, "gate": 1, "skill_full": float("nan"), "skill_min": 2, "refit": 0, "candidates": 0,
           "skill_window": 0, "probe": 1.0}
    assert set(bad) == set(PROPOSAL_RANGES)
    for name, value in bad.items():
        with pytest.raises(ValueError, match=rf"^proposal {name}=") as e:
            ParamProposal({"nu": (0.0, 1.0)}, **{name: value})
        assert "\n" not in str(e.value)
        if name in ("floor", "ensemble", "kappa"):  # the CLI's proposal options
            option = f"--proposal-{name}"
            assert cli.main(["train", "burgers1d", "--reservoir", "--proposal", "active", "--out", "never", option,
                             str(value)]) == 2
            assert str(e.value) in capsys.readouterr().err


def test_a_setting_the_proposal_does_not_read_is_refused_in_one_line():
    """ParamProposal (and so a reservoir's proposal_kwargs from Python): a setting given away from its default to a
    proposal that does not read it is refused, naming the proposals that do (it was silently ignored); at its default,
    or to a proposal that reads it, it is taken."""
    from pdestream.datasets.proposal import ParamProposal

    box = {"x": ("uniform", 0.0, 1.0, ())}
    for mode, name, value, users in (("uniform", "kappa", 5.0, "active"), ("loss", "top", 0.5, "generative"),
                                     ("generative", "bandwidth", 0.1, "loss"), ("active", "probe", 0.5, "generative"),
                                     ("uniform", "floor", 0.5, "loss / active / generative")):
        with pytest.raises(ValueError, match=rf"^proposal {name}={value!r} goes with proposal {users} \(not {mode}\)"):
            ParamProposal(box, mode=mode, **{name: value})
    ParamProposal(box, mode="uniform", kappa=1.0, floor=0.25)  # the defaults: nothing was set
    ParamProposal(box, mode="active", kappa=5.0, floor=0.5)
    ParamProposal(box, mode="generative", top=0.5, probe=0.0)
