"""A proposal over (parameters, IC latent) (``proposal_space="params+ic"``): what it proposes is what is solved, it
is recorded where explicit parameters are (the reservoir's state), and a deterministic stream resumes exactly."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from pdestream import generator
from pdestream.datasets.proposal import LATENT, ParamProposal
from pdestream.datasets.reservoir import ReservoirStream

PDE = generator.get_pde("burgers1d", n=32, n_frames=4)
JOINT = {"space": "params+ic", "floor": 0.5, "gate": False, "refit": 16, "candidates": 256}


def stream(**kw):
    args = dict(seed=3, view="operator", batch_size=4, capacity=8, max_reuse=2, solve_batch=4, mode="deterministic",
                proposal="active", proposal_kwargs=JOINT)
    args.update(kw)
    return ReservoirStream(PDE, **args)


def run(s, n, head=None):
    """The stream's first n batches, each step reporting a loss that grows with the IC latent's first coordinate
    (so the proposal has something to steer by); stops after ``head`` batches when given, without closing."""
    out = []
    for batch in DataLoader(s, batch_size=None):
        slots_latent = s._drawn[5]
        s.report_losses(batch, torch.from_numpy(np.exp(slots_latent[:, 0])).double())
        out.append(batch)
        if len(out) == (head or n):
            break
    if head is None:
        s.close()
    return out


def same(a, b):
    return len(a) == len(b) and all(torch.equal(x[k], y[k]) for x, y in zip(a, b) for k in x)


# the generative proposal learns from fresh solves only (a few here): its high-difficulty set is the top 3/4
STEERING = {"active": {"proposal": "active"},
            "generative": {"proposal": "generative", "proposal_kwargs": {**{k: v for k, v in JOINT.items() if k != "candidates"},
                                                                          "top": 0.75, "refit": 8}}}


@pytest.mark.parametrize("proposal", list(STEERING))
def test_a_joint_proposal_solves_what_it_proposes_and_resumes_exactly(proposal):
    kw = STEERING[proposal]
    full = run(stream(**kw), 14)
    first = stream(**kw)
    head = run(first, 14, head=6)
    state = first.state_dict()
    first.close()
    if proposal == "generative":  # it steered by a model before the cut (what resumes is not the uniform start)
        assert state["proposal"]["generative"]["model"] is not None
    latent = state["reservoir"]["storage"]["latent"]
    assert np.asarray(latent).shape == (8, PDE.latent_size()) and np.isfinite(latent).all()
    assert any(job["params"] and LATENT in job["params"] for job in state["producer"]["jobs"])
    torch.save(state, "/dev/null")  # plain values
    resumed = stream(**kw)
    resumed.load_state_dict(state)
    assert same(head + run(resumed, 8), full)
    # what is held is the generator's sample of (seed, index, params, latent), bit for bit, and the latents are the
    # proposal's (not the keys'): the state re-solved them so
    res = resumed.res
    slots = res.live()
    assert not np.isnan(res.latent_host[slots]).any()
    slot = int(slots[0])
    traj = generator.sample(PDE, [int(res.index[slot])], seed=3, latent=res.latent_host[slot],
                            params={k: float(res.params_host[slot, j]) for j, k in enumerate(PDE.PARAMS)})
    assert np.array_equal(np.asarray(traj.u[0]), res.storage.u[slot].numpy())
    own = generator.sample(PDE, [int(res.index[slot])], seed=3,
                           params={k: float(res.params_host[slot, j]) for j, k in enumerate(PDE.PARAMS)})
    assert not np.array_equal(np.asarray(own.u[0]), res.storage.u[slot].numpy())


def test_joint_proposals_draw_the_prior_uniformly_and_steer_the_latent():
    prior = PDE.latent_prior()
    p = ParamProposal({"nu": ("loguniform", 0.01, 0.1, ())}, mode="active", seed=0, latent_prior=prior, gate=False,
                      floor=0.25, refit=64, candidates=1024)
    first = p.propose(4000)
    z = first[LATENT]
    assert z.shape == (4000, PDE.latent_size())
    assert abs(z.std() / prior[2][0] - 1) < 0.03  # no fit yet: the prior itself (the key's law)
    for _ in range(8):  # loss grows with the first latent coordinate: the steered draws go there
        d = p.propose(64)
        p.record(np.c_[d["nu"]], np.exp(2 * d[LATENT][:, 0]), latent=d[LATENT])
    later = p.propose(4000)[LATENT][:, 0]
    assert later.mean() > 0.3 * prior[2][0], later.mean()
    assert np.isfinite(later).all()


def test_a_bad_proposal_space_is_one_line(capsys, tmp_path):
    from pdestream import cli

    out = tmp_path / "run"
    argv = ["train", "burgers1d", "--reservoir", "--proposal", "active", "--out", str(out)]
    assert cli.main([*argv, "--proposal-space", "ic"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--proposal-space='ic' not allowed; allowed: params, params+ic" in err
    assert cli.main(["train", "burgers1d", "--reservoir", "--proposal-space", "params+ic", "--out", str(out)]) == 2
    assert "--proposal-space goes with" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(ValueError, match="has no latent coordinates"):
        ReservoirStream(generator.get_pde("euler1d"), batch_size=4, capacity=8, solve_batch=4, proposal="active",
                        proposal_kwargs={"space": "params+ic"})


def test_a_training_run_with_a_joint_proposal_resumes_exactly(tmp_path, monkeypatch):
    from interrupt import interrupted_at

    from pdestream.surrogate.runs import resume_run, train_run

    data = {"kind": "reservoir", "capacity": 8, "max_reuse": 2.0, "solve_batch": 4, "warmup": 4,
            "mode": "deterministic", "proposal": "active", "proposal_kwargs": {**JOINT, "refit": 8}}
    kw = dict(model_cfg={"width": 8, "modes": 4, "layers": 2}, steps=12, batch_size=4, n_test=2, checkpoint_every=6,
              data_cfg=data)
    train_run(PDE, "stream", tmp_path / "whole", **kw)
    with interrupted_at(monkeypatch, 9), pytest.raises(KeyboardInterrupt):
        train_run(PDE, "stream", tmp_path / "cut", **kw)
    state = torch.load(tmp_path / "cut" / "checkpoint.pt", weights_only=True)["data"]["state"]
    assert "latent" in state["reservoir"]["storage"] and state["proposal"]["dims"] == 1 + PDE.latent_size()
    _, step = resume_run(tmp_path / "cut")
    assert step == 6
    a = torch.load(tmp_path / "whole" / "model.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_a_2d_joint_state_saved_before_the_twins_were_paired_is_refused_in_one_line():
    # a 2D IC latent's layout changed when its conjugate twins were paired (generator.ics): an older state's held
    # latents would now give other initial conditions, so its resume is refused (a 1D state, whose layout did not
    # change, still resumes)
    pde2 = generator.get_pde("burgers2d", n=16, n_frames=3)
    s = ReservoirStream(pde2, seed=0, view="operator", batch_size=2, capacity=4, max_reuse=2, solve_batch=2,
                        mode="deterministic", proposal="generative", proposal_kwargs={"space": "params+ic"})
    run(s, 2)
    state = s.state_dict()
    assert state["latent_twins"] is True
    del state["latent_twins"]
    again = ReservoirStream(pde2, seed=0, view="operator", batch_size=2, capacity=4, max_reuse=2, solve_batch=2,
                            mode="deterministic", proposal="generative", proposal_kwargs={"space": "params+ic"})
    with pytest.raises(ValueError, match="^reservoir state saved before a 2D / 3D IC latent paired") as e:
        again.load_state_dict(state)
    assert "\n" not in str(e.value)
    old = stream()
    run(old, 2, head=2)
    flat = old.state_dict()
    old.close()
    del flat["latent_twins"]
    stream().load_state_dict(flat)  # 1D: resumes
