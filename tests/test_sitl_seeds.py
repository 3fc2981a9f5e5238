"""`compare --modes ...solver-in-the-loop` over several seeds, resumable per (arm, seed), and the solver-in-the-loop
arm's unroll curriculum (``--unroll-schedule``; issue 29). Before, --seeds was silently ignored (seed 0 only).

Tiny models and runs (burgers1d n=32 -> coarse 16, 11 frames, FNO width 8, 2-3 steps).
"""

import json

import numpy as np
import pytest
import torch

from pdestream import cli, datasets, generator
from pdestream.surrogate.mode_table import parse_unroll_schedule
from pdestream.surrogate.modes import make_mode

torch.set_num_threads(1)

SMALL = ["compare", "burgers1d", "--modes", "solver-in-the-loop", "--set", "n=32", "--set", "n_frames=11",
         "--coarse-n", "16", "--batch-size", "4", "--model-set", "width=8", "--model-set", "modes=4",
         "--model-set", "layers=2", "--test-samples", "2", "--threads", "1"]


def test_corrector_arms_train_every_seed_report_mean_and_std_and_resume(tmp_path, capsys, monkeypatch):
    out = tmp_path / "cmp"
    argv = [*SMALL, "--steps", "2", "--seeds", "2", "--out", str(out)]
    assert cli.main(argv) == 0
    runs = {"sitl_unroll1", "sitl_unroll1_noise", "sitl_unroll4"}
    for run in runs:  # one run per (arm, seed), each with its own seed
        for seed in (0, 1):
            assert json.loads((out / f"{run}_seed{seed}" / "run.json").read_text())["seed"] == seed
    result = json.loads((out / "compare.json").read_text())
    trained = [a for a in result["arms"] if a["mode"] == "solver-in-the-loop"]
    assert len(trained) == 3
    for a in trained:
        assert a["seeds"] == [0, 1]
        values = [s["rollout_mean"] for s in a["per_seed"]]
        assert values[0] != values[1]  # other weights and data per seed
        assert a["rollout_mean"] == pytest.approx(np.mean(values))
        assert a["rollout_mean_std"] == pytest.approx(np.std(values, ddof=1))
    md = (out / "compare.md").read_text()
    assert "2 model and data seeds [0, 1]" in md and " ± " in md
    inside, beyond = md.split("## Beyond the training range")  # (since 407da2b every arm is rolled out beyond too)
    for part in (inside, beyond):
        verdicts = [line for line in part.splitlines() if line.startswith("- ")]
        assert len(verdicts) == 6 and all("the seed spread" in line for line in verdicts)  # 3 metrics x 2 arms
    capsys.readouterr()

    def no_training(*args, **kwargs):
        raise AssertionError("a finished (arm, seed) was trained again")

    # the same command again: every finished (arm, seed) read back, the same figures
    monkeypatch.setattr("pdestream.experiments.interactive_compare.train_run", no_training)
    assert cli.main(argv) == 0
    assert capsys.readouterr().out.count("read back (not retrained)") == 6
    again = json.loads((out / "compare.json").read_text())
    assert [a["rollout_mean"] for a in again["arms"]] == [a["rollout_mean"] for a in result["arms"]]
    # other settings on the same out: one line, before any work
    assert cli.main([*SMALL, "--steps", "3", "--seeds", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pdestream: error: ") and "holds a finished run with other settings (steps: the run's " in err
    assert "\n" not in err



def train_only_seed(monkeypatch, seed: int) -> list:
    """compare's training patched to fail for any seed but ``seed``; the seeds it trained, in order."""
    from pdestream.experiments import interactive_compare

    trained, real = [], interactive_compare.train_run

    def only(*args, **kwargs):
        assert kwargs["seed"] == seed, f"seed {kwargs['seed']} was trained again"
        trained.append(kwargs["seed"])
        return real(*args, **kwargs)

    monkeypatch.setattr(interactive_compare, "train_run", only)
    return trained


def test_a_one_seed_run_is_read_back_as_seed_0_of_a_several_seed_rerun(tmp_path, capsys, monkeypatch):
    """--seeds 1 then --seeds 2 on the same out: seed 0 (in ARM/, not ARM_seed0/) is read back, only seed 1 trains
    (before, the rerun trained seed 0 again under ARM_seed0: on ns2d a quarter of an hour)."""
    out = tmp_path / "cmp"
    assert cli.main([*SMALL, "--steps", "2", "--seeds", "1", "--out", str(out)]) == 0
    one = {a["arm"]: a["rollout_mean"] for a in json.loads((out / "compare.json").read_text())["arms"]}
    capsys.readouterr()
    trained = train_only_seed(monkeypatch, 1)
    assert cli.main([*SMALL, "--steps", "2", "--seeds", "2", "--out", str(out)]) == 0
    assert capsys.readouterr().out.count("read back (not retrained)") == 3 and trained == [1, 1, 1]
    assert not any((out / f"{run}_seed0").exists() for run in ("sitl_unroll1", "sitl_unroll1_noise", "sitl_unroll4"))
    for a in json.loads((out / "compare.json").read_text())["arms"]:
        if a["mode"] == "solver-in-the-loop":
            assert a["seeds"] == [0, 1] and a["per_seed"][0]["rollout_mean"] == one[a["arm"]]


def test_only_seed_trains_that_seed_alone_and_a_run_without_it_reads_it_back(tmp_path, capsys, monkeypatch):
    """--only-seed S: one process per seed (a comparison's seeds spread over cores or machines); it writes no tables,
    and the same command without it trains only the seeds still missing, then writes them."""
    out = tmp_path / "cmp"
    argv = [*SMALL, "--steps", "2", "--seeds", "2", "--out", str(out)]
    assert cli.main([*argv, "--only-seed", "1"]) == 0
    assert "(every arm, seed 1)" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["sitl_unroll1_noise_seed1", "sitl_unroll1_seed1",
                                                     "sitl_unroll4_seed1"]  # no tables, no seed 0
    trained = train_only_seed(monkeypatch, 0)
    assert cli.main(argv) == 0
    assert capsys.readouterr().out.count("read back (not retrained)") == 3 and trained == [0, 0, 0]
    arms = [a for a in json.loads((out / "compare.json").read_text())["arms"] if a["mode"] == "solver-in-the-loop"]
    assert len(arms) == 3 and all(a["seeds"] == [0, 1] for a in arms)


def test_only_arm_trains_those_arms_and_a_run_without_it_trains_the_rest(tmp_path, capsys, monkeypatch):
    out = tmp_path / "cmp"
    argv = [*SMALL, "--steps", "2", "--seeds", "1", "--out", str(out)]
    assert cli.main([*argv, "--only-arm", "sitl_unroll4"]) == 0
    assert "trained (sitl_unroll4)" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["sitl_unroll4"]  # that arm alone, no tables
    assert cli.main([*argv, "--only-arm", "sitl_unroll1,sitl_unroll1_noise"]) == 0  # beside it, e.g. another core
    capsys.readouterr()
    trained = train_only_seed(monkeypatch, 0)
    assert cli.main(argv) == 0
    assert capsys.readouterr().out.count("read back (not retrained)") == 3 and trained == []
    assert (out / "compare.md").is_file()


def test_only_seed_outside_the_seeds_or_without_modes_is_one_line_before_any_work(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert cli.main([*SMALL, "--steps", "2", "--seeds", "2", "--only-seed", "2", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == ("pdestream: error: --only-seed 2 not among the seeds trained (0...1: "
                                               "--seeds 2)")
    assert cli.main(["compare", "burgers1d", "--quick", "--only-seed", "1", "--out", str(out)]) == 2
    assert "--only-seed 1 goes with --modes" in capsys.readouterr().err
    assert cli.main([*SMALL, "--steps", "2", "--only-arm", "sitl_unroll4,pairs", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == ("pdestream: error: --only-arm pairs not an arm of this comparison; its "
                                               "arms: sitl_unroll1, sitl_unroll1_noise, sitl_unroll4")
    assert cli.main(["compare", "burgers1d", "--quick", "--only-arm", "x", "--out", str(out)]) == 2
    assert "--only-arm x goes with --modes" in capsys.readouterr().err
    assert not out.exists()


def test_a_model_setting_written_otherwise_reads_the_same_arm_back(tmp_path, capsys, monkeypatch):
    # --model-set width=08 against the finished arm of width=8 was refused as "other settings" (compared as strings)
    out = tmp_path / "cmp"
    argv = [*SMALL, "--steps", "2", "--out", str(out)]
    assert cli.main(argv) == 0
    capsys.readouterr()

    def no_training(*args, **kwargs):
        raise AssertionError("a finished arm was trained again")

    monkeypatch.setattr("pdestream.experiments.interactive_compare.train_run", no_training)
    assert cli.main([a.replace("width=8", "width=08") for a in argv]) == 0
    assert capsys.readouterr().out.count("read back (not retrained)") == 3
    assert cli.main([a.replace("width=8", "width=9") for a in argv]) == 2  # another width: another model
    assert "model_cfg" in capsys.readouterr().err


def test_built_in_model_settings_compare_as_numbers_your_own_models_as_given():
    from pdestream.experiments.interactive_config import comparable_model_cfg

    assert comparable_model_cfg({"model": "fno", "model_cfg": {"width": "08", "modes": 4}}) == {"width": 8, "modes": 4}
    assert comparable_model_cfg({"model": "unet2d", "model_cfg": {"depth": " 3"}}) == {"depth": 3}
    assert comparable_model_cfg({"model": "fno", "model_cfg": {"width": "wide"}}) == {"width": "wide"}  # refused later
    mine = {"model": "my.models:Net", "model_cfg": {"width": "08"}}
    assert comparable_model_cfg(mine) == {"width": "08"}  # your own model parses its own settings


def test_the_rollouts_figure_names_the_unroll_it_shows(tmp_path, monkeypatch):
    from pdestream.experiments import interactive_compare

    seen = []
    monkeypatch.setattr(interactive_compare, "plot_rollouts", lambda path, pde, rows, *a, **k: seen.extend(rows))
    assert cli.main([*SMALL, "--steps", "1", "--seeds", "1", "--unroll", "3", "--out", str(tmp_path / "c")]) == 0
    assert "solver-in-the-loop (unroll 3)" in seen and not any("unroll 0" in r for r in seen)

def test_unroll_at_follows_the_schedule_and_the_loss_unrolls_that_many_steps():
    fine = generator.get_pde("burgers1d", n=32, n_frames=11)
    mode = make_mode({"name": "solver-in-the-loop", "unroll": 3, "coarse_n": 16,
                      "unroll_schedule": [[1, 2], [3, 1]]}).bind(fine)
    assert [mode.unroll_at(s) for s in range(1, 6)] == [1, 1, 3, 3, 3]  # the last unroll after the schedule
    assert mode.settings()["unroll_schedule"] == [[1, 2], [3, 1]]  # run.json
    x = torch.linspace(0, 2 * np.pi, 33)[:-1]
    u = torch.sin(x)[None, None, None].repeat(2, 4, 1, 1)  # [B, T, C, n]
    batch = {"x": u[:, :1], "y": u[:, 1:], "params": torch.full((2, 1), 0.05)}
    norm = datasets.Normalization(("u",), torch.zeros(1), torch.ones(1), ("nu",), torch.zeros(1), torch.ones(1), 1)
    calls = []
    solver = mode.step
    mode.step = lambda s, p: calls.append(1) or solver(s, p)
    net = lambda z, p: torch.zeros_like(z)  # noqa: E731
    net.ndim = 1
    for step, k in ((1, 1), (2, 1), (3, 3)):
        calls.clear()
        loss, per_example = mode.step_loss(net, batch, norm, step)
        assert len(calls) == k and bool(torch.isfinite(loss))


def test_unroll_schedule_in_steps_and_bad_values_are_one_line(tmp_path, capsys):
    assert parse_unroll_schedule("1:0.3,4:0.3,16:0.4", 1500) == [[1, 450], [4, 450], [16, 600]]
    for bad in ("1:0.5,4:0.6", "0:1", "4", "a:1", "1:0.5:2"):
        assert cli.main([*SMALL, "--steps", "3", "--unroll-schedule", bad, "--out", str(tmp_path / "x")]) == 2
        err = capsys.readouterr().err.strip()
        assert err == (f"pdestream: error: --unroll-schedule {bad!r} not allowed; allowed: UNROLL:SHARE pairs, "
                       "comma-separated, each unroll a positive integer and each share of the optimizer steps > 0, "
                       "the shares summing to 1, e.g. 1:0.3,4:0.3,16:0.4")
    assert cli.main([*SMALL, "--steps", "3", "--unroll-schedule", "4:0.1,1:0.9", "--out", str(tmp_path / "x")]) == 2
    assert "the phase of unroll 4 gets no optimizer step of --steps 3" in capsys.readouterr().err
    # not silently dropped where no arm takes it
    argv = ["compare", "burgers1d", "--modes", "one-step", "--quick", "--unroll-schedule", "1:1", "--out"]
    assert cli.main([*argv, str(tmp_path / "y")]) == 2
    assert "goes with the solver-in-the-loop arm" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_the_schedule_trains_the_solver_in_the_loop_arm_and_is_recorded(tmp_path):
    out = tmp_path / "cmp"
    assert cli.main([*SMALL, "--steps", "3", "--unroll-schedule", "1:0.34,4:0.66", "--out", str(out)]) == 0
    mode = json.loads((out / "sitl_unroll1-4" / "run.json").read_text())["mode"]
    assert mode["unroll"] == 4 and mode["unroll_schedule"] == [[1, 1], [4, 2]]
    assert "unroll_schedule" not in json.loads((out / "sitl_unroll1" / "run.json").read_text())["mode"]
    md = (out / "compare.md").read_text()
    assert "solver-in-the-loop (unroll 1->4)" in md and "unroll curriculum 1:0.34,4:0.66" in md


def test_modes_go_on_only_in_an_out_of_their_own(tmp_path, capsys):
    out = tmp_path / "budget"  # another comparison's output: refused as before, not mixed into
    out.mkdir()
    (out / "compare.json").write_text(json.dumps({"config": {"arms": ["fifo"]}}))
    assert cli.main([*SMALL, "--steps", "2", "--out", str(out)]) == 2
    assert "already holds compare output (compare.json); pass --overwrite" in capsys.readouterr().err


def test_an_interrupted_arm_goes_on_from_its_checkpoint_to_the_uninterrupted_result(tmp_path, capsys, monkeypatch):
    """An arm killed part-way resumes from its last checkpoint (not from step 0) on the same command, and ends
    with the weights and figures of the run that was never interrupted (issue 29: compare checkpointed an arm only
    at its end, and a 1 h 40 min arm killed near its end started over)."""
    from interrupt import interrupted_at

    argv = [*SMALL, "--modes", "solver-in-the-loop", "--steps", "4", "--seeds", "1"]
    assert cli.main([*argv, "--out", str(tmp_path / "whole")]) == 0
    cut = tmp_path / "cut"
    capsys.readouterr()
    with interrupted_at(monkeypatch, 3):
        assert cli.main([*argv, "--out", str(cut)]) == 130
    first = sorted(p.name for p in cut.iterdir() if (p / "checkpoint.pt").is_file())
    assert len(first) == 1 and not (cut / first[0] / "metrics.json").exists()  # killed inside its first arm
    assert capsys.readouterr().err == (f"pdestream: interrupted; {cut} keeps 0 finished runs and 1 interrupted one at "
                                       f"a checkpoint ({first[0]}/); rerun the same command to go on from them\n")
    assert cli.main([*argv, "--out", str(cut)]) == 0
    assert f"interrupted in {cut / first[0]}, went on from its checkpoint at step 2 of 4" in capsys.readouterr().out
    whole = json.loads((tmp_path / "whole" / "compare.json").read_text())["arms"]
    again = json.loads((cut / "compare.json").read_text())["arms"]
    assert [a["rollout_mean"] for a in again] == [a["rollout_mean"] for a in whole]
    a = torch.load(tmp_path / "whole" / first[0] / "model.pt", weights_only=True)["model"]
    b = torch.load(cut / first[0] / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_modes_at_equal_wall_clock_train_each_arm_for_the_budget_and_say_so(tmp_path, capsys):
    """`compare --modes ... --budget S`: every trained arm trains S seconds (a 4-step unroll costs 4 solves per
    update, so it reaches fewer steps than the pairs arm), run.json records the seconds, compare.md says so."""
    out = tmp_path / "cmp"
    argv = [*SMALL, "--modes", "solver-in-the-loop", "--budget", "3", "--out", str(out)]
    assert cli.main(argv) == 0
    result = json.loads((out / "compare.json").read_text())
    trained = [a for a in result["arms"] if a["mode"] == "solver-in-the-loop"]
    assert len(trained) == 3 and all(a["steps"] >= 1 for a in trained)
    for arm in ("sitl_unroll1", "sitl_unroll4"):
        run = json.loads((out / arm / "run.json").read_text())
        metrics = json.loads((out / arm / "metrics.json").read_text())
        assert run["seconds"] == 3 and metrics["stop"] == "seconds" and metrics["wall"] >= 3
    assert "equal wall clock: 3 s of training" in (out / "compare.md").read_text()
    # a curriculum is in shares of the steps, which a budget does not fix: one line, before any work
    capsys.readouterr()
    assert cli.main([*argv[:-2], "--unroll-schedule", "1:0.5,4:0.5", "--out", str(tmp_path / "other")]) == 2
    err = capsys.readouterr().err.strip()
    assert "is in shares of --steps; with --budget 3 the steps an arm reaches are not known" in err and "\n" not in err
    assert not (tmp_path / "other").exists()


def test_the_corrector_summary_says_higher_when_solver_in_the_loop_is_worse():
    """compare.md said "0.18x lower than the coarse solver alone" for an error 5.5 times higher."""
    from pdestream.experiments.interactive_report import _arms_lines, score_against_coarse

    def arm(name, mode, err):
        return {"arm": name, "mode": mode, "n": 16, "seeds": [0], "rollout_mean": err, "rollout_p95": err,
                "end_mean": err, "end_p95": err, "end_max": err, "wall_s": 1.0, "steps": 2, "final_loss": 0.1}

    arms = [arm("coarse solver", "none", 0.1), arm("pairs (unroll 1)", "solver-in-the-loop", 0.4),
            arm("pairs + noise (unroll 1)", "solver-in-the-loop", 0.8), arm("sitl", "solver-in-the-loop", 0.55)]
    score_against_coarse(arms)
    line = next(x for x in _arms_lines(arms) if "solver-in-the-loop rollout mean error" in x)
    assert "5.50x higher than the coarse solver alone" in line and "1.38x higher than the correction trained on " \
        "pairs" in line and "1.45x lower than pairs + noise" in line and "lower than the coarse" not in line, line
