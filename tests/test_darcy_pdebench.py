"""darcy2d with PDEBench's set-up (the pdebench_darcy2d_beta* recipes): the bump measure against its definition
(independent quadrature), points=cells against a direct solve of the cell system with u = 0 at the ghost centres
(assembled here), u linear in the forcing beta, a sample's bits alone and in a batch, and bad input in one line."""

import math

import jax
import numpy as np
import pytest
import scipy.integrate as si
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from pdestream import generator as g
from pdestream import recipes
from pdestream.generator.steady.darcy2d import GaussianBumps

BETAS = ("1e-2", "1e-1", "1e0", "1e1", "1e2")


def pdebench_like(**kw):
    return g.get_pde("pdebench_darcy2d_beta1e0", kw)


# One small configuration shared by the solving tests (one compile): f given per sample within its domain
SMALL = {"n": 20, "f": "loguniform(0.01, 100)"}


def _expected_s(xs: np.ndarray, ys: np.ndarray, count: int, w_max: float) -> float:
    """E[mean over the points (x_i, y_j) of s] from the definition: the centre's and the width's integrals done by
    scipy quad (no closed form): count (1 / w_max) int_0^w_max mean_ij E_c[e^-(x_i - c)^2/w] E_c[e^-(y_j - c)^2/w] dw."""
    def profile(x, w):  # E over a centre uniform on [0, 1] of one axis factor
        return si.quad(lambda c: math.exp(-(x - c) ** 2 / w), 0.0, 1.0, epsabs=1e-13, epsrel=1e-11)[0]

    def integrand(w):
        px = np.array([profile(x, w) for x in xs])
        py = np.array([profile(y, w) for y in ys])
        return float(np.outer(px, py).mean())

    return count * si.quad(integrand, 0.0, w_max, epsabs=1e-11, epsrel=1e-9, limit=200)[0] / w_max


def test_bump_threshold_is_the_expected_grid_mean_of_its_definition():
    pde = pdebench_like(n=6)
    x = np.asarray(pde.grid.coords(), np.float64)
    assert np.allclose(x, (np.arange(6) + 0.5) / 6)
    want = _expected_s(x, x, 5, 0.5)
    assert abs(pde.ic.threshold(pde.grid) - want) < 1e-8 * want, (pde.ic.threshold(pde.grid), want)
    other = GaussianBumps(count=5, w_max=0.6).threshold(pde.grid)
    assert abs(other - want) > 0.05 * want  # w_max matters


def test_bump_samples_follow_the_measure():
    """4000 draws on 6 x 6 cells: the mean of s at each point against its expectation (quad), the grid mean of g = s - c
    at 0, each within 4.5 standard errors; a measure with another w_max is told apart."""
    pde, draws = pdebench_like(n=6), 4000
    keys = jax.random.split(jax.random.key(11), draws)
    field = np.asarray(jax.jit(jax.vmap(lambda k: pde.ic.sample(k, pde.grid)[0]))(keys), np.float64)
    c = pde.ic.threshold(pde.grid)
    s = field + c
    x = np.asarray(pde.grid.coords(), np.float64)
    se = s.std(0, ddof=1) / np.sqrt(draws)
    for i, j in ((0, 0), (2, 3), (5, 1)):
        want = _expected_s(x[[i]], x[[j]], 5, 0.5)
        assert abs(s[:, i, j].mean() - want) < 4.5 * se[i, j], (i, j, s[:, i, j].mean(), want, se[i, j])
        wrong = _expected_s(x[[i]], x[[j]], 5, 0.8)
        assert abs(s[:, i, j].mean() - wrong) > 8 * se[i, j]  # the test can fail
    means = field.mean((1, 2))
    assert abs(means.mean()) < 4.5 * means.std(ddof=1) / np.sqrt(draws)


def test_the_coefficient_is_a_pos_above_the_threshold_and_a_neg_below():
    pde = pdebench_like(**SMALL)
    t = g.sample(pde, [0, 3], seed=5)
    for b, i in enumerate((0, 3)):
        _, k_field = jax.random.split(jax.random.fold_in(jax.random.key(5), i))
        gi = np.asarray(pde.ic.sample(k_field, pde.grid)[0])
        assert np.array_equal(np.asarray(t.inputs[b, 0]), np.where(gi > 0, 1.0, 0.1).astype(np.float32))


def assemble_cells(a: np.ndarray, h: float) -> sp.csr_matrix:
    """-div(a grad .) on n x n cell centres, u = 0 at the ghost centres one cell beyond the last ones (a whole h
    away), face coefficient the harmonic mean (a_P at a wall face: a is copied into the ghost); float64."""
    n = a.shape[0]
    rows, cols, vals = [], [], []
    for i in range(n):
        for j in range(n):
            diag = 0.0
            for ii, jj in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)):
                inside = 0 <= ii < n and 0 <= jj < n
                q = a[ii, jj] if inside else a[i, j]
                c = 2 * a[i, j] * q / (a[i, j] + q)
                diag += c
                if inside:
                    rows.append(i * n + j), cols.append(ii * n + jj), vals.append(-c / h**2)
            rows.append(i * n + j), cols.append(i * n + j), vals.append(diag / h**2)
    return sp.csr_matrix((vals, (rows, cols)), shape=(n * n, n * n))


def test_cells_solve_the_system_with_zero_at_the_ghost_centres():
    n = SMALL["n"]
    t = g.sample(pdebench_like(**SMALL), range(2), seed=3)
    for b in range(2):
        a, f = np.asarray(t.inputs[b, 0], np.float64), float(t.params["f"][b])
        assert set(np.unique(a).tolist()) == {float(np.float32(0.1)), 1.0}
        want = spl.spsolve(assemble_cells(a, 1.0 / n).tocsc(), np.full(n * n, f)).reshape(n, n)
        u = np.asarray(t.u[b, 0], np.float64)
        assert np.linalg.norm(u - want) < 1e-5 * np.linalg.norm(want)


def test_cells_converge_to_the_dirichlet_problem():
    """a = 1: -Laplacian(u) = 1 with u = 0 on the walls; the cell-centred values against the series solution at the
    centres: the ghost placement is first order in the wall position (error halves with h)."""
    def exact(x):
        k = np.arange(1, 200, 2)
        s = np.sin(np.pi * np.outer(x, k))  # [points, modes]
        coef = 16 / (np.pi**4 * np.outer(k, k) * (k[:, None] ** 2 + k[None, :] ** 2))
        return s @ coef @ s.T

    errors = []
    for n in (16, 32):
        pde = g.get_pde("darcy2d", n=n, points="cells", a_pos="1", a_neg="1", f="1", tol=1e-7)
        u = np.asarray(g.sample(pde, [0]).u[0, 0], np.float64)
        errors.append(np.abs(u - exact(np.asarray(pde.grid.coords(), np.float64))).max())
    rate = np.log2(errors[0] / errors[1])
    assert 0.8 < rate < 1.3, (errors, rate)


def test_u_is_linear_in_beta():
    """The recipes differ only in f = beta: a power of two scales every CG iterate exactly (bit for bit); the five
    published betas agree with beta times the beta = 1 solution to the solve's tolerance."""
    pde = pdebench_like(**SMALL)

    def at(beta):
        return g.sample(pde, range(3), seed=1, params={"f": [beta] * 3})

    base = at(1.0)
    assert np.array_equal(np.asarray(at(0.25).u), 0.25 * np.asarray(base.u))
    for tag in BETAS:
        r = recipes.RECIPES[f"pdebench_darcy2d_beta{tag}"]
        assert {k: v for k, v in r.settings.items() if k != "f"} == {
            k: v for k, v in recipes.RECIPES["pdebench_darcy2d_beta1e0"].settings.items() if k != "f"}
        beta = float(r.settings["f"])
        t = at(beta)
        assert np.array_equal(np.asarray(t.inputs), np.asarray(base.inputs))
        u, want = np.asarray(t.u, np.float64), beta * np.asarray(base.u, np.float64)
        assert np.linalg.norm(u - want) < 2e-5 * np.linalg.norm(want), tag


def test_sample_bit_identical_alone_and_in_any_batch():
    pde = pdebench_like(**SMALL)
    batch = g.sample(pde, range(10), seed=4)
    assert batch.u.shape == (10, 1, 20, 20) and batch.inputs.shape == (10, 1, 20, 20)
    for i in (0, 9):
        alone = g.sample(pde, [i], seed=4)
        assert np.array_equal(np.asarray(alone.u[0]), np.asarray(batch.u[i]))
        assert np.array_equal(np.asarray(alone.inputs[0]), np.asarray(batch.inputs[i]))
    mixed = g.sample(pde, [9, 2, 5], seed=4)
    assert np.array_equal(np.asarray(mixed.u), np.asarray(batch.u)[[9, 2, 5]])


def test_the_recipes_show_their_source_settings_and_differences(capsys):
    from pdestream import cli

    for tag, beta in zip(BETAS, ("0.01", "0.1", "1", "10", "100")):
        assert cli.main(["recipes", "show", f"pdebench_darcy2d_beta{tag}"]) == 0
        out = capsys.readouterr().out
        for words in ("source:", "arxiv.org/abs/2210.07182", "reaction_diffusion_2D_multi_solution_Hydra.py",
                      f"--set f={beta}", "--set points=cells", "--set ic=bumps", "--set n=128", "batch mean",
                      "train seed 0 n 9000", "differs:", "pseudo-time t = 2", "harmonic mean"):
            assert words in out, (tag, words)
        pde = g.get_pde(f"pdebench_darcy2d_beta{tag}")
        assert pde.n == 128 and pde.points == "cells" and pde.grid.spacing == 1 / 128
    assert recipes.not_expressible("pdebench_darcy2d") is None


@pytest.mark.parametrize("setting, message", [
    ({"ic.count": "0"}, "ic.count=0 not allowed: the number of bumps must be an integer >= 1"),
    ({"ic.count": "10000000"}, "ic.count=10000000 not allowed on 16384 points: .* allowed: 1 <= count <= 2048"),
    ({"ic.w_max": "0"}, "ic.w_max=0.0 not allowed: the widest bump's w must be > 0"),
    ({"points": "faces"}, "points='faces' not allowed; allowed: nodes, cells"),
    ({"ic": "sines"}, "unknown ic kind 'sines'; allowed: neumann_grf, bumps"),
])
def test_bad_settings_are_refused_with_one_line(setting, message):
    with pytest.raises(ValueError, match=message) as err:
        pdebench_like(**setting)
    assert "\n" not in str(err.value)
