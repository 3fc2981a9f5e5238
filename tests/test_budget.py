"""Budget-matched comparison: stratified test sets, per-arm budgets, outputs, CLI refusals."""

import json

import h5py
import numpy as np
import pytest
import torch

from pdestream import cli, datasets, generator
from pdestream.datasets.proposal import ParamProposal
from pdestream.experiments.budget import BudgetConfig, budget_compare, stratified_test_set
from pdestream.surrogate.evaluate import error_stats

torch.set_num_threads(1)
TINY = generator.get_pde("burgers1d", n=32, n_frames=5)
TINY_MODEL = {"width": 8, "modes": 4, "layers": 2}


def test_stratified_test_set_puts_one_sample_in_every_stratum():
    pde = generator.get_pde("kdv1d", n=32, n_frames=3, t_end=0.1)  # two random parameters
    test = stratified_test_set(pde, 10, seed=0, chunk=4)
    params = torch.cat([b["params"] for b in test]).numpy()
    assert params.shape == (10, 2) and sum(len(b["index"]) for b in test) == 10
    z = ParamProposal(datasets.param_domains(pde)).to_unit(params)
    for d in range(2):
        assert sorted((z[:, d] * 10).astype(int).tolist()) == list(range(10))  # Latin hypercube
    # the trajectories are the generator's samples with those parameters (identity: seed, index, params)
    ref = generator.sample(pde, [4, 5], seed=1_000_003, params={"alpha": params[4:6, 0], "beta": params[4:6, 1]})
    assert np.array_equal(np.asarray(ref.u), test[1]["u"][:2].numpy())


def test_error_stats():
    assert error_stats(np.array([1.0, 2.0, 3.0, 4.0])) == {"mean": 2.5, "p95": pytest.approx(3.85),
                                                          "p99": pytest.approx(3.97), "cvar95": 4.0, "max": 4.0}


def test_sim_budget_gives_every_arm_the_same_solves(tmp_path):
    cfg = BudgetConfig(sim_budget=16, steps=12, batch_size=8, model_cfg=TINY_MODEL, n_test=8, capacity=16, seeds=1,
                       solve_batch=8, snapshots=3)
    result = budget_compare(TINY, tmp_path, cfg, log=lambda *_: None)
    arms = {r["arm"]: r for r in result["arms"]}
    assert set(arms) == {"precomputed", "fifo", "reservoir", "reservoir_loss"}
    assert arms["precomputed"]["trajectories_solved"] == 16 and arms["precomputed"]["steps"] == 12
    for name in ("reservoir", "reservoir_loss"):
        assert arms[name]["trajectories_solved"] == 16 and arms[name]["steps"] == 12
        assert max(arms[name]["reuse"]) <= arms[name]["stats"]["reuse_max"] + 1e-9
    # FIFO uses each solve once: 16 trajectories x 4 windows... operator view: 16 examples = 2 batches of 8
    assert arms["fifo"]["steps"] == 2
    for r in arms.values():
        assert {"test_mean", "test_p95", "test_p99", "test_cvar95", "test_max", "shifted_mean", "shifted_p99",
                "shifted_cvar95"} <= set(r)
        assert r["test_mean"] <= r["test_p95"] <= r["test_p99"] <= r["test_max"] and len(r["errors"]["test"]) == 8
        assert r["test_p95"] <= r["test_cvar95"] <= r["test_max"] and set(r["intervals"]) == {
            f"{s}_{m}" for s in ("test", "shifted") for m in ("mean", "p95", "p99", "cvar95", "max")}
        assert [p["step"] for p in r["curve"]] == sorted(p["step"] for p in r["curve"])
    for name in ("compare.md", "compare.csv", "compare.json", "compare.png"):
        assert (tmp_path / name).stat().st_size > 0
    table = (tmp_path / "compare.md").read_text()
    # two tables (the figures, their bootstrap intervals): header + separator + 4 arms each
    assert table.count("\n| ") == 12 and "16 solved trajectories and 12 optimizer steps per arm" in table
    assert "| arm | test mean | test p95 | test p99 | test cvar95 | test max | shifted mean |" in table
    assert "Bootstrap intervals (95%, percentile bootstrap over the test trajectories, 1000 resamples, seed 0" in table
    assert "**Too few test trajectories for a tail claim** (test, shifted)" in table
    assert "test: 8 trajectories, p99 rests on the worst 2, CVaR_0.95 on the worst 1, max on 1" in table
    assert "test p99: " in table and "(rests on the worst 2 of 8 test trajectories: no tail claim below 1024)" in table
    saved = json.loads((tmp_path / "compare.json").read_text())
    assert saved["param_names"] == ["nu"] and len(saved["test_params"]["test"]) == 8
    for arm in saved["arms"]:  # the per-trajectory errors every figure comes from, per seed
        assert len(arm["per_seed"][0]["errors"]["test"]) == 8 and len(arm["per_seed"][0]["errors"]["shifted"]) == 8
    header = (tmp_path / "compare.csv").read_text().splitlines()[0].split(",")
    assert {"test_p99", "test_cvar95", "shifted_p99", "test_p99_lo", "test_p99_hi"} <= set(header)


class FakeClock:
    """A clock for ``time.perf_counter`` that moves only by ``tick`` per reading and by what a test adds to ``now``:
    a budget run measured by it does the same whatever the machine's load."""

    def __init__(self, tick: float):
        self.now, self.tick = 1000.0, tick

    def perf_counter(self) -> float:
        self.now += self.tick
        return self.now


def fake_clock(monkeypatch, tick: float = 0.01) -> FakeClock:
    """The budget arms' clock (experiments.budget and the training loop, surrogate.train) replaced by a FakeClock."""
    from pdestream.experiments import budget
    from pdestream.surrogate import train

    clock = FakeClock(tick)
    monkeypatch.setattr(budget, "time", clock)
    monkeypatch.setattr(train, "time", clock)
    return clock


STEP_READS = 8  # clock readings per training step, with room (the loop reads it 6 times a step)


def test_time_budget_stops_every_arm_at_the_budget(tmp_path, monkeypatch):
    # by a fake clock: a timed version failed at load ~7 (an arm spent its 5 s compiling and trained 0 steps)
    budget, clock = 2.0, fake_clock(monkeypatch)
    cfg = BudgetConfig(budget_s=budget, arms=("precomputed", "reservoir"), batch_size=8, model_cfg=TINY_MODEL,
                       seeds=1, n_test=4, capacity=16, solve_batch=8, snapshots=2)
    result = budget_compare(TINY, tmp_path, cfg, log=lambda *_: None)
    for r in result["arms"]:  # the last step started before the deadline ends at most one step after it
        assert budget <= r["wall_s"] <= budget + STEP_READS * clock.tick and r["steps"] > 0, (r["wall_s"], r["steps"])
        assert len(r["curve"]) == 2 and r["curve"][-1]["elapsed"] >= budget
    # the precomputed arm sized its dataset by the rule and stored only the operator view's two frames
    plan = result["arms"][0]["precompute"]
    assert plan["frames_stored"] == 2 and plan["frames"] == 5 and plan["rule"] == "each trajectory trained on 16 times"
    assert plan["solve_per_s"] > 0 and plan["step_s"] > 0 and 0 < plan["solve_share"] <= plan["solve_cap"] == 0.5
    with h5py.File(tmp_path / "precomputed" / "cache.h5", "r") as f:
        assert f["u"].shape[1] == 2
    table = (tmp_path / "compare.md").read_text()
    assert "Precomputed arm (seed 0):" in table and "frames 0 and 4 only of 5" in table
    assert "one seed, no spread to judge by" in table


@pytest.mark.parametrize("seconds_per_trajectory, solved", [
    ((0.005, 0.005, 0.25), 32),  # fast while measured, then 50x slower: the first rate planned ~380 trajectories
    ((1.0,), 8),  # the first chunk alone takes 80% of the budget
])
def test_a_slow_solver_cannot_take_the_precomputed_arms_training_time(tmp_path, monkeypatch, seconds_per_trajectory,
                                                                       solved):
    """The budget is a deadline whatever the measured rates said: solving stops by half the budget (one chunk
    past it at worst), the arm trains, and its clock ends at most one step after the budget. It used to size the
    dataset once from the first rate, solve it all (95 s of a 10 s budget here) and train 0 steps."""
    from pdestream.experiments.budget import run_arm

    view = datasets.for_sample(datasets.make_view("operator"), TINY.n_frames, len(TINY.INPUTS))
    tests = {"test": stratified_test_set(TINY, 4, 0)}
    clock, sample, calls = fake_clock(monkeypatch), generator.sample, []

    def slow(pde, indices, *args, **kwargs):  # every solve costs its trajectories' seconds on the fake clock
        out = sample(pde, indices, *args, **kwargs)
        calls.append(len(indices))
        clock.now += seconds_per_trajectory[min(len(calls), len(seconds_per_trajectory)) - 1] * len(indices)
        return out

    monkeypatch.setattr(generator, "sample", slow)
    budget = 10.0
    cfg = BudgetConfig(budget_s=budget, arms=("precomputed",), batch_size=8, model_cfg=TINY_MODEL, seeds=1, n_test=4,
                       solve_batch=8, snapshots=2)
    rec = run_arm("precomputed", TINY, view, cfg, tmp_path, tests, log=lambda *_: None)
    plan, chunk = rec["precompute"], max(seconds_per_trajectory) * cfg.solve_batch
    assert rec["trajectories_solved"] == solved and len(calls) == solved // cfg.solve_batch
    # solving ends by half the budget, or with the one chunk that may not (the first, after ~20 clock readings)
    assert plan["solve_share"] * budget <= max(0.5 * budget, chunk + 30 * clock.tick)
    assert rec["steps"] >= 1 and budget <= rec["wall_s"] <= budget + STEP_READS * clock.tick, (rec["steps"], rec["wall_s"])
    with h5py.File(tmp_path / "cache.h5", "r") as f:  # the cache holds what was solved, every sample complete
        assert f["u"].shape[0] == solved and (f["complete"][:] == 1).all()


def test_the_precomputed_arm_stores_the_operator_views_frames_bit_for_bit():
    from pdestream.experiments.budget import stored_pde

    pde = generator.get_pde("kdv1d", n=32, n_frames=9, t_end=0.2)
    stored = stored_pde(pde, datasets.make_view("operator"))
    assert stored.n_frames == 2 and stored.step_dt == pde.step_dt
    whole = np.asarray(generator.sample(pde, [0, 1, 2], seed=3).u)
    ends = np.asarray(generator.sample(stored, [0, 1, 2], seed=3).u)
    assert np.array_equal(ends, whole[:, [0, -1]])
    assert stored_pde(pde, datasets.make_view("next_step")) is pde  # next-step windows use every frame


def test_the_precomputed_dataset_size_rule():
    from pdestream.experiments.budget import precompute_size

    cfg = BudgetConfig(budget_s=20.0, batch_size=32, max_reuse=16)
    # N / 100 s solving + N * 16 / 32 steps of 10 ms = 10 s left: N = 10 / (0.01 + 0.005)
    assert precompute_size(cfg, rate=100.0, step_s=0.01, left_s=10.0, per=1) == 666
    assert precompute_size(cfg, rate=100.0, step_s=10.0, left_s=10.0, per=1) == 32  # at least one batch
    fixed = BudgetConfig(budget_s=20.0, precompute_share=0.5)
    assert precompute_size(fixed, rate=100.0, step_s=0.01, left_s=19.0, per=1) == 900  # (10 s - 1 s spent) x 100/s


def test_verdicts_weigh_the_margin_against_the_seed_spread():
    from pdestream.experiments.budget import verdicts

    arms = [{"arm": "precomputed", "test_mean": 0.10, "test_mean_std": 0.01, "test_max": 0.5, "test_max_std": 0.2},
            {"arm": "reservoir", "test_mean": 0.05, "test_mean_std": 0.01, "test_max": 0.4, "test_max_std": 0.2}]
    mean, worst = verdicts(arms, 3)
    assert mean.startswith("test mean: reservoir 0.0500 vs precomputed 0.1000 (x2.00") and "reservoir wins" in mean
    assert "outside the seed spread 0.0200" in mean
    assert worst.startswith("test max: reservoir") and "within the seed spread 0.4000, no clear winner" in worst
    assert all("one seed" in line for line in verdicts(arms, 1))


@pytest.mark.parametrize("args, message", [
    (["--budget", "0"], "--budget=0.0 not allowed; must be a number of seconds > 0"),
    (["--budget", "-5"], "--budget=-5.0 not allowed"),
    (["--sim-budget", "0"], "--sim-budget=0 not allowed; must be an integer >= 1 (trajectories)"),
    (["--budget", "5", "--sim-budget", "4"], "give exactly one budget"),
    (["--budget", "5", "--arms", "cache"], "arms ['cache'] not allowed; choose from precomputed, fifo"),
    (["--budget", "5", "--precompute-share", "1"], "precompute share=1.0 not allowed; must be in (0, 1)"),
    (["--budget", "5", "--capacity", "4"], "capacity=4 not allowed: must be >= batch_size (32)"),
    (["--sim-budget", "16", "--arms", "reservoir", "--priority-power", "2"],
     "--priority-power goes with the arms reservoir_active or reservoir_priority (prioritized replay)"),
    (["--budget", "5", "--arms", "reservoir_priority", "--priority-cap", "2"],
     "--priority-cap=2 goes with --sim-budget and the arms reservoir_active or reservoir_priority"),
    (["--modes", "one-step", "--priority-power", "2"], "--priority-power goes with compare --budget / --sim-budget"),
    (["--sim-budget", "16", "--arms", "reservoir_priority", "--priority-cap", "0.5"],
     "--priority-cap=0.5 not allowed; must be a number >= 1"),
    (["--sim-budget", "16", "--arms", "reservoir_priority", "--priority-floor", "0"],
     "priority_floor=0.0 not allowed; must be in (0, 1] (the uniform share of draws)"),
    (["--sim-budget", "16", "--arms", "fifo,reservoir", "--proposal-gate", "off"],
     "--proposal-gate goes with the arms reservoir_loss / reservoir_active / reservoir_generative; nothing here uses "
     "it: drop it"),
    (["--sim-budget", "16", "--arms", "reservoir,reservoir_active", "--proposal-ensemble", "1"],
     "proposal ensemble=1 not allowed; must be an integer >= 2 (the uncertainty signal is the disagreement of its members)"),
])
def test_budget_refusals_are_one_line_and_create_nothing(capsys, tmp_path, args, message):
    out = tmp_path / "cmp"
    assert cli.main(["compare", "burgers1d", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


def test_cli_quick_budget_compare_runs(capsys, tmp_path):
    out = tmp_path / "cmp"
    assert cli.main(["compare", "--quick", "--sim-budget", "16", "--steps", "6", "--batch-size", "8",
                     "--capacity", "16", "--test-samples", "4", "--arms",
                     "fifo,reservoir_loss,reservoir_active,reservoir_priority",
                     "--model-set", "width=8", "--model-set", "modes=4", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| fifo |" in printed and "| reservoir_loss |" in printed and "compare.png" in printed
    assert "| reservoir_active |" in printed and "| reservoir_priority |" in printed
    # the priority arms may draw a trajectory up to --priority-cap (4) times the mean reuse, the others about once it
    arm = {name: json.loads((out / name / "arm.json").read_text()) for name in ("reservoir_loss", "reservoir_priority")}
    mean = 6 * 8 / 16
    assert max(arm["reservoir_loss"]["reuse"]) <= 1.05 * mean + 1
    assert max(arm["reservoir_priority"]["reuse"]) <= 4 * 1.05 * mean + 1


def test_combine_seeds_reports_mean_and_spread():
    from pdestream.experiments.budget import combine_seeds

    runs = [{"arm": "a", "test_mean": 1.0, "test_p95": 2.0, "test_max": 3.0, "steps": 5, "curve": [1]},
            {"arm": "a", "test_mean": 3.0, "test_p95": 4.0, "test_max": 9.0, "steps": 6, "curve": [2]}]
    out = combine_seeds(runs)
    assert out["test_mean"] == 2.0 and out["test_max"] == 6.0 and out["test_mean_std"] == pytest.approx(2 ** 0.5)
    assert out["curve"] == [1] and [r["steps"] for r in out["per_seed"]] == [5, 6]


def test_budget_arms_train_with_the_mode_asked(tmp_path):
    """The arms run the one training loop with the training mode (they used to ignore it: one-step always)."""
    cfg = BudgetConfig(sim_budget=8, steps=4, arms=("precomputed", "reservoir"), batch_size=4, model_cfg=TINY_MODEL, seeds=1,
                       n_test=4, capacity=8, solve_batch=4, snapshots=2, view="next_step",
                       mode={"name": "pushforward", "unroll": 2})
    result = budget_compare(TINY, tmp_path, cfg, log=lambda *_: None)
    for r in result["arms"]:
        summary = json.loads((tmp_path / r["arm"] / "metrics.json").read_text())
        assert summary["mode"] == {"name": "pushforward", "unroll": 2} and summary["steps"] == 4 == r["steps"]
        assert summary["view_args"]["k_out"] == 2 if "view_args" in summary else True


def test_budget_refuses_a_mode_its_view_cannot_train(tmp_path):
    cfg = BudgetConfig(sim_budget=8, steps=4, model_cfg=TINY_MODEL, mode={"name": "pushforward", "unroll": 2})
    with pytest.raises(ValueError, match="--mode pushforward needs the next_step view"):
        budget_compare(TINY, tmp_path / "out", cfg, log=lambda *_: None)
    assert not (tmp_path / "out").exists()
