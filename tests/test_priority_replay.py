"""Prioritized replay in the training reservoir (draw="priority"): draws follow the reported losses, the reuse
bound holds, deterministic batches repeat and resume exactly, damaged states are refused."""

import collections

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from pdestream import generator
from pdestream.datasets.reservoir import Reservoir, ReservoirStream

PDE = generator.get_pde("burgers1d", n=32, n_frames=4)


def store(power=1.0, floor=0.25, cap=10**6, n=10):
    res = Reservoir(capacity=n, cap_uses=cap, n_windows=1, eviction="fifo", draw="priority",
                    rng=np.random.default_rng(0), priority_power=power, priority_floor=floor)
    res.insert(torch.zeros(n, 2, 1, 4), torch.zeros(n, 1), np.arange(n))
    return res


def shares(res, draws=4000):
    counts = collections.Counter()
    for _ in range(draws):
        slots, _starts = res.draw(1)
        counts[int(slots[0])] += 1
    return np.array([counts[s] for s in range(res.capacity)]) / draws


def test_draws_follow_the_reported_losses_over_the_floor():
    res = store()
    res.set_priority(np.arange(10), np.r_[100.0, np.ones(9)])
    got = shares(res)
    # 0.75 x 100 / 109 + 0.25 / 10 = 0.713 for the hard one; 0.75 / 109 + 0.025 = 0.032 for each other
    assert abs(got[0] - 0.713) < 0.03 and np.abs(got[1:] - 0.032).max() < 0.015
    flat = store(power=0.0)  # power 0: uniform whatever the losses
    flat.set_priority(np.arange(10), np.r_[100.0, np.ones(9)])
    assert np.abs(shares(flat) - 0.1).max() < 0.025


def test_new_trajectories_start_at_the_highest_priority_and_nan_leaves_it():
    res = store(n=12)  # 10 held below, two empty slots
    res.index[:] = -1
    res.serial[:] = -1
    res.insert(torch.zeros(10, 2, 1, 4), torch.zeros(10, 1), np.arange(10))
    res.set_priority(np.arange(10), np.linspace(1, 5, 10))
    res.set_priority(np.array([3]), np.array([np.nan]))
    assert res.priority[3] == pytest.approx(1 + 3 * 4 / 9)
    res.insert(torch.zeros(2, 2, 1, 4), torch.zeros(2, 1), np.array([10, 11]))
    assert res.priority[10] == res.priority[11] == 5.0


def test_the_reuse_bound_holds_under_priorities():
    res = store(cap=5, floor=0.01)
    res.set_priority(np.arange(10), np.r_[1e6, np.ones(9)])
    uses = collections.Counter()
    while True:
        slots, _ = res.draw(3)
        if not len(slots):
            break
        uses.update(slots.tolist())
    assert max(uses.values()) == 5 and sum(uses.values()) == 50


def stream(**kw):
    args = dict(seed=3, view="operator", batch_size=4, capacity=16, max_reuse=8, solve_batch=4, mode="deterministic",
                draw="priority", target_reuse=2, sim_budget=24)
    args.update(kw)
    return ReservoirStream(PDE, **args)


def run(s, n=None, state_at=None):
    """Batches of ``s`` (the first n), each reported with a loss that grows as nu falls (1 / nu^3); the state after
    ``state_at`` batches too."""
    out, state = [], None
    for batch in DataLoader(s, batch_size=None):
        s.report_losses(batch, (1.0 / batch["params"][:, 0]).double() ** 3)
        out.append(batch)
        if len(out) == state_at:
            state = s.state_dict()
        if len(out) == n:
            break
    s.close()
    return out, state


def same(a, b):
    return len(a) == len(b) and all(torch.equal(x[k], y[k]) for x, y in zip(a, b) for k in x)


def test_priority_batches_repeat_resume_exactly_and_favour_the_hard_samples():
    full, state = run(stream(), n=24, state_at=9)  # 96 draws of 24 samples: 4 each on average, the bound 8
    again, _ = run(stream(), n=24)
    assert same(full, again)
    resumed = stream()
    resumed.load_state_dict(state)
    rest, _ = run(resumed, n=15)
    assert same(full[:9] + rest, full)
    # every sample solved once, each within the bound; the low-viscosity (high-loss) half drawn more
    uses = collections.Counter(i for b in full for i in b["index"].tolist())
    nu = {i: float(p[0]) for b in full for i, p in zip(b["index"].tolist(), b["params"])}
    assert sorted(uses) == list(range(24)) and max(uses.values()) <= 8
    order = sorted(uses, key=nu.get)

    def hard_over_easy(counts):
        return np.mean([counts[i] for i in order[:12]]) / np.mean([counts[i] for i in order[12:]])

    plain, _ = run(stream(draw="uniform"), n=24)
    plain_uses = collections.Counter(i for b in plain for i in b["index"].tolist())
    # (seeds 0-3: 2.2, 1.6, 2.2, 2.4 against uniform draws' 1.04, 0.78, 0.78, 1.29)
    assert hard_over_easy(uses) > 1.5 and hard_over_easy(plain_uses) < 1.35


@pytest.mark.parametrize("bad", [-1.0, 1e300, float("nan")])
def test_a_damaged_priority_state_is_refused_in_one_line(bad):
    _, state = run(stream(), n=4, state_at=4)
    state["reservoir"]["sampler"]["priority"][0] = bad
    with pytest.raises(ValueError, match=r"^reservoir state: priority must be .* numbers in \[1e-30, 1e30\]") as err:
        stream().load_state_dict(state)
    assert "\n" not in str(err.value)
