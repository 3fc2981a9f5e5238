"""Progress of long solves: the dispatch hook (reports inside a solve, bits unchanged), the Meter's count, rate and
time left (a fake clock: no wall times asserted), generate's plain lines off a terminal, and a phase's count."""

import itertools
import json

import numpy as np
import pytest

from pdestream import cli, generator, meter
from pdestream.generator import dispatch
from pdestream.generator.flow.problem import FlowProblem
from pdestream.surrogate.phases import phase

SPECTRAL = dict(n=32, n_frames=6)


@pytest.fixture(autouse=True)
def _progress_on(monkeypatch):
    monkeypatch.setenv("PDESTREAM_PROGRESS", "1")  # tests/conftest.py turns it off for every other test


def test_pdestream_progress_0_turns_a_meter_off(monkeypatch, capsys):
    monkeypatch.setenv("PDESTREAM_PROGRESS", "0")
    m = meter.Meter("karman2d", 4, "samples", clock=lambda: 100.0, terminal=False, live=False)
    assert not m.enabled and not m.tick(100.0) and capsys.readouterr().err == ""
FLOW = dict(n=16, radius="uniform(0.15, 0.2)", re="uniform(20, 40)", t_start=0.3, t_end=0.6, n_frames=3)


def solve_reporting(pde, indices, seed=1, work=None):
    """(u as numpy, [(done, total)] reported by the solve) with calls of ``work`` point-steps (several calls)."""
    reports = []
    with dispatch.call_size(work or dispatch.DISPATCH_WORK), dispatch.progress_to(lambda d, t: reports.append((d, t))):
        u = np.asarray(generator.sample(pde, indices, seed=seed).u)
    return u, reports


def check_fractions(reports):
    assert len(reports) >= 3  # split into several calls
    fractions = [d / t for d, t in reports]
    assert all(b > a for a, b in itertools.pairwise(fractions)) and fractions[-1] == 1.0
    assert len({t for _, t in reports}) == 1


@pytest.mark.parametrize("name, settings, work", [
    ("burgers1d", SPECTRAL, 2**10),
    pytest.param("karman2d", FLOW, 2**12, marks=pytest.mark.slow),  # flow compiles: ~35 s on 2 loaded cores
])
def test_a_solve_reports_increasing_fractions_ending_at_one_and_the_same_bits(name, settings, work):
    pde = generator.get_pde(name, **settings)
    u, reports = solve_reporting(pde, [0, 3], work=work)
    check_fractions(reports)
    with dispatch.call_size(work):  # the same calls without a callback: the same bits
        quiet = np.asarray(generator.sample(pde, [0, 3], seed=1).u)
    assert np.array_equal(u, quiet)


def test_the_hook_is_per_thread_and_restored():
    seen = []
    with dispatch.progress_to(lambda d, t: seen.append((d, t))):
        dispatch.report(2, 4)
        with dispatch.progress_to(None):
            dispatch.report(3, 4)
        dispatch.report(7, 4)  # clamped
    dispatch.report(1, 4)
    assert seen == [(2, 4), (4, 4)] and meter.current() is None


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_the_meter_gives_a_count_a_rate_and_the_time_left(capsys):
    clock = Clock()
    m = meter.Meter("karman2d", 4, "samples", clock=clock, terminal=False, live=False)
    clock.t += 2
    assert not m.tick()  # before FIRST
    clock.t += 2
    assert m.tick() and "0/4 samples, no rate yet" in capsys.readouterr().err
    clock.t += 1
    m.set(0.5)  # a first report: no line yet (EVERY s after the last one)
    clock.t += 5
    m.set(1.5)  # 1 sample in 5 s since the first report: 5 s/sample, 2.5 samples left
    err = capsys.readouterr().err
    assert err.strip() == "karman2d: 1.50/4 samples, 5 s/sample, ~12 s left (10 s so far)"
    m.set(1.0)  # never goes back
    assert m.done == 1.5
    m.close()


def test_generate_off_a_terminal_prints_a_count_a_rate_and_the_time_left(capsys, tmp_path, monkeypatch):
    clock = Clock()

    def ticking():  # a second per look: every report is due for a line
        clock.t += 1
        return clock.t

    monkeypatch.setattr(meter.time, "monotonic", ticking)
    monkeypatch.setattr(dispatch, "DISPATCH_WORK", 2**10)  # several calls per block (bits do not depend on it)
    code = cli.main(["generate", "burgers1d", "--n", "4", "--block", "2", "--out", str(tmp_path / "b.h5"),
                     "--set", "n=32", "--set", "n_frames=6"])
    err = capsys.readouterr().err
    assert code == 0
    lines = [line for line in err.splitlines() if line.startswith("burgers1d: ")]
    assert lines and all("/4 samples" in line for line in lines)
    assert any(("samples/s" in line or "s/sample" in line) and " left " in line and "/4 samples" in line
               and not line.startswith("burgers1d: 0/") for line in lines), err


def test_a_phase_counts_the_trajectories_its_solves_report(capsys, monkeypatch):
    clock = Clock()

    def ticking():
        clock.t += 1
        return clock.t

    monkeypatch.setattr(meter.time, "monotonic", ticking)
    monkeypatch.setattr(meter, "FIRST", 0.0)
    monkeypatch.setattr(meter, "EVERY", 0.0)
    with phase("building the test set (64 trajectories)", total=64, solves=2):
        for _ in range(2):  # two padded batches of 32, each reporting its steps
            for done in (1, 2, 4):
                dispatch.report(done, 4)
    lines = capsys.readouterr().err.splitlines()
    counts = [line.split(": ")[1].split(" ")[0] for line in lines if "trajectories, " in line]
    assert "8/64" in counts and "32/64" in counts and "40/64" in counts and "64/64" in counts
    assert lines[-1].startswith("building the test set (64 trajectories): done in")


@pytest.mark.parametrize("workers", ["0", "2"])
def test_an_external_solver_reports_each_finished_sample(workers, monkeypatch):
    from external_solvers import Decay

    from pdestream.generator.external import solver as external

    monkeypatch.setenv(external.WORKERS_ENV, workers)  # in this process / in worker processes
    pde = Decay(delay=0.3 if workers != "0" else 0.0)  # in workers: the wait sees some samples finish apart
    reports = []
    with dispatch.progress_to(lambda d, t: reports.append((d, t))):
        u = np.asarray(generator.sample(pde, [0, 1, 2, 3], seed=1).u)
    assert reports[-1] == (4, 4) and all(t == 4 for _, t in reports)
    assert all(b[0] > a[0] for a, b in itertools.pairwise(reports))
    assert len(reports) == 4 if workers == "0" else len(reports) >= 1
    assert np.array_equal(u, np.asarray(generator.sample(pde, [0, 1, 2, 3], seed=1).u))  # no callback: same bits


def test_training_lines_give_the_rate_and_the_time_left(capsys):
    from pdestream.surrogate.phases import RunProgress

    run = RunProgress("arm", 4, every=0.0)
    run.show(1, {"loss": "0.5"})
    run.close()
    line = capsys.readouterr().err.strip()
    assert line.startswith("arm: step 1/4, ") and " steps/s, ~" in line and " left, loss 0.5" in line, line


def test_a_recorded_run_gives_the_time_left_within_first_seconds_before_any_count(capsys):
    clock = Clock()  # the last run: 40 s to its first count (the compile), then 20 s per sample
    m = meter.Meter("karman2d", 4, "samples", clock=clock, terminal=False, live=False,
                    last={"startup_s": 40.0, "unit_s": 20.0}, starting="compiling the solver")
    clock.t += meter.FIRST
    assert m.tick()  # nothing counted yet: the estimate is the last run's start-up left and its 4 samples
    assert capsys.readouterr().err.strip() == ("karman2d: 0/4 samples, ~20 s/sample last time, ~1 min 57 s left "
                                               "(compiling the solver: about 40 s last time) (3 s so far)")
    clock.t += 60  # later than the last start-up, still nothing: at least the 4 samples are left
    assert "~1 min 20 s left" in m.text()
    clock.t += 1
    m.set(0.1)  # the first count: the start-up is over; no rate of its own within a second
    assert m.text().startswith("karman2d: 0.10/4 samples, ~20 s/sample last time, ~1 min 18 s left (")
    clock.t += 2
    m.set(0.2)  # its own rate: 0.1 sample in 2 s
    assert m.text() == "karman2d: 0.20/4 samples, 20 s/sample, ~1 min 16 s left (1 min 6 s so far)"
    m.close()


def test_without_a_record_the_meter_says_what_it_waits_for_and_no_rate_from_the_start_up(capsys):
    clock = Clock()
    m = meter.Meter("karman2d", 4, "samples", clock=clock, terminal=False, live=False, starting="compiling the solver")
    clock.t += meter.FIRST
    assert m.tick() and capsys.readouterr().err.strip() == \
        "karman2d: 0/4 samples, compiling the solver, time left unknown (3 s so far)"
    clock.t += 40.5
    m.set(0.04)  # a first count after a 43.5 s compile: a rate since the start would say ~1 h left
    clock.t += 0.5
    assert m.text().endswith("0.04/4 samples, no rate yet, time left unknown (44 s so far)")
    clock.t += 1
    m.set(0.1)  # 0.06 in 1.5 s: 25 s/sample
    assert m.text() == "karman2d: 0.10/4 samples, 25 s/sample, ~1 min 38 s left (45 s so far)"
    m.close()


def test_a_coarse_count_gets_a_rate_since_the_start_once_it_is_every_seconds_old():
    clock = Clock()
    m = meter.Meter("darcy2d (dask)", 4, "samples", clock=clock, terminal=False, live=False)
    clock.t += 10
    m.add(2)  # a first block of 2, after 10 s; the next one comes only when it is finished
    assert m.rate() is None
    clock.t += meter.EVERY
    assert m.rate() == pytest.approx(2 / 15)
    m.close()


def test_the_measured_times_are_recorded_by_key_and_read_back(tmp_path, monkeypatch):
    from pdestream.datasets import timings

    path = tmp_path / "progress.json"
    monkeypatch.setenv(timings.HISTORY_ENV, str(path))
    clock = Clock()
    m = meter.Meter("karman2d", 4, "samples", clock=clock, terminal=False, live=False)
    assert m.measured() is None
    clock.t += 40
    m.set(0.5)
    assert m.measured() is None  # one count: no seconds per unit yet
    clock.t += 0.5
    m.set(0.6)
    assert m.measured() is None  # a burst: under a second after the first count
    clock.t += 29.5
    m.set(2)  # 1.5 samples in 30 s after the first count
    clock.t += 100  # written after the solves: not counted
    m.close()
    timings.remember("generate karman2d abc cpu", m.measured())
    assert timings.recall("generate karman2d abc cpu") == {"startup_s": 40.0, "unit_s": 20.0, "basis": "last time"}
    # another config of the same entry and backend: its compile costs about the same
    assert timings.recall("generate karman2d other cpu")["basis"] == "last time, another config"
    assert timings.recall("generate karman2d other gpu") is None and timings.recall("generate cavity2d abc cpu") is None
    typical = {"startup_s": 5.0, "unit_s": 1.0, "basis": "typical"}
    assert timings.recall("generate cavity2d abc cpu", typical) == typical  # no record: the entry's own figures
    path.write_text("{not json")
    assert timings.recall("generate karman2d abc cpu") is None  # garbled: as if nothing was recorded
    monkeypatch.setenv(timings.HISTORY_ENV, "")  # off: nothing read or written
    path.unlink()
    timings.remember("generate karman2d abc cpu", {"startup_s": 1.0, "unit_s": 2.0})
    assert timings.history_path() is None and not path.exists()


@pytest.mark.parametrize("name", [n for n, cls in generator.PDES.items() if issubclass(cls, FlowProblem)])
def test_a_flow_at_its_defaults_has_an_estimate_on_a_machine_with_no_record(name, monkeypatch, tmp_path):
    """A first flow run compiles for 30 s or more: its entry declares what a default run took on 2 CPU cores, so
    the first line has a time left; another grid compiles and solves at another cost, so it gets none."""
    from pdestream.datasets import _bridge, timings

    monkeypatch.setenv(timings.HISTORY_ENV, str(tmp_path / "progress.json"))  # no record of any run
    pde = generator.get_pde(name)
    key = _bridge.progress_key("generate", pde)
    first = timings.recall(key, _bridge.typical_times(pde))
    assert first["basis"] == "typical of its defaults on 2 CPU cores" and first["startup_s"] > 0 < first["unit_s"]
    other = pde.replace(n_frames=pde.n_frames + 1)
    assert timings.recall(_bridge.progress_key("generate", other), _bridge.typical_times(other)) is None
    m = meter.Meter(name, 4, "samples", last=first, starting="compiling the solver", enabled=False)
    assert "typical of its defaults on 2 CPU cores" in m.text() and " left " in m.text()


def test_generate_records_its_times_and_the_next_run_starts_from_them(capsys, tmp_path, monkeypatch):
    from pdestream.datasets import timings

    monkeypatch.setenv(timings.HISTORY_ENV, str(tmp_path / "progress.json"))
    clock = Clock()

    def ticking():  # a second per look: the counts are seconds apart
        clock.t += 1
        return clock.t

    monkeypatch.setattr(meter.time, "monotonic", ticking)
    monkeypatch.setattr(dispatch, "DISPATCH_WORK", 2**10)  # several reports per block
    args = ["generate", "burgers1d", "--n", "4", "--block", "2", "--set", "n=32", "--set", "n_frames=6"]
    assert cli.main([*args, "--out", str(tmp_path / "a.h5")]) == 0
    (key, rec), = json.loads((tmp_path / "progress.json").read_text()).items()
    assert key.startswith("generate burgers1d ") and key.endswith(" cpu") and rec["unit_s"] > 0
    first, seen = timings.recall(key), []
    real = meter.Meter.__init__
    monkeypatch.setattr(meter.Meter, "__init__", lambda self, *a, **k: seen.append(k.get("last")) or real(self, *a, **k))
    assert cli.main([*args, "--out", str(tmp_path / "b.h5")]) == 0
    assert first is not None and seen == [first]  # the second run's meter had the first run's times


@pytest.mark.parametrize("name, settings", [("darcy2d", dict(n=16)), ("poisson2d", dict(n=16))])
def test_a_steady_solve_reports_each_finished_chunk_and_the_same_bits(name, settings):
    pde = generator.get_pde(name, **settings)
    indices = list(range(20))  # 3 chunks of 8 (padded)
    u, reports = solve_reporting(pde, indices)
    assert reports == [(1, 3), (2, 3), (3, 3)]
    assert np.array_equal(u, np.asarray(generator.sample(pde, indices, seed=1).u))  # no callback: the same bits


def test_the_dask_count_moves_with_the_fractions_running_tasks_report():
    from pdestream.datasets.distributed import BlockCount

    clock = Clock()
    bar = meter.Meter("darcy2d (dask)", 12, "samples", initial=4, clock=clock, terminal=False, live=False)
    count = BlockCount(bar)  # blocks 4..7 and 8..11 to do, 0..3 done before (a resume)
    count.event((0.0, (4, 8, 0.25)))
    count.event((0.0, (8, 12, 0.5)))
    assert bar.done == 4 + 1 + 2  # inside both blocks, before either finished
    count.event((0.0, (4, 8, 0.1)))  # out of order: a block's count never goes back
    assert bar.done == 7
    count.finished(4, 8)
    count.event((0.0, (4, 8, 1.0)))  # late, after its block finished: not counted twice
    assert bar.done == 8 + 2
    count.finished(8, 12)
    assert bar.done == 12
    bar.close()


def test_a_terminal_bar_shows_the_last_runs_time_left_until_it_has_a_rate(capsys):
    clock = Clock()
    m = meter.Meter("karman2d", 4, "samples", clock=clock, terminal=True, live=False,
                    last={"startup_s": 40.0, "unit_s": 20.0})
    clock.t += 3
    m.tick()
    assert "~1 min 57 s left, last time" in capsys.readouterr().err
    m.set(0.5)
    clock.t += 2
    m.set(1.0)  # its own rate: tqdm's remaining, no postfix
    assert "last time" not in m.bar.postfix
    m.close()


def test_the_unit_of_one_is_its_singular():
    # "21.5 s/trajectorie" was printed while building a test set of trajectories
    from pdestream.meter import singular

    assert [singular(u) for u in ("trajectories", "samples", "steps", "s", "bytes")] == [
        "trajectory", "sample", "step", "s", "byte"]
