"""benchmarks/active_suite.py's bookkeeping, not its results: units run once, finished ones are skipped, a unit
stopped under way leaves nothing, a unit whose estimate passes --max-minutes is not started, bad input is one line."""

import json

import pytest

from benchmarks import active_suite as suite

TINY = {"settings": {"n": "32"}, "sim_budget": 8, "steps": 4, "batch_size": 4, "n_test": 8,
        "model_cfg": {"width": 4, "modes": 4, "layers": 1}}


def _run(out, seeds, minutes=60.0):
    suite.main(["--out", str(out), "--problems", "burgers1d", "--seeds", str(seeds), "--max-minutes", str(minutes)],
               tiny=TINY)


def test_resume_skips_finished_units_and_discards_stale(tmp_path, capsys):
    _run(tmp_path, 1)
    first = {a: (tmp_path / "burgers1d" / f"{a}_seed0" / "arm.json").read_text() for a in suite.ARMS}
    stale = tmp_path / "burgers1d" / ".tmp-reservoir_seed1"  # what a killed unit leaves
    stale.mkdir()
    (stale / "arm.json").write_text("{}")
    capsys.readouterr()
    _run(tmp_path, 2)
    log = capsys.readouterr().out
    assert "2 of 4 units to run" in log and "seed 0" not in log.split("units to run")[1].split("#")[0]
    for a in suite.ARMS:  # seed 0 untouched, seed 1 recorded
        assert (tmp_path / "burgers1d" / f"{a}_seed0" / "arm.json").read_text() == first[a]
        assert json.loads((tmp_path / "burgers1d" / f"{a}_seed1" / "arm.json").read_text())["seed"] == 1
    assert not stale.exists()
    text = (tmp_path / "summary.md").read_text()
    assert "Units missing (0)" in text and "| 0,1 |" in text and "uniform / active" in text

    # a finished problem whose units took "a day" each: the next seed's unit is not started
    for f in (tmp_path / "burgers1d").glob("*/unit.json"):
        f.write_text(json.dumps({"unit_s": 86400.0}))
    capsys.readouterr()
    _run(tmp_path, 3, minutes=30)
    log = capsys.readouterr().out
    assert "stop: burgers1d reservoir seed 2 would take ~1440.0 min" in log
    assert not (tmp_path / "burgers1d" / "reservoir_seed2").exists()
    assert "Units missing (2)" in (tmp_path / "summary.md").read_text()
    suite.main(["--out", str(tmp_path), "--problems", "burgers1d", "--seeds", "3", "--summary-only"])
    log = capsys.readouterr().out
    assert "units to run" not in log and "Units missing (2)" in log and "**not trained**" in log  # tiny: mean ~1


def test_unit_stopped_under_way_leaves_nothing(tmp_path, monkeypatch, capsys):
    import pdestream.experiments.budget as budget

    def stopped(arm, pde, view, cfg, out, tests, log=print, seed=0):
        out.mkdir(parents=True, exist_ok=True)
        (out / "arm.json").write_text("{}")  # half-written, then the deadline
        raise suite.Deadline()

    monkeypatch.setattr(budget, "run_arm", stopped)
    _run(tmp_path, 1)
    assert "burgers1d reservoir seed 0 discarded" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "burgers1d").iterdir()) == ["test.pt", "test_params.json"]


def test_bad_problem_is_one_line(tmp_path):
    with pytest.raises(SystemExit, match="--problems 'nope': unknown nope"):
        suite.main(["--out", str(tmp_path), "--problems", "nope"])


def test_the_horizon_rule_keeps_a_diffusive_entry_and_cuts_a_chaotic_one():
    """benchmarks.predictability: a perturbation of diffusion1d's initial state decays (amplification < 1 at every
    time, so its t_end stays); the rule cuts a growth curve at the last time within one decade."""
    from benchmarks import predictability as pr

    g = pr.growth("diffusion1d", n=2, settings={"n": "32"})
    assert len(g["t"]) == pr.HALVINGS + 1 and g["t"][-1] == pytest.approx(g["t_end"])
    assert max(g["amplification"]) < 1.0 and pr.horizon(g) == pytest.approx(g["t_end"])
    chaotic = {"t": [1.0, 2.0, 4.0], "amplification": [2.0, 9.0, 300.0]}
    assert pr.horizon(chaotic) == 2.0
    assert pr.horizon({"t": [1.0, 2.0], "amplification": [50.0, 900.0]}) == 1.0  # none within: the shortest


@pytest.mark.slow
def test_wall_clock_suite_runs_its_arms_on_both_test_sets_and_keeps_no_data(tmp_path, capsys):
    """benchmarks.wallclock_suite: the precomputed arm, the stream and (on an untuned entry) the active arm at one
    time budget; every unit is evaluated on the in-domain and the shifted set; the precomputed arm's cache is not
    kept in the record; the summary gives both pairs' ratios and the stream's steps against the precomputed arm's."""
    from benchmarks import wallclock_suite as wall

    tiny = {"settings": {"n": "32"}, "budget": 3.0, "batch_size": 4, "n_test": 8,
            "model_cfg": {"width": 4, "modes": 4, "layers": 1}}
    wall.main(["--out", str(tmp_path), "--problems", "fisher_kpp1d", "--seeds", "1"], tiny=tiny)
    assert "3 of 3 units to run" in capsys.readouterr().out
    for arm in ("precomputed", "reservoir", "reservoir_active"):
        unit = tmp_path / "fisher_kpp1d" / f"{arm}_seed0"
        rec = json.loads((unit / "arm.json").read_text())
        assert len(rec["errors"]["test"]) == len(rec["errors"]["shifted"]) == 8
        assert not any(f.suffix in (".h5", ".pt") for f in unit.iterdir())
    precomputed = json.loads((tmp_path / "fisher_kpp1d" / "precomputed_seed0" / "arm.json").read_text())
    assert precomputed["precompute"]["solve_share"] > 0 and precomputed["trajectories_solved"] >= 4
    text = (tmp_path / "summary.md").read_text()
    assert "**precomputed / stream**" in text and "**stream / active**" in text and "shifted p99" in text
    assert "stream x" in text and "the steps" in text and "Units missing (0)" in text


@pytest.mark.slow
def test_generative_suite_steers_the_joint_space_and_reports_its_gate(tmp_path, capsys):
    """benchmarks.generative_suite: the uniform arm and the generative arm over (parameters, IC latent); the steered
    unit records its gate (skill, steered share, the lift) and the summary gives it per seed."""
    from benchmarks import generative_suite as gen

    tiny = {"settings": {"n": "32"}, "sim_budget": 16, "steps": 8, "batch_size": 4, "n_test": 8,
            "model_cfg": {"width": 4, "modes": 4, "layers": 1}}
    gen.main(["--out", str(tmp_path), "--problems", "burgers1d", "--seeds", "1"], tiny=tiny)
    assert "2 of 2 units to run" in capsys.readouterr().out
    rec = json.loads((tmp_path / "burgers1d" / "reservoir_generative_seed0" / "arm.json").read_text())
    assert {"proposal_skill", "proposal_steer", "proposal_lift", "proposal_lift_high"} <= set(rec["stats"])
    text = (tmp_path / "summary.md").read_text()
    assert "**uniform / generative**" in text and "the generative arm's gate at the end, per seed" in text
    low = rec["stats"]["proposal_lift"]
    assert ("the lift [" in text) == (low == low)  # measured (not NaN): both bounds said
