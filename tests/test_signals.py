"""Interrupts: a rollout runs in bounded calls (bit-identical to one call), a cancelled producer stops at the
next call, and a real Ctrl-C (or two) stops `pdestream generate` within seconds, with one line and exit 130,
leaving a cache that does not read as complete and that --resume finishes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import jax.numpy as jnp
import numpy as np
import pytest
import zarr

from pdestream import datasets, generator
from pdestream.datasets.cache import is_complete
from pdestream.generator import chunked, dispatch, sampler
from pdestream.generator.spectral import rollout


def _setup(pde, batch):
    """(params, u0, coefficients) of samples 0..batch-1, as the sampler builds them."""
    keys = sampler.sample_keys(0, np.arange(batch))
    pad = rollout.SETUP_CHUNK - batch
    p = len(pde.PARAMS)
    part = rollout.compiled_setup(pde)(jnp.concatenate([keys, jnp.repeat(keys[:1], pad, 0)]),
                                       np.zeros((rollout.SETUP_CHUNK, p), np.float32),
                                       np.zeros((rollout.SETUP_CHUNK, p), bool))
    return chunked.join([part], batch)


@pytest.mark.parametrize("name, overrides", [
    ("burgers1d", {"n": 32, "n_frames": 5, "t_end": 0.2}),  # nonlinear, 1D
    ("ns2d", {"n": 16, "n_frames": 4, "t_end": 0.3}),  # nonlinear, 2D
    ("grayscott2d", {"n": 16, "n_frames": 3, "t_end": 10}),  # two fields
    ("diffusion1d", {"n": 32, "n_frames": 5}),  # linear: exact exponential steps
])
def test_bounded_calls_give_the_bits_of_one_call(name, overrides):
    pde = generator.get_pde(name, overrides)
    params, u0, coeffs = _setup(pde, 3)
    ref, ref_finite = rollout.compiled_evolve(pde)(u0, params, coeffs)  # the whole rollout in one call
    per_step = 3 * len(pde.FIELDS) * pde.n**pde.NDIM
    # a frame per call; then pieces of a frame (1 step, 2 steps per call); then everything in one call
    for work, overhead in [(per_step * pde.steps_per_frame, 0), (per_step, 0), (2 * per_step, 0), (2**40, 2**13)]:
        with dispatch.call_size(work, overhead):
            [(u, finite)] = rollout.evolve_bounded(pde, [(u0, params, coeffs)])
        assert u.shape == ref.shape
        assert bool(jnp.array_equal(u, ref)), f"{name}: bounded calls ({work} point-steps each) changed the bits"
        assert np.array_equal(finite, ref_finite)
    if pde.NDIM > 1:
        return
    # and through sample(): split into 1-step calls == one call
    with dispatch.call_size(2**40):
        whole = generator.sample(pde, [0, 5, 7], seed=3)
    with dispatch.call_size(1, 0):
        np.testing.assert_array_equal(np.asarray(generator.sample(pde, [0, 5, 7], seed=3).u), np.asarray(whole.u))
    assert (dispatch.work(), dispatch.step_overhead()) == (dispatch.DISPATCH_WORK, dispatch.STEP_OVERHEAD)  # restored


def test_solve_and_advance_run_in_bounded_calls_with_the_bits_of_one_call(monkeypatch):
    """generator.solve and generator.interactive.advance use the rollout's bounded calls (a Ctrl-C or a cancel
    stops them between two), and give the bits of the one-call programs they ran as before."""
    import functools

    import jax

    from pdestream.generator.spectral import interactive

    pde = generator.get_pde("burgers1d", {"n": 32, "n_frames": 4, "t_end": 0.3})
    x = pde.grid.coords()
    u0 = jnp.asarray(np.stack([np.sin(2 * np.pi * x), np.cos(2 * np.pi * x) ** 3])[:, None], jnp.float32)
    p = {"nu": jnp.asarray([0.02, 0.05], jnp.float32)}
    whole = jax.jit(lambda u, q: jax.vmap(functools.partial(rollout._evolve, pde))(
        u, q, jax.lax.map(functools.partial(rollout._coefficients, pde), q)))(u0, p)  # solve's one call
    coeffs = interactive._coefficients_for(pde, p, 2, jax.devices("cpu")[0])
    ahead = jax.jit(jax.vmap(functools.partial(interactive._advance_one, pde, 2)))(u0, p, coeffs)  # advance's
    syncs = []
    monkeypatch.setattr(dispatch, "sync", lambda states, sync=dispatch.sync: syncs.append(1) or sync(states))
    for work, overhead in [(2**40, 2**13), (1, 0), (2 * 32 * 3, 0)]:  # one call; a step per call; 3 steps
        syncs.clear()
        with dispatch.call_size(work, overhead):
            assert bool(jnp.array_equal(generator.solve(pde, u0, p).u, whole))
            solve_calls = len(syncs)
            u2, finite = interactive.advance(pde, u0, p, frames=2)
        assert bool(jnp.array_equal(u2, ahead)) and bool(finite.all())
        steps = pde.steps_per_frame
        assert (solve_calls, len(syncs) - solve_calls) == {2**40: (1, 0), 1: (3 * steps, 2 * steps),
                                                           192: (3 * -(-steps // 3), -(-2 * steps // 3))}[work]
    stop = threading.Event()
    stop.set()
    dispatch.cancel_on(stop)  # a cancelled thread's solve and advance stop at their first call boundary
    try:
        with dispatch.call_size(2 * 32 * 3, 0):  # several calls each (one call has no boundary to stop at)
            with pytest.raises(dispatch.Cancelled):
                generator.solve(pde, u0, p)
            with pytest.raises(dispatch.Cancelled):
                interactive.advance(pde, u0, p)
    finally:
        dispatch.cancel_on(None)


# burgers1d on 32 points with a long t_end: ~1500 steps per frame; the whole batch in one call would take
# tens of seconds, each bounded call a small fraction of a second.
LONG = {"n": 32, "n_frames": 3, "t_end": 12000}


class SyncCount:
    """Counts the bounded calls' host syncs (dispatch.sync), so a test can wait for solving to have started and
    count the calls made after a stop, instead of reading a clock."""

    def __init__(self, monkeypatch):
        self.calls, self.started = 0, threading.Event()
        real = dispatch.sync

        def counted(states):
            self.calls += 1
            self.started.set()
            return real(states)

        monkeypatch.setattr(dispatch, "sync", counted)

    def wait_for_calls(self, n: int = 2) -> None:
        for _ in range(12000):  # a hang guard only (120 s), never a limit on speed
            if self.calls >= n:
                return
            time.sleep(0.01)
        raise AssertionError(f"the solve made {self.calls} bounded calls in 120 s")


def test_a_cancelled_solve_stops_at_the_next_call(monkeypatch):
    pde = generator.get_pde("burgers1d", LONG)
    generator.sample(generator.get_pde("burgers1d", {**LONG, "t_end": 1}), np.arange(8))  # compile first
    count, stop, result = SyncCount(monkeypatch), threading.Event(), {}

    def solve():
        dispatch.cancel_on(stop)
        try:
            generator.sample(pde, np.arange(8))
            result["outcome"] = "finished"
        except dispatch.Cancelled:
            result["outcome"] = "cancelled"

    thread = threading.Thread(target=solve)
    thread.start()
    count.wait_for_calls(2)
    stop.set()
    at_stop = count.calls
    thread.join(120)
    assert result["outcome"] == "cancelled", result
    assert count.calls - at_stop <= 1  # the call in flight, then its sync raises: one bounded call, not the rest


def test_prefetch_close_cancels_its_producer(monkeypatch):
    from pdestream.datasets._prefetch import _LIVE, prefetch

    short, long = generator.get_pde("burgers1d", {**LONG, "t_end": 1}), generator.get_pde("burgers1d", LONG)
    generator.sample(short, np.arange(4))  # compiled
    items = prefetch(lambda: (generator.sample(pde, np.arange(4)) for pde in (short, long, long)))
    next(items)  # the producer now solves the long one
    count = SyncCount(monkeypatch)
    count.wait_for_calls(2)
    items.close()
    at_close = count.calls
    for _ in range(12000):  # hang guard (120 s): the rest of the long solves would take far more calls
        if not any(t.name == "pdestream-prefetch" and t.is_alive() for t in threading.enumerate()):
            break
        time.sleep(0.01)
    assert count.calls - at_close <= 1, "the producer kept solving after its consumer closed it"
    assert not _LIVE or all(not t.is_alive() for _, t in _LIVE)


@pytest.mark.parametrize("producer", ["thread", "process"])
def test_closing_a_reservoir_stops_its_solves(producer, monkeypatch):
    from pdestream.datasets.reservoir import ReservoirStream

    count = SyncCount(monkeypatch)
    stream = ReservoirStream(generator.get_pde("burgers1d", LONG), batch_size=4, capacity=8, solve_batch=4,
                             producer=producer)
    stream._start()  # submits solve jobs
    if producer == "thread":
        count.wait_for_calls(2)  # solving (a process producer solves in another process: nothing to count here)
    else:
        time.sleep(3.0)  # the process is starting up or solving; either way close must not wait for its solve
    closed = threading.Thread(target=stream.close)
    closed.start()
    closed.join(120)  # hang guard: the solve in flight alone takes minutes (LONG), its bounded calls a moment
    assert not closed.is_alive(), "close waited for the solve in flight"
    assert not any(t.name.startswith("pdestream-solver") and t.is_alive() for t in threading.enumerate())


# Samples in the Ctrl-C tests' one block: solving them all takes over 10 minutes on an idle 2-core CPU, so a
# process that waited for the solve to end instead of stopping at the next bounded call runs into the tests'
# 300 s hang guard (no test reads a clock to judge speed).
HUGE_N = 512


def _generate(out, *extra):
    return subprocess.Popen([sys.executable, "-m", "pdestream.cli", "generate", "burgers1d", "--n", str(HUGE_N),
                             "--block", str(HUGE_N),
                             *(f"--set={k}={v}" for k, v in LONG.items()), "--out", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_solving(proc, out, seconds=3.0):
    """Return once ``out`` exists (the cache is created right before the first solve) and ``seconds`` more."""
    deadline = time.monotonic() + 120
    while not out.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(seconds)  # the compile (~1 s) and then the first bounded calls
    assert proc.poll() is None, "the writer ended before the interrupt"


@pytest.mark.parametrize("signals", [1, 2])
def test_ctrl_c_stops_generate_within_seconds(tmp_path, signals):
    out = tmp_path / "a.zarr"
    proc = _generate(out)
    _wait_for_solving(proc, out)
    for _ in range(signals):
        proc.send_signal(signal.SIGINT)
        time.sleep(0.2)
    _, err = proc.communicate(timeout=300)  # hang guard: the block's solve takes far longer (HUGE_N samples)
    assert proc.returncode == 130, err  # never 134 (abort) or -2 (killed by the second SIGINT)
    progress, last = err.splitlines()[:-1], err.splitlines()[-1]  # progress lines, then the one line
    assert last == "pdestream: interrupted; nothing was written" and err.endswith("\n"), err
    assert all(line.startswith("burgers1d: ") for line in progress), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no cache, no hidden work copy, no lock file


def test_ctrl_c_stops_stream_training_within_seconds(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.cli", "train", "burgers1d", "--source", "stream", "--steps", "5",
                             "--batch-size", "4", "--test-samples", "1", *(f"--set={k}={v}" for k, v in LONG.items()),
                             "--model-set", "width=4", "--model-set", "modes=2", "--model-set", "layers=1",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_solving(proc, out / "run.json", seconds=4.0)  # the stream's first solve (normalization) runs
    for _ in range(2):
        proc.send_signal(signal.SIGINT)
        time.sleep(0.2)
    _, err = proc.communicate(timeout=300)  # hang guard: the normalization draw's solve alone takes far longer
    assert proc.returncode == 130, err[-2000:]
    assert err == "pdestream: interrupted; nothing was kept (no checkpoint yet); run the command again to start over\n"
    assert not out.exists()  # the run directory it created, with run.json: the same command starts again


def _live_in_group(pgid: int) -> list[str]:
    """The processes of group ``pgid`` still running (zombies awaiting their reaper left out)."""
    ps = subprocess.run(["ps", "-eo", "pgid=,stat=,args="], capture_output=True, text=True).stdout
    return [line for line in ps.splitlines() if line.split()[0] == str(pgid) and not line.split()[1].startswith("Z")]


PRODUCER_SCRIPT = """
import os, signal, sys, time
from pdestream.datasets.producers import open_producer

if __name__ == "__main__":
    pool, closer, _ = open_producer("process", 2)
    for f in [pool.submit(int) for _ in range(4)]:
        f.result()  # both workers are up, and idle now
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # this process: its owner's Ctrl-C handling, elsewhere
    os.killpg(0, signal.SIGINT)  # a terminal's Ctrl-C reaches the whole process group
    time.sleep(3)
    print(pool.submit(int, "7").result())  # the workers are still there, and work
    closer.close()
"""


def test_a_process_producers_workers_leave_ctrl_c_to_their_owner(tmp_path):
    (tmp_path / "producer.py").write_text(PRODUCER_SCRIPT)
    proc = subprocess.run([sys.executable, str(tmp_path / "producer.py")], capture_output=True, text=True,
                          timeout=300, start_new_session=True)
    assert proc.returncode == 0 and proc.stdout == "7\n", proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "KeyboardInterrupt" not in proc.stderr, proc.stderr[-3000:]


@pytest.mark.slow
def test_ctrl_c_of_ddp_reservoir_training_with_process_producers(tmp_path):
    """A terminal's Ctrl-C reaches the launcher, both ranks and their producers' workers: one line, exit 130, a
    checkpoint to resume from, no traceback from any process and none of them left running."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.cli", "train", "burgers1d", "--ddp", "2", "--reservoir",
                             "--producer", "process", "--workers", "2", "--capacity", "8", "--solve-batch", "4", "--steps", "100000",
                             "--batch-size", "4", "--test-samples", "1", "--checkpoint-every", "5",
                             "--set=n=32", "--set=n_frames=5", "--set=t_end=0.5", "--model-set", "width=4",
                             "--model-set", "modes=2", "--model-set", "layers=1", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    _wait_for_solving(proc, out / "checkpoint.pt", seconds=2.0)  # training, its producers solving or idle
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err[-3000:]
    *progress, last = err.splitlines()
    assert last == f"pdestream: interrupted; {out} holds a checkpoint; pdestream train --resume {out} continues from it"
    assert all(line.startswith("train: ") for line in progress), err[-3000:]
    deadline = time.monotonic() + 30  # the launcher has exited; what it stopped may take a moment to go
    while _live_in_group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _live_in_group(proc.pid) == []
    assert {"checkpoint.pt", "run.json"} <= {p.name for p in out.iterdir()} and not (out / "metrics.json").exists()


def test_ctrl_c_in_compare_removes_the_out_dir_it_created(tmp_path):
    out = tmp_path / "cmp"
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.cli", "compare", "burgers1d", "--modes", "one-step", "--quick",
                             "--steps", "100000", "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    _wait_for_solving(proc, out / "one-step" / "run.json", seconds=1.0)  # the first arm is training
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    assert err == "pdestream: interrupted; nothing was kept (no run had finished)\n"
    assert sorted(tmp_path.iterdir()) == []  # no empty DIR that would need --overwrite


def test_an_interrupt_raised_where_python_cannot_raise_is_sent_again(monkeypatch):
    """A Ctrl-C handled inside a gc callback (JAX has one) or a __del__ cannot raise there: Python prints the
    KeyboardInterrupt and drops it, and the CLI then ignored every later Ctrl-C. Its unraisable hook sends it again."""
    from pdestream import interrupts

    class Dies:
        def __del__(self):
            raise KeyboardInterrupt  # as first_interrupt does when the signal arrives in here

    previous = signal.signal(signal.SIGINT, interrupts.first_interrupt)
    monkeypatch.setattr(sys, "unraisablehook", interrupts.redeliver_interrupt)
    try:
        with pytest.raises(KeyboardInterrupt):
            Dies()  # dropped at once: its __del__ runs
            for _ in range(200):
                time.sleep(0.01)
    finally:
        signal.signal(signal.SIGINT, previous)


def _interrupting(monkeypatch, module, name, at, files):
    """Replace ``module.name`` (a run or a comparison writing to its positional argument ``at``, the output
    directory) by one that writes ``files`` (paths under it) and is then interrupted."""
    import importlib
    from pathlib import Path

    def interrupted(*args, **kwargs):
        out = Path(args[at])
        for f in files:
            (out / f).parent.mkdir(parents=True, exist_ok=True)
            (out / f).write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib.import_module(module), name, interrupted)


TRAIN = ["train", "burgers1d", "--set=n=32", "--set=n_frames=3", "--steps", "5"]


def test_interrupted_train_keeps_a_checkpoint_and_only_what_it_did_not_create(tmp_path, monkeypatch, capsys):
    from pdestream import cli

    out = tmp_path / "run"
    _interrupting(monkeypatch, "pdestream.surrogate.runs", "train_run", 2, ["run.json", "checkpoint.pt"])
    assert cli.main([*TRAIN, "--out", str(out)]) == 130
    assert capsys.readouterr().err == (f"pdestream: interrupted; {out} holds a checkpoint; pdestream train --resume "
                                       f"{out} continues from it\n")
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.pt", "run.json"]
    # --overwrite, no checkpoint yet: the new run (built beside the old one) goes, the old run and the user's file stay
    (out / "checkpoint.pt").unlink()
    (out / "notes.txt").write_text("mine")
    _interrupting(monkeypatch, "pdestream.surrogate.runs", "train_run", 2, ["run.json", "metrics.csv"])
    assert cli.main([*TRAIN, "--out", str(out), "--overwrite"]) == 130
    assert "nothing of the new run was kept (no checkpoint yet)" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "run.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    # a fresh run in a directory that was there: only what the command wrote goes
    (out / "run.json").unlink()
    _interrupting(monkeypatch, "pdestream.surrogate.runs", "train_run", 2, ["run.json", "metrics.csv"])
    assert cli.main([*TRAIN, "--out", str(out)]) == 130
    assert "nothing was kept (no checkpoint yet)" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_interrupted_compare_keeps_finished_runs_and_what_it_did_not_create(tmp_path, monkeypatch, capsys):
    from pdestream import cli

    argv = ["compare", "burgers1d", "--modes", "one-step,pushforward", "--quick", "--out"]
    out = tmp_path / "cmp"
    _interrupting(monkeypatch, "pdestream.experiments.interactive_compare", "interactive_compare", 1,
                  ["one-step/run.json", "one-step/metrics.json", "pushforward/run.json"])
    assert cli.main([*argv, str(out)]) == 130
    assert capsys.readouterr().err == (f"pdestream: interrupted; {out} keeps 1 finished run (one-step/); rerun "
                                       "the same command to go on from them\n")  # (--modes resumes)
    assert sorted(p.name for p in out.iterdir()) == ["one-step", "pushforward"]
    mine = tmp_path / "mine"  # a directory the user made: it stays, with what was in it
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    _interrupting(monkeypatch, "pdestream.experiments.interactive_compare", "interactive_compare", 1, ["one-step/run.json"])
    assert cli.main([*argv, str(mine)]) == 130
    assert capsys.readouterr().err == "pdestream: interrupted; nothing was kept (no run had finished)\n"
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def test_stale_work_copies_of_dead_writers_are_removed_by_the_next_run(tmp_path):
    """kill -9 cannot clean up: a hidden ``.NAME.PID.new/tmp`` sibling stays until the next writer of NAME,
    which removes those whose writer is gone, and leaves a live writer's and anything else alone."""
    import os

    from pdestream import cli

    dead = subprocess.Popen(["true"])
    dead.wait()  # a pid that no longer runs
    out = tmp_path / "a.zarr"
    stale = [tmp_path / f".a.zarr.{dead.pid}.new.zarr", tmp_path / f".a.zarr.{dead.pid}.tmp.zarr"]
    kept = [tmp_path / f".a.zarr.{os.getpid()}.tmp.zarr",  # a live writer's (this process)
            tmp_path / f".a.zarr.{dead.pid}.notes.zarr", tmp_path / ".a.zarr.backup"]  # not a work copy
    for p in stale + kept:
        p.mkdir()
        (p / "zarr.json").write_text("{}")
    assert cli.main(["generate", "burgers1d", "--n", "1", "--set=n=32", "--set=n_frames=3", "--out", str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["a.zarr", *(p.name for p in kept)])


def test_ctrl_c_after_a_block_leaves_a_resumable_cache(tmp_path, capsys):
    out = tmp_path / "a.zarr"
    setting = ["--set=n=32", "--set=n_frames=3", "--set=t_end=300"]  # ~1 s per sample (block of 1)
    args = ["generate", "burgers1d", "--n", "4", "--block", "1", *setting]
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.cli", *args, "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            if (zarr.open_group(out, mode="r")["complete"][:] == 1).sum() >= 1:
                break
        except Exception:  # not created yet
            pass
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, "the writer finished before Ctrl-C: use a slower config"
    assert err.startswith(f"pdestream: interrupted; {out} holds ") and err.endswith(
        " of 4 samples; run the command with --resume added to finish it\n")
    ds = datasets.open_cache(out)
    assert not is_complete(ds)
    ds.close()
    from pdestream import cli

    assert cli.main([*args, "--out", str(out), "--resume"]) == 0
    ref = tmp_path / "ref.zarr"
    assert cli.main([*args, "--out", str(ref)]) == 0
    a, b = datasets.open_cache(out), datasets.open_cache(ref)
    assert is_complete(a)
    np.testing.assert_array_equal(a["u"].values, b["u"].values)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.zarr", "ref.zarr"]


def test_call_size_is_checked_and_restored():
    with pytest.raises(ValueError, match="work=0 not allowed"):
        with dispatch.call_size(0):
            pass
    with dispatch.call_size(7, 1):
        with dispatch.call_size(9):
            assert (dispatch.work(), dispatch.step_overhead()) == (9, dispatch.STEP_OVERHEAD)
        assert (dispatch.work(), dispatch.step_overhead(), dispatch.pieces(5, 3)) == (7, 1, [2, 2, 1])
    assert dispatch.work() == dispatch.DISPATCH_WORK


def test_interrupted_ranks_without_rank_0_s_account_are_described_from_the_disk(tmp_path):
    """When rank 0 leaves no words (its Ctrl-C arrived as a failed collective, or it was stopped), the launcher
    says what the run directory holds and does rank 0's clean-up: a checkpoint is kept for --resume; a new run
    without one is removed, and what was there before stays."""
    from pdestream.interrupts import snapshot
    from pdestream.surrogate.config import TrainConfig
    from pdestream.surrogate.launch import _ranks_left

    tmp = tmp_path / "ranks"
    tmp.mkdir()
    (tmp / "rank1.err").write_text("")  # the other ranks have nothing to say
    kept = tmp_path / "kept"
    cfg = TrainConfig(pde="burgers1d", out=str(kept))
    before = snapshot(kept)
    kept.mkdir()
    (kept / "run.json").write_text("{}")
    (kept / "checkpoint.pt").write_bytes(b"")
    assert _ranks_left(tmp, cfg, [], before) == (f"{kept} holds a checkpoint; pdestream train --resume {kept} "
                                                  "continues from it")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    before = snapshot(mine)
    (mine / "run.json").write_text("{}")
    cfg = TrainConfig(pde="burgers1d", out=str(mine))
    assert _ranks_left(tmp, cfg, [], before) == "nothing was kept (no checkpoint yet); run the command again to start over"
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    (tmp / "rank0.err").write_text("rank 0's words")
    assert _ranks_left(tmp, cfg, [], before) == "rank 0's words"
