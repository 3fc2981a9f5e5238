"""TrajectoryStream: sharding over workers and ranks, bit identity with generator.sample, exact resume,
flat memory, normalization statistics and argument errors. Small grids (burgers1d n=32, 6 frames)."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from pdestream import generator
from pdestream.datasets import _bridge, collate, examples, gather, make_view
from pdestream.datasets.stream import TrajectoryStream, stream_loader

SEED = 5


@pytest.fixture(scope="module")
def pde():
    return generator.get_pde("burgers1d", {"n": "32", "n_frames": "6"})


def reference(pde, i, seed=SEED):
    """Sample i solved alone, as numpy."""
    return np.asarray(generator.sample(pde, [i], seed).u[0])


def indices_of(batches):
    return [i for b in batches for i in b["index"].tolist()]


def by_index(batches):
    """{index: u [T, C, n]} from whole-view batches."""
    return {int(i): b["u"][j] for b in batches for j, i in enumerate(b["index"])}


def test_gather_equals_collated_examples(pde):
    data = _bridge.sample_tensors(pde, [3, 9], SEED)
    for view in (make_view("whole"), make_view("operator", t_in=1, t_out=-2), make_view("next_step", k_in=2, k_out=2)):
        ref = [ex for b, i in enumerate([3, 9]) for ex in
               examples(view, data["u"][b], data["t"], data["params"][b], i)]
        starts = view.starts(pde.n_frames)
        traj = torch.tensor([b for b in range(2) for _ in starts])
        start = torch.tensor(starts * 2)
        got = gather(view, data["u"], data["t"], data["params"], data["index"], traj, start)
        want = collate(ref)
        assert got.keys() == want.keys()
        for k in want:
            assert torch.equal(got[k], want[k]), (view, k)


def test_streamed_sample_is_generator_sample_bit_for_bit(pde):
    stream = TrajectoryStream(pde, SEED, view="whole", batch_size=3, n_samples=7, solve_batch=4)
    batches = list(DataLoader(stream, batch_size=None))
    assert sorted(indices_of(batches)) == list(range(7))
    got = by_index(batches)
    for i in (0, 4, 6):  # 6 sits in a padded final solve batch
        np.testing.assert_array_equal(got[i].numpy(), reference(pde, i))
    params = {int(i): p for b in batches for i, p in zip(b["index"], b["params"])}
    assert params[4].item() == float(generator.sample(pde, [4], SEED).params["nu"][0])
    # next-step windows are slices of the same trajectory: x = frames s..s+1, y = frame s+2
    ns = TrajectoryStream(pde, SEED, view="next_step", k_in=2, windows=2, batch_size=4, n_samples=3, solve_batch=2)
    t = pde.times()
    for b in ns:
        for x, y, t0, i in zip(b["x"], b["y"], b["t0"], b["index"]):
            u = reference(pde, int(i))
            s = int(np.flatnonzero(t == t0.item())[0])
            np.testing.assert_array_equal(x.numpy(), u[s : s + 2])
            np.testing.assert_array_equal(y.numpy(), u[s + 2 : s + 3])


def test_union_over_ranks_without_workers_equals_single_process(pde):
    kw = dict(view="whole", batch_size=4, n_samples=11, solve_batch=4)
    single = indices_of(TrajectoryStream(pde, SEED, **kw))
    ranks = [indices_of(TrajectoryStream(pde, SEED, rank=r, world_size=2, **kw)) for r in (0, 1)]
    assert sorted(single) == list(range(11))
    assert sorted(ranks[0] + ranks[1]) == list(range(11))  # no duplicates, no gaps
    assert set(ranks[0]) == set(range(0, 11, 2))


def test_union_over_two_spawn_workers_and_two_ranks(pde):
    kw = dict(view="whole", batch_size=3, n_samples=13, solve_batch=4)
    single = by_index(list(TrajectoryStream(pde, SEED, **kw)))
    union = []
    for rank in (0, 1):
        batches = list(stream_loader(TrajectoryStream(pde, SEED, rank=rank, world_size=2, **kw), num_workers=2))
        union += indices_of(batches)
        for i, u in by_index(batches).items():  # same bytes from a spawned worker
            assert torch.equal(u, single[i])
    assert sorted(union) == list(range(13))


def test_resume_mid_epoch_yields_exactly_the_rest(pde):
    kw = dict(view="next_step", windows=2, batch_size=5, n_samples=9, solve_batch=4)
    full = list(TrajectoryStream(pde, SEED, **kw))
    stream = TrajectoryStream(pde, SEED, **kw)
    it = iter(stream)
    head = [next(it) for _ in range(3)]
    state = stream.state_dict()
    assert state["consumed"] == [15] and state["epoch"] == 0
    resumed = TrajectoryStream(pde, SEED, **kw)
    resumed.load_state_dict(state)
    tail = list(resumed)
    assert len(head) + len(tail) == len(full)
    for got, want in zip(head + tail, full):
        for k in want:
            assert torch.equal(got[k], want[k]), k
    # a finished epoch moves on: fresh indices, new windows
    assert resumed.state_dict()["epoch"] == 1
    assert sorted(set(indices_of(resumed))) == list(range(9, 18))


def test_resume_with_spawn_workers(pde):
    kw = dict(view="whole", batch_size=2, n_samples=10, solve_batch=4)
    stream = TrajectoryStream(pde, SEED, **kw)
    loader = stream_loader(stream, num_workers=2)
    seen = []
    for k, b in enumerate(loader):
        seen += b["index"].tolist()
        if k == 2:
            state = stream.state_dict()
            break
    assert state["consumed"] == [4, 2]  # round robin over the two workers' shards
    # persistent workers pick up state and epoch through shared memory: clear it, restore it, go on
    stream.set_epoch(0)
    stream.load_state_dict(state)
    rest = indices_of(loader)
    assert sorted(seen + rest) == list(range(10))
    assert sorted(indices_of(loader)) == list(range(10, 20))  # the next epoch, same workers


def test_epochs_and_set_epoch(pde):
    stream = TrajectoryStream(pde, SEED, view="operator", batch_size=8, n_samples=6, solve_batch=4)
    assert sorted(indices_of(stream)) == list(range(6))
    assert sorted(indices_of(stream)) == list(range(6, 12))  # new samples each epoch
    stream.set_epoch(4)
    assert sorted(indices_of(stream)) == list(range(24, 30))
    fixed = TrajectoryStream(pde, SEED, view="operator", batch_size=8, n_samples=6, solve_batch=4, resample=False)
    first, second = list(fixed), list(fixed)
    assert indices_of(first) != indices_of(second)  # reshuffled ...
    assert sorted(indices_of(first)) == sorted(indices_of(second)) == list(range(6))  # ... same samples


def test_endless_stream_memory_stays_flat(pde):
    def rss_mb():
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024

    stream = TrajectoryStream(pde, SEED, view="next_step", batch_size=64, solve_batch=32)
    it = iter(stream)
    for _ in range(20):  # warm up: compile, allocator pools
        next(it)
    before = rss_mb()
    seen = 0
    for _ in range(300):  # 19200 examples, 3840 trajectories (5 windows each)
        seen += len(next(it)["index"])
    grown = rss_mb() - before
    assert seen == 300 * 64
    assert grown < 25, f"RSS grew {grown:.1f} MB over {seen} examples"
    assert stream.state_dict()["consumed"] == [320 * 64]


def test_blowup_is_raised_not_streamed(pde, monkeypatch):
    def blow(*args, **kwargs):
        raise generator.BlowUpError("burgers1d: 1 of 4 trajectories blew up (NaN/Inf)")

    monkeypatch.setattr(_bridge, "sample_tensors", blow)
    for prefetch in (True, False):
        with pytest.raises(generator.BlowUpError, match="blew up"):
            next(iter(TrajectoryStream(pde, SEED, view="whole", prefetch=prefetch)))


def test_normalization_matches_numpy(pde):
    norm = TrajectoryStream(pde, SEED).normalization(n=10)
    u = np.asarray(generator.sample(pde, range(10), SEED).u, np.float64)  # [B, T, C, n]
    np.testing.assert_allclose(norm.mean.numpy(), u.mean(axis=(0, 1, 3)), atol=1e-6)
    np.testing.assert_allclose(norm.std.numpy(), u.std(axis=(0, 1, 3)), rtol=1e-5)
    x = torch.from_numpy(u[:2].astype(np.float32))
    z = norm.normalize(x)
    assert abs(z.std().item() - 1) < 0.5
    torch.testing.assert_close(norm.denormalize(z), x)
    assert norm.from_dict(norm.to_dict()).std.tolist() == norm.std.tolist()


@pytest.mark.parametrize("kwargs, match", [
    (dict(view="sideways"), "unknown view 'sideways'"),
    (dict(view="next_step", k_in=4, k_out=3), "longer than the trajectory"),
    (dict(view="operator", t_out=6), "t_out=6 outside"),
    (dict(batch_size=0), "batch_size=0"),
    (dict(solve_batch=-1), "solve_batch=-1"),
    (dict(n_samples=0), "n_samples=0"),
    (dict(rank=2, world_size=2), r"rank=2 not allowed; must be in \[0, 2\)"),
    (dict(rank=0), "both rank and world_size"),
    (dict(world_size=0, rank=0), "world_size=0"),
    (dict(on_blowup="ignore"), "on_blowup='ignore'"),
    (dict(seed=-1), "seed=-1"),
])
def test_bad_arguments_raise_value_error(pde, kwargs, match):
    kwargs = {"seed": SEED, **kwargs}
    with pytest.raises(ValueError, match=match):
        TrajectoryStream(pde, **kwargs)


def test_bad_loader_and_state_arguments(pde):
    stream = TrajectoryStream(pde, SEED, n_samples=4)
    with pytest.raises(ValueError, match="num_workers=-1"):
        stream_loader(stream, num_workers=-1)
    with pytest.raises(ValueError, match="context='fork'"):
        stream_loader(stream, num_workers=1, context="fork")
    with pytest.raises(ValueError, match="seed=6"):
        stream.load_state_dict({**stream.state_dict(), "seed": 6})
    stream.load_state_dict({**stream.state_dict(), "consumed": [1, 1]})
    with pytest.raises(ValueError, match=r"saved with num_workers=2 per rank, resumed with num_workers=0;"):
        iter(stream)  # this process iterating: num_workers=0, as the user set it (not "1")


def test_a_script_may_exit_with_a_stream_still_open(tmp_path):
    # The prefetch thread is inside a JAX call when the interpreter exits; it must finish, not abort.
    import subprocess
    import sys

    script = tmp_path / "leave_open.py"
    script.write_text(
        "from pdestream import generator\nfrom pdestream.datasets import TrajectoryStream\n"
        "it = iter(TrajectoryStream(generator.get_pde('burgers1d', n=256), 0, view='whole', batch_size=16))\n"
        "next(it)\nprint('done')\n"
    )
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "done" in out.stdout, out.stderr[-500:]
    assert "terminate called" not in out.stderr


def test_progress_counts_snapshots_and_pickles_to_a_copy():
    import pickle

    from pdestream.datasets.progress import StreamPosition

    p = StreamPosition()
    p.set_epoch(2)
    p.add(1, 5)
    p.add(1, 3)
    assert p.epoch == 2 and p.consumed(1) == 8 and p.snapshot(2) == (2, [0, 8])
    copy = pickle.loads(pickle.dumps(p))  # plain pickling: independent memory
    copy.add(1, 1)
    assert (p.consumed(1), copy.consumed(1)) == (8, 9) and copy.unpickled and not p.unpickled
    p.restore(3, [4, 5])
    assert p.snapshot(2) == (3, [4, 5]) and p.workers == 2
    with pytest.raises(ValueError, match="saved with num_workers=2 per rank, resumed with num_workers=3"):
        p.record_workers(3)
    p.restore(0, [1, 2], worker=1, workers=2)  # inside worker 1: for its next iteration only
    assert p.start(1, 2, share=False) == (0, 2) and p.snapshot(2) == (3, [4, 5])
    p.advance(1, 3, share=False)
    assert p.snapshot(2, worker=1) == (0, [0, 5])


def test_out_of_range_state_is_refused_not_wrapped(pde):
    stream = TrajectoryStream(pde, SEED, n_samples=4)
    for key, value in (("consumed", [2**63]), ("epoch", 2**64), ("consumed", [-1])):
        with pytest.raises(ValueError, match=f"{key}={value if key == 'epoch' else value[0]} not allowed"):
            stream.load_state_dict({**stream.state_dict(), key: value})
    assert stream.state_dict()["consumed"] == [0] and stream.epoch == 0
    # numpy values read back from a saved state: plain numbers in the messages, no np.int64(...)
    for key, value, words in (("seed", np.int64(6), "state has seed=6 but this stream has seed="),
                              ("consumed", [np.uint64(2**63)], "consumed=9223372036854775808 not allowed"),
                              ("consumed", 5, "consumed=5; must be a list of counts"),
                              ("epoch", np.float64(1.0), "epoch=1.0 not allowed")):
        with pytest.raises(ValueError) as err:
            stream.load_state_dict({**stream.state_dict(), key: value})
        assert words in str(err.value) and "np." not in str(err.value)
    with pytest.raises(ValueError, match="not a TrajectoryStream state"):
        stream.load_state_dict({"seed": SEED})


def test_numpy_arguments_are_named_as_plain_numbers(pde):
    for kwargs, words in (({"batch_size": np.int64(-1)}, "batch_size=-1 not allowed"),
                          ({"rank": np.int64(5), "world_size": 2}, "rank=5 not allowed"),
                          ({"seed": np.float32(1.5)}, "seed=1.5 not allowed")):
        with pytest.raises(ValueError) as err:
            TrajectoryStream(pde, **kwargs)
        assert words in str(err.value) and "np." not in str(err.value)


def test_spawned_workers_need_the_main_guard(tmp_path):
    """A script that starts spawn workers from unguarded top-level code gets one clear line, not the
    multiprocessing RuntimeError wall; the same script under `if __name__ == "__main__":` runs."""
    import subprocess
    import sys

    body = ("s = TrajectoryStream(generator.get_pde('burgers1d', n=32, n_frames=3), 0, view='whole', batch_size=2, "
            "n_samples=2)\nprint(sum(len(b['u']) for b in stream_loader(s, num_workers=1)))\n")
    head = "from pdestream import generator\nfrom pdestream.datasets import TrajectoryStream\nfrom pdestream.datasets.stream import stream_loader\n"
    bad, good = tmp_path / "bad.py", tmp_path / "good.py"
    bad.write_text(head + body)
    good.write_text(head + "def main():\n" + "".join("    " + line + "\n" for line in body.splitlines())
                    + "if __name__ == '__main__':\n    main()\n")
    res = subprocess.run([sys.executable, str(bad)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 1 and "RuntimeError" not in res.stderr and "bootstrapping" not in res.stderr
    assert res.stderr.strip() == (  # the one line, no traceback above it (MainGuardError)
        "stream_loader(num_workers=1) starts spawned worker processes, which import bad.py again: "
        "put the code that runs it (line 5) under `if __name__ == \"__main__\":`")
    res = subprocess.run([sys.executable, str(good)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stdout.strip() == "2", res.stderr[-2000:]
