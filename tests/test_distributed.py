"""Dask generation against the single-process writer (bit for bit, with a worker killed mid-run, on resume)
and 2-rank streaming over torch.distributed (gloo, meeting through a file). Tiny: burgers1d n=32, 5 frames, 12 samples,
blocks of 4. Each test that starts a Dask cluster costs ~10-20 s of start-up on 2 cores."""

import json
import logging
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from pdestream import cli, generator
from pdestream.datasets import open_cache, write_cache
from pdestream.datasets.distributed import _worker_env, write_cache_dask
from pdestream.datasets.store import format_of

try:
    import cloudpickle
    from distributed import Client, LocalCluster, WorkerPlugin

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import this test module
except ImportError:  # the optional dask extra: its tests report a skip with the reason, the rank test still runs
    LocalCluster, WorkerPlugin = None, object
needs_dask = pytest.mark.skipif(LocalCluster is None, reason="dask not installed: pip install -e '.[dask]'")

N, BLOCK, SEED = 12, 4, 3
SETTINGS = {"n": "32", "n_frames": "5"}


@pytest.fixture(scope="module")
def pde():
    return generator.get_pde("burgers1d", SETTINGS)


@pytest.fixture(scope="module")
def reference(pde, tmp_path_factory):
    """The single-process cache the Dask runs must reproduce."""
    path = tmp_path_factory.mktemp("ref") / "ref.zarr"
    write_cache(pde, path, N, seed=SEED, block=BLOCK, progress=False)
    return path


@pytest.fixture(scope="module")
def cluster():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR, env=_worker_env()) as c:
        yield c


def assert_same_cache(got, want):
    a, b = open_cache(got), open_cache(want)
    assert sorted(a.variables) == sorted(b.variables)
    for name in b.variables:
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)
    assert a.attrs == b.attrs  # includes pdestream_complete == 1
    assert not np.isnan(a["u"].values).any()


@needs_dask
def test_two_workers_equal_single_process_bit_for_bit(pde, reference, tmp_path, monkeypatch):
    import dask

    spawn_env = dask.config.get("distributed.nanny.pre-spawn-environ")  # MALLOC_TRIM_THRESHOLD_, OMP_NUM_THREADS...
    for name in spawn_env:
        monkeypatch.delenv(name, raising=False)
    out = tmp_path / "dask.zarr"
    done = write_cache_dask(pde, out, N, seed=SEED, workers=2, block=BLOCK, progress=False)  # embedded cluster
    # its nannies wrote these into this process's environment to pass them on: undone (a solver worker started
    # here later inherited MALLOC_TRIM_THRESHOLD_ and spent 2.2x the CPU per NumPy solve)
    assert not set(spawn_env) & set(os.environ)
    assert (done.written, done.n_samples) == (N, N)
    assert_same_cache(out, reference)
    ref = np.asarray(generator.sample(pde, [5], SEED).u[0])  # sample 5 solved alone, not by any writer
    np.testing.assert_array_equal(open_cache(out)["u"].values[5], ref[:, 0])


class KillOnce(WorkerPlugin):
    """Kills its worker process the first time a worker starts the task of block [4, 8)."""

    def __init__(self, marker: str):
        self.marker = marker

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and str(key).endswith("-4-8") and not os.path.exists(self.marker):
            open(self.marker, "w").close()
            os._exit(1)


@needs_dask
def test_killed_worker_block_is_redone(pde, reference, cluster, tmp_path):
    marker = tmp_path / "killed"
    with Client(cluster) as client:
        client.register_plugin(KillOnce(str(marker)), name="kill-once")
        before = set(client.scheduler_info()["workers"])
        out = tmp_path / "dask.zarr"
        done = write_cache_dask(pde, out, N, seed=SEED, scheduler=cluster.scheduler_address, block=BLOCK,
                                progress=False)
        client.wait_for_workers(2, timeout=60)
        after = set(client.scheduler_info()["workers"])
        client.unregister_worker_plugin("kill-once")
    assert marker.exists() and before != after  # a worker really died (the nanny started a new one)
    assert done.written == N
    assert_same_cache(out, reference)


@needs_dask
def test_running_tasks_report_their_block_fractions_to_the_client(pde, reference, cluster, tmp_path, monkeypatch):
    from pdestream.datasets import distributed

    monkeypatch.setenv("PDESTREAM_PROGRESS", "1")  # tests/conftest.py turns progress off; the events go with it
    events = []
    counted = distributed.BlockCount.event

    def event(self, ev):  # the client's handler of the tasks' events (this process)
        events.append(ev[1])
        counted(self, ev)

    monkeypatch.setattr(distributed.BlockCount, "event", event)
    out = tmp_path / "dask.zarr"
    write_cache_dask(pde, out, N, seed=SEED, scheduler=cluster.scheduler_address, block=BLOCK, progress=True)
    blocks = {(lo, lo + BLOCK) for lo in range(0, N, BLOCK)}
    assert events and all((lo, hi) in blocks and 0 < f <= 1 for lo, hi, f in events), events
    assert_same_cache(out, reference)


@needs_dask
def test_resume_redoes_only_missing_blocks_and_hdf5_is_refused(pde, reference, cluster, tmp_path):
    with pytest.raises(ValueError, match="one writer per file"):
        write_cache_dask(pde, tmp_path / "x.h5", N, seed=SEED, block=BLOCK)
    assert not (tmp_path / "x.h5").exists()
    out = tmp_path / "resume.zarr"
    write_cache(pde, out, N, seed=SEED, block=BLOCK, progress=False)
    fmt = format_of(out)
    store = fmt.open(out, writable=True)  # as if the run died while writing block [4, 8)
    store["u"][4:8] = np.zeros((4, pde.n_frames, pde.n), np.float32)
    store["complete"][4:8] = np.zeros(4, np.int8)
    fmt.mark_complete(store, value=0)
    store.close()
    with pytest.raises(FileExistsError):
        write_cache_dask(pde, out, N, seed=SEED, scheduler=cluster.scheduler_address, block=BLOCK)
    done = write_cache_dask(pde, out, N, seed=SEED, scheduler=cluster.scheduler_address, resume=True,
                            progress=False)
    assert done.written == BLOCK
    assert_same_cache(out, reference)
    # nothing left to do: no scheduler is contacted (this address would fail after a 20 s timeout)
    assert write_cache_dask(pde, out, N, seed=SEED, scheduler="tcp://127.0.0.1:1", resume=True).written == 0


@needs_dask
def test_cli_dask_executor_and_its_errors(reference, cluster, tmp_path, capsys):
    small = ["generate", "burgers1d", "--n", str(N), "--seed", str(SEED), "--block", str(BLOCK),
             *[a for k, v in SETTINGS.items() for a in ("--set", f"{k}={v}")]]
    out = tmp_path / "cli.zarr"
    assert cli.main([*small, "--out", str(out), "--executor", "dask", "--scheduler", cluster.scheduler_address]) == 0
    assert f"wrote {N} samples" in capsys.readouterr().out
    assert_same_cache(out, reference)
    for extra, message in ((["--out", str(tmp_path / "a.h5"), "--executor", "dask"], "one writer per file"),
                           (["--out", str(tmp_path / "b.zarr"), "--workers", "2"], "go with --executor dask"),
                           (["--out", str(tmp_path / "c.zarr"), "--executor", "dask", "--workers", "2",
                             "--scheduler", "tcp://127.0.0.1:1"], "with --scheduler the cluster has its own")):
        assert cli.main([*small, *extra]) == 2
        err = capsys.readouterr().err
        assert err.startswith("pdestream: error: ") and message in err and err.count("\n") == 1, err


STARTUP_S = 180  # the longest a scheduler or worker process may take to come up (2 loaded cores: tens of seconds)


def _start_dask_process(args, log_path, env) -> subprocess.Popen:
    """``python -m distributed.cli.<args>`` (what ``dask scheduler`` / ``dask worker`` run) in its own process group,
    its output in a log file (read on failure)."""
    log = open(log_path, "w")
    try:
        return subprocess.Popen([sys.executable, "-m", *args], stdout=log, stderr=subprocess.STDOUT, env=env,
                                process_group=0)
    finally:
        log.close()


def _stop_dask_process(proc: subprocess.Popen) -> None:
    """SIGTERM to its process group (a worker's nanny and the worker it spawned), a bounded wait, then SIGKILL."""
    for sig, wait_s in ((signal.SIGTERM, 30), (signal.SIGKILL, 10)):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            proc.wait(wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


def _scheduler_address(path, proc, log_path) -> str:
    """The address a ``dask scheduler --scheduler-file`` wrote, waiting at most STARTUP_S seconds."""
    for _ in range(STARTUP_S * 10):
        if proc.poll() is not None:
            pytest.fail(f"dask scheduler exited with {proc.returncode}: {open(log_path).read()[-2000:]}")
        try:
            return json.loads(path.read_text())["address"]
        except (OSError, ValueError, KeyError):
            time.sleep(0.1)
    pytest.fail(f"no scheduler address after {STARTUP_S} s: {open(log_path).read()[-2000:]}")


@needs_dask
@pytest.mark.slow
def test_cluster_of_separate_processes_equals_single_process_bit_for_bit(pde, reference, tmp_path):
    """docs/guides/dask.md, "A cluster of machines": a scheduler and two workers started as separate processes
    (``dask scheduler``, ``dask worker ADDRESS --nworkers 1 --nthreads 1`` with the documented environment), each
    worker standing in for a machine; write_cache_dask(..., scheduler=address) writes the plain cache bit for bit."""
    env = {**os.environ, **_worker_env()}  # JAX on the CPU, one XLA thread (as docs/guides/dask.md says)
    procs = []
    try:
        file, log = tmp_path / "scheduler.json", tmp_path / "scheduler.log"
        procs.append(_start_dask_process(["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
                                          "--no-dashboard", "--scheduler-file", str(file)], log, env))
        address = _scheduler_address(file, procs[0], log)
        assert address.startswith("tcp://127.0.0.1:")
        for i in range(2):  # two "machines"
            procs.append(_start_dask_process(
                ["distributed.cli.dask_worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                 "--no-dashboard", "--name", f"node-{i}", "--local-directory", str(tmp_path / f"node-{i}"),
                 "--death-timeout", "60"], tmp_path / f"node-{i}.log", env))
        with Client(address, timeout="60s", set_as_default=False) as client:
            try:
                client.wait_for_workers(2, timeout=STARTUP_S)
            except TimeoutError:
                logs = "; ".join(open(tmp_path / f"node-{i}.log").read()[-1000:] for i in range(2))
                pytest.fail(f"the 2 workers did not join within {STARTUP_S} s: {logs}")
            names = sorted(w["name"] for w in client.scheduler_info()["workers"].values())
            assert names == ["node-0", "node-1"]
            for w in client.run(lambda: os.environ.get("XLA_FLAGS", "")).values():
                assert "--xla_cpu_multi_thread_eigen=false" in w
        out = tmp_path / "cluster.zarr"
        done = write_cache_dask(pde, out, N, seed=SEED, scheduler=address, block=BLOCK, progress=False)
        assert (done.written, done.n_samples) == (N, N)
        assert_same_cache(out, reference)
    finally:
        for proc in reversed(procs):  # the workers first, then the scheduler
            _stop_dask_process(proc)


RANK = r"""
import json, sys
import numpy as np, torch.distributed as dist
from torch.utils.data import DataLoader
from pdestream import generator
from pdestream.datasets.stream import TrajectoryStream

rank, store, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
dist.init_process_group("gloo", init_method=f"file://{store}", rank=rank, world_size=2)
pde = generator.get_pde("burgers1d", json.loads(sys.argv[4]))
stream = TrajectoryStream(pde, seed=int(sys.argv[5]), view="whole", batch_size=3, n_samples=11, solve_batch=4)
u = {int(i): x.numpy() for b in DataLoader(stream, batch_size=None) for i, x in zip(b["index"], b["u"])}
everyone = [None, None]
dist.all_gather_object(everyone, sorted(u))
np.savez(out, placement=np.array(stream.placement()), gathered=np.array(json.dumps(everyone)),
         **{f"u{i}": x for i, x in u.items()})
dist.destroy_process_group()
"""


def test_two_ranks_stream_disjoint_samples_whose_union_is_complete(pde, tmp_path):
    # rendezvous through a file (torch's FileStore), not a port: no bind-close-reuse race with other processes
    store, env = tmp_path / "rendezvous", {**os.environ, "JAX_PLATFORMS": "cpu"}
    procs = [subprocess.Popen([sys.executable, "-c", RANK, str(r), str(store), str(tmp_path / f"rank{r}.npz"),
                               json.dumps(SETTINGS), str(SEED)], env=env, stderr=subprocess.PIPE, text=True)
             for r in (0, 1)]
    errors = [p.communicate(timeout=180)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errors
    got = [np.load(tmp_path / f"rank{r}.npz") for r in (0, 1)]
    for r in (0, 1):
        assert got[r]["placement"].tolist() == [r, 2]  # rank and world size came from torch.distributed
    gathered = [json.loads(str(g["gathered"])) for g in got]
    assert gathered[0] == gathered[1]  # all_gather_object agrees on both ranks
    ranks = gathered[0]
    assert set(ranks[0]).isdisjoint(ranks[1]) and sorted(ranks[0] + ranks[1]) == list(range(11))
    assert ranks[0] == list(range(0, 11, 2))
    for r, i in ((0, 4), (1, 9)):  # streamed on a rank == solved alone here, bit for bit
        np.testing.assert_array_equal(got[r][f"u{i}"], np.asarray(generator.sample(pde, [i], SEED).u[0]))
