"""The corrector's fine -> coarse restriction (issue 29, ``--restrict fourier|points``): the Fourier truncation on
periodic axes (``surrogate.modes.fourier_restrict``) against point sampling, walls and staggered fields left as
they were, and what run.json records (a run.json without "restrict" reads back as point sampling)."""

import json
import math

import pytest
import torch

from pdestream import cli, generator
from pdestream.experiments.interactive_compare import _finished
from pdestream.experiments.interactive_config import InteractiveConfig, arm_settings, comparable_mode
from pdestream.surrogate.mode_table import mode_settings
from pdestream.surrogate.modes import fourier_restrict, make_mode, subsample
from tests.test_sitl_noise import corrector_train_argv

torch.set_num_threads(1)

FINE = generator.get_pde("burgers1d", n=32, n_frames=11)


def _grid(n: int) -> torch.Tensor:
    """x_i = 2 pi i / n, float64 [n]."""
    return torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)


@pytest.mark.parametrize("n, factor", [(64, 4), (45, 3)])  # even and odd coarse grids (16, 15)
def test_a_field_the_coarse_grid_resolves_restricts_to_the_same_values_both_ways(n, factor):
    x = _grid(n)
    nc = n // factor
    top = (nc - 1) // 2  # the highest wavenumber below the coarse Nyquist
    u1 = 0.3 + torch.sin(x) - 0.7 * torch.cos(top * x + 0.4) + 0.2 * torch.sin(2 * x)
    u2 = u1[:, None] * (1 + torch.cos(top * x - 1.0))[None, :]  # [n, n], band-limited in both axes
    for u, ndim in ((u1[None, None], 1), (u2[None, None], 2)):
        points, fourier = subsample(u, factor, ndim), subsample(u, factor, ndim, restrict="fourier")
        assert fourier.shape == points.shape == (1, 1, *(nc,) * ndim)
        assert torch.allclose(fourier, points, atol=1e-12), float((fourier - points).abs().max())


def test_a_mode_at_the_coarse_n_is_dropped_by_fourier_and_aliased_to_a_constant_by_points():
    n, nc = 64, 16
    u = torch.cos(nc * _grid(n))[None, None].float()  # k = n_coarse: every coarse point sees its crest
    assert torch.equal(subsample(u, n // nc, 1), torch.ones(1, 1, nc))  # the mean the coarse solver would keep
    assert float(subsample(u, n // nc, 1, restrict="fourier").abs().max()) < 1e-6
    nyquist = torch.cos(nc // 2 * _grid(n))[None, None].float()  # the coarse Nyquist mode: zeroed
    assert float(subsample(nyquist, n // nc, 1, restrict="fourier").abs().max()) < 1e-6
    assert float(subsample(nyquist, n // nc, 1).abs().min()) == 1.0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fourier_keeps_the_mean_of_random_fields(dtype):
    gen = torch.Generator().manual_seed(0)
    u = (torch.randn(4, 3, 64, 64, generator=gen, dtype=torch.float64) + 2.0).to(dtype)
    fourier, points = subsample(u, 4, 2, restrict="fourier"), subsample(u, 4, 2)
    tol = 1e-6 if dtype == torch.float32 else 1e-13
    assert fourier.dtype == dtype
    assert torch.allclose(fourier.double().mean((-2, -1)), u.double().mean((-2, -1)), atol=tol, rtol=0)
    assert not torch.allclose(points.double().mean((-2, -1)), u.double().mean((-2, -1)), atol=1e-3)  # it aliases


def test_walls_and_staggered_fields_are_restricted_alike_either_way():
    gen = torch.Generator().manual_seed(1)
    u = torch.randn(2, 3, 32, 32, generator=gen)
    for bc in (("dirichlet",), ("neumann",)):
        v = u[:, :, 0]
        assert torch.equal(subsample(v, 4, 1, bc, restrict="fourier"), subsample(v, 4, 1, bc))
    locations = ("face_x", "face_y", "centre")
    assert torch.equal(subsample(u, 4, 2, None, locations, "fourier"), subsample(u, 4, 2, None, locations))
    # periodic x, walls y: the walls axis keeps its cell means, the periodic one is truncated
    mixed = subsample(u, 4, 2, ("periodic", "dirichlet"), restrict="fourier")
    assert mixed.shape == (2, 3, 8, 8)
    assert torch.allclose(mixed, fourier_restrict(0.5 * (u[..., 1::4] + u[..., 2::4]), 8, 2), atol=1e-6)
    assert torch.equal(subsample(u, 4, 2, ("periodic", "dirichlet")), 0.5 * (u[..., ::4, 1::4] + u[..., ::4, 2::4]))


def test_fourier_restrict_refuses_a_coarse_grid_finer_than_the_fine_in_one_line():
    with pytest.raises(ValueError, match=r"^fourier_restrict: n_coarse=40 not allowed on an axis of 32 points"):
        fourier_restrict(torch.zeros(1, 32), 40, 1)


def test_settings_record_fourier_where_it_acts_and_absence_reads_as_points():
    new = mode_settings("solver-in-the-loop", coarse_n=16)
    assert new["restrict"] == "fourier"  # the default for a new run
    assert make_mode(new, FINE).settings()["restrict"] == "fourier"
    assert "restrict" not in make_mode({**new, "restrict": "points"}, FINE).settings()
    walls = generator.get_pde("burgers1d", n=32, n_frames=11, bc="dirichlet")
    assert "restrict" not in make_mode(new, walls).settings()  # no periodic axis: nothing to record
    old = make_mode({"name": "solver-in-the-loop", "unroll": 8, "coarse_n": 16})  # a run.json before the setting
    assert old.restrict == "points"
    with pytest.raises(ValueError, match=r"--restrict='spline' not allowed; allowed: fourier, points"):
        mode_settings("solver-in-the-loop", restrict="spline")
    with pytest.raises(ValueError, match=r"--restrict=points goes with solver-in-the-loop, not one-step"):
        mode_settings("one-step", restrict="points")


def test_the_coarse_rollout_restricts_start_and_reference_as_asked():
    u = torch.randn(2, 3, 1, 32, generator=torch.Generator().manual_seed(2))
    params = torch.full((2, len(FINE.PARAMS)), 0.05)
    for how in ("fourier", "points"):
        mode = make_mode(mode_settings("solver-in-the-loop", unroll=1, coarse_n=16, restrict=how)).bind(FINE)
        _, truth = mode.rollout(None, None, u, params)
        assert torch.allclose(truth, subsample(u[:, 1:], 2, 1, restrict=how))


def test_train_records_it_and_an_old_run_reads_back_as_points(tmp_path, capsys):
    new, old = tmp_path / "new", tmp_path / "old"
    assert cli.main(corrector_train_argv(new, 1)) == 0
    assert json.loads((new / "run.json").read_text())["mode"]["restrict"] == "fourier"
    assert cli.main(corrector_train_argv(old, 1, "--restrict", "points")) == 0
    mode = json.loads((old / "run.json").read_text())["mode"]
    assert "restrict" not in mode and make_mode(mode).restrict == "points"  # as every run.json before the option
    # compare's read-back of a finished arm: the default (fourier) refused in one line naming --restrict points
    cfg = InteractiveConfig(modes=("solver-in-the-loop",), steps=2, batch_size=4, lr=1e-3, coarse_n=16,
                            model_cfg=json.loads((old / "run.json").read_text())["model_cfg"])  # as --model-set wrote it
    pde = FINE.replace({"n": 32})
    with pytest.raises(ValueError, match=r"restrict the run's points, asked fourier: pass --restrict points\);") as e:
        _finished(old, pde, arm_settings(cfg, "solver-in-the-loop", unroll=1, noise=0.0), cfg, 0)
    assert "\n" not in str(e.value)
    cfg.restrict = "points"
    assert _finished(old, pde, arm_settings(cfg, "solver-in-the-loop", unroll=1, noise=0.0), cfg, 0) is not None
    # train --resume goes on with the run's own restriction; another one is refused naming what to drop
    assert cli.main(["train", "--resume", str(old), "--restrict", "fourier"]) == 2
    assert "drop --restrict" in capsys.readouterr().err


def test_a_grid_the_flag_does_not_act_on_compares_equal_whatever_it_says():
    """Walls on every axis (or staggered fields): a run.json without "restrict" (written before the option, or by a
    fourier run there, which does not record it) reads back under the default; on a periodic grid it does not."""
    walled = generator.get_pde("burgers1d", n=32, n_frames=11, bc="dirichlet")
    old = {"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16}
    new = mode_settings("solver-in-the-loop", unroll=1, coarse_n=16, restrict="fourier")
    assert comparable_mode(old, walled) == comparable_mode(new, walled)
    assert comparable_mode(old, FINE) != comparable_mode(new, FINE)
    assert comparable_mode(old, FINE) == comparable_mode({**new, "restrict": "points"}, FINE)
    karman = generator.get_pde("karman2d")  # staggered (MAC) fields
    assert comparable_mode(old, karman) == comparable_mode(new, karman)


def test_compare_md_names_the_restriction_only_where_it_acts():
    """adv51: compare.md said "restriction on periodic axes: Fourier truncation" of a grid with walls on every axis
    and of karman2d's staggered fields, where --restrict does not act (the arms there may have run with points)."""
    from pdestream.experiments.interactive_report import restriction_words

    assert restriction_words("fourier", FINE) == ("fine -> coarse restriction on periodic axes: Fourier truncation "
                                                  "(the coarse grid's modes, its Nyquist mode zeroed)")
    assert restriction_words("points", FINE).endswith("point sampling (every factor-th point)")
    walled = generator.get_pde("burgers1d", n=32, n_frames=11, bc="dirichlet")
    for pde in (walled, generator.get_pde("karman2d")):
        for how in ("fourier", "points"):
            words = restriction_words(how, pde)
            assert "Fourier" not in words and "point sampling" not in words and "does not act" in words, words


@pytest.mark.parametrize("command", ["train", "compare"])
@pytest.mark.parametrize("restrict", ["fourier", "points"])
def test_an_explicit_restrict_on_a_grid_it_does_not_act_on_is_refused_in_one_line(tmp_path, capsys, command, restrict):
    """adv51: `--restrict fourier` on walls ran rc 0, the flag unread (the house refuses options no arm reads).
    Nothing is written; the default (no flag) still runs there (test above)."""
    out = tmp_path / "run"
    argv = corrector_train_argv(out, 1, "--set", "bc=dirichlet", "--restrict", restrict)
    if command == "compare":
        argv = ["compare", "burgers1d", "--modes", "solver-in-the-loop", "--quick", "--set", "bc=dirichlet",
                "--restrict", restrict, "--out", str(out)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert f"--restrict {restrict} does not act on burgers1d (no periodic axis" in err and "\n" not in err, err
    assert not out.exists()


def test_an_explicit_restrict_on_staggered_fields_names_them():
    from pdestream.surrogate.mode_table import check_restrict_acts

    check_restrict_acts(generator.get_pde("karman2d"), None)  # not given: nothing to refuse
    with pytest.raises(ValueError, match=r"karman2d \(staggered \(MAC\) fields"):
        check_restrict_acts(generator.get_pde("karman2d"), "fourier")
    check_restrict_acts(FINE, "points")  # acts on a periodic grid


@pytest.mark.parametrize("name, settings, restrict, words", [
    ("burgers1d", {}, "fourier", "against the fine solution Fourier-truncated"),
    ("burgers1d", {}, None, "against the fine solution subsampled"),  # run.json before the setting: points
    # adv52: a grid with walls restricts by the mean of the two fine points around each coarse centre whatever
    # --restrict says (the run records none): the report said "subsampled"
    ("diffusion1d", {"bc": "dirichlet"}, None, "against the fine solution averaged to the coarse cell centres"),
    ("diffusion2d", {"bc.x": "dirichlet"}, "fourier",
     "against the fine solution Fourier-truncated on its periodic axes, averaged to the coarse cell centres across "
     "its walls"),
])
def test_the_run_report_names_the_restriction_the_grid_takes(name, settings, restrict, words):
    from pdestream.surrogate.launch import run_report

    mode = {"name": "solver-in-the-loop", "unroll": 2, "coarse_n": 16, **({"restrict": restrict} if restrict else {})}
    s = {"steps": 2, "wall": 1.0, "t_data": 0.0, "t_compute": 1.0, "data_share": 0.0, "trajectories_seen": 2,
         "final_loss": 0.1, "test": {"test": {"rel_l2": 0.1, "nrmse": 0.1}}, "mode": mode,
         "pde": generator.get_pde(name, {"n": 32, **settings}).config()}
    assert f"(errors on the coarse grid n=16, {words})" in run_report(s, "fno", "stream", 2, "run")


def test_the_corrector_figures_name_the_restriction_only_where_it_acts():
    """adv52: compare.png's and corrector.png's titles said "Fourier-restricted" of a grid with walls on every axis
    (compare's default --restrict is fourier; adv51 fixed compare.md's words only)."""
    from pdestream.experiments.interactive_report import _restriction

    walled = generator.get_pde("burgers1d", n=32, n_frames=11, bc="dirichlet")
    assert _restriction({"config": {"restrict": "fourier"}, "fine_pde": FINE.config()}) == "Fourier-restricted"
    assert _restriction({"config": {}, "fine_pde": FINE.config()}) == "subsampled"
    assert _restriction({"config": {"restrict": "fourier"}, "fine_pde": walled.config()}) == "cell / face means"
