"""Long unrolls of the corrector (issue 29): gradient clipping (``SolverInTheLoop(clip=NORM)``, the training loop
clips the global gradient norm) and rematerialisation (``remat``: each unrolled step recomputed in the backward
pass). Tiny runs: burgers1d n=32 -> coarse 16, a tiny FNO.
"""

import json
import math

import pytest
import torch

from pdestream import cli, datasets, generator
from pdestream.surrogate.mode_table import mode_settings
from pdestream.surrogate.models import build_model
from pdestream.surrogate.modes import make_mode
from pdestream.surrogate.runs import resume_run, train_run
from tests.interrupt import interrupted_at
from tests.test_sitl_noise import corrector_train_argv

torch.set_num_threads(1)

FINE = generator.get_pde("burgers1d", n=32, n_frames=11)
TINY = {"width": 8, "modes": 4, "layers": 2}


def _batch(k: int) -> tuple[dict, datasets.Normalization]:
    """k + 1 frames of 6 fine trajectories as a next-step window batch, and their normalization."""
    d = datasets.sample_tensors(FINE, range(6), 0)
    u = d["u"][:, : k + 1]  # [B, k + 1, C, n]
    b = {"x": u[:, :1], "y": u[:, 1:], "params": d["params"]}
    return b, datasets.Normalization.from_batch(b, 1)


@pytest.mark.parametrize("k", [1, 4])
def test_remat_gives_the_loss_and_gradients_of_the_plain_unroll(k):
    b, norm = _batch(k)
    grads = {}
    for remat in (False, True):
        torch.manual_seed(0)
        model = build_model("fno", 1, 1, 1, 1, **TINY)
        mode = make_mode({"name": "solver-in-the-loop", "unroll": k, "coarse_n": 16, "remat": remat}).bind(FINE)
        loss, per = mode.step_loss(model, b, norm, 1)
        loss.backward()
        grads[remat] = (loss.item(), per, [p.grad.clone() for p in model.parameters()])
    (l0, per0, g0), (l1, per1, g1) = grads[False], grads[True]
    assert l1 == pytest.approx(l0, rel=1e-5) and torch.allclose(per0, per1, rtol=1e-5)
    # the forward of remat runs the solver's no-gradient program: equal to float32 rounding, not bit for bit
    for a, c in zip(g0, g1):
        assert float((a - c).norm()) <= 1e-4 * float(a.norm()) + 1e-7
    assert any(float(a.norm()) > 0 for a in g1)  # the parameters got their gradients through the checkpoints


def test_remat_keeps_only_the_states_between_steps_until_the_backward():
    """What the forward pass keeps for the backward: the unrolled steps' activations and the solver's JAX residuals
    without remat; with it, only each checkpoint's inputs (counted by torch's saved-tensor hooks and the solver's
    differentiable program's calls)."""
    from pdestream.datasets import solver

    b, norm = _batch(4)
    kept = {}
    for remat in (False, True):
        torch.manual_seed(0)
        model = build_model("fno", 1, 1, 1, 1, **TINY)
        mode = make_mode({"name": "solver-in-the-loop", "unroll": 4, "coarse_n": 16, "remat": remat}).bind(FINE)
        saved, vjps = [], []
        forward = solver._SolverFunction.forward

        def counting(ctx, *args):
            vjps.append(1)
            return forward(ctx, *args)

        solver._SolverFunction.forward = staticmethod(counting)
        try:
            with torch.autograd.graph.saved_tensors_hooks(lambda t: saved.append(t.numel()) or t, lambda t: t):
                loss, _ = mode.step_loss(model, b, norm, 1)
        finally:
            solver._SolverFunction.forward = staticmethod(forward)
        kept[remat] = (sum(saved), len(vjps))
        loss.backward()  # the recomputation runs here
    # the first step from the constant start runs the no-gradient program either way; the other three keep their
    # JAX residuals across the forward only without remat
    assert kept[False][1] == 3 and kept[True][1] == 0
    assert kept[True][0] < kept[False][0] / 2, kept  # step 1's activations and the three checkpoints' inputs


def test_settings_state_clip_and_remat_only_when_on_and_only_for_the_corrector():
    base = {"name": "solver-in-the-loop", "unroll": 4, "coarse_n": 16}
    assert make_mode({"name": "solver-in-the-loop", "coarse_n": 16}).settings() == base  # run.json as before
    assert make_mode({**base, "clip": "0.5", "remat": True}).settings() == {**base, "clip": 0.5, "remat": True}
    for bad in ("0", "-1", "nan", "inf", "abc"):
        with pytest.raises(ValueError, match=f"^--clip='{bad}' not allowed; must be a finite number > 0"):
            mode_settings("solver-in-the-loop", clip=bad)
    with pytest.raises(ValueError, match="^--clip=1.0 goes with solver-in-the-loop, not pushforward"):
        mode_settings("pushforward", clip=1.0)
    with pytest.raises(ValueError, match="^--remat=True goes with solver-in-the-loop, not one-step"):
        mode_settings("one-step", remat=True)


def test_clipping_counts_the_steps_it_clipped_and_resumes_exactly(tmp_path, monkeypatch):
    kw = dict(model_cfg=TINY, steps=6, batch_size=4, n_test=2, checkpoint_every=3, view=datasets.NextStep(1, 1))
    mode = {"name": "solver-in-the-loop", "unroll": 2, "coarse_n": 16}
    tight = train_run(FINE, "stream", tmp_path / "tight", mode={**mode, "clip": 1e-6}, **kw)
    loose = train_run(FINE, "stream", tmp_path / "loose", mode={**mode, "clip": 1e9}, **kw)
    plain = train_run(FINE, "stream", tmp_path / "plain", mode=mode, **kw)
    assert tight["clipped_steps"] == 6 and loose["clipped_steps"] == 0 and "clipped_steps" not in plain
    assert json.loads((tmp_path / "tight" / "run.json").read_text())["mode"]["clip"] == 1e-6
    a = torch.load(tmp_path / "loose" / "model.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "plain" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)  # a bound never reached changes nothing
    c = torch.load(tmp_path / "tight" / "model.pt", weights_only=True)["model"]
    assert not all(torch.equal(a[k], c[k]) for k in a)
    with interrupted_at(monkeypatch, 5), pytest.raises(KeyboardInterrupt):
        train_run(FINE, "stream", tmp_path / "cut", mode={**mode, "clip": 1e-6}, **kw)
    resumed, step = resume_run(tmp_path / "cut")
    assert step == 3 and resumed["clipped_steps"] == 6  # the counter went on from the checkpoint
    d = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(c[k], d[k]) for k in c)


def test_cli_takes_clip_and_remat_and_refuses_them_without_the_corrector(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(corrector_train_argv(out, 2, "--clip", "1.5", "--remat")) == 0
    assert json.loads((out / "run.json").read_text())["mode"] == {
        "name": "solver-in-the-loop", "unroll": 2, "coarse_n": 16, "clip": 1.5, "remat": True,
        "restrict": "fourier"}  # a new run: the default restriction
    capsys.readouterr()
    for argv, said in [(["train", "burgers1d", "--out", str(tmp_path / "r2"), "--clip", "1"],
                        "--clip=1 goes with solver-in-the-loop, not one-step"),
                       (["compare", "burgers1d", "--out", str(tmp_path / "c"), "--remat"],
                        "--clip, --remat and --restrict go with --modes"),
                       (["compare", "burgers1d", "--out", str(tmp_path / "c"), "--modes", "one-step", "--clip", "1"],
                        "--clip goes with the corrector's arms")]:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert said in err and err.count("\n") == 1, err


def test_compare_modes_rolls_every_arm_out_beyond_the_training_range_too(tmp_path, capsys):
    """compare --modes (not --quick): a second held-out set with the parameters beyond the training range
    (--shift), every seed's saved model and the coarse solver rolled out on it, in compare.md and compare.json."""
    out = tmp_path / "cmp"
    argv = ["compare", "burgers1d", "--modes", "one-step,solver-in-the-loop", "--set", "n=32", "--set", "n_frames=11",
            "--steps", "2", "--batch-size", "4", "--model-set", "width=8", "--model-set", "modes=4", "--model-set",
            "layers=2", "--test-samples", "4", "--coarse-n", "16", "--unroll", "2", "--seeds", "2", "--shift", "-0.25",
            "--out", str(out)]
    assert cli.main(argv) == 0
    said = capsys.readouterr().out
    result = json.loads((out / "compare.json").read_text())
    beyond = result["beyond"]
    assert beyond["domains"] == "nu ~ loguniform(0.00562341, 0.01)"  # below loguniform(0.01, 0.1) by a quarter (log)
    assert [a["arm"] for a in beyond["arms"]] == [a["arm"] for a in result["arms"]]
    assert all(a["seeds"] == [0, 1] for a in beyond["arms"] if a["mode"] != "none")
    assert all(math.isfinite(a["rollout_mean"]) and a["rollout_mean"] > 0 for a in beyond["arms"])
    inside = {a["arm"]: a["rollout_mean"] for a in result["arms"]}
    assert all(inside[a["arm"]] != a["rollout_mean"] for a in beyond["arms"])  # another test set
    md = (out / "compare.md").read_text()
    assert "## Beyond the training range (nu ~ loguniform(0.00562341, 0.01))" in md
    assert md.count("Solver-in-the-loop against each non-interacting corrector arm") == 2
    assert "beyond the range: end error mean" in said
    # a rerun reads every arm back and rolls it out again on both sets, to the same figures
    assert cli.main(argv) == 0
    again = json.loads((out / "compare.json").read_text())["beyond"]
    assert [a["rollout_mean"] for a in again["arms"]] == [a["rollout_mean"] for a in beyond["arms"]]


@pytest.mark.parametrize("clip, remat, said", [(0.5, True, ", every corrector arm's gradient clipped to global norm 0.5 "
                                                            "and rematerialised (--remat)"),
                                               (0.5, False, ", every corrector arm's gradient clipped to global norm 0.5"),
                                               (None, True, ", every corrector arm rematerialised (--remat)"),
                                               (None, False, None)])
def test_compare_md_says_the_corrector_arms_were_clipped_or_rematerialised(tmp_path, clip, remat, said):
    """compare.md's header named neither --clip nor --remat (only compare.json's config had them)."""
    from pdestream.experiments.interactive_config import InteractiveConfig
    from pdestream.experiments.interactive_report import write_tables

    def arm(name, mode):
        return {"arm": name, "mode": mode, "n": 16, "seeds": [0], "frames": 4, **dict.fromkeys(
            ("rollout_mean", "rollout_p95", "end_mean", "end_p95", "end_max", "wall_s", "final_loss"), 0.1), "steps": 2}

    cfg = InteractiveConfig(modes=("solver-in-the-loop",), clip=clip, remat=remat)
    write_tables(tmp_path, {"arms": [arm("coarse solver", "none")]}, generator.get_pde("burgers1d", n=32), cfg)
    head = (tmp_path / "compare.md").read_text().splitlines()[0]
    assert (said in head) if said else ("clipped" not in head and "remat" not in head), head


def test_compare_md_names_no_unroll_the_arms_do_not_take(tmp_path):
    """--unroll-schedule 1:0.5,2:0.5 with the corrector arms alone: the header said "unroll 4" (the default of an
    --unroll no arm took); the curriculum is named instead."""
    from pdestream.experiments.interactive_config import InteractiveConfig
    from pdestream.experiments.interactive_report import write_tables

    arm = {"arm": "coarse solver", "mode": "none", "n": 16, "seeds": [0], "frames": 4, "steps": 2, **dict.fromkeys(
        ("rollout_mean", "rollout_p95", "end_mean", "end_p95", "end_max", "wall_s", "final_loss"), 0.1)}
    for modes, schedule, has in ((("solver-in-the-loop",), "1:0.5,2:0.5", False), (("solver-in-the-loop",), None, True),
                                 (("pushforward", "solver-in-the-loop"), "1:0.5,2:0.5", True)):
        cfg = InteractiveConfig(modes=modes, unroll_schedule=schedule, steps=4)
        write_tables(tmp_path, {"arms": [arm]}, generator.get_pde("burgers1d", n=32), cfg)
        head = (tmp_path / "compare.md").read_text().splitlines()[0]
        assert ("unroll 4," in head) == has, head


def test_a_finished_arm_of_another_clip_is_refused_naming_the_values(tmp_path):
    """A rerun with another --clip said only "other settings (mode)"."""
    from pdestream.experiments.interactive_compare import _finished
    from pdestream.experiments.interactive_config import InteractiveConfig, arm_settings

    cfg = InteractiveConfig(modes=("solver-in-the-loop",), clip=0.5, coarse_n=16, steps=2)
    pde = generator.get_pde("burgers1d", n=64, n_frames=5)
    settings = arm_settings(cfg, "solver-in-the-loop", unroll=1)
    run = tmp_path / "arm"
    run.mkdir()
    have = {"model": cfg.model, "model_cfg": cfg.model_cfg, "steps": 3, "seconds": None, "batch_size": cfg.batch_size,
            "lr": cfg.lr, "seed": 0, "mode": {**make_mode(settings).settings(), "clip": 1.0}, "pde": pde.config()}
    (run / "run.json").write_text(json.dumps(have))
    (run / "metrics.json").write_text("{}")
    (run / "model.pt").write_bytes(b"")
    with pytest.raises(ValueError) as err:
        _finished(run, pde, settings, cfg, 0)
    assert "other settings (steps: the run's 3, asked 2; mode: clip the run's 1.0, asked 0.5)" in str(err.value), \
        str(err.value)


def test_a_network_mode_worse_than_one_step_is_said_higher_not_a_fraction_lower():
    """compare.md read "0.50x lower than one-step" for an end error twice one-step's (as the corrector's summary did
    before adv49's fix)."""
    from pdestream.experiments.interactive_report import _arms_lines

    def arm(name, end):
        return {"arm": name, "mode": name, "n": 32, "seeds": [0], "end_mean": end, "end_p95": end, "end_max": end,
                "rollout_mean": end, "rollout_p95": end, "wall_s": 1.0, "steps": 2, "final_loss": 0.1}

    text = "\n".join(_arms_lines([arm("one-step", 0.1), arm("pushforward", 0.2), arm("oracle", 0.05)]))
    assert "pushforward: end error 2.00x higher than one-step" in text
    assert "oracle: end error 2.00x lower than one-step" in text
    # adv51: a tie to the digits shown read "1.00x lower than one-step" (an untrained noise arm equal to one-step)
    tie = "\n".join(_arms_lines([arm("one-step", 0.1), arm("noise", 0.1002)]))
    assert "noise: end error the same (x1.00) as one-step" in tie, tie
