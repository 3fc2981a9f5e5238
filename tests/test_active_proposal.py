"""Active sampling (ParamProposal mode "active"): loss model + ensemble disagreement, sharp proposal, uniform floor,
background fit that never changes what is proposed."""

import copy
import time

import numpy as np
import pytest
import torch
from test_reservoir import same, stream, take

from pdestream.datasets import proposal as proposal_module
from pdestream.datasets.proposal import ParamProposal, loss_model

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


@pytest.mark.parametrize("ensemble", [1, 0, -3, True, 2.5])
def test_an_ensemble_below_two_is_refused_in_one_line(ensemble):
    with pytest.raises(ValueError) as err:
        ParamProposal(DOMAINS, mode="active", ensemble=ensemble)
    assert str(err.value) == (f"proposal ensemble={ensemble!r} not allowed; must be an integer >= 2 (the uncertainty "
                              "signal is the disagreement of its members)")


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
    rng = np.random.default_rng(5)
    for _ in range(20):  # across further refits: the resumed fits follow the same sequence
        params = np.stack([np.exp(rng.uniform(np.log(0.01), np.log(0.1), 32)), np.ones(32), rng.uniform(-1, 1, 32)], 1)
        losses = rng.uniform(0.1, 1.0, 32)
        outs = []
        for p in (prop, again, copied):
            p.record(params, losses)
            outs.append(p.propose(8))
        assert all(np.array_equal(o["nu"], outs[0]["nu"]) and np.array_equal(o["a"], outs[0]["a"]) for o in outs)
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
