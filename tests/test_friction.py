"""First-user friction of issue 21 outside the training loop: refusals that come first, in one line, and leave
nothing behind; a stream loop that ends promptly."""

import numpy as np
import pytest

import cli
import generator


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
    assert not any((out / m).exists() for m in cli.RUN_MARKERS)
