"""The training reservoir in parts: states saved in the old flat layout still resume bit for bit, the saved state
is the parts' states composed, ReservoirConfig holds the settings (keywords still work), and a storage is
swapped by a new class implementing ``Storage``."""

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from pdestream import generator
from pdestream.datasets.reservoir import ReservoirConfig, ReservoirStream
from pdestream.datasets.reservoir_storage import Storage
from pdestream.datasets.views import gather

PDE = generator.get_pde("burgers1d", n=32, n_frames=4)
FLAT = json.loads((Path(__file__).parent / "data" / "reservoir_flat_states.json").read_text())


def digest(batches) -> str:
    h = hashlib.sha256()
    for b in batches:
        for k in sorted(b):
            h.update(k.encode())
            h.update(b[k].contiguous().numpy().tobytes())
    return h.hexdigest()


def run(stream, n, report=False):
    out = []
    for batch in DataLoader(stream, batch_size=None):
        if report:  # the loss the saved run reported: it grows as nu falls
            stream.report_losses(batch, (1.0 / batch["params"][:, 0]).double() ** 3)
        out.append(batch)
        if len(out) == n:
            break
    stream.close()
    return out


@pytest.mark.parametrize("case", sorted(FLAT))
def test_a_state_saved_in_the_flat_layout_resumes_bit_for_bit(case):
    """tests/data/reservoir_flat_states.json: states saved by the reservoir before it was split (commit e6c9933),
    with the digest of the batches that followed them there."""
    saved = FLAT[case]
    s = ReservoirStream(PDE, **saved["settings"])
    s.load_state_dict(saved["state"])
    composed = s.state_dict()
    rest = run(s, len(saved["rest_index"]), saved["report_losses"])
    assert [b["index"].tolist() for b in rest] == saved["rest_index"] and digest(rest) == saved["rest_sha256"]
    again = ReservoirStream(PDE, **saved["settings"])  # the composed layout it now saves resumes the same way
    again.load_state_dict(composed)
    assert digest(run(again, len(saved["rest_index"]), saved["report_losses"])) == saved["rest_sha256"]


def test_the_state_is_the_parts_states_composed():
    s = ReservoirStream(PDE, **FLAT["priority"]["settings"])
    run(s, 3, report=True)
    state = s.state_dict()
    assert state["layout"] == 2 and {"reservoir", "producer", "schedule", "proposal"} <= set(state)
    assert set(state["reservoir"]) == {"slots", "storage", "writer", "sampler", "rng"}
    assert state["reservoir"]["sampler"]["draw"] == "priority" and state["reservoir"]["writer"]["eviction"] == "fifo"
    assert len(state["reservoir"]["sampler"]["priority"]) == len(state["reservoir"]["slots"])
    assert state["producer"]["next_index"] == sum(len(j["indices"]) for j in state["producer"]["jobs"]) + \
        state["reservoir"]["writer"]["inserted"]


def test_a_damaged_flat_state_is_refused_in_one_line():
    state = json.loads(json.dumps(FLAT["uniform_random"]["state"]))
    state["serial"][0] = -1
    with pytest.raises(ValueError, match=r"^reservoir state: writer.serial holds -1") as err:
        ReservoirStream(PDE, **FLAT["uniform_random"]["settings"]).load_state_dict(state)
    assert "\n" not in str(err.value)
    state = json.loads(json.dumps(FLAT["uniform_random"]["state"]))
    del state["counters"]
    with pytest.raises(ValueError, match=r"^reservoir state is incomplete or malformed \(KeyError: 'counters'\)$"):
        ReservoirStream(PDE, **FLAT["uniform_random"]["settings"]).load_state_dict(state)


def test_a_config_and_keywords_give_the_same_stream():
    cfg = ReservoirConfig(capacity=8, max_reuse=2, solve_batch=4, mode="deterministic", draw="least_used")
    by_config = run(ReservoirStream(PDE, seed=3, view="operator", batch_size=4, config=cfg), 6)
    by_keywords = run(ReservoirStream(PDE, seed=3, view="operator", batch_size=4, capacity=8, max_reuse=2,
                                      solve_batch=4, mode="deterministic", draw="least_used"), 6)
    overridden = run(ReservoirStream(PDE, seed=3, view="operator", batch_size=4, config=replace(cfg, draw="uniform"),
                                     draw="least_used"), 6)  # a keyword overrides the config's setting
    assert digest(by_config) == digest(by_keywords) == digest(overridden)
    s = ReservoirStream(PDE, seed=3, view="operator", batch_size=4, config=cfg)
    assert s.reservoir_config.max_reuse == 2.0 and s.warmup == 4 and s.capacity == 8


def test_the_defaults_are_the_cli_and_experiments_ones():
    from pdestream.experiments.budget import BudgetConfig

    d = ReservoirConfig()
    assert (d.capacity, d.max_reuse, d.solve_batch, d.mode, d.draw, d.eviction) == (512, 16.0, 16, "async", "uniform", "fifo")
    b = BudgetConfig(budget_s=1.0)
    assert (b.capacity, b.max_reuse, b.solve_batch, b.reservoir_mode, b.priority_power, b.priority_floor) == \
        (d.capacity, d.max_reuse, d.solve_batch, d.mode, d.priority_power, d.priority_floor)


class NumpyStorage(Storage):
    """Another storage, as a user would add one: numpy arrays on the host (a stand-in for a memory-mapped spill)."""

    def __init__(self, capacity, device):
        self.capacity, self.device = capacity, torch.device("cpu")
        self.index = np.full(capacity, -1, np.int64)
        self.u = self.params_host = None
        self.puts = 0

    def put(self, slots, u, params, index):
        if self.u is None:
            self.u = np.zeros((self.capacity, *u.shape[1:]), np.float32)
            self.params_host = np.zeros((self.capacity, params.shape[1]), np.float32)
        self.u[slots], self.params_host[slots], self.index[slots] = u.cpu().numpy(), params.cpu().numpy(), index
        self.puts += 1

    def gather(self, view, t, slots, starts):
        return gather(view, torch.from_numpy(self.u), t, torch.from_numpy(self.params_host), torch.from_numpy(self.index),
                      torch.from_numpy(slots), torch.from_numpy(starts))

    def to(self, device):
        if torch.device(device).type != "cpu":
            raise ValueError("NumpyStorage keeps its trajectories on the host")


def test_a_storage_is_swapped_by_a_new_class_not_an_edit():
    kw = dict(seed=3, view="operator", batch_size=4, capacity=8, max_reuse=2, solve_batch=4, mode="deterministic",
              draw="uniform", eviction="random")
    plain = run(ReservoirStream(PDE, **kw), 8)
    s = ReservoirStream(PDE, **kw, storage=NumpyStorage)
    assert digest(run(s, 8)) == digest(plain) and s.res.storage.puts > 2
