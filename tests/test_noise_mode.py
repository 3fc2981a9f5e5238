"""The noise training mode (surrogate/modes.py ``Noise``, Sanchez-Gonzalez et al. 2020): its perturbation's
statistics, its target, run.json, resume, the CLI's refusal of a bad scale and its arm in `compare --modes`.

Synthetic batches (no solver) for the rule itself; tiny runs (burgers1d n=32, 11 frames, a tiny FNO) for the rest.
"""

import json

import pytest
import torch
from torch import nn

from pdestream import cli, datasets, generator
from pdestream.surrogate import build_model
from pdestream.surrogate.mode_table import NOISE_RULE
from pdestream.surrogate.modes import Noise, OneStep, make_mode, random_walk, training_view
from pdestream.surrogate.runs import resume_run, train_run
from tests.interrupt import interrupted_at

torch.set_num_threads(1)

PDE = generator.get_pde("burgers1d", n=32, n_frames=11)
TINY = {"width": 8, "modes": 4, "layers": 2}
MEAN, STD = 3.0, 2.0  # the synthetic data's statistics: normalized units are (u - 3) / 2


def norm(channels: int = 1) -> datasets.Normalization:
    fields = tuple(f"f{c}" for c in range(channels))
    return datasets.Normalization(fields, torch.full((channels,), MEAN), torch.full((channels,), STD), ("nu",),
                                  torch.zeros(1), torch.ones(1), 1)


def batch(k_in: int, k_out: int, size: int = 64, n: int = 64, channels: int = 1, seed: int = 1) -> dict:
    """Physical-unit windows of mean MEAN and std STD: x [size, k_in, C, n], y [size, k_out, C, n]."""
    g = torch.Generator().manual_seed(seed)
    u = MEAN + STD * torch.randn(size, k_in + k_out, channels, n, generator=g)
    return {"x": u[:, :k_in], "y": u[:, k_in:], "params": torch.rand(size, 1, generator=g)}


class Seen(nn.Module):
    """A stand-in network that keeps its input ([B, k_in*C, n]) and answers ``answer(x)``."""

    ndim = 1

    def __init__(self, answer):
        super().__init__()
        self.w = nn.Parameter(torch.ones(()))  # something to differentiate
        self.answer, self.seen = answer, None

    def forward(self, x, p):
        self.seen = x.detach().clone()
        return self.w * self.answer(x)


def noisy_input(mode: Noise, b: dict, step: int = 7) -> torch.Tensor:
    """(what the network was given - the clean normalized input) of one training step: eps [B, k_in, C, n]."""
    c = b["x"].shape[2]
    model = Seen(lambda x: x[:, -c:])
    mode.step_loss(model, b, norm(c), step)
    clean = (b["x"] - MEAN) / STD
    return model.seen.reshape(clean.shape) - clean


@pytest.mark.parametrize("sigma", [0.05, 0.3])
def test_one_input_frame_gets_noise_of_the_stated_fraction_of_the_std(sigma):
    mode = Noise(sigma).bind(PDE, seed=0)
    eps = noisy_input(mode, batch(1, 1, size=64, n=64))  # 4096 draws
    # in normalized units the data's std is 1: the noise's std is sigma (ignored: 0; applied twice: sigma^2; in
    # physical units instead of normalized: sigma / STD)
    assert abs(float(eps.mean())) < 4 * sigma / 64
    assert float(eps.std()) == pytest.approx(sigma, rel=0.06)
    # in physical units it is sigma times the data's std
    assert float((eps * STD).std()) == pytest.approx(sigma * STD, rel=0.06)


def test_input_frames_get_a_random_walk_whose_newest_frame_has_the_stated_std():
    sigma, k_in = 0.2, 4
    eps = noisy_input(Noise(sigma).bind(PDE, 0), batch(k_in, 1, size=64, n=64))  # [64, 4, 1, 64]
    for j in range(1, k_in + 1):  # frame j (oldest = 1): std sigma * sqrt(j / k_in), mean 0
        frame = eps[:, j - 1]
        assert abs(float(frame.mean())) < 4 * sigma / 64, j
        assert float(frame.std()) == pytest.approx(sigma * (j / k_in) ** 0.5, rel=0.06), j
    # the increments are independent, each N(0, sigma^2 / k_in): a random walk, not one draw repeated
    steps = torch.diff(eps, dim=1, prepend=torch.zeros_like(eps[:, :1]))
    for j in range(k_in):
        assert float(steps[:, j].std()) == pytest.approx(sigma / k_in ** 0.5, rel=0.06)
    corr = torch.corrcoef(steps[:, :, 0].permute(1, 0, 2).reshape(k_in, -1))
    assert float((corr - torch.eye(k_in)).abs().max()) < 0.05
    # random_walk itself, over many draws
    big = random_walk(0, 1, (20000, 3, 1, 1), 0.5)
    assert torch.allclose(big.std(dim=(0, 2, 3)), 0.5 * torch.tensor([1 / 3, 2 / 3, 1.0]).sqrt(), rtol=0.03)


def test_the_target_is_the_clean_next_frames():
    sigma, k_in, k_out = 0.1, 2, 3
    b = batch(k_in, k_out, size=16, n=32)
    mode = Noise(sigma).bind(PDE, 0)
    # a network that copies its newest input frame k_out times: its loss is that of x_t + eps_t against the clean
    # y (normalized), not against y + eps_t (the uncorrected target, which the copy would match better)
    copy = Seen(lambda x: x[:, -1:].repeat(1, k_out, 1))
    loss, per = mode.step_loss(copy, b, norm(), 3)
    eps = random_walk(0, 3, tuple(b["x"].shape), sigma)
    given = (b["x"] - MEAN) / STD + eps
    clean_y = (b["y"] - MEAN) / STD
    assert torch.allclose(copy.seen.reshape(given.shape), given, atol=1e-6)
    expect = ((given[:, -1:] - clean_y) ** 2).mean()
    assert loss.item() == pytest.approx(expect.item(), rel=1e-5)
    assert loss.item() != pytest.approx((((given[:, -1:] - clean_y - eps[:, -1:]) ** 2).mean()).item(), rel=1e-3)
    pred = given[:, -1:].repeat(1, k_out, 1, 1).flatten(1)
    assert torch.allclose(per, ((pred - clean_y.flatten(1)).norm(dim=1) / clean_y.flatten(1).norm(dim=1)).double())


def test_noise_is_a_pure_function_of_seed_and_step_and_zero_noise_is_one_step():
    b = batch(2, 1, size=4, n=16)
    a = noisy_input(Noise(0.1).bind(PDE, 5), b, step=9)
    assert torch.equal(a, noisy_input(Noise(0.1).bind(PDE, 5), b, step=9))  # the same (seed, step): the same draw
    assert not torch.allclose(a, noisy_input(Noise(0.1).bind(PDE, 5), b, step=10))
    assert not torch.allclose(a, noisy_input(Noise(0.1).bind(PDE, 6), b, step=9))
    torch.manual_seed(0)
    model = build_model("fno", 1, 2, 1, 1, **TINY)
    zero, _ = Noise(0.0).bind(PDE, 0).step_loss(model, b, norm(), 1)
    plain, _ = OneStep().step_loss(model, b, norm(), 1)
    noisy, _ = Noise(0.1).bind(PDE, 0).step_loss(model, b, norm(), 1)
    assert zero.item() == plain.item() != noisy.item()


def test_a_mask_channel_gets_no_noise_and_the_view_must_have_frames():
    class Flow:  # what bind reads of a PDE: its fields and their locations
        FIELDS = ("u", "solid")
        FIELD_LOCATIONS = {"u": "centre", "solid": "mask"}

    eps = noisy_input(Noise(0.2).bind(Flow(), 0), batch(2, 1, size=8, n=16, channels=2))
    assert float(eps[:, :, 0].abs().max()) > 0 and torch.equal(eps[:, :, 1], torch.zeros_like(eps[:, :, 1]))
    assert training_view(Noise(0.1), datasets.NextStep(2, 3)) == datasets.NextStep(2, 3)  # any k_in, any k_out
    with pytest.raises(ValueError, match="perturbs the input frames of the next_step view, not 'operator'"):
        training_view(Noise(0.1), datasets.Operator())


def test_settings_and_run_json_state_the_scale_and_rule_and_resume_is_exact(tmp_path, monkeypatch):
    assert make_mode({"name": "noise"}).settings() == {"name": "noise", "noise": 0.01, "rule": NOISE_RULE}
    kw = dict(model_cfg=TINY, steps=6, batch_size=4, n_test=2, checkpoint_every=3, view=datasets.NextStep(2, 1),
              mode={"name": "noise", "noise": 0.3})
    whole = train_run(PDE, "stream", tmp_path / "whole", **kw)
    with interrupted_at(monkeypatch, 5), pytest.raises(KeyboardInterrupt):
        train_run(PDE, "stream", tmp_path / "cut", **kw)
    settings = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert settings["mode"] == {"name": "noise", "noise": 0.3, "rule": NOISE_RULE}
    assert "random walk" in NOISE_RULE and "clean" in NOISE_RULE
    resumed, step = resume_run(tmp_path / "cut")
    assert step == 3 and resumed["mode"] == whole["mode"] == settings["mode"]
    a = torch.load(tmp_path / "whole" / "model.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    # and the noise matters: the same run without it ends elsewhere
    plain = train_run(PDE, "stream", tmp_path / "plain", **{**kw, "mode": {"name": "noise", "noise": 0.0}})
    c = torch.load(tmp_path / "plain" / "model.pt", weights_only=True)["model"]
    assert plain["mode"]["noise"] == 0.0 and not all(torch.equal(a[k], c[k]) for k in a)


@pytest.mark.parametrize("command", ["train", "compare"])
@pytest.mark.parametrize("value", ["-0.1", "nan", "abc", "inf", "-inf"])
def test_cli_refuses_a_bad_noise_scale_in_one_line_at_once(tmp_path, capsys, command, value):
    out = tmp_path / "run"
    argv = (["train", "burgers1d", "--mode", "noise", "--steps", "2"] if command == "train" else
            ["compare", "burgers1d", "--modes", "one-step,noise", "--quick"])
    rc = cli.main([*argv, f"--noise={value}", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert f"--noise={value!r} not allowed; must be a finite number >= 0" in err and "data's std" in err, err
    assert not out.exists()


def test_cli_noise_goes_with_the_noise_mode_only(tmp_path, capsys):
    rc = cli.main(["train", "burgers1d", "--mode", "pushforward", "--noise", "0.1", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2 and "--noise=0.1 goes with solver-in-the-loop or noise, not pushforward" in err and err.count("\n") == 1
    rc = cli.main(["compare", "burgers1d", "--noise", "0.1", "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err
    assert rc == 2 and "--remat and --restrict go with --modes" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_cli_train_records_the_noise_and_compare_lists_a_noise_arm(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["train", "burgers1d", "--set", "n=32", "--set", "n_frames=11", "--steps", "3", "--batch-size",
                     "4", "--model-set", "width=8", "--model-set", "modes=4", "--model-set", "layers=2",
                     "--test-samples", "2", "--mode", "noise", "--noise", "0.05", "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["mode"] == {"name": "noise", "noise": 0.05, "rule": NOISE_RULE}
    assert "--mode noise (noise 0.05)" in capsys.readouterr().out
    cmp = tmp_path / "cmp"
    assert cli.main(["compare", "burgers1d", "--modes", "one-step,noise", "--quick", "--noise", "0.05",
                     "--out", str(cmp)]) == 0
    text = capsys.readouterr().out
    table = (cmp / "compare.md").read_text()
    assert "| noise | 32 |" in table and "| one-step | 32 |" in table and "| noise | 32 |" in text
    assert "noise: end error" in table and "input noise of std 0.05 x the data's std" in table
    arms = json.loads((cmp / "compare.json").read_text())["arms"]
    assert [(a["arm"], a.get("noise")) for a in arms] == [("one-step", None), ("noise", 0.05)]
    assert arms[1]["steps"] == 20 and all(v == v for v in arms[1]["curve"])


def test_cli_refuses_noise_on_a_steady_entry_in_one_line(tmp_path, capsys):
    rc = cli.main(["train", "darcy2d", "--set", "n=17", "--mode", "noise", "--steps", "2", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--mode noise perturbs input frames and darcy2d is steady" in err, err
    assert list(tmp_path.iterdir()) == []
