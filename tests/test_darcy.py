"""darcy2d: the PCG solve against a scipy sparse direct solve of the same discrete system (assembled here, entry
by entry), a manufactured solution's second-order convergence, the random field against its definition, and
the sampler's contract (key discipline, bit-identity in any batch, non-convergence reported)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from pdestream import generator as g
from pdestream.generator.steady import elliptic
from pdestream.generator.steady.darcy2d import Darcy2D


def darcy(**kw):
    return g.get_pde("darcy2d", **kw) if "darcy2d" in g.PDES else Darcy2D().replace(kw)


def assemble(a: np.ndarray, h: float) -> sp.csr_matrix:
    """-div(a grad .) on the interior nodes of an n x n grid (u = 0 on the boundary), five points, face
    coefficient 2 a_P a_Q / (a_P + a_Q); float64, unknowns ordered (i, j) row-major."""
    n = a.shape[0]
    m = n - 2
    rows, cols, vals = [], [], []
    for i in range(1, n - 1):
        for j in range(1, n - 1):
            diag = 0.0
            for ii, jj in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)):
                c = 2 * a[i, j] * a[ii, jj] / (a[i, j] + a[ii, jj])
                diag += c
                if 0 < ii < n - 1 and 0 < jj < n - 1:
                    rows.append((i - 1) * m + j - 1), cols.append((ii - 1) * m + jj - 1), vals.append(-c / h**2)
            rows.append((i - 1) * m + j - 1), cols.append((i - 1) * m + j - 1), vals.append(diag / h**2)
    return sp.csr_matrix((vals, (rows, cols)), shape=(m * m, m * m))


def direct(a: np.ndarray, f: float, h: float) -> np.ndarray:
    """The discrete solution on the interior nodes, [n-2, n-2] float64, by a sparse LU."""
    m = a.shape[0] - 2
    return spl.spsolve(assemble(np.asarray(a, np.float64), h).tocsc(), np.full(m * m, f)).reshape(m, m)


def rel(x, y) -> float:
    return float(np.linalg.norm(np.asarray(x, np.float64) - y) / np.linalg.norm(y))


def test_pcg_float64_matches_sparse_direct_solve():
    pde = darcy(n=33)
    a = np.asarray(g.sample(pde, [3], seed=1).inputs[0, 0], np.float64)  # a FNO threshold field: jumps 3 <-> 12
    assert set(np.unique(a)) == {3.0, 12.0}
    ref = direct(a, 1.0, 1 / 32)
    with jax.enable_x64(True):
        sol = elliptic.solve(jnp.asarray(a), jnp.ones((33, 33)), 1 / 32, 1e-10, 2000)
        loose = elliptic.solve(jnp.asarray(a), jnp.ones((33, 33)), 1 / 32, 1e-3, 2000)
    assert sol.u.dtype == jnp.float64
    assert bool(sol.reached) and float(sol.residual) <= 1e-10  # the stated tolerance, recomputed from u
    assert rel(np.asarray(sol.u)[1:-1, 1:-1], ref) < 1e-6
    assert float(loose.residual) <= 1e-3 and rel(np.asarray(loose.u)[1:-1, 1:-1], ref) > 1e-6  # tol is obeyed
    assert np.all(np.asarray(sol.u)[[0, -1]] == 0) and np.all(np.asarray(sol.u)[:, [0, -1]] == 0)


def test_samples_float32_match_sparse_direct_solve():
    """The generator's float32 samples (tol 1e-5) against the float64 direct solve of their own coefficient:
    within 1e-5 relative L2 (float32 rounding of u alone is ~6e-8; the CG tolerance dominates)."""
    pde = darcy(n=33, f="uniform(0.5, 2)")
    traj = g.sample(pde, range(3), seed=0)
    for b in range(3):
        a, f = np.asarray(traj.inputs[b, 0]), float(traj.params["f"][b])
        u = np.asarray(traj.u[b, 0])
        assert u.dtype == np.float32 and np.all(u[[0, -1]] == 0) and np.all(u[:, [0, -1]] == 0)
        assert rel(u[1:-1, 1:-1], direct(a, f, 1 / 32)) < 1e-5


def test_manufactured_solution_converges_at_second_order():
    """u = sin(pi x) sin(pi y) with the smooth a = 1 + 0.5 sin(2 pi x) sin(2 pi y) and the f it implies."""
    pi = np.pi
    errors, sizes = [], (17, 33, 65)
    for n in sizes:
        x = np.linspace(0, 1, n)
        X, Y = np.meshgrid(x, x, indexing="ij")
        a = 1 + 0.5 * np.sin(2 * pi * X) * np.sin(2 * pi * Y)
        ax, ay = pi * np.cos(2 * pi * X) * np.sin(2 * pi * Y), pi * np.sin(2 * pi * X) * np.cos(2 * pi * Y)
        u = np.sin(pi * X) * np.sin(pi * Y)
        ux, uy = pi * np.cos(pi * X) * np.sin(pi * Y), pi * np.sin(pi * X) * np.cos(pi * Y)
        f = 2 * pi**2 * a * u - ax * ux - ay * uy  # -div(a grad u) = -(a lap u + grad a . grad u)
        with jax.enable_x64(True):
            sol = elliptic.solve(jnp.asarray(a), jnp.asarray(f), 1 / (n - 1), 1e-12, 5000)
        assert bool(sol.reached)
        errors.append(np.sqrt(np.mean((np.asarray(sol.u) - u) ** 2)))
    slope = np.polyfit(np.log([1 / (n - 1) for n in sizes]), np.log(errors), 1)[0]
    assert 1.9 < slope < 2.1, (slope, errors)


def _grf_definition(n: int, tau: float, alpha: float) -> np.ndarray:
    """Covariance matrix of g at the n x n nodes, from N(0, (-Lap + tau^2)^-alpha) with zero-flux boundaries:
    sum over modes (k1, k2) != 0 of lambda_k phi_k(p) phi_k(q), phi_k = c_k1 c_k2 cos(pi k1 x) cos(pi k2 y)."""
    x, k = np.linspace(0, 1, n), np.arange(n)
    c = np.where(k == 0, 1.0, np.sqrt(2))
    lam = (np.pi**2 * (k[:, None] ** 2 + k[None, :] ** 2) + tau**2) ** (-alpha)
    lam[0, 0] = 0
    phi = (c[None, :] * np.cos(np.pi * x[:, None] * k[None, :]))  # [point, mode]
    modes = np.einsum("ik,jl->ijkl", phi, phi).reshape(n * n, n * n)  # [point (i, j), mode (k, l)]
    return modes @ np.diag(lam.ravel()) @ modes.T


def test_random_field_covariance_and_threshold_follow_the_definition():
    n, samples = 10, 3000
    pde = darcy(n=n)
    keys = jax.random.split(jax.random.key(7), samples)
    field = jax.jit(jax.vmap(lambda k: pde.ic.sample(k, pde.grid)[0]))(keys)
    field = np.asarray(field, np.float64).reshape(samples, -1)
    cov = _grf_definition(n, 3.0, 2.0)
    emp = field.T @ field / samples
    # sampling error of a (co)variance estimate: sqrt((C_pp C_qq + C_pq^2) / N)
    se = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / samples)
    assert np.max(np.abs(emp - cov) / se) < 5.5
    assert np.max(np.abs(field.mean(0)) / np.sqrt(np.diag(cov) / samples)) < 5.5
    assert np.max(np.abs(_grf_definition(n, 5.0, 2.0) - cov) / se) > 20  # the test can tell tau apart
    # a from the field of the same key: the sampler's key discipline, fold_in(key(seed), i) -> (params, field)
    traj = g.sample(pde, [0, 5], seed=2)
    for b, i in enumerate((0, 5)):
        _, k_field = jax.random.split(jax.random.fold_in(jax.random.key(2), i))
        gi = np.asarray(pde.ic.sample(k_field, pde.grid)[0])
        assert np.array_equal(np.asarray(traj.inputs[b, 0]), np.where(gi > 0, 12.0, 3.0).astype(np.float32))


def test_sample_bit_identical_alone_and_in_any_batch():
    pde = darcy(n=24, f="uniform(0.5, 2)")
    batch = g.sample(pde, range(11), seed=4)
    assert batch.u.shape == (11, 1, 24, 24) and batch.inputs.shape == (11, 1, 24, 24) and batch.t.shape == (0,)
    for i in (0, 6, 10):
        alone = g.sample(pde, [i], seed=4)
        assert np.array_equal(np.asarray(alone.u[0]), np.asarray(batch.u[i]))
        assert np.array_equal(np.asarray(alone.inputs[0]), np.asarray(batch.inputs[i]))
    mixed = g.sample(pde, [10, 2, 6], seed=4)
    assert np.array_equal(np.asarray(mixed.u), np.asarray(batch.u)[[10, 2, 6]])
    given = g.sample(pde, [6], seed=4, params={"f": [float(batch.params["f"][6])]})
    assert np.array_equal(np.asarray(given.u[0]), np.asarray(batch.u[6]))
    other = g.sample(pde, [6], seed=5)
    assert not np.array_equal(np.asarray(other.inputs[0]), np.asarray(batch.inputs[6]))


def test_non_convergence_is_reported_like_a_blow_up():
    pde = darcy(n=24, max_iter=5)
    with pytest.raises(g.BlowUpError, match=r"darcy2d: 2 of 2 solves did not converge .*max_iter=5.*index 0"):
        g.sample(pde, [0, 1])
    with pytest.raises(g.BlowUpError, match="did not converge"):
        g.sample(pde, [0], on_blowup="redraw", max_redraws=1)


@pytest.mark.parametrize("setting, message", [
    ({"n": 3}, "n=3 not allowed"),
    ({"tol": 0.0}, "tol=0.0 not allowed"),
    ({"max_iter": 0}, "max_iter=0 not allowed"),
    ({"a_neg": "uniform(-1, 3)"}, "a_neg=uniform"),
    ({"ic": "grf"}, "unknown ic kind 'grf'; allowed: neumann_grf"),
    ({"ic.tau": "-1"}, "ic.tau=-1.0 not allowed"),
    ({"t_end": "2"}, "unknown setting 't_end'"),
])
def test_bad_settings_are_refused_with_one_line(setting, message):
    with pytest.raises(ValueError, match=message) as err:
        darcy(**setting)
    assert "\n" not in str(err.value)


def test_solve_from_an_initial_condition_is_refused():
    with pytest.raises(ValueError, match="darcy2d is steady: it has no initial condition to evolve; use sample"):
        g.solve(darcy(n=16), np.zeros((1, 16, 16), np.float32), {"a_pos": 12.0, "a_neg": 3.0, "f": 1.0})


def test_cache_stream_and_cli_end_to_end(capsys, tmp_path):
    """generate -> inspect -> train on the cache and on the stream; the cache holds a and u beside each other with
    no time axis, and its operator examples are the generator's (a, u) bit for bit."""
    import torch

    from pdestream import cli, datasets

    path = tmp_path / "darcy.zarr"
    assert cli.main(["generate", "darcy2d", "--n", "6", "--set", "n=16", "--out", str(path)]) == 0
    ds = datasets.open_cache(path)
    assert ds["a"].dims == ds["u"].dims == ("sample", "y", "x") and "time" not in ds.dims
    ds.close()
    traj = g.sample(darcy(n=16), [4], seed=0)
    ex = datasets.CachedTrajectories(path, view="operator")[4]
    assert torch.equal(ex["x"], torch.from_numpy(np.array(traj.inputs[0])))
    assert torch.equal(ex["y"], torch.from_numpy(np.array(traj.u[0])))
    stream = datasets.TrajectoryStream(darcy(n=16), view="operator", batch_size=6, n_samples=6, solve_batch=6,
                                       shuffle=False, prefetch=False)
    batch = next(iter(stream))
    assert batch["x"].shape == (6, 1, 16, 16) and batch["y"].shape == (6, 1, 16, 16)
    norm = stream.normalization(n=6)
    assert norm.fields == ("a", "u") and norm.of_x.fields == ("a",) and norm.of_y.fields == ("u",)
    capsys.readouterr()
    assert cli.main(["inspect", str(path), "--plot", str(tmp_path / "d.png")]) == 0
    out = capsys.readouterr().out
    assert "steady (no time axis)" in out and "field a:" in out and "field u:" in out
    assert (tmp_path / "d.png").stat().st_size > 0
    for source in (str(path), "stream"):
        code = cli.main(["train", "darcy2d", "--set", "n=16", "--source", source, "--view", "operator", "--steps",
                         "3", "--test-samples", "4", "--out", str(tmp_path / f"run-{source[-4:]}"), "--threads", "1"])
        assert code == 0, capsys.readouterr().err
    code = cli.main(["train", "darcy2d", "--set", "n=16", "--view", "next_step", "--steps", "3", "--out",
                     str(tmp_path / "bad")])  # without --view a steady entry trains on its operator view
    err = capsys.readouterr().err
    assert code == 2 and "next_step needs a time axis" in err and "Traceback" not in err
    assert not (tmp_path / "bad").exists()


def test_new_parameters_never_recompile_and_domains_are_checked():
    from pdestream.generator.steady.darcy2d import _compiled_setup, _compiled_solve

    pde = darcy(n=16, f="uniform(0.5, 2)", a_pos="uniform(10, 14)")
    g.sample(pde, [7, 8, 11], seed=5)
    sizes = _compiled_setup(pde)._cache_size(), _compiled_solve(pde)._cache_size()
    for seed, idx in ((0, [0, 1, 2]), (1, [5, 6, 9])):
        g.sample(pde, idx, seed=seed)
    g.sample(pde, [0, 1, 2], seed=0, params={"f": 1.5, "a_pos": 11.0})
    assert (_compiled_setup(pde)._cache_size(), _compiled_solve(pde)._cache_size()) == sizes
    with pytest.raises(ValueError, match=r"f=3 not allowed: outside its domain uniform\(0.5, 2"):
        g.sample(pde, [0], params={"f": 3.0})


def test_a_zero_source_gives_the_exact_zero_solution():
    t = g.sample(darcy(n=17, f=0), [0, 1], seed=0)  # was reported as non-convergence with advice that cannot help
    assert np.all(np.asarray(t.u) == 0.0)
