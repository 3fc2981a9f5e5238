"""``refine``: a spectral entry solved on n * refine points per axis with every refine-th point kept (the FNO
paper's Navier-Stokes sets: 256^2 solved, 64^2 kept; recipes fno_ns2d_nu1e-4 / _nu1e-5)."""

from __future__ import annotations

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from pdestream import generator
from pdestream.generator.spectral.fourier import Grid


@pytest.mark.parametrize("ndim", [1, 2, 3])
@pytest.mark.parametrize("factor", [2, 3, 4])
def test_interpolation_keeps_the_points_and_is_exact_for_band_limited_fields(ndim, factor):
    grid = Grid(ndim, 8, 2 * math.pi)
    u = np.random.default_rng(ndim).standard_normal((2, *grid.shape)).astype(np.float32)
    fine = np.asarray(grid.interpolate(jnp.asarray(u), factor))
    assert fine.shape == (2, *(8 * factor,) * ndim)
    np.testing.assert_allclose(fine[(Ellipsis, *(slice(None, None, factor),) * ndim)], u, atol=1e-5)
    # a field of modes below the Nyquist one is its own interpolant: the fine grid's samples of it
    x = Grid(ndim, 8 * factor, 2 * math.pi).coords().astype(np.float64)
    mesh = np.meshgrid(*(x,) * ndim, indexing="ij")
    exact = np.sin(3 * mesh[0] + 1.0) + np.cos(2 * mesh[-1])
    coarse = exact[tuple(slice(None, None, factor) for _ in range(ndim))]
    got = np.asarray(grid.interpolate(jnp.asarray(coarse, jnp.float32), factor))
    np.testing.assert_allclose(got, exact, atol=2e-5)


def test_interpolation_by_one_is_the_field_itself_and_a_bad_factor_is_one_line():
    u = jnp.asarray(np.random.default_rng(0).standard_normal((2, 8, 8)), jnp.float32)
    assert np.array_equal(np.asarray(Grid(2, 8, 1.0).interpolate(u, 1)), np.asarray(u))
    for bad in (0, -2, 1.5, True):
        with pytest.raises(ValueError, match=f"factor={bad!r} not allowed: need an integer >= 1"):
            Grid(2, 8, 1.0).interpolate(u, bad)


def test_a_refined_sample_is_the_fine_solve_with_its_points_kept_alone_and_in_a_batch():
    pde = generator.get_pde("fno_ns2d_nu1e-3").replace(n=16, refine=4, t_end=2.0, n_frames=3)
    fine = generator.get_pde("fno_ns2d_nu1e-3").replace(n=64, t_end=2.0, n_frames=3)
    batch = np.asarray(generator.sample(pde, [0, 1, 2], seed=5).u)
    assert batch.shape == (3, 3, 1, 16, 16)
    whole = np.asarray(generator.sample(fine, [0, 1, 2], seed=5).u)
    assert np.array_equal(batch, whole[..., ::4, ::4])
    assert np.array_equal(np.asarray(generator.sample(pde, [2], seed=5).u)[0], batch[2])
    # frame 0 is the fine IC's points, which the coarse grid alone could not draw (modes above its band)
    coarse = np.asarray(generator.sample(pde.replace(refine=1), [0], seed=5).u)[0, 0]
    assert not np.allclose(coarse, batch[0, 0], atol=1e-3)


def test_a_refined_solve_interpolates_the_callers_state_onto_the_solve_grid():
    """diffusion1d from a sine: the exact decay exp(-nu k^2 t) at the kept points, via the 4x finer grid."""
    pde = generator.get_pde("diffusion1d").replace(n=16, refine=4, length=2 * math.pi, t_end=0.5, n_frames=3,
                                                    nu="0.3")
    x = pde.grid.coords().astype(np.float64)
    u0 = np.sin(3 * x) + 0.5 * np.cos(5 * x)
    traj = generator.solve(pde, u0[None, None].astype(np.float32), {"nu": [0.3]})
    assert traj.u.shape == (1, 3, 1, 16)
    for i, t in enumerate(pde.times()):
        exact = np.exp(-0.3 * 9 * t) * np.sin(3 * x) + 0.5 * np.exp(-0.3 * 25 * t) * np.cos(5 * x)
        np.testing.assert_allclose(np.asarray(traj.u)[0, i, 0], exact, atol=3e-6)


def test_a_refined_cache_holds_the_kept_grid_and_says_it_was_solved_finer(tmp_path, capsys):
    from pdestream import cli, datasets

    path = tmp_path / "r.h5"
    assert cli.main(["generate", "diffusion1d", "--n", "2", "--set", "n=16", "--set", "refine=4", "--set", "n_frames=2",
                     "--set", "length=2", "--out", str(path)]) == 0
    with datasets.open_cache(path) as ds:  # the kept points' coordinates: spacing length / n, not length / (4 n)
        np.testing.assert_allclose(ds["x"].values, np.arange(16) * 2 / 16)
        assert ds["u"].sizes["x"] == 16 and json.loads(ds.attrs["pdestream_config"])["refine"] == 4
    capsys.readouterr()
    assert cli.main(["inspect", str(path)]) == 0
    assert "x=16 (solved on 4 times as many points per axis, 1 point in 4 kept)" in capsys.readouterr().out


def test_a_refined_block_holds_about_32_mib_of_the_solve_grids_trajectories():
    from pdestream.datasets import cache

    pde = generator.get_pde("ns2d", n=64, refine=16, n_frames=31)
    fine = 4 * pde.n_frames * (64 * 16) ** 2  # one trajectory on the 1024^2 grid solved on: 130 MB
    assert cache.default_block(pde, 1000) * fine <= max(fine, cache.TARGET_BLOCK_BYTES)
    assert cache.default_block(pde.replace(refine=1), 1000) == 2**25 // (4 * 31 * 64**2)  # unrefined: as before (66)


def test_refine_enters_the_config_only_above_one():
    plain = generator.get_pde("ns2d")
    assert "refine" not in plain.config()
    assert plain.replace(refine=1).config_hash() == plain.config_hash()
    refined = plain.replace(refine=2)
    assert refined.config()["refine"] == 2 and refined.config_hash() != plain.config_hash()
    assert "solved on 128x128" in refined.describe() and "1 point in 2 kept" in refined.describe()


@pytest.mark.parametrize("name, settings, words", [
    ("ns2d", {"refine": 0}, "refine=0 not allowed: need an integer >= 1"),
    ("ns2d", {"refine": 2.5}, "refine"),
    ("ns2d", {"refine": 100}, "refine=100 not allowed with n=64: the solve grid"),
    # too large a refine names the largest allowed (it was restated from the solve grid's n: "n <= 4096 in 1D")
    ("burgers1d", {"refine": 99999999999999999999}, "allowed: refine <= 65536 with n=256"),
    ("diffusion2d", {"bc": "dirichlet", "refine": 2}, "refine=2 not allowed with walls"),
])
def test_bad_refine_is_one_line_naming_it(name, settings, words):
    with pytest.raises(ValueError) as err:
        generator.get_pde(name).replace(**settings)
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("name, shown", [("ns2d", {"refine": 1, "t_start": 0.0}), ("darcy2d", {"points": "nodes"}),
                                          ("fno_ns2d_nu1e-4", {"refine": 4})])
def test_the_list_shows_the_settings_a_config_leaves_out_at_their_defaults(capsys, name, shown):
    """refine, t_start and points stay out of a config at their defaults (hashes unchanged), not out of the list."""
    from pdestream import cli

    assert cli.main(["list", name]) == 0
    out = capsys.readouterr().out
    assert cli.main(["list", name, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["settings"]
    for key, value in shown.items():
        assert f"\n  {key} = {value}\n" in out and rows[key]["default"] == value, (key, out)


def test_the_interactive_modes_refuse_a_refined_problem():
    pde = generator.get_pde("fno_ns2d_nu1e-3").replace(n=16, refine=2, t_end=1.0, n_frames=2)
    u = jnp.zeros((1, 1, 16, 16), jnp.float32)
    with pytest.raises(ValueError, match="refine=2 not allowed here"):
        generator.interactive.advance(pde, u, {"nu": jnp.full((1,), 1e-3, jnp.float32)})


def test_compare_modes_refuse_a_refined_oracle_before_any_work(tmp_path, capsys):
    # `compare --modes one-step,oracle --set refine=2` built the test set and trained the one-step arm, then refused
    # the oracle, leaving OUT with a run in it (and `--modes oracle` an empty OUT)
    from pdestream import cli

    for modes in ("oracle", "one-step,oracle"):
        out = tmp_path / modes
        assert cli.main(["compare", "burgers1d", "--modes", modes, "--set", "n=16", "--set", "refine=2", "--set",
                         "n_frames=4", "--steps", "1", "--seeds", "1", "--test-samples", "1", "--unroll", "1",
                         "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "refine=2 not allowed here" in err and "test set" not in err and not out.exists(), (modes, err)


def test_a_cache_of_another_refine_names_both_values_not_none():
    # train --source CACHE --set refine=1 on a refined cache said "refine: cache 2 vs asked None" (a config leaves
    # refine out at 1)
    from pdestream.surrogate.checks import check_cache_matches

    plain, refined = generator.get_pde("burgers1d", n=16), generator.get_pde("burgers1d", n=16, refine=2)
    for cache, asked, said in ((refined, plain, "refine: cache 2 vs asked 1"), (plain, refined, "refine: cache 1 vs asked 2")):
        with pytest.raises(ValueError) as err:
            check_cache_matches("c.h5", cache.config(), asked, {"refine": "x"})
        assert said in str(err.value), str(err.value)


def test_a_cache_of_the_automatic_step_says_so_not_none():
    # train --source CACHE --set dt=0.001 on a cache of the automatic step said "dt: cache None vs asked 0.001"
    from pdestream.surrogate.checks import check_cache_matches

    auto, fixed = generator.get_pde("burgers1d", n=16), generator.get_pde("burgers1d", n=16, dt=0.001)
    for cache, asked, said in ((auto, fixed, "dt: cache automatic (the stable step) vs asked 0.001"),
                               (fixed, auto, "dt: cache 0.001 vs asked automatic (the stable step)")):
        with pytest.raises(ValueError) as err:
            check_cache_matches("c.h5", cache.config(), asked, {"dt": "x"})
        assert said in str(err.value) and "None" not in str(err.value), str(err.value)


def test_a_refined_problem_steps_as_its_solve_grid_and_the_operator_arm_stores_its_frames():
    # step_dt was the kept grid's (0.02 here, unstable on the solve grid): compare --budget's operator arm pinned it
    # as dt and refused the run ("dt=0.020000000020000002 is unstable"), leaving OUT behind; a blow-up named it too
    from pdestream import datasets
    from pdestream.experiments.budget import stored_pde

    pde = generator.get_pde("burgers1d", n=16, refine=2, n_frames=5)
    assert pde.step_dt == pde.solved.step_dt and pde.steps_per_frame == pde.solved.steps_per_frame
    stored = stored_pde(pde, datasets.make_view("operator"))
    full = np.asarray(generator.sample(pde, range(2), seed=1).u)
    ends = np.asarray(generator.sample(stored, range(2), seed=1).u)
    assert stored.n_frames == 2 and np.array_equal(ends[:, -1], full[:, -1]) and np.array_equal(ends[:, 0], full[:, 0])


def test_the_fno_recipes_at_low_viscosity_solve_on_256_and_keep_64():
    for name, t_end in (("fno_ns2d_nu1e-4", 30.0), ("fno_ns2d_nu1e-5", 20.0)):
        pde = generator.get_pde(name)
        assert (pde.n, pde.refine, pde.solved.n, pde.t_end, pde.n_frames) == (64, 4, 256, t_end, int(t_end) + 1)
        assert pde.grid.shape == (64, 64) and pde.solved.grid.shape == (256, 256)


def test_the_forced_velocity_bound_grows_from_rest_at_most_by_the_forcings_rms():
    """The diagonal forcing 0.1 (sin + cos)(2 pi (x + y)) is the curl of a body force of amplitude 0.1 / (2 pi):
    rms 0.1 / (2 pi sqrt 2). The bound's growth term caps the laminar amplitude (1 / nu) in a short window, and
    leaves the entries whose laminar amplitude is the smaller unchanged."""
    pde = generator.get_pde("fno_ns2d_nu1e-3")
    assert pde.forcing_velocity_rms(pde.grid) == pytest.approx(0.1 / (2 * math.pi * math.sqrt(2)), rel=1e-6)
    k_f = 2 * math.pi
    assert pde.derived_velocity_bound() == pytest.approx(0.1 / (k_f * 2e-3 * k_f**2), rel=1e-9)  # laminar, as before
    low = generator.get_pde("fno_ns2d_nu1e-5").solved
    ic = low.replace(t_end=1e-9, n_frames=2).derived_velocity_bound()  # the IC's 4 std, no growth yet
    assert low.derived_velocity_bound() == pytest.approx(ic + 4 * 20.0 * 0.1 / (2 * math.pi * math.sqrt(2)), rel=1e-6)
    assert generator.get_pde("ns2d").derived_velocity_bound() == pytest.approx(1 / (0.01 * 16 + 0.1))  # laminar
