"""The noise baseline on the corrector (surrogate/modes.py ``SolverInTheLoop(noise=SIGMA)``, issue 29): the
coarse start state perturbed by N(0, SIGMA^2) in normalized units, the fine target clean; and the corrector
metrics of `compare --modes solver-in-the-loop` (the "pairs + noise" arm, improvement and gap closed against
the coarse solver, curves.csv, corrector.png).

Synthetic batches for the rule; tiny runs (burgers1d n=32 -> coarse 16, 11 frames, a tiny FNO) for the rest.
"""

import csv
import json
import re

import pytest
import torch
from torch import nn

from pdestream import cli, datasets, generator
from pdestream.surrogate.mode_table import SITL_NOISE_RULE, mode_settings
from pdestream.surrogate.modes import SolverInTheLoop, make_mode, subsample
from pdestream.surrogate.runs import resume_run, train_run
from tests.interrupt import interrupted_at
from tests.test_noise_mode import MEAN, STD, TINY, norm  # the synthetic data's statistics

torch.set_num_threads(1)

FINE = generator.get_pde("burgers1d", n=32, n_frames=11)


def batch(size: int = 64, n: int = 32, k_out: int = 1, seed: int = 1) -> dict:
    """Physical-unit windows on the fine grid: x [size, 1, 1, n], y [size, k_out, 1, n], params in nu's range."""
    g = torch.Generator().manual_seed(seed)
    u = MEAN + STD * torch.randn(size, 1 + k_out, 1, n, generator=g)
    return {"x": u[:, :1], "y": u[:, 1:], "params": 0.01 + 0.09 * torch.rand(size, 1, generator=g)}


def sitl(noise: float, seed: int = 0, unroll: int = 1) -> SolverInTheLoop:
    return make_mode({"name": "solver-in-the-loop", "unroll": unroll, "coarse_n": 16, "noise": noise}).bind(FINE, seed)


@pytest.mark.parametrize("sigma", [0.05, 0.3])
def test_the_coarse_start_state_gets_noise_of_the_stated_fraction_of_the_std(sigma):
    b = batch(size=256)
    mode = sitl(sigma)
    clean = subsample(b["x"][:, -1], 2, 1)  # the fine state at the coarse points: [256, 1, 16], 4096 draws
    eps = (mode.start(b, norm(), 7) - clean) / STD  # in normalized units
    # N(0, sigma^2) in normalized units (ignored: 0; in physical units instead: sigma / STD; twice: sigma * sqrt 2)
    assert abs(float(eps.mean())) < 4 * sigma / 64
    assert float(eps.std()) == pytest.approx(sigma, rel=0.06)
    assert float((eps * STD).std()) == pytest.approx(sigma * STD, rel=0.06)  # sigma x the data's std, physically
    # independent across points: no correlation between neighbours
    flat = eps[:, 0]
    assert abs(float(torch.corrcoef(torch.stack([flat[:, :-1].flatten(), flat[:, 1:].flatten()]))[0, 1])) < 0.06
    # a pure function of (seed, step); no noise: the clean state exactly
    assert torch.equal(mode.start(b, norm(), 7), sitl(sigma).start(b, norm(), 7))
    assert not torch.allclose(mode.start(b, norm(), 7), mode.start(b, norm(), 8))
    assert not torch.allclose(mode.start(b, norm(), 7), sitl(sigma, seed=1).start(b, norm(), 7))
    assert torch.equal(sitl(0.0).start(b, norm(), 7), clean)


class Recorder(nn.Module):
    """A stand-in coarse solver step: the identity, keeping what it was given."""

    def __init__(self):
        super().__init__()
        self.seen = []

    def forward(self, s, params):
        self.seen.append(s.detach().clone())
        return s


class Zero(nn.Module):
    """A correction network that corrects nothing (but has a parameter to differentiate)."""

    ndim = 1

    def __init__(self):
        super().__init__()
        self.w = nn.Parameter(torch.ones(()))

    def forward(self, z, p):
        return 0 * self.w * z


def test_the_solver_steps_from_the_perturbed_state_and_the_target_stays_clean():
    sigma, b = 0.1, batch(size=16, k_out=2)
    mode = sitl(sigma, unroll=2)
    mode.step = Recorder()
    loss, per = mode.step_loss(Zero(), b, norm(), 3)
    start = mode.start(b, norm(), 3)
    assert torch.allclose(mode.step.seen[0], start, atol=1e-6)  # the first solver step starts from s0 + eps
    assert not torch.allclose(start, subsample(b["x"][:, -1], 2, 1))
    # identity solver and zero correction: both unrolled states are s0 + eps, against the clean fine frames
    pred = ((start - MEAN) / STD)[:, None].repeat(1, 2, 1, 1)
    target = (subsample(b["y"], 2, 1) - MEAN) / STD
    assert loss.item() == pytest.approx(((pred - target) ** 2).mean().item(), rel=1e-5)
    # not against targets moved with the noise (the uncorrected target)
    eps = pred - ((subsample(b["x"][:, -1], 2, 1) - MEAN) / STD)[:, None]
    assert loss.item() != pytest.approx(((pred - (target + eps)) ** 2).mean().item(), rel=1e-3)
    assert per.shape == (16,)


def test_a_mask_channel_gets_no_noise():
    mode = sitl(0.2)
    mode.locations = ("centre", "mask")  # a flow's geometry channel is not perturbed
    eps = mode.perturbation(1, torch.zeros(32, 2, 16))
    assert float(eps[:, 0].abs().max()) > 0 and torch.equal(eps[:, 1], torch.zeros_like(eps[:, 1]))
    # and the start state's mask channel is the restricted mask bit for bit (no round trip through the
    # normalization), the other channel perturbed
    mode.factor, mode.walls = 2, ("periodic",)
    g = torch.Generator().manual_seed(2)
    x = torch.stack([MEAN + STD * torch.randn(8, 32, generator=g), (torch.rand(8, 32, generator=g) > 0.5).float()], 1)
    two = datasets.Normalization(("u", "solid"), torch.tensor([MEAN, 0.37]), torch.tensor([STD, 0.48]), ("nu",),
                                 torch.zeros(1), torch.ones(1), 1)
    start = mode.start({"x": x[:, None]}, two, 4)
    clean = subsample(x, 2, 1, None, mode.locations)
    assert torch.equal(start[:, 1], clean[:, 1]) and not torch.allclose(start[:, 0], clean[:, 0])


def test_settings_state_the_noise_and_rule_only_when_it_is_on():
    assert mode_settings("solver-in-the-loop")["noise"] == 0.0  # default: no noise (not the noise mode's 0.01)
    assert make_mode({"name": "solver-in-the-loop", "coarse_n": 16}).settings() == {
        "name": "solver-in-the-loop", "unroll": 4, "coarse_n": 16}  # run.json as before the setting existed
    assert make_mode({"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16, "noise": 0.1}).settings() == {
        "name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16, "noise": 0.1, "rule": SITL_NOISE_RULE}
    assert "clean" in SITL_NOISE_RULE and "N(0, noise^2)" in SITL_NOISE_RULE
    with pytest.raises(ValueError, match="--noise=-0.1 not allowed"):
        make_mode({"name": "solver-in-the-loop", "noise": -0.1})


def test_run_json_records_the_noise_and_resume_is_exact(tmp_path, monkeypatch):
    kw = dict(model_cfg=TINY, steps=6, batch_size=4, n_test=2, checkpoint_every=3, view=datasets.NextStep(1, 1),
              mode={"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16, "noise": 0.2})
    whole = train_run(FINE, "stream", tmp_path / "whole", **kw)
    with interrupted_at(monkeypatch, 5), pytest.raises(KeyboardInterrupt):
        train_run(FINE, "stream", tmp_path / "cut", **kw)
    settings = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert settings["mode"] == {"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16, "noise": 0.2,
                                "rule": SITL_NOISE_RULE}
    resumed, step = resume_run(tmp_path / "cut")
    assert step == 3 and resumed["mode"] == whole["mode"] == settings["mode"]
    a = torch.load(tmp_path / "whole" / "model.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def corrector_train_argv(out, unroll: int, *extra: str) -> list[str]:
    """`pdestream train` of a tiny corrector (burgers1d 32 -> 16, 2 steps, a tiny FNO) into ``out``, plus ``extra``."""
    return ["train", "burgers1d", "--set", "n=32", "--set", "n_frames=11", "--steps", "2", "--batch-size", "4",
            "--model-set", "width=8", "--model-set", "modes=4", "--model-set", "layers=2", "--test-samples", "2",
            "--mode", "solver-in-the-loop", "--coarse-n", "16", "--unroll", str(unroll), *extra, "--out", str(out)]


def test_cli_train_takes_noise_for_the_corrector(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(corrector_train_argv(out, 1, "--noise", "0.05")) == 0
    assert json.loads((out / "run.json").read_text())["mode"]["noise"] == 0.05
    assert "noise 0.05" in capsys.readouterr().out


def test_compare_pairs_noise_arm_at_zero_is_the_pairs_arm_and_the_corrector_metrics(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert cli.main(["compare", "burgers1d", "--modes", "solver-in-the-loop", "--quick", "--unroll", "2",
                     "--noise", "0", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    result = json.loads((out / "compare.json").read_text())
    arms = {a["arm"]: a for a in result["arms"]}
    assert list(arms) == ["coarse solver", "pairs (unroll 1)", "pairs + noise (unroll 1)",
                          "solver-in-the-loop (unroll 2)"]
    pairs, noisy = arms["pairs (unroll 1)"], arms["pairs + noise (unroll 1)"]
    # SIGMA = 0: the same training bit for bit (same weights, same rollout errors)
    a = torch.load(out / "sitl_unroll1" / "model.pt", weights_only=True)["model"]
    b = torch.load(out / "sitl_unroll1_noise" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert pairs["curve"] == noisy["curve"] and pairs["curve_p95"] == noisy["curve_p95"]
    assert pairs["steps"] == noisy["steps"] == arms["solver-in-the-loop (unroll 2)"]["steps"] == 20  # equal steps
    # the row in compare.md (and the printed table); the scores against the coarse solver
    table = (out / "compare.md").read_text()
    assert "| pairs + noise (unroll 1) | 16 |" in table and "| pairs + noise (unroll 1) | 16 |" in text
    assert "share of the coarse-to-fine gap closed 1 - e_arm / e_coarse" in table
    base = arms["coarse solver"]
    for arm in list(arms)[1:]:
        v = arms[arm]["vs_coarse"]
        for key in ("rollout_mean", "rollout_p95", "end_mean"):
            assert v[key]["improvement"] == pytest.approx(base[key] / arms[arm][key])
            assert v[key]["gap_closed"] == pytest.approx(1 - arms[arm][key] / base[key])
        assert f"| {arm} | {v['rollout_mean']['improvement']:.2f}x | {v['rollout_mean']['gap_closed']:+.1%} |" in table
    # (a tiny run: solver-in-the-loop may come out worse, said as "Nx higher" since adv49)
    assert "rollout p95" in table and re.search(r"\d\.\d\dx (lower|higher) than pairs \+ noise", table)
    # error against time per arm: curves.csv (mean and p95 per frame), corrector.png
    with open(out / "curves.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 * 10 and rows[0]["arm"] == "coarse solver" and rows[0]["frame"] == "1"
    got = [float(r["p95"]) for r in rows if r["arm"] == "pairs + noise (unroll 1)"]
    assert got == pytest.approx(noisy["curve_p95"], rel=1e-5)
    assert float(rows[0]["t"]) == pytest.approx(result["frame_dt"])
    assert (out / "corrector.png").stat().st_size > 1000 and "corrector.png" in text


@pytest.mark.slow
def test_pairs_steps_give_the_pairs_arms_their_own_steps_and_a_rerun_reads_them_back(tmp_path, capsys):
    """--pairs-steps: equal wall clock for the corrector's arms (solver-in-the-loop's unrolled steps cost more)."""
    out = tmp_path / "cmp"
    argv = ["compare", "burgers1d", "--modes", "solver-in-the-loop", "--quick", "--unroll", "2", "--pairs-steps",
            "30", "--out", str(out)]
    assert cli.main(argv) == 0
    arms = {a["arm"]: a for a in json.loads((out / "compare.json").read_text())["arms"]}
    assert arms["pairs (unroll 1)"]["steps"] == arms["pairs + noise (unroll 1)"]["steps"] == 30
    assert arms["solver-in-the-loop (unroll 2)"]["steps"] == 20
    assert "20 optimizer steps (the two pairs arms: 30)" in (out / "compare.md").read_text()
    capsys.readouterr()
    assert cli.main(argv) == 0  # every arm read back, none retrained
    assert capsys.readouterr().out.count("read back (not retrained)") == 3
    runs = [json.loads((out / d / "run.json").read_text())["steps"] for d in ("sitl_unroll1", "sitl_unroll2")]
    assert runs == [30, 20]


@pytest.mark.parametrize("extra, said", [
    (["--pairs-steps", "30"],
     "--pairs-steps, --corrector-start, --noise, --clip, --remat and --restrict go with --modes"),
    (["--modes", "solver-in-the-loop", "--pairs-steps", "0"], "--pairs-steps"),
    (["--modes", "pushforward", "--pairs-steps", "30"], "--pairs-steps 30 goes with the corrector's arms"),
])
def test_pairs_steps_refusals_are_one_line(tmp_path, capsys, extra, said):
    assert cli.main(["compare", "burgers1d", "--quick", "--out", str(tmp_path / "c"), *extra]) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1, err
