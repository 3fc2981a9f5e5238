"""poisson1d/2d and helmholtz1d/2d: the direct spectral solve against an independent float64 solve with scipy's
transforms, exactness on a finite series and convergence on a smooth field, wall values held, Neumann
solvability, identity, the data side, and the one-line refusals."""

import numpy as np
import pytest
import scipy.fft as sf
import torch

from pdestream import datasets, generator


def rel(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def scipy_solve(f: np.ndarray, k2: float, length: float, lo: float, hi: float) -> np.ndarray:
    """-Lap u - k2 u = f on [0, L]^2, u = lo + (hi - lo) x / L on the walls (Dirichlet both axes), cell centres, in
    float64 with scipy's DST: the lifted problem's sine coefficients divided by |kappa|^2 - k2."""
    n = f.shape[0]
    x = (np.arange(n) + 0.5) / n
    g = lo + (hi - lo) * x[:, None] * np.ones(n)[None, :]
    rhs = sf.dstn(f + k2 * g, type=2, norm="ortho")
    kappa2 = (np.pi * np.arange(1, n + 1) / length) ** 2
    return sf.idstn(rhs / (kappa2[:, None] + kappa2[None, :] - k2), type=2, norm="ortho") + g


@pytest.mark.parametrize("name", ["poisson2d", "helmholtz2d"])
def test_samples_match_an_independent_float64_solve_with_lifted_walls(name):
    pde = generator.get_pde(name, n=32, bc_lo="uniform(-1, 1)", bc_hi="uniform(-1, 1)")
    t = generator.sample(pde, [0, 1, 2], seed=5)
    for i in range(3):
        k2 = float(t.params["k"][i]) ** 2 if "k" in t.params else 0.0
        want = scipy_solve(np.asarray(t.inputs[i, 0], np.float64), k2, 1.0, float(t.params["bc_lo"][i]),
                           float(t.params["bc_hi"][i]))
        assert rel(t.u[i, 0], want) < 1e-5


def test_exact_on_a_finite_series_and_spectrally_convergent_on_a_smooth_field():
    pde = generator.get_pde("poisson2d", n=32)
    x = pde.grid.coords(0).astype(np.float64)
    X, Y = np.meshgrid(x, x, indexing="ij")
    u = np.sin(np.pi * X) * np.sin(3 * np.pi * Y)
    f = 10 * np.pi**2 * u
    got = np.asarray(pde.solve_one(np.asarray(f, np.float32), {"bc_lo": 0.0, "bc_hi": 0.0}))
    assert rel(got, u) < 1e-6
    errors = []  # u = x^2 (1 - x)^2 y (1 - y): smooth, its odd extension is only C^1 (algebraic convergence)
    for n in (16, 32, 64):
        pde = generator.get_pde("poisson1d", n=n)
        x = pde.grid.coords(0).astype(np.float64)
        u = x**3 * (1 - x) ** 3
        f = -(6 * x * (1 - x) ** 3 - 18 * x**2 * (1 - x) ** 2 + 6 * x**3 * (1 - x))  # -u''
        errors.append(rel(pde.solve_one(np.asarray(f, np.float32), {"bc_lo": 0.0, "bc_hi": 0.0}), u))
    slope = -np.polyfit(np.log([16, 32, 64]), np.log(errors), 1)[0]
    assert slope > 1.9, (slope, errors)


def test_neumann_walls_conserve_and_refuse_a_source_without_solution():
    pde = generator.get_pde("poisson2d", n=32, bc="neumann")
    t = generator.sample(pde, [0, 1], seed=0)
    assert abs(float(t.inputs.mean())) < 1e-6 * float(np.abs(t.inputs).max())  # the folded source has mean 0
    assert abs(float(t.u.mean())) < 1e-6  # the constant mode is set to 0
    with pytest.raises(ValueError, match="whose source has a nonzero mean has no solution") as err:
        generator.get_pde("poisson2d", bc="neumann", **{"ic.mean": 1.0})
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="ic.mean=1 not allowed on Dirichlet walls: the field is drawn odd about them"):
        generator.get_pde("poisson2d", bc="x=dirichlet,y=neumann", **{"ic.mean": 1.0})  # the fold would drop it


@pytest.mark.parametrize("settings, message", [
    ({"k": "uniform(3, 3.2)"}, r"k=uniform\(3.0, 3.2\) not allowed: k\^2 comes within 0.197 of the eigenvalue 9.87"),
    ({"bc": "neumann", "bc_lo": "1"}, "bc_lo=1.0 not allowed: no axis is Dirichlet"),
    ({"bc": "wall"}, "bc='wall' not allowed; allowed: dirichlet, neumann, periodic"),
])
def test_bad_settings_are_one_line(settings, message):
    with pytest.raises(ValueError, match=message) as err:
        generator.get_pde("helmholtz1d", **settings)
    assert "\n" not in str(err.value)


def test_identity_and_the_data_side(tmp_path):
    pde = generator.get_pde("helmholtz2d", n=16, bc="x=dirichlet,y=periodic", bc_lo="uniform(0, 1)")
    batch = generator.sample(pde, range(5), seed=2)
    alone = generator.sample(pde, [3], seed=2)
    np.testing.assert_array_equal(np.asarray(batch.u[3]), np.asarray(alone.u[0]))
    given = generator.sample(pde, [3], seed=2, params={k: np.asarray(v[3:4]) for k, v in batch.params.items()})
    np.testing.assert_array_equal(np.asarray(given.u[0]), np.asarray(alone.u[0]))
    path = tmp_path / "h.zarr"
    datasets.write_cache(pde, path, n_samples=5, seed=2)
    ds = datasets.open_cache(path)
    assert ds.attrs["bc"] == "dirichlet periodic" and ds.attrs["bc_type"] == "wall periodic"
    cached = datasets.CachedTrajectories(path, view="operator")
    ex = cached[3]
    assert torch.equal(ex["y"].reshape(-1), torch.from_numpy(np.array(batch.u[3])).reshape(-1))


def test_train_on_a_poisson_cache_and_stream(tmp_path, capsys):
    from pdestream import cli

    assert cli.main(["train", "poisson2d", "--set", "n=16", "--steps", "5", "--batch-size", "4", "--test-samples",
                     "2", "--model-set", "width=8", "--model-set", "modes=4", "--model-set", "layers=2", "--threads",
                     "1", "--out", str(tmp_path / "run")]) == 0
    assert "trained fno on stream for 5 steps" in capsys.readouterr().out
