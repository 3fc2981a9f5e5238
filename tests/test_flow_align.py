"""benchmarks/flow_align.py (issue 28): the alignment-averaged grid study's order, limit and verdict rule."""

import json

import pytest

from benchmarks import flow_align


def test_three_grid_order_and_limit_of_a_second_order_sequence():
    p, lim = flow_align.three_grid(1.0 + 4e-2, 1.0 + 1e-2, 1.0 + 2.5e-3)
    assert p == pytest.approx(2.0) and lim == pytest.approx(1.0)
    assert flow_align.three_grid(1.0, 2.0, 1.5) == (None, None)  # the differences change sign


def test_verdict_reads_no_order_when_a_difference_is_inside_the_scatter():
    assert flow_align.verdict([(1.04, 0.001), (1.01, 0.001), (1.0025, 0.001)], 2.0).startswith("met")
    assert flow_align.verdict([(1.04, 0.001), (1.01, 0.02), (1.0025, 0.001)], 2.0).startswith("no order")
    assert flow_align.verdict([(1.04, 0.001), (1.01, 0.001), (1.0, 0.001)], 1.58).startswith("met")
    assert flow_align.verdict([(1.04, 0.001), (1.02, 0.001), (1.01, 0.001)], 1.0).startswith("missed")


def test_tables_average_over_the_shifts(tmp_path):
    rows = [{"ny": ny, "nx": 86 * ny // 16, "shift_x": s, "cd": 5.5 + s / ny, "cl": 0.01, "dp": 0.117,
             "cd_cv": 5.58, "cl_cv": 0.0107} for ny in (16, 32, 64) for s in (0.0, 0.5)]
    for s in (0.0, 0.5):
        (tmp_path / f"shift_{s:g}.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows if r["shift_x"] == s))
    st = flow_align.stats(flow_align.load(tmp_path)[0])
    assert st[32]["cd"][0] == pytest.approx(5.5 + 0.25 / 32) and st[32]["cd"][1] == pytest.approx(0.25 / 32)
    assert "| 16/32/64 | Cd |" in flow_align.tables(*flow_align.load(tmp_path))
    with pytest.raises(SystemExit, match="no folder"):
        flow_align.main([str(tmp_path / "nope")])
