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
