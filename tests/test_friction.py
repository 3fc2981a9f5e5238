"""First-user friction of issue 21 outside the training loop: refusals that come first, in one line, and leave
nothing behind; a stream loop that ends promptly."""

import numpy as np
import pytest

from pdestream import cli, generator
from pdestream.surrogate.launch import RUN_MARKERS


def one_line(code, capsys, *words):
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    return err


@pytest.mark.parametrize("seed", [True, False, np.bool_(True)])
def test_a_bool_seed_is_refused(seed):
    pde = generator.get_pde("burgers1d", n=16, n_frames=2, t_end=0.01)
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        generator.sample(pde, [0], seed=seed)


def test_compare_shift_0_is_refused_before_anything_is_written(tmp_path, capsys):
    for extra in ([], ["--quick"]):
        out = tmp_path / f"c{len(extra)}"
        code = cli.main(["compare", "burgers1d", "--set", "n=32", "--shift", "0", "--out", str(out), *extra])
        one_line(code, capsys, "--shift 0")
        assert not out.exists()


@pytest.mark.parametrize("shift", ["1e300", "-1e300", "1e30"])
def test_compare_a_shift_past_the_floats_is_one_line(tmp_path, capsys, shift):
    """--shift 1e300 raised OverflowError from nu's loguniform domain (a traceback)."""
    out = tmp_path / "c"
    code = cli.main(["compare", "burgers1d", "--set", "n=32", "--modes", "one-step", f"--shift={shift}",
                     "--out", str(out)])
    one_line(code, capsys, f"--shift {float(shift):g}", "nu", "past the largest float")
    assert not out.exists()


@pytest.mark.parametrize("shift_set, words", [
    # the training domain itself, a part of it, a value in it: "Beyond the training range" was the range itself
    ("nu=loguniform(0.01, 0.1)", "--shift-set nu=loguniform(0.01, 0.1) lies inside the training range"),
    ("nu=loguniform(0.02, 0.05)", "lies inside the training range loguniform(0.01, 0.1)"),
    ("nu=0.05", "lies inside the training range"),
    # a setting, not a parameter: the beyond set was solved on another grid
    ("n=32", "--shift-set n=32: n is not a parameter of burgers1d; allowed: nu"),
])
def test_compare_a_shift_set_that_is_not_beyond_the_range_is_one_line(tmp_path, capsys, shift_set, words):
    out = tmp_path / "c"
    code = cli.main(["compare", "burgers1d", "--set", "n=32", "--modes", "one-step", "--shift-set", shift_set,
                     "--out", str(out)])
    one_line(code, capsys, words)
    assert not out.exists()


@pytest.mark.parametrize("bad", [
    ["--source", "no_such_cache.zarr"],  # missing cache
    ["--reservoir", "--producer", "dask", "--scheduler", "tcp://127.0.0.1:9"],  # unreachable scheduler
    ["--reservoir", "--scheduler", "tcp://127.0.0.1:9"],  # a scheduler without --producer dask
    ["--mode", "no-such-mode"],
    ["--set", "nu=-1"],
])
def test_a_refused_train_leaves_nothing_so_the_corrected_command_runs(tmp_path, capsys, bad):
    out = tmp_path / "run"
    args = ["train", "burgers1d", "--set", "n=16", "--set", "n_frames=3", "--set", "t_end=0.01", "--steps", "1",
            "--batch-size", "2", "--test-samples", "1", "--out", str(out)]
    try:
        code = cli.main(args + bad)
    except SystemExit as e:  # argparse's own refusal (a bad choice)
        code = e.code
    assert code != 0
    capsys.readouterr()
    assert not [p.name for p in out.glob("*")] if out.exists() else True  # nothing: no run.json to be refused by
    assert not any((out / m).exists() for m in RUN_MARKERS)


def _script(tmp_path, body: str):
    import os
    import subprocess
    import sys
    from pathlib import Path

    path = tmp_path / "script.py"
    path.write_text(body)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parent.parent)}
    return subprocess.run([sys.executable, str(path)], capture_output=True, text=True, env=env, timeout=300)


def test_an_unguarded_script_with_workers_gets_one_line(tmp_path):
    out = _script(tmp_path, "from pdestream import datasets, generator\n"
                            "pde = generator.get_pde('burgers1d', n=16, n_frames=3, t_end=0.01)\n"
                            "loader = datasets.stream_loader(datasets.TrajectoryStream(pde), num_workers=2)\n")
    assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr
    assert out.stderr.strip().splitlines() == [out.stderr.strip()] and "(line 3)" in out.stderr
    from pdestream.datasets.stream import MainGuardError

    assert issubclass(MainGuardError, ValueError)  # callers that catch the library's ValueError still do


@pytest.mark.slow
def test_a_script_that_breaks_out_of_a_worker_loop_exits_promptly(tmp_path):
    # torch joined each busy worker for up to 5 s (its MP_STATUS_CHECK_INTERVAL): ~5 s after the loop here
    # torch's interval raised to 60 s in the script: a shutdown that waited on it would take minutes, ours takes
    # WORKER_JOIN_S and a terminate, so the 30 s below is a wide gap under any load, not a speed limit
    out = _script(tmp_path, "import time\nfrom pdestream import datasets, generator\n"
                            "import torch.utils.data._utils as torch_utils\n"
                            "torch_utils.MP_STATUS_CHECK_INTERVAL = 60.0\n"
                            "if __name__ == '__main__':\n"
                            "    pde = generator.get_pde('burgers1d')\n"
                            "    loader = datasets.stream_loader(datasets.TrajectoryStream(pde), num_workers=2)\n"
                            "    for i, b in enumerate(loader):\n"
                            "        if i == 2:\n"
                            "            break\n"
                            "    t = time.monotonic()\n"
                            "    del loader, b\n"
                            "    print(time.monotonic() - t)\n")
    assert out.returncode == 0, out.stderr
    assert float(out.stdout.split()[-1]) < 30.0  # WORKER_JOIN_S, then busy workers are stopped


@pytest.mark.slow
def test_a_dask_blow_up_prints_our_line_and_not_the_clusters_report(tmp_path, capfd):
    pytest.importorskip("distributed")
    code = cli.main(["generate", "darcy2d", "--n", "2", "--set", "n=17", "--set", "max_iter=5", "--executor", "dask",
                     "--workers", "1", "--out", str(tmp_path / "d.zarr")])
    err = [line for line in capfd.readouterr().err.strip().splitlines() if not line.startswith("dask dashboard:")]
    assert code != 0 and len(err) == 1 and err[0].startswith("pdestream: error: darcy2d: 2 of 2 solves"), err


def test_stream_loader_names_what_it_takes():
    from pdestream import datasets

    with pytest.raises(ValueError, match="stream_loader takes a TrajectoryStream, got Burgers"):
        datasets.stream_loader(generator.get_pde("burgers1d", n=16), num_workers=0)
