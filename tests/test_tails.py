"""Tail metrics (p99, CVaR_0.95), their bootstrap intervals and the too-small-test-set line: pure numpy."""

import numpy as np
import pytest

from pdestream.experiments.budget_report import combine_seeds, interval_table, verdicts
from pdestream.surrogate.tails import bootstrap_intervals, cvar, rests_on, tail_metrics, tail_note


def test_tail_metrics_match_a_hand_computation():
    e = np.arange(1.0, 201.0)  # 1, 2, ..., 200 (shuffled: order must not matter)
    np.random.default_rng(0).shuffle(e)
    m = tail_metrics(e)
    assert m["mean"] == 100.5 and m["max"] == 200.0
    # p99: position 0.99 * 199 = 197.01 of the sorted values 1..200 -> 198 + 0.01 * (199 - 198)
    assert m["p99"] == pytest.approx(198.01)
    assert m["p95"] == pytest.approx(1 + 0.95 * 199)
    # CVaR_0.95 of 200: the mean of the worst ceil(0.05 * 200) = 10, i.e. of 191..200
    assert m["cvar95"] == pytest.approx(195.5)
    assert cvar(np.array([5.0, 1.0, 3.0])) == 5.0  # N <= 20: the worst one
    assert cvar(np.arange(21.0)) == pytest.approx(19.5)  # ceil(1.05) = 2 worst: 19, 20
    assert cvar(np.arange(100.0), level=0.9) == pytest.approx(94.5)  # worst 10
    assert m["p95"] <= m["p99"] <= m["max"] and m["p95"] <= m["cvar95"] <= m["max"]


def test_bootstrap_interval_covers_the_estimate_shrinks_with_n_and_is_reproducible():
    rng = np.random.default_rng(1)
    widths = {}
    for n in (128, 2048):
        e = rng.lognormal(-2.0, 0.7, n)
        ci = bootstrap_intervals(e, resamples=1000, seed=0)
        point = tail_metrics(e)
        for metric, (lo, hi) in ci.items():
            assert lo <= point[metric] <= hi, (n, metric, lo, point[metric], hi)
        widths[n] = {k: hi - lo for k, (lo, hi) in ci.items()}
        assert ci == bootstrap_intervals(e, resamples=1000, seed=0)  # a fixed seed: the same report
    for metric in ("mean", "p95", "p99", "cvar95"):
        assert widths[2048][metric] < 0.5 * widths[128][metric], metric  # ~1/sqrt(16) = 0.25 of the width
    # several seeds on the same trajectories: paired resampling of the seed-mean figure
    e2 = np.stack([rng.lognormal(-2, 0.7, 256), rng.lognormal(-2, 0.7, 256)])
    lo, hi = bootstrap_intervals(e2)["mean"]
    assert lo <= e2.mean() <= hi


def test_what_the_tail_rests_on_and_the_too_small_warning():
    assert rests_on(128) == {"p95": 8, "p99": 3, "cvar95": 7, "max": 1}  # p99 of 128: between the 3rd and 2nd worst
    assert rests_on(1024)["p99"] == 12 and rests_on(1024)["cvar95"] == 52
    small = tail_note({"test": 128, "shifted": 128})
    assert small.startswith("**Too few test trajectories for a tail claim** (test, shifted)")
    assert ">= 1024 test trajectories" in small and "test: 128 trajectories, p99 rests on the worst 3" in small
    assert "CVaR_0.95 on the worst 7, max on 1" in small
    big = tail_note({"test": 1024})
    assert big.startswith("Tail metrics: test: 1024 trajectories, p99 rests on the worst 12") and "Too few" not in big


def _arm(name, seed_errors):
    runs = []
    for e in seed_errors:
        m = tail_metrics(np.asarray(e))
        runs.append({"arm": name, "steps": 10, "errors": {"test": list(e)}, **{f"test_{k}": v for k, v in m.items()}})
    return combine_seeds(runs)


def test_combined_records_keep_the_errors_and_carry_intervals_and_tail_verdicts():
    rng = np.random.default_rng(2)
    a = _arm("a", [rng.uniform(0, 1, 128) for _ in range(3)])
    b = _arm("b", [rng.uniform(0, 2, 128) for _ in range(3)])
    assert len(a["per_seed"]) == 3 and all(len(p["errors"]["test"]) == 128 for p in a["per_seed"])
    assert set(a["intervals"]) == {"test_mean", "test_p95", "test_p99", "test_cvar95", "test_max"}
    for c, (lo, hi) in a["intervals"].items():
        assert lo <= a[c] <= hi or c == "test_max"  # a bootstrap max never exceeds the observed max
    table = interval_table([a, b])
    assert "| arm | test mean | test p95 | test p99 | test cvar95 | test max |" in table
    assert table[-1].startswith("| b | ") and " [" in table[-1]
    lines = verdicts([a, b], 3)
    assert [line.split(":")[0] for line in lines] == ["test mean", "test p95", "test p99", "test cvar95", "test max"]
    assert "rests on the worst 3 of 128 test trajectories: no tail claim below 1024" in lines[2]
    assert "rests on the worst 7 of 128" in lines[3] and "rests on the worst 1 of 128" in lines[4]
    assert "rests on" not in lines[0] + lines[1]


def test_compare_md_states_the_skill_gate_of_the_steered_arms():
    from pdestream.experiments.budget_report import gate_line

    arms = [{"arm": "reservoir", "stats": {}}, {"arm": "reservoir_active",
                                                "stats": {"proposal_skill": 0.123, "proposal_steer": 0.185}}]
    line = gate_line(arms)
    assert line.startswith("Proposal skill gate (seed 0, at the end; steered share = (1 - floor) x clip(max(skill / "
                           "0.5, lift / log 2), 0, 1), 0 when the lift's upper bound is below 0")
    assert line.endswith("reservoir_active skill 0.12, steered share 0.18.") and "reservoir skill" not in line
    arms[1]["stats"]["proposal_lift"] = 0.234  # measured: said beside the skill
    assert gate_line(arms).endswith("reservoir_active skill 0.12, lift 0.23, steered share 0.18.")
    assert "--proposal-gate off" in gate_line(arms, gate=False) and gate_line(arms[:1]) == ""
