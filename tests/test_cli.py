"""The command line: list / generate / inspect, crash + --resume through a real process, and user errors
that print one line and exit non-zero without a traceback."""

import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from pdestream import cli, datasets
from pdestream.datasets.cache import is_complete
from pdestream.surrogate import launch

SMALL = ["--set", "n=32", "--set", "n_frames=6"]


def run_cli(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_list_names_every_pde(capsys):
    code, out, _ = run_cli(capsys, "list")
    assert code == 0 and "burgers1d: u_t + u u_x = nu u_xx" in out and "ns2d" in out


def test_generate_then_inspect(capsys, tmp_path):
    path = tmp_path / "b.zarr"
    code, out, err = run_cli(capsys, "generate", "burgers1d", "--n", "6", "--seed", "2", "--out", str(path), *SMALL,
                             "--set", "nu=loguniform(0.02,0.05)")
    assert code == 0 and all(line.startswith("burgers1d: ") and "/6 samples" in line for line in err.splitlines())
    assert out.count("\n") == 1 and "wrote 6 samples" in out  # one summary line; progress lines (a slow run) on stderr
    ds = datasets.open_cache(path)
    assert is_complete(ds) and ds.attrs["pdestream_seed"] == 2
    assert 0.02 <= ds["nu"].values.min() and ds["nu"].values.max() <= 0.05
    code, out, _ = run_cli(capsys, "inspect", str(path), "--plot", str(tmp_path / "b.png"))
    assert code == 0
    for text in ("burgers1d", "u_t + u u_x = nu u_xx", "6 of 6 complete", "param nu: [", "field u: mean",
                 "bytes on disk", '"n": 32'):
        assert text in out, text
    assert (tmp_path / "b.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_resume_of_a_complete_cache_says_so(capsys, tmp_path):
    path = tmp_path / "b.h5"
    args = ["generate", "burgers1d", "--n", "3", "--out", str(path), *SMALL]
    assert run_cli(capsys, *args)[0] == 0
    before = path.read_bytes()
    code, out, err = run_cli(capsys, *args, "--resume")
    assert (code, err) == (0, "") and out == f"{path} is already complete: all 3 samples were written; nothing to solve\n"
    assert path.read_bytes() == before  # not a byte touched (it was opened for writing: 15 bytes of HDF5 metadata)


def test_a_cache_larger_than_the_disk_is_refused_up_front(capsys, tmp_path):
    code, out, err = run_cli(capsys, "generate", "burgers1d", "--n", str(2**32), "--out", str(tmp_path / "c.zarr"))
    assert code == 2 and err.count("\n") == 1 and f"cannot write {tmp_path / 'c.zarr'}: no space left on device (" in err
    assert " GiB free)" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", [["burgers1d"], None, 3])
def test_a_pde_name_that_is_not_a_string_is_one_line(name):
    from pdestream import generator

    with pytest.raises(ValueError, match=r"^unknown PDE .*; allowed: .*burgers1d"):
        generator.get_pde(name)


def test_generate_from_toml(capsys, tmp_path):
    (tmp_path / "c.toml").write_text('[pde]\nname = "diffusion1d"\nn = 32\nn_frames = 4\n')
    code, _, err = run_cli(capsys, "generate", "--config", str(tmp_path / "c.toml"), "--n", "2",
                           "--out", str(tmp_path / "d.h5"))
    assert code == 0, err
    ds = datasets.open_cache(tmp_path / "d.h5")
    assert ds.attrs["pde"] == "diffusion1d" and ds.sizes["x"] == 32 and ds.sizes["time"] == 4


@pytest.mark.parametrize("args, message", [
    (["generate", "nosuchpde", "--n", "2", "--out", "{tmp}/a.h5"], "unknown PDE 'nosuchpde'"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/a.h5", "--set", "nu"], "bad --set 'nu'"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/a.h5", "--set", "nu=-1"], "nu=-1"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/a.h5", "--set", "colour=3"], "unknown setting 'colour'"),
    # a key given twice with other values: the last one won, silently
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/a.h5", "--set", "refine=2", "--set", "refine=3"],
     "--set refine given twice (refine=2 and refine=3); allowed: one value per key"),
    (["train", "burgers1d", "--out", "{tmp}/r", "--model-set", "width=8", "--model-set", "width=16"],
     "--model-set width given twice"),
    (["train", "burgers1d", "--out", "{tmp}/r", "--model-set", "width"], "bad --model-set 'width'"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/nodir/a.h5"], "does not exist"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/locked/a.h5"], "not writable"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/exists.h5/a.h5"], "is not a directory"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/a.nc"], "must end in .h5, .hdf5 or .zarr"),
    (["generate", "burgers1d", "--n", "0", "--out", "{tmp}/a.h5"], "n_samples=0"),
    (["generate", "burgers1d", "--n", "2", "--out", "{tmp}/exists.h5"], "exists; pass --resume"),
    (["train", "burgers1d", "--out", "{tmp}/r", "--source", ""], "--source '' is empty; allowed: stream"),
    (["inspect", "{tmp}/missing.zarr"], "does not exist"),
    (["inspect", "{tmp}/exists.h5"], "not a readable hdf5 cache"),
])
def test_user_errors_are_one_line(capsys, tmp_path, args, message):
    (tmp_path / "exists.h5").write_bytes(b"\0" * 64)  # also a corrupted cache
    (tmp_path / "locked").mkdir(mode=0o500)
    if os.geteuid() == 0 and "locked" in " ".join(args):
        pytest.skip("root writes anywhere")
    code, out, err = run_cli(capsys, *[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert code != 0 and out == ""
    assert err.startswith("pdestream: error: ") and err.count("\n") == 1 and message in err, err


@pytest.mark.parametrize("args, message", [
    (["--seed", "-1"], "seed=-1 not allowed"),
    (["--seed", str(2**63)], f"seed={2**63} not allowed"),
    (["--block", "0"], "block=0 not allowed"),
    (["--n", str(2**32 + 1)], f"n_samples={2**32 + 1} not allowed"),
    (["--set", "n_frames=0"], "n_frames"),
])
def test_refused_generate_creates_nothing(capsys, tmp_path, args, message):
    """Every argument is checked before the cache is created, so a corrected rerun needs no --overwrite."""
    argv = ["generate", "burgers1d", "--n", "4", "--out", str(tmp_path / "s.h5"), *SMALL, *args]
    code, out, err = run_cli(capsys, *argv)
    assert code != 0 and out == "" and err.startswith("pdestream: error: ") and message in err, err
    assert list(tmp_path.iterdir()) == []


def test_no_traceback_through_a_real_process(tmp_path):
    res = subprocess.run([sys.executable, "-m", "pdestream.cli", "generate", "nosuchpde", "--n", "2", "--out",
                          str(tmp_path / "a.h5")], capture_output=True, text=True, timeout=120)
    assert res.returncode != 0 and "Traceback" not in res.stderr
    assert res.stderr.strip().splitlines() == [res.stderr.strip()] and "unknown PDE" in res.stderr


# ~0.7 s per block of 4 on a 2-core CPU (a long t_end: many steps). The tests kill the writer once its first
# block is flagged; 5 more blocks (~3.5 s here) leave a wide margin on a fast machine with a warm compile cache.
N_SLOW = 24
SLOW = ["burgers1d", "--n", str(N_SLOW), "--seed", "5", "--block", "4", "--set", "n=64", "--set", "n_frames=6",
        "--set", "t_end=100"]


def _complete_flags(path):
    if not path.exists():
        return None
    try:
        with h5py.File(path, "r", locking=False) as f:  # the writer holds the lock; its metadata is static
            return f["complete"][:]
    except (OSError, KeyError):
        return None


def _writer_with_4_samples_flagged(part):
    """A `generate` subprocess writing ``part``, returned once at least 4 samples are flagged complete."""
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.cli", "generate", *SLOW, "--out", str(part)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        flags = _complete_flags(part)
        if flags is not None and flags.sum() >= 4:
            break
        time.sleep(0.005)
    return proc


def test_kill_9_then_resume_equals_an_uninterrupted_run(capsys, tmp_path):
    full, part = tmp_path / "full.h5", tmp_path / "part.h5"
    assert run_cli(capsys, "generate", *SLOW, "--out", str(full))[0] == 0  # also warms the compile cache
    proc = _writer_with_4_samples_flagged(part)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the writer finished before it could be killed: use a slower config"
    ds = datasets.open_cache(part)
    written = int((ds["complete"].values == 1).sum())
    assert not is_complete(ds) and 4 <= written < N_SLOW
    ds.close()
    with pytest.raises(ValueError, match="incomplete"):
        datasets.CachedTrajectories(part)
    code, out, err = run_cli(capsys, "generate", *SLOW, "--out", str(part), "--resume")
    assert code == 0, err
    assert f"wrote {N_SLOW - written} samples" in out
    a, b = datasets.open_cache(full), datasets.open_cache(part)
    assert is_complete(b)
    for name in ("u", "nu", "sample", "complete", "redraws"):
        np.testing.assert_array_equal(a[name].values, b[name].values)
    assert a.attrs == b.attrs


def test_ctrl_c_leaves_an_incomplete_cache_and_one_line(tmp_path):
    part = tmp_path / "part.h5"
    proc = _writer_with_4_samples_flagged(part)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, "the writer finished before Ctrl-C: use a slower config"
    assert err.startswith(f"pdestream: interrupted; {part} holds ") and err.count("\n") == 1
    ds = datasets.open_cache(part)
    assert not is_complete(ds) and 4 <= int((ds["complete"].values == 1).sum()) < N_SLOW


def test_version_prints_the_installed_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit:
        cli.main(["--version"])
    assert exit.value.code == 0
    assert capsys.readouterr().out.strip() == f"pdestream {version('pdestream')}"


@pytest.mark.parametrize("command, shown", [
    ("generate", ["seed, i) (default: 0, or the --split's)", "(default: raise)"]),
    ("train", ["(default: stream)", "optimizer steps (default: 1000)", "(default: 0.001)"]),
    ("compare", ["(default: 128)", "(default: h5)", "(default: 0.003)"]),
])
def test_help_shows_defaults(capsys, monkeypatch, command, shown):
    monkeypatch.setenv("COLUMNS", "240")  # one option per line
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    out = capsys.readouterr().out
    for text in shown:
        assert text in out, text
    assert "(default: None)" not in out and "(default: False)" not in out


def test_stream_training_leaves_the_solver_a_core(monkeypatch):
    for cores, threads in ((1, 1), (2, 1), (8, 7)):
        monkeypatch.setattr(launch.os, "sched_getaffinity", lambda pid, cores=cores: set(range(cores)))
        assert launch.default_threads("stream") == threads
        assert launch.default_threads("burgers.h5") == threads  # a cache too: torch's threads on every core of a
        # busy machine trained 17-30x slower


def test_train_without_threads_applies_the_stream_default(capsys, monkeypatch, tmp_path):
    import torch

    from pdestream.surrogate import runs

    seen = []

    def stop(*args, **kwargs):
        seen.append(torch.get_num_threads())
        raise ValueError("stopped before training")

    monkeypatch.setattr(runs, "train_run", stop)
    monkeypatch.setattr(launch.os, "sched_getaffinity", lambda pid: {0, 1, 2})
    before = torch.get_num_threads()
    try:
        for extra, threads in (([], 2), (["--threads", "1"], 1)):
            code, _, err = run_cli(capsys, "train", "burgers1d", "--out", str(tmp_path / "run"), *SMALL, *extra)
            assert code == 2 and "stopped before training" in err
            assert seen.pop() == threads
    finally:
        torch.set_num_threads(before)


def test_dask_with_zero_workers_is_refused_not_run_with_two(tmp_path, capsys):
    pytest.importorskip("distributed")
    out = tmp_path / "c.zarr"
    code = cli.main(["generate", "burgers1d", "--n", "2", *SMALL, "--executor", "dask", "--workers", "0",
                     "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "workers=0 not allowed" in err, err
    assert not out.exists()


def test_a_warning_of_pdestream_is_one_line_and_others_keep_python_s_form(capsys):
    # inside a command (interrupts.run), cavity2d's UnderResolved warning printed Python's "path/problem.py:226:
    # UnderResolved: ..." and the source line "self.validate()"
    import warnings

    from pdestream import generator
    from pdestream.interrupts import run

    def build():
        generator.get_pde("cavity2d", n=32)
        warnings.warn("not ours", DeprecationWarning, stacklevel=1)

    seen = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = shown = lambda message, category, *rest: seen.append(category.__name__)
        assert run(build, standalone=False) == 0
        assert warnings.showwarning is shown  # given back
    assert seen == ["DeprecationWarning"]  # another package's warning goes to the hook it replaced
    err = capsys.readouterr().err
    ours = [line for line in err.splitlines() if "under-resolved" in line]
    assert len(ours) == 1 and ours[0].startswith("pdestream: warning: cavity2d: re=uniform(100.0, 400.0) on n=32 is "
                                                 "under-resolved"), err
    assert "problem.py" not in err and "validate()" not in err


@pytest.mark.parametrize("plot, words", [("nodir/x.png", "directory nodir does not exist"),
                                         ("x.txt", "--plot x.txt: allowed: a file ending in .png"),
                                         (".", "--plot .: allowed: a file ending in .png")])
def test_a_bad_plot_path_is_refused_before_the_summary(capsys, tmp_path, monkeypatch, plot, words):
    """--plot . wrote a hidden '.png' (rc 0, 'plot: .'); x.txt was matplotlib's error after the whole summary."""
    path = tmp_path / "b.h5"
    assert run_cli(capsys, "generate", "burgers1d", "--n", "2", "--out", str(path), *SMALL)[0] == 0
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "inspect", str(path), "--plot", plot)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and words in err, (out, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.h5"]


def test_plot_replaces_only_its_own_figures(capsys, tmp_path):
    """--plot over an existing file of the user's overwrote it (rc 0); it replaces only a figure it wrote (marked
    in the file's metadata), written whole beside it and moved into place."""
    path = tmp_path / "b.h5"
    assert run_cli(capsys, "generate", "burgers1d", "--n", "2", "--out", str(path), *SMALL)[0] == 0
    for name in ("fig.png", "fig.pdf", "fig.svg"):
        for _ in range(2):  # the second run replaces the first one's figure
            assert run_cli(capsys, "inspect", str(path), "--plot", str(tmp_path / name))[0] == 0
    mine = tmp_path / "mine.png"
    mine.write_bytes(b"the user's own picture")
    code, out, err = run_cli(capsys, "inspect", str(path), "--plot", str(mine))
    assert code == 2 and out == "" and "the file exists and is not a figure pdestream inspect wrote" in err, err
    assert mine.read_bytes() == b"the user's own picture"
    assert run_cli(capsys, "inspect", str(path), "--plot", str(tmp_path / "fig.jpg"))[0] == 0
    code, _, err = run_cli(capsys, "inspect", str(path), "--plot", str(tmp_path / "fig.jpg"))
    assert code == 2 and "a JPEG holds no mark of it" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.h5", "fig.jpg", "fig.pdf", "fig.png", "fig.svg", "mine.png"]
