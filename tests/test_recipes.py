"""Recipes: published data sets by name (pdestream.recipes), resolved wherever a PDE name is, on tiny grids."""

import dataclasses
import json
import shlex

import jax
import numpy as np
import pytest

from pdestream import cli, recipes
from pdestream import generator as g
from pdestream.datasets import open_cache
from pdestream.datasets.generate import GenerateConfig, generate
from pdestream.generator.ics import RandomSines

TINY = {"n": 32, "n_frames": 3}  # pdebench_advection1d at a size a test affords


def run_cli(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_the_list_names_every_recipe_with_its_source_and_the_sets_it_skips(capsys):
    code, out, _ = run_cli(capsys, "recipes")
    assert code == 0
    for r in recipes.RECIPES.values():
        line = next(line for line in out.splitlines() if line.startswith(r.name + " "))
        assert r.entry in line and r.paper in line and r.where in line
    assert "cfdbench_cavity_bc" in out and "not expressible" in out


def test_show_prints_source_settings_splits_and_differences(capsys):
    code, out, _ = run_cli(capsys, "recipes", "show", "fno_ns2d_nu1e-3")
    assert code == 0
    for words in ("source:", "arxiv.org/abs/2010.08895", "ns_2d.py:113", ":126 (forcing)", "--set forcing=diagonal", "--set nu=0.001",
                  "--set ic.tau=7", "train seed 0 n 1000", "test seed 2 n 200", "Crank-Nicolson"):
        assert words in out, words
    shown = json.loads(recipes.show("pdebench_advection1d", as_json=True))
    assert shown["settings"]["c"] == "choice(0.1, 0.4, 1.0, 4.0)" and shown["splits"]["valid"] == {"seed": 1, "n": 500}


@pytest.mark.parametrize("name", list(recipes.RECIPES))
def test_the_shown_settings_copied_into_a_shell_make_the_recipes_own_problem(name):
    """The settings line of `recipes show`, as a shell splits it, gives the entry the recipe's exact config (a rounded
    number, e.g. ic.sigma 18.5203 for 18.520259..., or an unquoted choice(...) would not)."""
    line = next(x for x in recipes.show(name).splitlines() if x.startswith("  settings:"))
    words = shlex.split(line.removeprefix("  settings:"))
    assert words[::2] == ["--set"] * (len(words) // 2), words
    made = g.get_pde(recipes.RECIPES[name].entry, dict(w.split("=", 1) for w in words[1::2]))
    assert made == dataclasses.replace(g.get_pde(name), recipe=made.recipe)


def test_the_list_of_a_recipe_names_it_and_offers_only_settings_set_takes(capsys):
    code, out, _ = run_cli(capsys, "list", "fno_ns2d_nu1e-4")
    assert code == 0 and "  recipe: fno_ns2d_nu1e-4 (pdestream recipes show fno_ns2d_nu1e-4" in out
    assert "  refine = 4\n" in out and "recipe = " not in out  # --set recipe=... is refused: not a setting
    code, out, _ = run_cli(capsys, "list", "fno_ns2d_nu1e-4", "--json")
    shown = json.loads(out)
    assert shown["recipe"] == "fno_ns2d_nu1e-4" and "recipe" not in shown["settings"]


@pytest.mark.parametrize("argv, words", [
    (("recipes", "show", "fno_burger"), ["'fno_burger'", "did you mean fno_burgers1d", "allowed: fno_burgers1d"]),
    (("recipes", "show"), ["give one recipe", "pdebench_advection1d"]),
    (("recipes", "fno_burgers1d"), ["unknown recipes command 'fno_burgers1d'", "show NAME"]),
    (("generate", "fno_burgrs1d", "--n", "1", "--out", "x.h5"), ["unknown PDE 'fno_burgrs1d'", "fno_burgers1d"]),
    (("generate", "burgers1d", "--split", "train", "--out", "x.h5"), ["--split train needs a recipe", "'burgers1d'"]),
    (("generate", "fno_burgers1d", "--split", "test", "--seed", "5", "--out", "x.h5"), ["fixes the seed (2)"]),
    (("generate", "fno_burgers1d", "--split", "valid", "--seed", "0", "--out", "x.h5"), ["fixes the seed (1)",
                                                                                          "drop --seed 0"]),
    (("generate", "pdebench_advection1d", "--split", "test", "--n", "5000", "--out", "x.h5"),
     ["--n 5000 is more than the test split's 1000 samples; allowed: --n 1..1000", "--seed 2 --n 5000"]),
])
def test_bad_recipe_input_is_one_line(capsys, tmp_path, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, *argv)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", list(recipes.RECIPES))
def test_every_recipe_is_valid_for_its_entry_and_round_trips(name):
    r = recipes.RECIPES[name]
    pde = g.get_pde(name)  # __post_init__ runs the entry's validate()
    assert pde.NAME == r.entry and pde.recipe == name and pde.config()["recipe"] == name
    assert pde == dataclasses.replace(g.get_pde(r.entry, r.settings), recipe=name)
    assert all(getattr(pde, k) == v for k, v in r.settings.items() if isinstance(v, (int, float)))
    assert g.from_config(pde.config()) == pde
    assert set(r.splits) == set(recipes.SPLITS) and len({s.seed for s in r.splits.values()}) == 3
    assert g.get_pde(r.entry).config().get("recipe") is None  # the plain entry's config is unchanged


def test_set_overrides_a_recipe_and_a_cache_records_the_recipe_and_its_source(capsys, tmp_path):
    pde = g.get_pde("fno_burgers1d", {"n": "64"})
    assert pde.n == 64 and str(pde.nu) == "0.1" and pde.ic.alpha == 2.0 and pde.recipe == "fno_burgers1d"
    out = tmp_path / "a.h5"
    code, said, err = run_cli(capsys, "generate", "pdebench_advection1d", "--n", "2", "--out", str(out),
                              "--set", "n=32", "--set", "n_frames=3", "--set", "c=0.4")
    assert code == 0, err
    # the label keeps where the data came from, and says they are not the published set
    assert "note: recipe pdebench_advection1d with c, n, n_frames changed (not the published set)" in said, said
    with open_cache(out) as ds:
        config = json.loads(ds.attrs["pdestream_config"])
        assert ds.attrs["pdestream_recipe"] == "pdebench_advection1d" and config["recipe"] == "pdebench_advection1d"
        assert "PDEBench" in ds.attrs["pdestream_recipe_source"] and "beta1e0.yaml" in ds.attrs["pdestream_recipe_source"]
        assert config["n"] == 32 and config["c"] == "0.4" and config["ic"]["kind"] == "sines"
        assert np.allclose(ds["c"].values, 0.4)
    code, shown, _ = run_cli(capsys, "inspect", str(out))
    assert code == 0 and ("recipe: pdebench_advection1d with c, n, n_frames changed (not the published set): "
                          "Takamoto et al. 2022") in shown, shown
    assert "; seed 0 (the train split's seed: its first 2 of 9000)" in shown  # the seed says which split it is
    from pdestream.datasets.inspect import split_note

    assert split_note("pdebench_advection1d", 2, 1000) == " (the test split's seed: all)"
    assert split_note("pdebench_advection1d", 1, 600) == " (the valid split's seed: its 500 and 100 beyond it)"
    assert split_note("pdebench_advection1d", 7, 2) == ""


def test_splits_are_reproducible_disjoint_and_prefixes(tmp_path):
    def split(name, n, out):
        generate(GenerateConfig(pde="pdebench_advection1d", settings=TINY, split=name, n=n, out=str(tmp_path / out)))
        with open_cache(tmp_path / out) as ds:
            return int(ds.attrs["pdestream_seed"]), ds["u"].values

    seed_train, train = split("train", 3, "train.h5")
    seed_test, test = split("test", 2, "test.h5")
    _, again = split("train", 2, "again.h5")
    assert (seed_train, seed_test) == (0, 2)
    assert np.array_equal(again, train[:2])  # reproducible, and a smaller split is the full one's prefix
    assert not any(np.allclose(a[0], b[0]) for a in train for b in test)  # no test IC is a train IC


def test_sines_advected_equal_the_exact_translate_and_a_sample_is_batch_independent():
    # the sines IC (PDEBench's measure) through advection1d against u0(x - c t) of the same draw, evaluated exactly
    pde = g.get_pde("advection1d", n=64, t_end=0.5, n_frames=3, ic="sines")
    ic, x = RandomSines(), np.asarray(pde.grid.coords())
    keys = [jax.random.PRNGKey(i) for i in range(4)]
    u0 = np.stack([np.asarray(ic._one(k, x, 1.0)) for k in keys])
    c = np.array([0.1, 0.4, 1.0, -0.7], np.float32)
    u = np.asarray(g.solve(pde, u0[:, None], {"c": c}).u)[:, -1, 0]
    exact = np.stack([np.asarray(ic._one(k, ((x - ci * 0.5) % 1.0).astype(np.float32), 1.0)) for k, ci in zip(keys, c)])
    assert np.abs(u - exact).max() < 1e-4 * np.abs(exact).max()
    batch = np.asarray(g.sample(pde, range(4), seed=3).u)
    assert np.array_equal(np.asarray(g.sample(pde, [2], seed=3).u)[0], batch[2])
    rd = np.asarray(g.sample(g.get_pde("pdebench_reaction_diffusion1d", n=32, n_frames=2), range(3), seed=0).u)
    # normalised: u0 spans [0, 1] (frame 0 is the IC through the solver's transforms: within float32 rounding)
    assert np.allclose(rd[:, 0].min(axis=-1), 0.0, atol=1e-6) and np.allclose(rd[:, 0].max(axis=-1), 1.0, atol=1e-6)
    with pytest.raises(ValueError, match="ic='sines' not allowed: it serves 1D and advection2d is 2D"):
        g.get_pde("advection2d", ic="sines")


def test_diagonal_forcing_drives_the_exact_single_wavevector_solution():
    # w depends on x + y only, so u . grad w = 0: from w0 = 0, w(t) = f (1 - exp(-s t)) / s, s = 2 nu k_f^2 + drag
    pde = g.get_pde("ns2d", n=32, length=1.0, nu="0.01", forcing="diagonal", forcing_amplitude=0.1,
                    forcing_wavenumber=1, drag=0.05, t_end=2.0, n_frames=3)
    w = np.asarray(g.solve(pde, np.zeros((1, 1, 32, 32), np.float32), {"nu": [0.01]}).u)[0, :, 0]
    x = np.asarray(pde.grid.coords(), np.float64)
    k_f, s = 2 * np.pi, 2 * 0.01 * (2 * np.pi) ** 2 + 0.05
    f = 0.1 * (np.sin(k_f * (x[:, None] + x[None, :])) + np.cos(k_f * (x[:, None] + x[None, :])))
    for j, t in enumerate(pde.times()):
        assert np.abs(w[j] - f * (1 - np.exp(-s * t)) / s).max() < 1e-5, j


def test_the_stream_takes_a_recipe_name():
    from pdestream.datasets import TrajectoryStream

    stream = TrajectoryStream("fno_burgers1d", batch_size=2, n_samples=2)
    assert stream.pde.recipe == "fno_burgers1d" and stream.pde.n == 1024 and str(stream.pde.nu) == "0.1"


def test_a_stratified_draw_of_a_choice_domain_keeps_its_end_options():
    # compare --budget's test set (ParamProposal.from_unit) clipped choice(0.1, ..., 4.0) to just inside 4.0, and
    # the solver refused c=4 "outside its domain": pdestream compare pdebench_advection1d failed
    from pdestream.datasets import param_domains
    from pdestream.datasets.proposal import ParamProposal

    prop = ParamProposal(param_domains(g.get_pde("pdebench_advection1d")), mode="uniform")
    drawn = prop.from_unit(np.linspace(0.0, 1.0, 9)[:, None])["c"]
    assert sorted(set(drawn.tolist())) == [0.1, 0.4, 1.0, 4.0]


def test_pdebench_dam_break_is_centred_and_keeps_its_mirror_symmetries():
    # PDEBench's dam sits at the centre of its box: the depth stays symmetric under x <-> y and both mirrors
    pde = g.get_pde("pdebench_swe2d", n=32, t_end=0.3, n_frames=2)
    h = np.asarray(g.sample(pde, range(2), seed=0).u)[:, :, 0]  # [B, T, y, x] or [B, T, x, y]: symmetric either way
    assert h[:, 0].max() == 2.0 and h[:, 0].min() == 1.0
    for field in (h[:, 0], h[:, -1]):
        for mirrored in (field.transpose(0, 2, 1), field[:, ::-1, :], field[:, :, ::-1]):
            assert np.abs(mirrored - field).max() < 1e-4
    assert np.abs(h[:, -1] - h[:, 0]).max() > 0.1  # and it moved


CFDBENCH_SETS = [f"cfdbench_{family}_{subset}" for family in ("cavity", "tube", "cylinder")
                 for subset in ("bc", "geo", "prop")]


@pytest.mark.parametrize("name", CFDBENCH_SETS)
def test_cfdbench_sets_are_refused_with_their_reason_not_approximated(capsys, tmp_path, monkeypatch, name):
    # none of CFDBench's nine cavity / tube / cylinder subsets is a recipe: each is listed with why, and naming it
    # anywhere a PDE name goes says why in one line (not "unknown"), nothing written
    monkeypatch.chdir(tmp_path)
    assert name not in recipes.RECIPES and recipes.not_expressible(name)
    _, listing, _ = run_cli(capsys, "recipes")
    assert name in listing
    for argv in (("recipes", "show", name), ("generate", name, "--n", "1", "--out", "x.h5")):
        code, out, err = run_cli(capsys, *argv)
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
        assert f"recipe {name!r} is not expressible yet" in err and "luo-yining/CFDBench@6c30c62" in err
        assert "unknown" not in err
    assert list(tmp_path.iterdir()) == []
    assert recipes.not_expressible("cfdbench_cavity") is None  # a family alone is no set


def test_cfdbench_cavity_bc_threshold_is_the_flow_familys_own():
    # the refusal's numbers: lid 50 m/s, nu = 1e-5, 64 cells; cavity2d itself accepts a side of 0.5 mm and
    # refuses 0.52 mm for the cell Reynolds number (the reason's "L > 0.51 mm"), and 1 cm at 781
    def cavity(side):
        return g.get_pde("cavity2d", n=64, length=side, lid="50", re=str(50 * side / 1e-5), t_end=1e-3, n_frames=2)

    assert cavity(0.0005).length == 0.0005
    for side, cell_re in ((0.00052, "40.6"), (0.01, "781")):
        with pytest.raises(ValueError, match=f"cell Reynolds number .* = {cell_re}; the limit is 40"):
            cavity(side)
    assert "78125 L" in recipes.not_expressible("cfdbench_cavity_bc") and "L > 0.51 mm" in recipes.not_expressible(
        "cfdbench_cavity_bc")


def test_cfdbench_cylinder_reynolds_limit_is_karman2ds_own():
    # the refusal's "64 cells across the height resolve Re <= 284": CFDBench's channel 0.12 m high, d = 0.02 m, 1 m/s
    def cylinder(re):
        return g.get_pde("karman2d", n=64, aspect=2, length=0.12, radius="0.01", cx="0.06", cy="0.059", speed="1",
                         plug="1", re=str(re), t_start=0.0, t_end=0.01, n_frames=2)

    assert cylinder(284).n == 64
    with pytest.raises(ValueError, match=r"cell Reynolds number .* = 42.2; the limit is 40"):
        cylinder(300)
    assert "Re <= 284" in recipes.not_expressible("cfdbench_cylinder_prop")


def test_a_recipe_as_published_has_nothing_changed_and_a_set_names_what_it_changed():
    for name in recipes.RECIPES:
        assert recipes.changed_from(name, g.get_pde(name).config()) == [], name
    pde = g.get_pde("pdearena_smoke2d", {"refine": "4", "nu": "0.01"})  # nu: the recipe's own value
    assert pde.recipe == "pdearena_smoke2d" and recipes.changed_from(pde.recipe, pde.config()) == ["refine"]
    assert recipes.changed_note("no_such_recipe", {"n": 3}) == ""


def test_training_a_recipe_takes_its_published_input_frames_unless_told(tmp_path):
    from pdestream.surrogate.config import TrainConfig
    from pdestream.surrogate.launch import input_frames

    pde = g.get_pde("pdebench_diffusion_sorption1d", {"n": "32", "n_frames": "12", "t_end": "5"})
    assert recipes.RECIPES["pdebench_diffusion_sorption1d"].input_frames == 10
    said = []
    assert input_frames(pde, TrainConfig(), said.append) == 10 and "--k-in 10: recipe pdebench_diffusion_sorption1d" in said[0]
    assert input_frames(pde, TrainConfig(k_in=2), said.append) == 2  # told
    assert input_frames(g.get_pde("pdebench_diffusion_sorption1d", {"n_frames": "8"}), TrainConfig(), said.append) == 1  # no room
    assert input_frames(g.get_pde("burgers1d"), TrainConfig(), said.append) == 1  # not a recipe
    assert input_frames(g.get_pde("fno_burgers1d"), TrainConfig(), said.append) == 1  # an operator set: none
    assert input_frames(pde, TrainConfig(view="operator"), said.append) == 1


@pytest.mark.slow
def test_a_trained_recipe_records_its_input_frames(tmp_path):
    from pdestream.surrogate.config import TrainConfig
    from pdestream.surrogate.launch import train

    lines = []
    s = train(TrainConfig(pde="pdebench_diffusion_sorption1d", settings={"n": "32", "n_frames": "12", "t_end": "5"}, out=str(tmp_path / "r"),
                          steps=1, batch_size=2, test_samples=1, threads=1, model_cfg={"width": 4, "modes": 2,
                                                                                         "layers": 1}), log=lines.append)
    run = json.loads((tmp_path / "r" / "run.json").read_text())
    assert s["steps"] == 1 and "k_in" in json.dumps(run) and '"k_in": 10' in json.dumps(run), run
