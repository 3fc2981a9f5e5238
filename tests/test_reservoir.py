"""Training reservoir: reuse bound, eviction, determinism and resume, sample identity, producers, proposal."""

import collections

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from pdestream import generator
from pdestream.datasets.proposal import ParamProposal
from pdestream.datasets.reservoir import Reservoir, ReservoirStream

PDE = generator.get_pde("burgers1d", n=32, n_frames=4)


def take(stream, n=None):
    """The stream's batches (the first n, or all of a finite one), then close it."""
    out = []
    for batch in DataLoader(stream, batch_size=None):
        out.append(batch)
        if len(out) == n:
            break
    stream.close()
    return out


def same(a, b):
    return len(a) == len(b) and all(torch.equal(x[k], y[k]) for x, y in zip(a, b) for k in x)


# --- the store alone ---------------------------------------------------------------------------------
def test_store_never_exceeds_the_bound_and_never_serves_an_evicted_trajectory():
    rng = np.random.default_rng(0)
    res = Reservoir(capacity=6, cap_uses=3, n_windows=2, eviction="random", draw="uniform", rng=rng)
    held, uses, next_index = set(), collections.Counter(), 0
    for _step in range(400):
        if rng.random() < 0.3 and res.room() >= 2:  # a producer inserts a batch of 2
            before = set(res.index[res.live()].tolist())
            res.insert(torch.zeros(2, 3, 1, 4), torch.zeros(2, 1), np.array([next_index, next_index + 1]))
            next_index += 2
            held = set(res.index[res.live()].tolist())
            assert len(before - held) == 2 or len(before) + 2 <= 6  # only used ones make way
        slots, starts = res.draw(1)
        if not len(slots):  # the loop would wait: everything held is at its bound
            assert all(res.uses[s] == 3 for s in res.live())
            continue
        slot, start = int(slots[0]), int(starts[0])
        assert 0 <= start < 2
        idx = int(res.index[slot])
        assert idx in held  # never a trajectory already evicted
        uses[idx] += 1
        assert uses[idx] <= 3  # never above the bound
    assert res.evicted > 0 and max(uses.values()) == 3
    assert res.reuse(per_trajectory=1).max() <= 3


def test_store_evicts_fifo_among_used_only_and_least_used_balances():
    res = Reservoir(capacity=4, cap_uses=5, n_windows=3, eviction="fifo", draw="least_used",
                    rng=np.random.default_rng(1))
    res.insert(torch.zeros(4, 4, 1, 2), torch.zeros(4, 0), np.arange(4))
    assert res.room() == 0  # nothing drawn yet: a new solve must wait, not evict an unused one
    for _ in range(3):
        slots, _starts = res.draw(3)
        assert len(set(slots.tolist())) == 3  # a trajectory at most once per draw
    assert sorted(res.uses.tolist()) == [2, 2, 2, 3]  # least used first: balanced
    for _ in range(3):
        res.draw(1)
    assert sorted(res.uses.tolist()) == [3, 3, 3, 3]
    assert (res.window_uses == 1).all()  # three windows each, every window once: least-drawn windows first
    res.insert(torch.zeros(1, 4, 1, 2), torch.zeros(1, 0), np.array([10]))
    assert 0 not in res.index and 10 in res.index  # the oldest made way


# --- the stream ---------------------------------------------------------------------------------------
def stream(**kw):
    args = dict(seed=3, view="operator", batch_size=4, capacity=8, max_reuse=2, solve_batch=4, mode="deterministic")
    args.update(kw)
    return ReservoirStream(PDE, **args)


def test_deterministic_batches_repeat_and_resume_exactly():
    full = take(stream(draw="uniform", eviction="random"), 12)
    assert same(full, take(stream(draw="uniform", eviction="random"), 12))
    first = stream(draw="uniform", eviction="random")
    head = []
    for batch in DataLoader(first, batch_size=None):
        head.append(batch)
        if len(head) == 5:
            break
    state = first.state_dict()
    first.close()
    torch.save(state, "/dev/null")  # plain values
    resumed = stream(draw="uniform", eviction="random")
    resumed.load_state_dict(state)
    assert same(head + take(resumed, 7), full)


def _res(state: dict) -> dict:
    return state["reservoir"]


@pytest.mark.parametrize("edit, message", [
    (lambda s: s["producer"].update(next_index=2**64), "producer.next_index holds 18446744073709551616"),
    (lambda s: _res(s)["writer"]["serial"].__setitem__(0, -1), "writer.serial holds -1"),
    (lambda s: _res(s)["slots"].__setitem__(0, 10**6), "slots holds 1000000"),
    (lambda s: _res(s)["storage"]["index"].pop(), "storage.index has"),
    (lambda s: _res(s)["sampler"].pop("uses"), "incomplete or malformed"),
    (lambda s: s.update(max_reuse=16.0), "max_reuse=16.0 but this stream has max_reuse=2.0"),
    (lambda s: s.update(view="next_step"), "view='next_step' but this stream has view='operator'"),
    (lambda s: s["proposal"].pop("rng"), "proposal entry is damaged"),
    (lambda s: _res(s)["sampler"]["window_uses"].append([0]), "sampler.window_uses has"),
    (lambda s: s["schedule"].update(batches=-1), "schedule.batches holds -1"),
])
def test_a_loaded_state_with_bad_integers_is_refused_in_one_line(edit, message):
    first = stream(draw="uniform", eviction="random")
    take(first, 3)
    state = first.state_dict()
    first.close()
    edit(state)
    resumed = stream(draw="uniform", eviction="random")
    with pytest.raises(ValueError, match=f"^reservoir state.*{message}") as err:
        resumed.load_state_dict(state)
    assert "\n" not in str(err.value)
    resumed.close()


def test_examples_are_the_generator_samples_and_reuse_is_bounded():
    batches = take(stream(max_reuse=3, draw="least_used"), 20)
    counts = collections.Counter(i for b in batches for i in b["index"].tolist())
    assert max(counts.values()) <= 3  # operator view: one use = one example
    idx = np.array(sorted(counts))
    ref = generator.sample(PDE, idx, seed=3)
    u = np.asarray(ref.u)
    for b in batches:
        for k, i in enumerate(b["index"].tolist()):
            j = int(np.searchsorted(idx, i))
            assert np.array_equal(b["x"][k].numpy(), u[j, 0]) and np.array_equal(b["y"][k].numpy(), u[j, -1])
            assert b["params"][k, 0].item() == float(ref.params["nu"][j])


def test_fifo_setting_uses_each_solve_once_in_order():
    batches = take(stream(capacity=4, max_reuse=1, draw="least_used", warmup=4), 6)
    seen = [sorted(b["index"].tolist()) for b in batches]
    assert seen == [list(range(4 * k, 4 * k + 4)) for k in range(6)]


def test_async_mode_respects_the_bound_and_reports_stats():
    s = stream(mode="async", max_reuse=2)
    batches = take(s, 15)
    counts = collections.Counter(i for b in batches for i in b["index"].tolist())
    # (failed once in ~6 whole-suite runs, index 17 drawn 3 times; not reproduced in 30 runs alone: the details)
    assert max(counts.values()) <= 2, (counts, [b["index"].tolist() for b in batches], s.res.index.tolist(),
                                       s.res.uses.tolist(), s.res.inserted, s.res.evicted)
    st = s.stats()
    assert st["inserted"] >= 8 and 0 <= st["wait_share"] <= 1 and st["reuse_max"] <= 2
    assert set(st) >= {"inserted", "evicted", "reuse_mean", "reuse_max", "solver_traj_per_s", "examples_per_s"}


def test_sim_budget_ends_the_stream():
    s = stream(sim_budget=8, max_reuse=1)
    batches = list(DataLoader(s, batch_size=None))
    s.close()
    assert sorted(i for b in batches for i in b["index"].tolist()) == list(range(8))


@pytest.mark.parametrize("kind", ["process", "dask"])
def test_other_producers_give_the_same_deterministic_batches(kind):
    if kind == "dask":
        pytest.importorskip("distributed")
    ref = take(stream(), 8)
    assert same(take(stream(producer=kind, workers=2), 8), ref)


@pytest.mark.parametrize("kw, message", [
    (dict(capacity=2), "capacity=2 not allowed: must be >= batch_size (4)"),
    (dict(max_reuse=0.5), "max_reuse=0.5 not allowed; must be a finite number >= 1"),
    (dict(warmup=9), "warmup=9 not allowed: must be <= capacity (8)"),
    (dict(draw="newest"), "draw='newest' not allowed; allowed: uniform, least_used, priority"),
    (dict(draw="priority", priority_power=-1), "priority_power=-1 not allowed; must be in [0, 8] (0: uniform draws)"),
    (dict(draw="priority", priority_floor=0), "priority_floor=0 not allowed; must be in (0, 1] (the uniform share of draws)"),
    (dict(eviction="lifo"), "eviction='lifo' not allowed; allowed: fifo, random"),
    (dict(mode="sync"), "mode='sync' not allowed; allowed: async, deterministic"),
    (dict(proposal="bayes"), "proposal='bayes' not allowed; allowed: uniform, loss, active, generative"),
    (dict(proposal="active", proposal_kwargs={"ensemble": 1}),
     "proposal ensemble=1 not allowed; must be an integer >= 2 (the uncertainty signal is the disagreement of its members) "
     "and <= 100 (each member is a loss model refitted at every refit)"),
])
def test_bad_settings_are_one_line_errors(kw, message):
    with pytest.raises(ValueError) as err:
        stream(**kw)
    assert str(err.value) == message


@pytest.mark.parametrize("kw, message", [
    (dict(proposal="bayes"), "proposal='bayes' not allowed; allowed: uniform, loss, active, generative"),
    (dict(proposal="loss", proposal_kwargs={"floor": float("nan")}),
     "proposal floor=nan not allowed; must be in (0, 1] (uniform share)"),
    (dict(proposal="active", proposal_kwargs={"kappa": 1e400}),
     "proposal kappa=inf not allowed; must be in [0, 100] (weight of the ensemble spread)"),
    (dict(proposal="loss", proposal_kwargs={"flor": 0.5}), "proposal_kwargs key 'flor' not allowed; allowed: floor, "
     "bandwidth, power, window, ensemble, kappa, top, step, gate, skill_full, skill_min, refit, candidates, "
     "skill_window, probe, space"),
    (dict(proposal="loss", proposal_kwargs=[0.5]), "proposal_kwargs=[0.5] not allowed; a dict of the proposal's "
     "settings (datasets.proposal.ParamProposal) or None"),
    (dict(proposal="active", proposal_kwargs={"space": "ic"}), "proposal space='ic' not allowed; allowed: params, "
     "params+ic"),
])
def test_the_config_checks_its_proposal_before_a_stream_is_built(kw, message):
    # adv52: ReservoirConfig.checked passed every one of these (the stream's ParamProposal refused the values later;
    # an unknown key was a TypeError there)
    from pdestream.datasets.reservoir_config import ReservoirConfig

    with pytest.raises(ValueError) as err:
        ReservoirConfig(**kw).checked(1)
    assert str(err.value) == message


def test_a_reservoir_larger_than_memory_is_refused():
    with pytest.raises(ValueError, match=r"capacity=100000000 not allowed: holding 100000000 trajectories takes .* GiB, "
                                         r"more than half of this machine's"):
        stream(capacity=10**8)


def test_bad_producer_is_refused_when_started():
    with pytest.raises(ValueError, match="producer='mpi' not allowed; allowed: thread, process, dask"):
        take(stream(producer="mpi"), 1)


# --- loss-driven proposal ------------------------------------------------------------------------------
def test_proposal_concentrates_where_the_loss_is_high_and_keeps_its_floor():
    domains = {"nu": ("loguniform", 0.01, 0.1, ()), "c": ("fixed", 1.0, 1.0, ())}
    # gate off here and below: these test what the steered draws do; one record call gives the skill gate no fresh
    # losses to score (test_active_proposal.py tests the gate)
    prop = ParamProposal(domains, mode="loss", floor=0.2, seed=0, gate=False)
    rng = np.random.default_rng(0)
    nu = np.exp(rng.uniform(np.log(0.01), np.log(0.1), 2000))
    loss = np.where(nu < 0.0159, 1.0, 0.01)  # high loss in the lowest fifth of the log box
    prop.record(np.stack([nu, np.ones_like(nu)], 1), loss)
    z = prop.to_unit(np.stack([prop.propose(5000)["nu"], np.ones(5000)], 1))[:, 0]
    low = (z < 0.2).mean()
    assert low > 0.7  # uniform would give 0.2
    for a in np.arange(0.2, 1.0, 0.2):  # the uniform floor reaches every region
        assert ((z >= a) & (z < a + 0.2)).mean() > 0.5 * 0.2 * 0.2
    values = prop.propose(100)["nu"]
    assert values.min() >= 0.01 and values.max() <= 0.1
    again = ParamProposal(domains, mode="loss", floor=0.2, seed=0, gate=False)
    again.load_state_dict(prop.state_dict())
    assert np.array_equal(again.propose(10)["nu"], prop.propose(10)["nu"])


def test_uniform_proposal_leaves_parameters_to_the_solver():
    prop = ParamProposal({"nu": ("loguniform", 0.01, 0.1, ())}, mode="uniform")
    assert prop.propose(4) is None


def test_loss_driven_stream_solves_the_proposed_parameters():
    s = stream(proposal="loss", proposal_kwargs={"floor": 0.5})
    batches = []
    for batch in DataLoader(s, batch_size=None):
        s.report_losses(batch, torch.where(batch["params"][:, 0] < 0.02, 1.0, 0.001).double())
        batches.append(batch)
        if len(batches) == 30:
            break
    s.close()
    nu = torch.cat([b["params"][:, 0] for b in batches])
    assert nu.min() >= 0.01 and nu.max() <= 0.1
    late = torch.cat([b["params"][:, 0] for b in batches[15:]])
    assert (late < 0.02).float().mean() > 0.4  # uniform in log: 0.30


# --- through the training loop and the CLI ------------------------------------------------------------------
@pytest.mark.parametrize("proposal", ["loss", "active"])
def test_kill9_and_resume_through_a_deterministic_reservoir_is_bit_identical(tmp_path, proposal):
    from test_resume import STEPS, TINY_MODEL, TINY_PDE, kill_and_resume

    def fresh(out):
        return {"argv": ["train", "burgers1d", *TINY_PDE, *TINY_MODEL, "--steps", str(STEPS), "--batch-size", "8",
                         "--checkpoint-every", "10", "--test-samples", "2", "--threads", "1", "--out", str(out),
                         "--reservoir", "--reservoir-mode", "deterministic", "--capacity", "16", "--max-reuse", "3",
                         "--solve-batch", "8", "--proposal", proposal]}

    ckpt = kill_and_resume(tmp_path / "whole", tmp_path / "killed", fresh, kill_at=26)
    state = ckpt["data"]["state"]
    assert state["kind"] == "reservoir" and len(state["reservoir"]["slots"]) == 16 and state["proposal"]["reports"] > 0
    rows = (tmp_path / "whole" / "metrics.csv").read_text().splitlines()
    assert {"inserted", "evicted", "reuse_mean", "reuse_max", "wait_share"} <= set(rows[0].split(","))


def test_cli_reservoir_settings_are_checked(capsys, tmp_path):
    from pdestream import cli

    out = tmp_path / "run"
    assert cli.main(["train", "burgers1d", "--reservoir", "--capacity", "4", "--out", str(out)]) == 2
    assert "capacity=4 not allowed: must be >= batch_size (32)" in capsys.readouterr().err
    assert cli.main(["train", "burgers1d", "--reservoir", "--max-reuse", "0", "--out", str(out)]) == 2
    assert "max_reuse=0.0 not allowed; must be a finite number >= 1" in capsys.readouterr().err
    assert not out.exists()


def test_target_reuse_paces_a_fast_solver():
    paced = stream(mode="async", max_reuse=8, capacity=32, warmup=8, target_reuse=4)
    take(paced, 40)
    # 40 batches x 4 examples = 160 uses pay for 160 / 4 = 40 trajectories (+ the warm-up, one batch ahead)
    assert paced.res.inserted <= 8 + 160 / 4 + 2 * 4
    # the rule itself: hold the next solve until the draws have paid for the ones submitted
    s = stream(mode="async", max_reuse=8, capacity=32, warmup=8, target_reuse=4)
    s.res.insert(torch.zeros(8, 4, 1, 32), torch.zeros(8, 1), np.arange(8))
    s.next_index = 8 + 4 + 4  # warm-up, one batch paid for by 16 uses, one batch ahead
    s.res.drawn = 16  # the second batch is not paid for yet (4 uses per trajectory)
    assert s._paced()
    s.res.drawn = 17
    assert not s._paced()
    s.res.uses[:] = 8  # nothing drawable: never hold the solver back
    s.res.drawn = 0
    assert not s._paced()
    with pytest.raises(ValueError, match=r"target_reuse=9 not allowed; must be a number in \[1, max_reuse=8\]"):
        stream(max_reuse=8, target_reuse=9)


def test_proposal_follows_the_loss_not_where_earlier_proposals_crowded():
    prop = ParamProposal({"nu": ("uniform", 0.0, 1.0, ())}, mode="loss", floor=0.25, seed=1, gate=False)
    rng = np.random.default_rng(1)
    z = np.concatenate([rng.uniform(0.9, 1.0, 1500), rng.uniform(0.0, 1.0, 548)])  # earlier solves crowd the top
    prop.record(z[:, None], np.where(z > 0.9, 2.0, 1.0))  # the loss there is only twice as high
    share = (prop.propose(4000)["nu"] > 0.9).mean()
    assert 0.1 < share < 0.3  # ~0.16 follows the loss; weighting by loss alone would give ~0.65


def test_proposal_drops_non_finite_rows_and_never_proposes_nan_or_outside_the_box():
    domains = {"nu": ("loguniform", 0.01, 0.1, ()), "c": ("uniform", -1.0, 1.0, ())}
    prop = ParamProposal(domains, mode="loss", floor=0.25, seed=0)
    rng = np.random.default_rng(0)
    params = np.stack([np.exp(rng.uniform(np.log(0.01), np.log(0.1), 64)), rng.uniform(-1, 1, 64)], 1)
    params[5] = [np.nan, 0.5]  # one NaN parameter row (the reported failure: 44 of 512 proposals became NaN)
    losses = rng.uniform(0.1, 1.0, 64)
    losses[7] = np.inf
    prop.record(params, losses)
    assert prop.dropped == 2 and len(prop.losses) == 62
    out = prop.propose(512)
    for name, (_, lo, hi, _) in domains.items():
        assert np.isfinite(out[name]).all() and (out[name] >= lo).all() and (out[name] <= hi).all()


def test_proposal_weights_survive_huge_and_tiny_losses():
    prop = ParamProposal({"nu": ("uniform", 0.0, 1.0, ())}, mode="loss", floor=0.1, power=2.0, seed=0, gate=False)
    z = np.linspace(0.01, 0.99, 50)[:, None]
    losses = np.full(50, 1e-300)
    losses[40:] = 1e300  # squared: 1e600 overflows float64 ("Probabilities contain NaN" before)
    prop.record(z, losses)
    out = prop.propose(400)["nu"]
    assert np.isfinite(out).all()
    assert np.mean(out > 0.7) > 0.7  # the steered draws go where the loss is huge


# --- the reservoir on the training device ---------------------------------------------------------------------
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (run on a GPU machine)")
DEVICES = ["cpu", pytest.param("cuda", marks=CUDA)]


def on(batch: dict) -> set:
    return {v.device for v in batch.values() if isinstance(v, torch.Tensor)}


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("view", [dict(view="operator"), dict(view="next_step", k_in=1, k_out=2)])
def test_a_device_reservoir_gives_the_host_reservoirs_batches_on_its_device(device, view):
    host = take(stream(device="cpu", **view), 10)
    there = take(stream(device=device, **view), 10)
    want = datasets_device(device)
    assert all(on(b) == {want} for b in there)  # everything a batch holds
    assert same(host, [{k: v.cpu() for k, v in b.items()} for b in there])  # the same bits: copies only


def datasets_device(name: str) -> torch.device:
    from pdestream.datasets.reservoir import storage_device

    return storage_device(name)


@pytest.mark.parametrize("device", DEVICES)
def test_a_device_reservoir_keeps_the_bound_and_resumes_exactly(device):
    batches = take(stream(max_reuse=3, draw="least_used", device=device), 20)
    counts = collections.Counter(i for b in batches for i in b["index"].tolist())
    assert max(counts.values()) <= 3
    full = take(stream(draw="uniform", eviction="random", device=device), 9)
    first = stream(draw="uniform", eviction="random", device=device)
    head = take(first, 4)
    state = first.state_dict()
    resumed = stream(draw="uniform", eviction="random", device=device)
    resumed.load_state_dict(state)
    rest = take(resumed, 5)
    assert same([{k: v.cpu() for k, v in b.items()} for b in head + rest], [{k: v.cpu() for k, v in b.items()} for b in full])


def test_the_training_loop_places_a_reservoir_built_without_a_device(tmp_path):
    from pdestream.surrogate.models import build_model
    from pdestream.surrogate.train import train

    s = stream(device=None, sim_budget=16, max_reuse=1)
    placed = []
    place = s.place
    s.place = lambda device: (placed.append(device), place(device))
    model = build_model("fno", 1, 1, 1, len(PDE.PARAMS), bc=PDE.grid.bc, width=4, modes=2, layers=1)
    out = train(model, DataLoader(s, batch_size=None), 3, tmp_path / "run", log_every=1)
    s.close()
    assert placed == [torch.device("cpu")] and out["steps"] == 3 and s.res.device == torch.device("cpu")


def test_a_thread_solve_reaches_the_reservoir_through_dlpack_with_the_same_values():
    from pdestream.datasets import _bridge

    numpy_out = _bridge.solve_job(PDE.config(), 3, [0, 1, 2, 3])
    torch_out = _bridge.solve_job(PDE.config(), 3, [0, 1, 2, 3], on_device=True)
    assert isinstance(torch_out["u"], torch.Tensor) and not isinstance(numpy_out["u"], torch.Tensor)
    assert np.array_equal(torch_out["u"].cpu().numpy(), numpy_out["u"])
    assert np.array_equal(torch_out["params"], numpy_out["params"])


@pytest.mark.parametrize("bad, message", [
    ("gpu", "device='gpu' not allowed; allowed: cpu, cuda, cuda:N (None: the training device)"),
    ("mps", "device='mps' not allowed; allowed: cpu, cuda, cuda:N (None: the training device)"),
    ("cuda:x", "device='cuda:x' not allowed; allowed: cpu, cuda, cuda:N (None: the training device)"),
    ("cuda:99", "device='cuda:99' not allowed: torch sees"),
])
def test_a_bad_device_is_one_line(bad, message):
    with pytest.raises(ValueError) as err:
        stream(device=bad)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_cuda_without_a_gpu_is_one_line():
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    with pytest.raises(ValueError, match=r"^device='cuda' not allowed: torch sees no GPU here; allowed: cpu$"):
        stream(device="cuda")


def test_a_device_without_room_is_one_line_with_the_bytes_asked_and_free(monkeypatch):
    from pdestream.datasets import reservoir_storage as reservoir

    monkeypatch.setattr(reservoir, "free_bytes", lambda device: (123456, 80 * 2**30))
    with pytest.raises(ValueError) as err:
        reservoir.check_room(torch.device("cuda", 0), 10**9, "capacity=1000 (1000 trajectories)")
    assert str(err.value) == ("device='cuda:0' cannot hold capacity=1000 (1000 trajectories): it asks 1000000000 bytes "
                              "(0.93 GiB) and cuda:0 has 123456 bytes free (0.00 of 80.0 GiB); allowed: a smaller "
                              "capacity, or device='cpu'")
    reservoir.check_room(torch.device("cpu"), 10**15, "anything")  # the host: checked against RAM elsewhere


@CUDA
def test_a_reservoir_larger_than_the_gpu_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"^device='cuda:\d' cannot hold capacity=1000000000 .* asks \d+ bytes .* has \d+ "
                                         r"bytes free"):
        stream(capacity=10**9, device="cuda")


@CUDA
def test_train_run_with_a_reservoir_on_the_gpu(tmp_path):
    from pdestream.surrogate.runs import train_run

    cfg = {"kind": "reservoir", "capacity": 16, "max_reuse": 2, "solve_batch": 8, "mode": "deterministic"}
    s = train_run(PDE, "stream", tmp_path / "run", model_cfg={"width": 8, "modes": 4, "layers": 1}, steps=6,
                  batch_size=4, n_test=2, checkpoint_every=0, device="cuda", data_cfg=cfg)
    assert s["steps"] == 6 and s["data_stats"]["inserted"] >= 8


def test_the_default_solve_batch_follows_the_training_device():
    from pdestream import cli

    parse = cli.build_parser().parse_args
    assert cli.reservoir_cfg(parse(["train", "burgers1d", "--reservoir"]))["solve_batch"] == 16
    assert cli.reservoir_cfg(parse(["train", "burgers1d", "--reservoir", "--device", "cuda:1"]))["solve_batch"] == 128
    given = parse(["train", "burgers1d", "--reservoir", "--device", "cuda", "--solve-batch", "32"])
    assert cli.reservoir_cfg(given)["solve_batch"] == 32


@pytest.mark.slow
def test_a_killed_producer_process_stops_the_stream_in_one_line():
    import os
    import signal

    s = stream(mode="async", producer="process", workers=1)
    it = iter(DataLoader(s, batch_size=None))
    next(it)
    for pid in list(s._executor._processes):  # the pool's worker, as the OOM killer or a user would
        os.kill(pid, signal.SIGKILL)
    with pytest.raises(ValueError, match=r"a solver process of the reservoir's producer died .* while solving "
                                         r"samples \d+\.\.\d+; the stream stops"):
        for _ in range(200):
            next(it)
    s.close()


def test_a_solve_inserted_while_a_batch_is_assembled_never_swaps_the_batch_examples():
    """A batch assembled over several draws, with a scheduled insertion (and its evictions) between them: every
    example is the trajectory that was drawn (each sample delivered at least once, none beyond the bound)."""
    s = ReservoirStream(PDE, seed=3, view="operator", batch_size=3, capacity=6, max_reuse=4, target_reuse=2,
                        solve_batch=2, mode="deterministic", sim_budget=40)
    batches = take(s)
    counts = collections.Counter(i for b in batches for i in b["index"].tolist())
    # the reservoir's own use counts (trajectories by uses) are what the batches delivered
    delivered = np.bincount([counts.get(i, 0) for i in range(40)], minlength=s.res.cap_uses + 1)
    # (gathering at the end, this run delivered one sample 0 times and one 5 times: [1, 14, 5, 7, 12, 1] against
    # the counts' [0, 14, 7, 6, 13])
    assert delivered.tolist() == s.res.use_counts().tolist()
    assert max(counts.values()) <= 4
    ref = np.asarray(generator.sample(PDE, np.arange(40), seed=3).u)
    for b in batches:
        want = ref[b["index"].numpy(), -1]
        assert np.array_equal(b["y"].numpy().reshape(want.shape), want)
