"""A walled (Dirichlet / Neumann) entry through everything pdestream does with samples: stream == cache (Zarr and
HDF5, bc recorded where xarray shows it), the reservoir, the solver oracle, the differentiable step's gradients
(float64 finite differences), pickling for spawned workers, and the one-line refusals of bad boundary settings."""

import pickle

import jax
import numpy as np
import pytest
import torch
import xarray as xr

from pdestream import datasets, generator
from pdestream.datasets import _bridge
from pdestream.datasets.reservoir import ReservoirStream
from pdestream.datasets.solver import SolverOracle, SolverStep

torch.set_num_threads(1)
SETTINGS = {"n": 32, "n_frames": 5, "t_end": 0.2, "bc": "dirichlet", "bc_lo": "uniform(0, 1)", "bc_hi": "-0.5"}


@pytest.fixture(scope="module")
def pde():
    return generator.get_pde("burgers1d", **SETTINGS)


@pytest.mark.parametrize("fmt", ["zarr", "h5"])
def test_stream_and_cache_give_the_same_bits_and_the_cache_records_the_walls(pde, tmp_path, fmt):
    path = tmp_path / f"walls.{fmt}"
    datasets.write_cache(pde, path, n_samples=6, seed=2, block=4)
    ds = datasets.open_cache(path)
    assert ds.attrs["bc"] == "dirichlet" and ds.attrs["bc_type"] == "wall"
    assert ds["x"].attrs["bc"] == "dirichlet" and ds["x"].attrs["bc_type"] == "wall"
    np.testing.assert_allclose(ds["x"].values, (np.arange(32) + 0.5) / 32, rtol=1e-6)  # cell centres
    plain = xr.open_zarr(path) if fmt == "zarr" else xr.open_dataset(path, engine="h5netcdf")
    assert plain.attrs["bc_type"] == "wall" and plain["x"].attrs["bc"] == "dirichlet"
    stream = datasets.TrajectoryStream(pde, seed=2, view="whole", batch_size=6, n_samples=6, shuffle=False,
                                       resample=False, solve_batch=4)
    batch = next(iter(torch.utils.data.DataLoader(stream, batch_size=None)))
    cached = datasets.CachedTrajectories(path, view="whole")
    assert cached.pde.config() == pde.config() and type(cached.pde).__name__ == "Burgers1D_d"
    for k, i in enumerate(batch["index"].tolist()):
        assert torch.equal(cached[i]["u"], batch["u"][k]) and torch.equal(cached[i]["params"], batch["params"][k])
    # the lifted walls: u at the cell centres next to the walls approaches bc_lo and bc_hi
    u = ds["u"].values[:, 0]  # [sample, x] at t = 0 (0 1 ... stored in x order)
    lo = ds["bc_lo"].values
    assert np.all(np.abs(u[:, 0] - lo) < 0.5) and np.all(np.abs(u[:, -1] + 0.5) < 0.5)


def test_samples_are_bit_identical_alone_in_batches_and_with_explicit_params(pde):
    batch = generator.sample(pde, [0, 1, 2, 3, 4], seed=1)
    alone = generator.sample(pde, [3], seed=1)
    np.testing.assert_array_equal(np.asarray(batch.u[3]), np.asarray(alone.u[0]))
    given = generator.sample(pde, [3], seed=1, params={k: np.asarray(v[3:4]) for k, v in batch.params.items()})
    np.testing.assert_array_equal(np.asarray(given.u[0]), np.asarray(alone.u[0]))


def test_a_walled_pde_pickles_and_rebuilds_from_its_config(pde):
    again = pickle.loads(pickle.dumps(pde))
    assert again == pde and type(again) is type(pde) and hash(again) == hash(pde)
    assert generator.from_config(pde.config()) == pde
    assert generator.get_pde("burgers1d", bc="dirichlet").replace(bc="periodic") == generator.get_pde("burgers1d")


def test_reservoir_serves_walled_samples(pde):
    stream = ReservoirStream(pde, seed=3, view="operator", batch_size=4, capacity=8, max_reuse=2, solve_batch=4,
                             mode="deterministic")
    batches = []
    for batch in torch.utils.data.DataLoader(stream, batch_size=None):
        batches.append(batch)
        if len(batches) == 3:
            break
    stream.close()
    index = sorted({int(i) for b in batches for i in b["index"]})
    ref = _bridge.sample_tensors(pde, index, seed=3)
    for b in batches:
        for k, i in enumerate(b["index"].tolist()):
            assert torch.equal(b["x"][k].reshape(-1), ref["u"][index.index(i), 0].reshape(-1))  # operator view: frame 0


def test_the_oracle_advances_a_sampled_frame_to_the_next_one(pde):
    t = _bridge.sample_tensors(pde, range(3), seed=3)
    oracle = SolverOracle(pde)
    for i in range(pde.n_frames - 1):
        got, want = oracle(t["u"][:, i], t["params"]), t["u"][:, i + 1]
        assert float((got - want).abs().max() / want.abs().max()) < 2e-6


def test_solver_step_gradients_match_float64_finite_differences():
    pde = generator.get_pde("burgers1d", n=16, t_end=0.02, n_frames=2, bc="dirichlet", bc_lo="uniform(0, 1)",
                            bc_hi="uniform(-1, 1)")  # every parameter column is perturbed: give each a domain
    t = _bridge.sample_tensors(pde, range(2), seed=3)
    with jax.enable_x64(True):
        step = SolverStep(pde)
        u = t["u"][:, 0].double().requires_grad_(True)
        params = t["params"].double().requires_grad_(True)
        assert torch.autograd.gradcheck(step, (u, params), eps=1e-6, atol=1e-9, rtol=1e-6, fast_mode=False)
    assert not jax.config.jax_enable_x64


@pytest.mark.parametrize("settings, message", [
    ({"bc": "dirichlet"}, "fisher_kpp1d: bc='dirichlet' not allowed (dirichlet is not among this entry's boundaries); "
                          "allowed: periodic, neumann"),
    ({"bc": "wall"}, "bc='wall' not allowed; allowed: periodic, neumann"),
    ({"bc.z": "neumann"}, "bc.z not allowed: the axes of a 1D entry are x"),
    ({"bc_lo": "1"}, "unknown setting 'bc_lo'"),
    ({"bc": "x=periodic,x=neumann"}, "bc='x=periodic,x=neumann' not allowed: axis x given twice"),  # kept the last
])
def test_bad_boundary_settings_are_one_line(settings, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")) as err:
        generator.get_pde("fisher_kpp1d", **settings)
    assert "\n" not in str(err.value)


def test_boundary_values_on_a_periodic_axis_and_offsets_on_dirichlet_walls_are_refused():
    with pytest.raises(ValueError, match="unknown setting 'bc_lo'"):
        generator.get_pde("diffusion1d", bc="neumann", bc_lo="1")
    with pytest.raises(ValueError, match=r"ic.offset=0.5 not allowed on Dirichlet walls"):
        generator.get_pde("diffusion1d", bc="dirichlet", **{"ic.offset": 0.5})


def test_the_cli_lists_generates_and_refuses_walls(tmp_path, capsys):
    from pdestream import cli

    assert cli.main(["list"]) == 0
    out = capsys.readouterr().out
    assert "bc: periodic, dirichlet, neumann (--set bc=dirichlet, or one axis: --set bc.x=neumann)" in out
    assert "bc: dirichlet on every axis (fixed)" in out  # darcy2d
    path = tmp_path / "d.zarr"
    assert cli.main(["generate", "diffusion2d", "--n", "2", "--set", "n=16", "--set", "bc.y=neumann",
                     "--out", str(path)]) == 0
    capsys.readouterr()
    assert xr.open_zarr(path).attrs["bc"] == "periodic neumann"
    assert cli.main(["inspect", str(path)]) == 0
    assert "  boundaries: x periodic (periodic), y neumann (open)" in capsys.readouterr().out
    assert cli.main(["generate", "grayscott2d", "--n", "2", "--set", "bc=dirichlet", "--out", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bc='dirichlet' not allowed" in err and "allowed: periodic" in err
    assert not (tmp_path / "g").exists()


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["one-step", "pushforward", "oracle", "solver-in-the-loop"])
def test_every_training_mode_trains_and_resumes_on_walls(tmp_path, capsys, mode):
    from pdestream import cli

    out = tmp_path / "run"
    argv = ["train", "burgers1d", "--set", "n=64", "--set", "n_frames=6", "--set", "bc=dirichlet", "--set",
            "bc_lo=uniform(0, 1)", "--steps", "4", "--batch-size", "4", "--test-samples", "2", "--checkpoint-every",
            "2", "--model-set", "width=8", "--model-set", "modes=4", "--model-set", "layers=2", "--threads", "1",
            "--mode", mode, "--out", str(out)]
    if mode != "one-step":
        argv += ["--unroll", "2"]
    if mode == "solver-in-the-loop":
        argv += ["--coarse-n", "32"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["spec"]["bc"] == ["dirichlet"]  # the model padded for the walls, recorded for a resume
    (out / "metrics.json").unlink()  # as if killed after its last checkpoint
    ckpt["step"] = 2
    torch.save(ckpt, out / "checkpoint.pt")
    assert cli.main(["train", "--resume", str(out)]) == 0, capsys.readouterr().err
    assert "resumed" in capsys.readouterr().out


def test_list_name_shows_every_setting_and_json(capsys):
    import json

    from pdestream import cli

    assert cli.main(["list", "ns2d"]) == 0
    out = capsys.readouterr().out
    assert "  drag = 0.1" in out and "  forcing_wavenumber = 4" in out and "  ic.sigma = 12.0" in out
    assert cli.main(["list", "burgers1d", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["settings"]["nu"]["units"] == "length^2/time"
    assert data["settings"]["bc"]["allowed"] == ["periodic", "dirichlet", "neumann"]
    assert cli.main(["list", "--json"]) == 2
