"""How the correction network of solver-in-the-loop starts (``--corrector-start``, surrogate/modes.py
``SolverInTheLoop.corrector_start``, issue 29): "zero" sets the model's output layer to zero, so before the first
optimizer step the correction is exactly 0 and the corrected solver is the coarse solver; recorded in run.json,
kept by a resume, taken by `train` and every corrector arm of `compare --modes`; a bad value is one line.

Tiny models and runs (burgers1d n=32 -> coarse 16, 11 frames, FNO width 8).
"""

import json

import pytest
import torch
from torch import nn

from pdestream import cli, datasets, generator
from pdestream.surrogate import modes as modes_module
from pdestream.surrogate.models import build_model
from pdestream.surrogate.modes import make_mode
from pdestream.surrogate.runs import resume_run, train_run
from tests.interrupt import interrupted_at

torch.set_num_threads(1)

FINE = generator.get_pde("burgers1d", n=32, n_frames=11)
TINY = {"width": 8, "modes": 4, "layers": 2}
SMALL = ["--set", "n=32", "--set", "n_frames=11", "--steps", "2", "--batch-size", "4", "--model-set", "width=8",
         "--model-set", "modes=4", "--model-set", "layers=2", "--test-samples", "2"]


def corrector(start: str | None):
    s = {"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16}
    return make_mode(s if start is None else {**s, "corrector_start": start}).bind(FINE)


@pytest.mark.parametrize("model, cfg", [("fno", TINY), ("unet", {"channels": 4, "depth": 1})])
def test_a_zero_start_makes_the_correction_exactly_zero_and_random_does_not(model, cfg):
    g = torch.Generator().manual_seed(0)
    z, p = torch.randn(5, 1, 16, generator=g), torch.randn(5, 1, generator=g)
    torch.manual_seed(0)
    net = build_model(model, 1, 1, 1, 1, **cfg)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    corrector("random").init_model(net)  # random: the model's own initialisation, left as it is
    assert all(torch.equal(v, before[k]) for k, v in net.state_dict().items())
    assert float(net(z, p).detach().abs().max()) > 1e-3
    corrector("zero").init_model(net)
    out = net(z, p)
    assert out.shape == (5, 1, 16) and torch.equal(out, torch.zeros_like(out))
    # the corrected solver is then the coarse solver (to the normalization's round trip)
    mode = corrector("zero")
    norm = datasets.Normalization(("u",), torch.tensor([0.3]), torch.tensor([2.0]), ("nu",), torch.zeros(1),
                                  torch.ones(1), 1)
    s = 0.3 + 2.0 * torch.randn(5, 1, 16, generator=g)
    assert torch.allclose(mode.correct(net, norm, s, p), s, rtol=0, atol=1e-6)
    # only the output layer changed: the layers before it keep their initialisation (the network can still learn)
    changed = sorted(k for k, v in net.state_dict().items() if not torch.equal(v, before[k]))
    assert len(changed) == 2 and all(k.endswith(("linear.weight", "linear.bias")) for k in changed), changed


def test_settings_record_a_zero_start_only_and_a_bad_value_is_one_line():
    assert corrector(None).settings() == {"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16}  # as before
    assert corrector("random").settings() == corrector(None).settings()
    assert corrector("zero").settings()["corrector_start"] == "zero"
    with pytest.raises(ValueError, match=r"^--corrector-start='ones' not allowed; allowed: random, zero"):
        corrector("ones")
    with pytest.raises(ValueError, match="--corrector-start=zero goes with solver-in-the-loop, not one-step"):
        make_mode({"name": "one-step", "corrector_start": "zero"})

    class Own(nn.Module):
        def forward(self, z, p):
            return z

    with pytest.raises(ValueError, match="--corrector-start zero not allowed with the model Own: it has no output_layer"):
        corrector("zero").init_model(Own())


def test_run_json_records_the_zero_start_the_run_starts_at_zero_and_resume_is_exact(tmp_path, monkeypatch):
    first = []  # the correction of the first optimizer step, on its own input
    step_loss = modes_module.SolverInTheLoop.step_loss

    def spy(self, model, batch, norm, step):
        if not first:
            first.append(model(torch.randn(3, 1, 16), torch.zeros(3, 1)).detach())
        return step_loss(self, model, batch, norm, step)

    monkeypatch.setattr(modes_module.SolverInTheLoop, "step_loss", spy)
    kw = dict(model_cfg=TINY, steps=6, batch_size=4, n_test=2, checkpoint_every=3, view=datasets.NextStep(1, 1),
              mode={"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16, "corrector_start": "zero"})
    whole = train_run(FINE, "stream", tmp_path / "whole", **kw)
    assert torch.equal(first[0], torch.zeros_like(first[0]))
    with interrupted_at(monkeypatch, 5), pytest.raises(KeyboardInterrupt):
        train_run(FINE, "stream", tmp_path / "cut", **kw)
    settings = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert settings["mode"] == {"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16, "corrector_start": "zero"}
    resumed, step = resume_run(tmp_path / "cut")
    assert step == 3 and resumed["mode"] == whole["mode"] == settings["mode"]
    a = torch.load(tmp_path / "whole" / "model.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("argv", [["train", "burgers1d", "--mode", "solver-in-the-loop", "--steps", "2"],
                                  ["compare", "burgers1d", "--modes", "solver-in-the-loop", "--quick"]])
def test_cli_refuses_a_bad_start_in_one_line(tmp_path, capsys, argv):
    out = tmp_path / "run"
    rc = cli.main([*argv, "--corrector-start", "ones", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert "--corrector-start='ones' not allowed; allowed: random, zero" in err
    rc = cli.main(["compare", "burgers1d", "--corrector-start", "zero", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "--corrector-start, --noise, --clip, --remat and --restrict go with --modes" in err and err.count("\n") == 1
    assert not out.exists()


def test_cli_train_and_compare_take_the_zero_start(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["train", "burgers1d", *SMALL, "--mode", "solver-in-the-loop", "--coarse-n", "16", "--unroll",
                     "1", "--corrector-start", "zero", "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["mode"]["corrector_start"] == "zero"
    assert "corrector_start zero" in capsys.readouterr().out
    cmp = tmp_path / "cmp"
    assert cli.main(["compare", "burgers1d", "--modes", "solver-in-the-loop", "--quick", "--steps", "2",
                     "--unroll", "2", "--corrector-start", "zero", "--out", str(cmp)]) == 0
    assert "corrector start: zero" in (cmp / "compare.md").read_text()
    for arm in ("sitl_unroll1", "sitl_unroll1_noise", "sitl_unroll2"):  # every corrector arm
        assert json.loads((cmp / arm / "run.json").read_text())["mode"]["corrector_start"] == "zero"
    assert json.loads((cmp / "compare.json").read_text())["config"]["corrector_start"] == "zero"
