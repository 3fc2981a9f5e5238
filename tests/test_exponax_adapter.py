"""The Exponax adapter (generator.adapters.exponax): five steppers of 1, 2 and 3 dimensions agree with Exponax
run directly (the sample's parameters and first frame into the stepper, exponax.rollout); a sample's bits do not
depend on its batch; explicit parameters; the CLI writes a cache that reads back; refusals are one line."""

import json
import pickle
import sys

import numpy as np
import pytest

exponax = pytest.importorskip("exponax")

from pdestream import cli, datasets, generator  # noqa: E402
from pdestream.generator.external import exponax as adapter  # noqa: E402

# (name, settings, a parameter given a random domain): different dimensions, small grids (2D KS and 3D: slow set)
CASES = [
    ("exponax:Burgers", {"n": 32, "n_frames": 6, "dt": 0.01, "diffusivity": "uniform(0.01, 0.1)"}, "diffusivity"),
    ("exponax:KortewegDeVries", {"n": 32, "length": 20.0, "n_frames": 6, "dt": 0.01, "n_steps_per_frame": 2,
                                 "dispersivity": "uniform(0.5, 1.5)"}, "dispersivity"),
    ("exponax:Diffusion2d", {"n": 32, "n_frames": 5, "dt": 0.01, "diffusivity": "loguniform(0.001, 0.01)"},
     "diffusivity"),
    pytest.param("exponax:KuramotoSivashinsky", {"num_spatial_dims": 2, "n": 32, "length": 30.0, "n_frames": 5, "dt": 0.05,
                                     "gradient_norm_scale": "uniform(0.5, 1.0)"}, "gradient_norm_scale",
                 marks=pytest.mark.slow, id="KuramotoSivashinsky2d"),
    pytest.param("exponax:Advection3d", {"n": 16, "n_frames": 4, "dt": 0.01, "velocity": "uniform(-1, 1)"},
                 "velocity", marks=pytest.mark.slow, id="Advection3d"),
]


def direct(pde, params: dict, u0):
    """Exponax run directly: its stepper with these parameters, exponax.rollout from u0."""
    stepper = adapter.steppers()[pde.STEPPER](pde.num_spatial_dims, pde.length, pde.n, pde.dt,
                                              **{k: float(v) for k, v in params.items()})
    if pde.n_steps_per_frame > 1:
        stepper = exponax.RepeatedStepper(stepper, pde.n_steps_per_frame)
    return np.asarray(exponax.rollout(stepper, pde.n_frames - 1, include_init=True)(u0))


@pytest.mark.parametrize("name, settings, varied", CASES)
def test_samples_agree_with_exponax_run_directly(name, settings, varied):
    pde = generator.get_pde(name, settings)
    assert pde.NAME == f"exponax:{pde.STEPPER}" and name.startswith(pde.NAME)
    traj = generator.sample(pde, [0, 1, 2], seed=7)
    u = np.asarray(traj.u)
    assert u.shape == (3, pde.n_frames, len(pde.FIELDS), *(pde.n,) * pde.NDIM) and np.isfinite(u).all()
    assert len(set(np.asarray(traj.params[varied]).tolist())) == 3  # drawn per sample
    assert np.std(u[:, -1]) > 0 and not np.array_equal(u[0], u[1])
    worst = (0.0, 0.0)
    for i in range(3):
        ref = direct(pde, {k: v[i] for k, v in traj.params.items()}, u[i, 0])
        diff = np.abs(ref - u[i]).max()
        worst = max(worst[0], diff), max(worst[1], diff / np.abs(ref).max())
        np.testing.assert_allclose(u[i], ref, rtol=1e-5, atol=1e-6 * np.abs(ref).max())
    print(f"{name} {pde.NDIM}D: max abs diff {worst[0]:.3g}, max rel diff {worst[1]:.3g}")
    # identity: sample 1 alone is the batch's sample 1, bit for bit
    alone = generator.sample(pde, [1], seed=7)
    assert np.array_equal(np.asarray(alone.u[0]), u[1])
    # explicit parameters: a given value is used, the IC still comes from (seed, index)
    value = float(np.asarray(traj.params[varied])[0])
    given = generator.sample(pde, [1], seed=7, params={varied: value})
    assert float(given.params[varied][0]) == np.float32(value)
    assert np.array_equal(np.asarray(given.u[0, 0]), u[1, 0])
    ref = direct(pde, {k: v[0] for k, v in given.params.items()}, u[1, 0])
    np.testing.assert_allclose(np.asarray(given.u[0]), ref, rtol=1e-5, atol=1e-6 * np.abs(ref).max())


def test_config_pickle_and_dimensions():
    pde = generator.get_pde("exponax:Burgers", n=32, diffusivity="uniform(0.01, 0.1)", dt=0.02)
    assert pde.NDIM == 1 and pde.FIELDS == ("u",) and pde.config()["exponax_version"] == exponax.__version__
    assert generator.from_config(pde.config()) == pde and pickle.loads(pickle.dumps(pde)) == pde
    two = pde.replace(num_spatial_dims="2")  # as from --set: the 2D entry, the other settings kept
    assert two.NDIM == 2 and two.FIELDS == ("u0", "u1") and two.dt == 0.02 and str(two.diffusivity) == str(
        pde.diffusivity)
    assert two == generator.get_pde("exponax:Burgers2d", n=32, diffusivity="uniform(0.01, 0.1)", dt=0.02)
    assert generator.from_config(two.config()) == two and pickle.loads(pickle.dumps(two)) == two
    assert two.config_hash() != pde.config_hash()
    traj = generator.sample(pde.replace(n_frames=3), [0, 1], seed=3)  # generator.solve from the samples' ICs
    again = generator.solve(traj.pde, traj.u[:, 0], traj.params)
    assert np.array_equal(np.asarray(again.u), np.asarray(traj.u))
    assert "diffusivity ~ uniform(0.01, 0.1)" in pde.describe() and "convection_scale = 1.0 (fixed)" in pde.describe()


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_generate_a_cache_through_the_cli(tmp_path, capsys):
    out_path = tmp_path / "b.zarr"
    args = ["generate", "exponax:Burgers", "--n", "4", "--out", str(out_path), "--set", "n=32", "--set",
            "n_frames=4", "--set", "diffusivity=uniform(0.01, 0.1)"]
    code, out, err = run(capsys, *args)
    assert code == 0 and "wrote 4 samples" in out, err
    code, out, err = run(capsys, *args, "--resume")
    assert code == 0 and "already complete" in out, err
    cache = datasets.open_cache(out_path)
    pde = generator.from_config(json.loads(cache.attrs["pdestream_config"]))
    assert pde == generator.get_pde("exponax:Burgers", n=32, n_frames=4, diffusivity="uniform(0.01, 0.1)")
    stored = np.asarray(cache["u"].values)  # one variable per field: [sample, time, x]
    assert np.array_equal(stored, np.asarray(generator.sample(pde, range(4), seed=0).u)[:, :, 0])


def test_refusals_are_one_line(capsys, monkeypatch, tmp_path):
    cases = {"exponax:Nope": "unknown Exponax stepper 'Nope'; allowed: Advection,",
             "exponax:NavierStokesVorticity": "exponax:NavierStokesVorticity in 1D not allowed: Exponax refuses it"}
    for name, needle in cases.items():
        code, out, err = run(capsys, "generate", name, "--n", "2", "--out", str(tmp_path / "x.zarr"))
        assert code == 2 and err.count("\n") == 1 and needle in err and "Traceback" not in err, err
    with pytest.raises(ValueError, match="num_spatial_dims=4 not allowed: 1, 2 or 3"):
        generator.get_pde("exponax:Burgers", num_spatial_dims=4)
    with pytest.raises(ValueError, match="unknown setting 'order'"):
        generator.get_pde("exponax:Burgers", order=3)
    with pytest.raises(ValueError, match="exponax_version='0.0.1' but exponax .* is installed"):
        generator.get_pde("exponax:Burgers", exponax_version="0.0.1")
    with pytest.raises(ValueError, match="dt=-0.1 not allowed"):
        generator.get_pde("exponax:Burgers", dt=-0.1)
    monkeypatch.setitem(sys.modules, "exponax", None)  # as if not installed
    with pytest.raises(ValueError, match="^exponax is not installed: pip install exponax$"):
        generator.get_pde("exponax:Wave")
