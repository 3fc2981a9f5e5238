"""`refine` on the 2D flows: solve on n * refine cells per axis and store each block's means (``FlowProblem.restrict``),
as PDEArena's smoke recipe does (solved on 384^2, stored on 128^2); its identity, its divergence, its refusals."""

import jax.numpy as jnp
import numpy as np
import pytest

from pdestream import generator

# a small closed smoke box: 8^2 stored, 16^2 solved, a short window
SMALL = {"n": 8, "refine": 2, "t_end": 0.4, "n_frames": 3}


def _faces_divergence(u, v):
    """Per-cell flux balance of stored MAC frames [..., nx, ny] of a closed box (the right-most u and top v
    faces are walls: 0)."""
    uu = np.concatenate([u, np.zeros_like(u[..., :1, :])], -2)
    vv = np.concatenate([v, np.zeros_like(v[..., :1])], -1)
    return (uu[..., 1:, :] - uu[..., :-1, :]) + (vv[..., 1:] - vv[..., :-1])


def test_a_refined_sample_is_the_fine_solve_restricted_alone_and_in_a_batch():
    pde = generator.get_pde("smoke_box2d", SMALL)
    coarse = np.asarray(generator.sample(pde, range(2), seed=3).u)
    fine = np.asarray(generator.sample(pde.solved, range(2), seed=3).u)
    assert pde.solved.n == 16 and coarse.shape == (2, 3, 4, 8, 8) and fine.shape == (2, 3, 4, 16, 16)
    # the restriction written out with numpy: u the mean of the 2 fine faces on a coarse left face, v likewise on a
    # bottom face, p and smoke the 2 x 2 blocks' means
    want = np.stack([(fine[:, :, 0, ::2, 0::2] + fine[:, :, 0, ::2, 1::2]) / 2,
                     (fine[:, :, 1, 0::2, ::2] + fine[:, :, 1, 1::2, ::2]) / 2,
                     fine[:, :, 2].reshape(2, 3, 8, 2, 8, 2).mean((3, 5)),
                     fine[:, :, 3].reshape(2, 3, 8, 2, 8, 2).mean((3, 5))], axis=2)
    np.testing.assert_allclose(coarse, want, rtol=0, atol=1e-6)
    alone = np.asarray(generator.sample(pde, [1], seed=3).u)[0]
    assert np.array_equal(alone, coarse[1])  # bit for bit in a batch of one
    assert np.abs(coarse[:, 1:, 3] - coarse[:, :1, 3]).max() > 1e-3  # the smoke moved (the check above could fail)


@pytest.mark.slow
def test_the_stored_face_means_keep_a_divergence_free_field_divergence_free():
    pde = generator.get_pde("smoke_box2d", {**SMALL, "refine": 3})
    fine = np.asarray(generator.sample(pde.solved, range(1), seed=0).u)
    coarse = np.asarray(pde.restrict(jnp.asarray(fine)))
    speed = np.abs(coarse[:, 1:, :2]).max()
    assert speed > 1e-3
    fine_div = np.abs(_faces_divergence(fine[:, :, 0], fine[:, :, 1])).max()
    coarse_div = np.abs(_faces_divergence(coarse[:, :, 0], coarse[:, :, 1])).max()
    assert coarse_div <= 3 * fine_div + 1e-7 * speed  # the coarse cell's balance is the sum of its 9 fine ones
    # a point-sampled field (every third face) keeps no such balance: the check can tell
    picked = _faces_divergence(fine[:, :, 0, ::3, 1::3], fine[:, :, 1, 1::3, ::3])
    assert np.abs(picked).max() > 10 * coarse_div + 1e-6


def test_refine_enters_the_config_only_above_one_and_describes_both_grids():
    plain = generator.get_pde("smoke_box2d")
    assert "refine" not in plain.config() and plain.replace(refine=1).config_hash() == plain.config_hash()
    refined = plain.replace(refine=2)
    assert refined.config()["refine"] == 2 and refined.config_hash() != plain.config_hash()
    text = refined.describe()
    assert "32x32 cells on [0, 1]" in text and "solved on 64x64 cells (each 2x2 block's means stored)" in text
    assert refined.step_dt == refined.solved.step_dt < plain.step_dt  # the solve grid's step


def test_the_solve_grid_decides_the_cell_reynolds_limit():
    # PDEArena's box at 128^2: cell Reynolds number 100, refused; solved on 384^2 (33): accepted
    settings = {"n": 128, "length": 32.0, "buoyancy": "0.5", "nu": "0.01", "ic.scale": 11.0}
    with pytest.raises(ValueError, match="cell Reynolds number"):
        generator.get_pde("smoke_box2d", settings)
    with pytest.raises(ValueError, match=r"refine=2 not allowed with n=128: the solve grid \(n \* refine = 256"):
        generator.get_pde("smoke_box2d", {**settings, "refine": 2})
    assert generator.get_pde("smoke_box2d", {**settings, "refine": 3}).solved.n == 384


@pytest.mark.parametrize("name, settings, words", [
    ("smoke_box2d", {"refine": 0}, "refine=0 not allowed: need an integer >= 1"),
    ("smoke_box2d", {"refine": 1.5}, "refine: 1.5 is not an integer"),
    ("smoke_box2d", {"refine": True}, "refine"),
    ("karman2d", {"refine": 2}, "refine=2 not allowed: entries with bodies or per-sample outputs"),
    ("channel2d", {"refine": 2}, "refine=2 not allowed: entries with bodies"),
    ("plume3d", {"refine": 2}, "refine=2 not allowed: 3D flows"),
    ("cavity2d", {"refine": 400}, "refine=400 not allowed with n=64: the solve grid"),
    # a grid past the size limit is refused as that, before the multigrid's search for a nearby n (linear in n:
    # refine=99999999999999999999 or n=1e20 + 2 hung); these two were refused as the multigrid's, naming the solve
    # grid's n; a refine too large names the largest refine allowed
    ("smoke2d", {"refine": 100000}, "refine=100000 not allowed with n=32: the solve grid would hold 1024 * 100000^2 "
                                    "points per field; the limit is 16777216; allowed: refine <= 128 with n=32"),
    ("cavity2d", {"n": 1000002}, "n=1000002 not allowed: 1000004000004 grid points per field"),
    # the multigrid's nearby n are coarse n that work at this refine (it named the solve grid's: "196 or 200")
    ("cavity2d", {"n": 66, "refine": 3}, "refine=3 with n=66 (solved on 198 cells across) not allowed: the pressure "
                                         "multigrid"),
    ("cavity2d", {"n": 66, "refine": 3}, "nearby n that halve further with refine=3: 64 or 68"),
    ("cavity2d", {"n": 8, "refine": 65}, "no n halves further with refine=65"),
])
def test_bad_refine_is_one_line_naming_it(name, settings, words):
    with pytest.raises(ValueError) as err:
        generator.get_pde(name, settings)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_the_interactive_modes_refuse_a_refined_flow():
    pde = generator.get_pde("smoke_box2d", SMALL)
    u = jnp.zeros((1, 4, 8, 8), jnp.float32)
    params = {"buoyancy": jnp.ones((1,), jnp.float32), "nu": jnp.full((1,), 2e-3, jnp.float32)}
    with pytest.raises(ValueError, match="refine=2 not allowed here"):
        generator.interactive.advance(pde, u, params)


def test_cavity_warns_about_the_solve_grid_once():
    import warnings

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        generator.get_pde("cavity2d", {"n": 32, "refine": 2, "re": "uniform(100, 1000)"})
    said = [str(w.message) for w in seen if "under-resolved" in str(w.message)]
    assert len(said) == 1 and "on n=64" in said[0]


def test_pdearena_smoke_recipe_solves_on_384_and_stores_128():
    pde = generator.get_pde("pdearena_smoke2d")
    assert (pde.n, pde.refine, pde.solved.n, pde.length) == (128, 3, 384, 32.0)
    assert pde.grid.shape == (128, 128) and pde.n_frames == 14 and (pde.t_start, pde.t_end) == (13.5, 91.5)
    assert pde.solved.speed_bound() * pde.solved.h / 0.01 <= pde.MAX_CELL_REYNOLDS


@pytest.mark.slow  # a flow compile (~25 s on 2 shared cores)
def test_inspect_says_a_refined_flow_cache_holds_block_means(tmp_path, capsys):
    # a flow stores each block's means, not every k-th point (inspect said "1 point in 2 kept", a spectral refine's)
    from pdestream import cli

    path = tmp_path / "s.h5"
    args = [f"{k}={v}" for k, v in SMALL.items()]
    assert cli.main(["generate", "smoke_box2d", "--n", "1", "--out", str(path)]
                    + [w for a in args for w in ("--set", a)]) == 0
    capsys.readouterr()
    assert cli.main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "x=8 (solved on 2 times as many points per axis, each 2x2 block's means stored)" in out
    assert "kept)" not in out


def test_solve_from_a_callers_state_refuses_a_flow_in_one_line():
    # generator.solve(flow, u0, params) raised AttributeError ('SmokeBox2D' object has no attribute 'evolve')
    for settings in ({**SMALL, "n": 16, "refine": 1}, SMALL):
        pde = generator.get_pde("smoke_box2d", settings)
        with pytest.raises(ValueError, match="smoke_box2d: its solver does not start from a caller's state") as err:
            generator.solve(pde, np.zeros((1, 4, *pde.grid.shape), np.float32), {"buoyancy": [1.0], "nu": [2e-3]})
        assert "allowed: sample(pde, indices, seed" in str(err.value)


@pytest.mark.parametrize("settings, said", [
    ({"n_frames": 1}, "smoke_box2d: n_frames=1 not allowed: must be >= 2"),
    ({"cfl": 5}, "smoke_box2d: cfl=5 not allowed"),
    ({"advection": "x"}, "smoke_box2d: advection='x' not allowed"),
    ({"max_iter": 0}, "smoke_box2d: max_iter=0 not allowed"),
])
def test_a_setting_bad_on_any_grid_is_not_blamed_on_refine(settings, said):
    # it was "refine=2 not allowed with n=8: the solve grid (n * refine = 16 cells across) fails: n_frames=1 ..."
    with pytest.raises(ValueError) as err:
        generator.get_pde("smoke_box2d", {**SMALL, **settings})
    assert str(err.value).startswith(said) and "refine" not in str(err.value), str(err.value)
