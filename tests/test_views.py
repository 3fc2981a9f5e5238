"""The views' shared one-example behaviour (Whole, Operator, SteadyOperator): one example per trajectory, starting
at frame 0, read whole; the two operator views are evaluated as trained and make no rollout."""

import torch

from pdestream import datasets
from pdestream.datasets.views import SteadyOperator, Whole


def test_one_example_views_cut_whole_trajectories():
    u, t = torch.arange(5 * 3 * 4, dtype=torch.float32).reshape(5, 3, 4), torch.arange(5.0)
    for view in (Whole(), datasets.Operator(), datasets.Operator(1, 3), SteadyOperator(2)):
        assert view.per_trajectory(5) == 1
        assert view.starts(5) == [0]
        assert view.cut(5, 0) == (0, 5, view)
    for view in (datasets.Operator(1, 3), SteadyOperator(2)):
        assert view.rollout_k_in is None and view.evaluation() is view
    assert Whole().rollout_k_in is None
    ex = datasets.Operator(1, 3).example(u, t, 0)
    assert torch.equal(ex["x"], u[1]) and torch.equal(ex["y"], u[3])
    ex = SteadyOperator(2).example(u[0], t, 0)  # a steady sample [C_in + C, *space]
    assert torch.equal(ex["x"], u[0, :2]) and torch.equal(ex["y"], u[0, 2:])
    assert SteadyOperator(2).channels(1) == (2, 1) and datasets.Operator().channels(3) == (3, 3)
    assert SteadyOperator(2) == SteadyOperator(2) and hash(SteadyOperator(2)) == hash(SteadyOperator(2))
