"""PDE settings from TOML files and --set, as the CLI reads them (settings.pde_from_args)."""

import argparse

import pytest

from pdestream import cli, settings
from pdestream import generator as g


def args_for(tmp_path, text, sets=()):
    path = tmp_path / "pde.toml"
    path.write_text(text)
    return argparse.Namespace(config=str(path), set=list(sets))


def test_a_pde_table_and_top_level_keys_mean_the_same(tmp_path):
    table = settings.pde_from_args(None, args_for(tmp_path, '[pde]\nname = "ns2d"\nn = 32\nnu = "uniform(0.01, 0.02)"\n'
                                                      'ic = {kind = "grf", alpha = 3.0}\n'))
    top = settings.pde_from_args(None, args_for(tmp_path, 'pde = "ns2d"\nn = 32\nnu = "uniform(0.01, 0.02)"\n'
                                                    '[ic]\nkind = "grf"\nalpha = 3.0\n'))
    assert table == top == g.get_pde("ns2d", n=32, nu="uniform(0.01, 0.02)", ic={"kind": "grf", "alpha": 3.0})


def test_set_overrides_the_file(tmp_path):
    pde = settings.pde_from_args("burgers1d", args_for(tmp_path, "n = 64\nnu = 0.05\n", ["nu=0.02", "ic.tau=7"]))
    assert pde.n == 64 and str(pde.nu) == "0.02" and pde.ic.tau == 7.0


@pytest.mark.parametrize("text, words", [
    ('pde = "burgers1d"\nlength = [1]\n', ["length", "[1]"]),
    ('pde = "burgers1d"\nic = {kind = "grf", sigma = [1, 2]}\n', ["ic.sigma", "[1, 2]"]),
    ('pde = "ns2d"\n', ["burgers1d", "ns2d"]),
    ("n = 64\n", ["no PDE named"]),
    ("n = \n", ["not valid TOML"]),
])
def test_bad_config_files_give_one_clear_error(tmp_path, text, words):
    name = "burgers1d" if "ns2d" in text else None
    with pytest.raises(ValueError) as err:
        settings.pde_from_args(name, args_for(tmp_path, text))
    for word in words:
        assert word in str(err.value)


def test_train_refuses_a_cache_whose_settings_differ_from_the_config_file(tmp_path, capsys):
    cache = tmp_path / "c.h5"
    assert cli.main(["generate", "burgers1d", "--n", "4", "--set", "n=32", "--set", "n_frames=3",
                     "--out", str(cache)]) == 0
    (tmp_path / "other.toml").write_text("n = 64\nn_frames = 3\n")
    code = cli.main(["train", "burgers1d", "--source", str(cache), "--config", str(tmp_path / "other.toml"),
                     "--steps", "1", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code != 0 and "other settings" in err and "n: cache 32 vs asked 64" in err


@pytest.mark.parametrize("asked", ["periodic", "neumann"])
def test_train_refuses_other_boundaries_than_the_caches(tmp_path, capsys, asked):
    # bc=periodic on a Dirichlet cache trained on the Dirichlet data, rc 0 (bc=neumann was refused)
    cache = tmp_path / "c.h5"
    assert cli.main(["generate", "burgers1d", "--n", "4", "--set", "n=32", "--set", "n_frames=3",
                     "--set", "bc=dirichlet", "--out", str(cache)]) == 0
    capsys.readouterr()
    code = cli.main(["train", "burgers1d", "--source", str(cache), "--set", "n=32", "--set", "n_frames=3",
                     "--set", f"bc={asked}", "--steps", "1", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and f"bc: cache 'dirichlet' vs asked '{asked}'" in err, err
    assert not (tmp_path / "run").exists()
