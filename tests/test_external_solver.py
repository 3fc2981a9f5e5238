"""Any solver as a producer (generator.ExternalSolver, issue 19 item 2): bit-identical replay alone / batched /
streamed / cached, one line per failure (raises, NaN, wrong shape, timeout, crash, command exits non-zero), the
raise / redraw / skip policies, caches never complete after a failure, the CLI path, a worker killed mid-solve.

The solvers live in tests/external_solvers.py: worker processes import them by their module's name."""

import dataclasses
import os
import signal
import threading
import time
import warnings

import numpy as np
import pytest
import torch
from external_solvers import Cmd, CmdH5, CoordinateNamedParam, Decay, Faulty, Noisy, NoSolve

from pdestream import cli, datasets, generator
from pdestream.generator.external import solver as external
from pdestream.generator.sampler import SkippedSamples

pytestmark = pytest.mark.usefixtures("solver_settings")  # (tests/conftest.py)


def u_of(traj) -> np.ndarray:
    return np.asarray(traj.u)


def by_hand(pde, k: float, seed: int) -> np.ndarray:
    """Decay's closed form with the seed's white noise (not the worker's output)."""
    u0 = np.random.default_rng(seed).standard_normal(pde.n)
    return np.exp(-k * pde.times())[:, None, None] * u0[None, None, :]


def test_a_sample_is_the_solvers_output_for_its_drawn_params_and_seed():
    pde = Decay()
    traj = generator.sample(pde, [0, 1, 2], seed=5)
    assert traj.u.shape == (3, 5, 1, 16) and traj.u.dtype == np.float32
    # the parameters and the solver seed are the key's, as the sampler draws them
    for b, i in enumerate([0, 1, 2]):
        key = generator.sample_keys(5, np.array([i]))[0]
        params, seed = external._draw(pde, key, np.zeros(1, np.float32), np.zeros(1, bool))
        assert float(params["k"]) == float(traj.params["k"][b])
        assert np.array_equal(u_of(traj)[b], by_hand(pde, float(params["k"]), seed).astype(np.float32))
    assert 0.5 <= float(traj.params["k"].min()) and float(traj.params["k"].max()) <= 2.0
    assert "solved by Decay.solve" in pde.describe() and "NOT reproducible" not in pde.describe()


def test_replay_is_bit_identical_alone_batched_in_workers_in_process_and_by_command(monkeypatch):
    pde = Decay()
    batch = u_of(generator.sample(pde, [3, 4, 5, 6], seed=1))
    alone = np.stack([u_of(generator.sample(pde, [i], seed=1))[0] for i in (3, 4, 5, 6)])
    assert np.array_equal(batch, alone)
    external.configure(workers=2)
    assert np.array_equal(u_of(generator.sample(pde, [3, 4, 5, 6], seed=1)), batch)
    external.configure(workers=0)
    assert np.array_equal(u_of(generator.sample(pde, [3, 4, 5, 6], seed=1)), batch)
    external.configure(workers=1)
    for cmd in (Cmd(), CmdH5()):  # a command line writing .npy / .h5 gives the same bits as solve()
        assert np.array_equal(u_of(generator.sample(cmd, [3, 4, 5, 6], seed=1)), batch)
    # explicit parameters equal to the drawn ones: the same sample
    k = np.asarray(generator.sample(pde, [3, 4], seed=1).params["k"])
    assert np.array_equal(u_of(generator.sample(pde, [3, 4], seed=1, params={"k": k})), batch[:2])
    # identity: the config carries the class's origin
    assert pde.config()["origin"]["class"] == "Decay" and pde.config()["origin"]["source_sha256"]


@pytest.mark.parametrize("suffix", [".h5", ".zarr"])
def test_streamed_and_cached_samples_are_the_sampled_ones(tmp_path, suffix):
    pde = Decay()
    want = u_of(generator.sample(pde, list(range(6)), seed=2))
    stream = datasets.TrajectoryStream(pde, seed=2, view="whole", batch_size=3, n_samples=6, solve_batch=4,
                                       shuffle=False)
    got = {int(i): u for b in stream for i, u in zip(b["index"], b["u"])}
    assert sorted(got) == list(range(6)) and all(np.array_equal(got[i].numpy(), want[i]) for i in range(6))
    path = tmp_path / f"d{suffix}"
    datasets.write_cache(pde, path, 6, seed=2, block=4, progress=False)
    cached = datasets.CachedTrajectories(path, view="whole")
    assert np.array_equal(np.stack([cached[i]["u"].numpy() for i in range(6)]), want)


CAUSES = {
    "raise": "raised RuntimeError: no convergence in the Newton loop",
    "nan": "returned NaN/Inf (first in frame 2",
    "shape": "returned shape (5, 16); expected (5, 1, 16)",
    "complex": "returned complex values (dtype complex128); a sample holds real fields",
    "crash": "crashed: its worker process ended mid-solve (exit code 3) (solved 2 times)",
}


@pytest.mark.parametrize("fail", list(CAUSES))
def test_each_failure_is_one_line_naming_the_sample_its_params_and_the_cause(fail):
    with pytest.raises(generator.BlowUpError) as err:
        generator.sample(Faulty(fail=fail), list(range(6)), seed=0)
    text = str(err.value)
    assert "\n" not in text and CAUSES[fail] in text, text
    assert "1 of 6 samples failed in the external solver: index 0:" in text and "params q=0.0717" in text


def test_a_solve_past_the_timeout_is_one_line_and_its_worker_is_replaced():
    external.configure(timeout=1.0)  # the hung solve sleeps 60 s: without the timeout it would end in another error
    with pytest.raises(generator.BlowUpError, match=r"index 0: timed out after 1 s \(--solver-timeout\); its "
                                                    r"worker was stopped \(params q=0.0717") as err:
        generator.sample(Faulty(fail="hang"), list(range(3)), seed=0)
    assert "\n" not in str(err.value)
    # the next solves run in a fresh worker
    assert generator.sample(Faulty(fail="hang"), [1, 2], seed=0).u.shape[0] == 2


def test_a_command_that_exits_non_zero_is_one_line_with_its_last_stderr_line():
    with pytest.raises(generator.BlowUpError) as err:
        generator.sample(Cmd(exit_code=4), [0, 1], seed=0)
    text = str(err.value)
    assert "\n" not in text and "2 of 2" in text
    assert "raised RuntimeError: command exited with code 4: solver: the mesh is inverted" in text


def test_bad_classes_and_values_are_one_line_each():
    with pytest.raises(ValueError, match=r"class NoSolve lacks the required method solve\(self, params, seed\) "
                                         r"\(or a COMMAND\)$"):
        NoSolve()
    for fields in ((), ("u", "u"), ("u", ""), ["u"]):  # () divided by zero when a cache was sized
        bad = dataclasses.dataclass(frozen=True)(type("Bad", (Decay,), {"FIELDS": fields, "__module__": __name__}))
        with pytest.raises(ValueError, match=r"^decay_ext1d: FIELDS=.* not allowed: "):
            bad()
    with pytest.raises(ValueError, match="--solver-workers=-1 not allowed"):
        external.configure(workers=-1)
    with pytest.raises(ValueError, match="--solver-timeout=0 not allowed"):
        external.configure(timeout=0)
    with pytest.raises(ValueError, match=r"--solver-timeout=5 not allowed with --solver-workers 0"):
        external.configure(workers=0, timeout=5)  # the solve then hung past the timeout
    assert external.settings() == (1, None)  # a refused call changes nothing
    with pytest.raises(ValueError, match="on_blowup='drop' not allowed; allowed: 'raise', 'redraw', 'skip'"):
        generator.sample(Decay(), [0], on_blowup="drop")


def test_redraw_replaces_failed_samples_deterministically_and_skip_leaves_them_out():
    pde = Faulty(fail="nan")
    ok = u_of(generator.sample(Faulty(fail="none"), list(range(6)), seed=0))
    redrawn = generator.sample(pde, list(range(6)), seed=0, on_blowup="redraw")
    assert redrawn.redraws.tolist() == [1, 0, 0, 0, 0, 0] and np.isfinite(u_of(redrawn)).all()
    assert np.array_equal(u_of(redrawn)[1:], ok[1:]) and float(redrawn.params["q"][0]) >= 0.3
    again = generator.sample(pde, list(range(6)), seed=0, on_blowup="redraw")
    assert np.array_equal(u_of(again), u_of(redrawn))
    skipped = generator.sample(pde, list(range(6)), seed=0, on_blowup="skip")
    assert skipped.indices.tolist() == [1, 2, 3, 4, 5] and np.array_equal(u_of(skipped), ok[1:])
    assert len(skipped.skipped) == 1 and "skipped sample index 0: returned NaN/Inf" in skipped.skipped[0]


def test_the_stream_skips_with_one_warning_per_sample():
    pde = Faulty(fail="raise", threshold=0.5)
    stream = datasets.TrajectoryStream(pde, seed=0, view="whole", batch_size=4, n_samples=8, solve_batch=4,
                                       shuffle=False, on_blowup="skip")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        got = [int(i) for b in stream for i in b["index"]]
    x = np.asarray(generator.sample(Faulty(fail="none"), list(range(8)), seed=0).params["q"])
    assert got == [i for i in range(8) if x[i] >= 0.5] and 0 < len(got) < 8
    lines = [str(w.message) for w in seen if issubclass(w.category, SkippedSamples)]
    assert len(lines) == 8 - len(got) and all("raised RuntimeError: no convergence" in s for s in lines)


def test_the_reservoir_takes_an_external_solver_with_loss_driven_sampling_and_skip():
    pde = Faulty(fail="shape", threshold=0.2)
    stream = datasets.ReservoirStream(pde, seed=0, view="whole", batch_size=4, capacity=16, solve_batch=4,
                                      warmup=4, mode="deterministic", proposal="loss", sim_budget=12,
                                      on_blowup="skip")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        batches = []
        for batch in stream:
            batches.append(batch)
            stream.report_losses(batch, batch["u"].flatten(1).abs().mean(1))
    stream.close()
    skipped = [w for w in seen if issubclass(w.category, SkippedSamples)]
    held = {int(i) for b in batches for i in b["index"]}
    assert stream.stats()["skipped"] == len(skipped) == 12 - stream.stats()["inserted"]
    assert held and all(float(p) >= 0.2 for b in batches for p in b["params"][:, 0])
    # a sample's bits are its sample()'s, whatever the proposal chose for its parameters
    b = batches[0]
    one = generator.sample(pde, [int(b["index"][0])], seed=0, params={"q": [float(b["params"][0, 0])]})
    assert np.array_equal(b["u"][0].numpy(), u_of(one)[0])


def test_a_failed_cache_never_reads_complete_and_skip_is_refused(tmp_path):
    """Seed 5: samples 0-3 solve, sample 4 fails (q = 0.25 < 0.3): blocks of 2 before it are written, the cache
    stays incomplete, and what it holds are the samples' own bits."""
    pde = Faulty(fail="raise")
    path = tmp_path / "f.zarr"
    with pytest.raises(generator.BlowUpError, match="index 4: raised RuntimeError: no convergence"):
        datasets.write_cache(pde, path, 8, seed=5, block=2, progress=False)
    with datasets.open_cache(path) as ds:
        done = np.flatnonzero(ds["complete"].values == 1)
        assert not datasets.cache.is_complete(ds) and set(done) <= {0, 1, 2, 3}
        assert np.array_equal(ds["u"].values[done], u_of(generator.sample(pde, done, seed=5))[:, :, 0])
    with pytest.raises(ValueError, match="incomplete"):
        datasets.CachedTrajectories(path)
    with pytest.raises(ValueError, match="on_blowup='skip' not allowed for a cache: a cache holds every index"):
        datasets.write_cache(Decay(), tmp_path / "s.h5", 4, on_blowup="skip", progress=False)
    assert not (tmp_path / "s.h5").exists()


def test_a_solver_that_is_not_deterministic_says_so():
    assert "NOT reproducible: the solver is not deterministic" in Noisy().describe()
    assert "NOT reproducible" not in Decay().describe()


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_generate_by_import_path_and_one_line_errors(tmp_path, capsys, monkeypatch):
    out = tmp_path / "c.h5"
    code, stdout, err = run(capsys, "generate", "--pde", "external_solvers:Decay", "--n", "4", "--out", str(out),
                            "--solver-workers", "2", "--solver-timeout", "30", "--set", "n=8")
    assert code == 0 and "wrote 4 samples" in stdout, err
    with datasets.open_cache(out) as ds:
        assert np.array_equal(ds["u"].values, u_of(generator.sample(Decay(n=8), range(4), seed=0))[:, :, 0])
    code, stdout, err = run(capsys, "list", "external_solvers:Decay")
    assert code == 0 and "solved by Decay.solve" in stdout and "k ~ uniform(0.5, 2.0)" in stdout
    monkeypatch.setenv(external.TIMEOUT_ENV, "")
    cases = [
        (["--pde", "external_solvers:Faulty", "--set", "fail=shape"], "index 0: returned shape (5, 16)"),
        (["--pde", "external_solvers:Faulty", "--set", "fail=hang", "--solver-timeout", "1"], "index 0: timed out"),
        (["--pde", "external_solvers:NoSolve"], "lacks the required method solve(self, params, seed)"),
        (["--pde", "external_solvers_missing:Decay"], "module 'external_solvers_missing' does not import"),
        (["--pde", "external_solvers:Decay", "--on-blowup", "skip"], "a cache holds every index"),
        (["--pde", "external_solvers:Decay", "--solver-workers", "-2"], "--solver-workers=-2 not allowed"),
    ]
    for i, (extra, needle) in enumerate(cases):
        code, stdout, err = run(capsys, "generate", "--n", "4", "--out", str(tmp_path / f"e{i}.zarr"), *extra)
        assert code == 2 and err.count("\n") == 1 and needle in err and "Traceback" not in err, (extra, err)


def test_a_worker_killed_mid_solve_is_replaced_and_the_job_run_again():
    """kill -9 of a solver worker while it solves: the sample is solved again in a fresh worker; the result is
    the bits of an undisturbed run."""
    pde = Decay(delay=1.0)
    want = u_of(generator.sample(Decay(), [0, 1], seed=3))
    external._stop_all(exiting=False)  # the victim is one of this run's two workers
    external.configure(workers=2)
    generator.sample(pde, [0, 1], seed=3)  # workers up
    before = {p.pid for p in external._PROCS}
    assert len(before) == 2
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("traj", generator.sample(pde, [0, 1], seed=3)))
    thread.start()
    time.sleep(0.5)
    victim = sorted(before)[0]
    os.kill(victim, signal.SIGKILL)
    thread.join(30)
    assert not thread.is_alive() and np.array_equal(u_of(result["traj"]), want)
    assert victim not in {p.pid for p in external._PROCS}


def test_train_through_the_reservoir_by_import_path(tmp_path, capsys):
    code, out, err = run(capsys, "train", "--pde", "external_solvers:Decay", "--reservoir", "--capacity", "8",
                         "--solve-batch", "4", "--warmup", "4", "--batch-size", "4", "--view", "next_step",
                         "--steps", "3", "--test-samples", "4", "--on-blowup", "skip", "--out", str(tmp_path / "r"),
                         "--solver-workers", "2")
    assert code == 0 and "trained fno" in out, err
    assert isinstance(torch.load(tmp_path / "r" / "checkpoint.pt", weights_only=False), dict)


@pytest.mark.slow
def test_dask_and_process_producers_run_external_solves():
    pde = Decay()
    want = u_of(generator.sample(pde, list(range(8)), seed=0))
    for producer in ("process", "dask"):
        stream = datasets.ReservoirStream(pde, seed=0, view="whole", batch_size=4, capacity=8, solve_batch=4,
                                          warmup=8, mode="deterministic", producer=producer, workers=2, sim_budget=8,
                                          max_reuse=1)
        got = {int(i): u.numpy() for b in stream for i, u in zip(b["index"], b["u"])}
        stream.close()
        assert sorted(got) == list(range(8)) and all(np.array_equal(got[i], want[i]) for i in got), producer


def test_oracle_mode_refuses_an_external_solver_in_one_line(tmp_path, capsys):
    code, out, err = run(capsys, "train", "--pde", "external_solvers:Decay", "--mode", "oracle", "--steps", "2",
                         "--out", str(tmp_path / "o"))
    assert code == 2 and err.count("\n") == 1 and "does not advance a given state" in err, err
    assert not (tmp_path / "o").exists()


def test_a_padded_batch_solves_each_sample_once(monkeypatch):
    calls = []
    real = external.solve_all
    monkeypatch.setattr(external, "solve_all", lambda pde, jobs: calls.append(len(jobs)) or real(pde, jobs))
    traj = generator.sample(Decay(), [3, 4, 3, 4, 3], seed=0)
    assert calls == [2] and np.array_equal(u_of(traj)[2], u_of(traj)[0])


@pytest.mark.parametrize("suffix", ["h5", "zarr"])
def test_a_parameter_named_like_a_coordinate_is_refused_before_writing(tmp_path, suffix):
    # Zarr failed half-way ("array exists at path 'x'"); now one line names the clash and nothing is written
    path = tmp_path / f"c.{suffix}"
    with pytest.raises(ValueError, match=r"parameter\(s\) \['x'\] would be stored under a name the cache already"):
        datasets.write_cache(CoordinateNamedParam(), path, 2, progress=False)
    assert not path.exists() and not list(tmp_path.iterdir())


def test_a_solver_worker_leaves_out_the_malloc_setting_of_a_dask_nanny(monkeypatch):
    """A Dask nanny starts its worker with MALLOC_TRIM_THRESHOLD_=65536 (distributed.nanny.pre-spawn-environ); a solver
    worker started there must not inherit it: it fixes glibc's mmap threshold, and a NumPy solver on 160 KB arrays
    spent 2.2x the CPU per solve (every array mapped and zero-filled afresh). Other variables, and a user's own value,
    are passed on."""
    pytest.importorskip("distributed")  # (Dask loaded: as in a Dask worker process)
    import dask

    dask_value = str(dask.config.get("distributed.nanny.pre-spawn-environ")["MALLOC_TRIM_THRESHOLD_"])
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", dask_value)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    env = external._solver_env()
    assert "MALLOC_TRIM_THRESHOLD_" not in env and env["OMP_NUM_THREADS"] == "1"
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == dask_value  # the caller's own environment is untouched
    if os.path.exists("/proc/self/environ"):  # the worker process itself (Linux)
        proc = external._start_worker()
        try:
            for _ in range(100):  # (read empty for a moment after the exec)
                with open(f"/proc/{proc.pid}/environ", "rb") as f:
                    names = {kv.split(b"=", 1)[0] for kv in f.read().split(b"\0")}
                if b"PATH" in names:
                    break
                time.sleep(0.1)
            assert b"MALLOC_TRIM_THRESHOLD_" not in names and b"OMP_NUM_THREADS" in names
        finally:
            external._kill(proc)
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "1048576")  # not Dask's value: the user's, kept
    assert external._solver_env()["MALLOC_TRIM_THRESHOLD_"] == "1048576"
