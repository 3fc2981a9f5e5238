"""Walled spectral entries against things other than their own output: scipy's DCT/DST, analytic derivatives,
exact eigenfunction decay, the exact steady state of lifted boundary values, an independent float64 solver of the
sine-coefficient ODEs (scipy's transforms and DOP853), and ETDRK4's fourth-order convergence in time."""

import jax
import numpy as np
import pytest
import scipy.fft as sf
from scipy.integrate import solve_ivp

from pdestream import generator
from pdestream.generator.spectral.bounded import BoundedGrid, cos_analysis, cos_synthesis, sin_analysis, sin_synthesis


def rel(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("n", [8, 15, 32, 100])
def test_transforms_are_scipys_dct_and_dst_and_invert(n):
    u = np.random.default_rng(n).standard_normal((3, n))
    with jax.enable_x64(True):
        a = np.asarray(cos_analysis(jax.numpy.asarray(u)))
        b = np.asarray(sin_analysis(jax.numpy.asarray(u)))
        back_c = np.asarray(cos_synthesis(jax.numpy.asarray(a)))
        back_s = np.asarray(sin_synthesis(jax.numpy.asarray(b)))
    want_a = sf.dct(u, type=2) / n
    want_a[:, 0] /= 2  # synthesis amplitudes: u_j = a_0 + sum a_k cos(pi k (j + 1/2) / n)
    want_b = sf.dst(u, type=2) / n
    want_b[:, -1] /= 2
    np.testing.assert_allclose(a, want_a, atol=1e-13)
    np.testing.assert_allclose(b, want_b, atol=1e-13)
    np.testing.assert_allclose(back_c, u, atol=1e-12)
    np.testing.assert_allclose(back_s, u, atol=1e-12)


@pytest.mark.parametrize("bcs", [("dirichlet", "neumann"), ("neumann", "periodic"), ("periodic", "dirichlet")])
def test_gradients_of_both_parities_are_exact(bcs):
    g = BoundedGrid(2, 32, 2.0, bcs)
    x, y = np.meshgrid(g.coords(0).astype(np.float64), g.coords(1).astype(np.float64), indexing="ij")
    k = {"dirichlet": np.pi * 3 / 2.0, "neumann": np.pi * 2 / 2.0, "periodic": 2 * np.pi * 2 / 2.0}
    f = {"dirichlet": np.sin, "neumann": np.cos, "periodic": np.sin}
    df = {"dirichlet": np.cos, "neumann": lambda z: -np.sin(z), "periodic": np.cos}
    u = f[bcs[0]](k[bcs[0]] * x) * f[bcs[1]](k[bcs[1]] * y)
    want = [k[bcs[0]] * df[bcs[0]](k[bcs[0]] * x) * f[bcs[1]](k[bcs[1]] * y),
            k[bcs[1]] * f[bcs[0]](k[bcs[0]] * x) * df[bcs[1]](k[bcs[1]] * y)]
    v = g.rfft(jax.numpy.asarray(u, jax.numpy.float32))
    np.testing.assert_allclose(np.asarray(g.irfft(v)), u, atol=2e-6)
    for axis in (0, 1):
        np.testing.assert_allclose(np.asarray(g.gradient(v, axis)), want[axis], atol=2e-5 * np.abs(want[axis]).max())
    lap = np.asarray(g.irfft(g.laplacian() * v))
    np.testing.assert_allclose(lap, -(k[bcs[0]] ** 2 + k[bcs[1]] ** 2) * u, atol=2e-5 * np.abs(lap).max())


@pytest.mark.parametrize("bc, mode, basis", [("dirichlet", 3, np.sin), ("neumann", 2, np.cos)])
def test_diffusion_modes_decay_exactly(bc, mode, basis):
    pde = generator.get_pde("diffusion1d", n=64, bc=bc, nu=0.01, n_frames=6)
    x = pde.grid.coords(0).astype(np.float64)
    u0 = basis(np.pi * mode * x) + (0.3 if bc == "neumann" else 0.0)
    params = {"nu": 0.01, **({"bc_lo": 0.0, "bc_hi": 0.0} if bc == "dirichlet" else {})}
    u = np.asarray(generator.solve(pde, u0, params).u[0, :, 0])
    decay = np.exp(-0.01 * (np.pi * mode) ** 2 * pde.times())[:, None]
    exact = decay * basis(np.pi * mode * x) + (0.3 if bc == "neumann" else 0.0)
    assert rel(u, exact) < 1e-5
    if bc == "neumann":  # zero flux: the mean is conserved
        np.testing.assert_allclose(u.mean(axis=1), 0.3, atol=1e-6)


def test_lifted_boundary_values_reach_their_exact_steady_state():
    pde = generator.get_pde("diffusion1d", n=64, bc="dirichlet", bc_lo=1.0, bc_hi=2.0, nu=0.01, t_end=2000.0,
                            n_frames=2)
    traj = generator.sample(pde, [0, 1], seed=0)
    x = pde.grid.coords(0).astype(np.float64)
    np.testing.assert_allclose(np.asarray(traj.u[:, -1, 0]), np.broadcast_to(1.0 + x, (2, 64)), atol=1e-6)
    # frame 0 minus the line is a pure sine series: its value at the walls (sin(0), sin(pi m)) is 0
    w = np.asarray(traj.u[:, 0, 0], np.float64) - (1.0 + x)
    b = sf.dst(w, type=2) / 64
    b[:, -1] /= 2
    at = np.linspace(0, 1, 3)  # the walls and the centre
    series = b @ np.sin(np.pi * np.outer(np.arange(1, 65), at))
    np.testing.assert_allclose(series[:, [0, 2]], 0.0, atol=1e-12)


def burgers_reference(u0: np.ndarray, nu: float, times: np.ndarray) -> np.ndarray:
    """u_t + u u_x = nu u_xx with u = 0 on both walls of [0, 1], float64: the sine coefficients of u on n cell
    centres, the product formed at the points and projected back with scipy's DST (2/3-rule dealiasing), DOP853
    at rtol 1e-11. Independent of generator/: its own transforms, its own integrator."""
    n = u0.size
    m = np.arange(1, n + 1)
    keep = m <= 2 * n // 3

    def to_b(u):
        b = sf.dst(u, type=2) / n
        b[-1] /= 2
        return b

    def to_u(b):
        return sf.idst(b * np.where(m == n, 2.0, 1.0) * n, type=2)

    def to_ux(b):  # d/dx of sum b_m sin(pi m x): sum b_m pi m cos(pi m x), a cosine series (k = m; m = n vanishes)
        a = np.concatenate([[0.0], (np.pi * m * b)[:-1]])
        return sf.idct(a * np.where(np.arange(n) == 0, 2.0, 1.0) * n, type=2) / 2 * 2

    def rhs(t, b):
        u = to_u(b)
        return keep * (-nu * (np.pi * m) ** 2 * b + to_b(-u * to_ux(b)))

    sol = solve_ivp(rhs, (0, times[-1]), keep * to_b(u0), method="DOP853", t_eval=times, rtol=1e-11, atol=1e-13)
    return np.stack([to_u(sol.y[:, i]) for i in range(len(times))])


def test_burgers_with_walls_matches_an_independent_float64_solver():
    pde = generator.get_pde("burgers1d", n=64, bc="dirichlet", nu=0.05, t_end=0.5, n_frames=6)
    traj = generator.sample(pde, [0], seed=4)
    u = np.asarray(traj.u[0, :, 0], np.float64)
    ref = burgers_reference(u[0], 0.05, pde.times().astype(np.float64))
    errors = [rel(u[i], ref[i]) for i in range(1, pde.n_frames)]
    assert max(errors) < 1e-5, errors
    assert rel(u[-1], u[0]) > 0.05  # the solution moved: not a test of a constant


def test_etdrk4_is_fourth_order_in_time_on_walls():
    pde = generator.get_pde("allen_cahn1d", n=64, bc="neumann", nu=0.005, t_end=1.0, n_frames=2)
    u0 = np.asarray(generator.sample(pde, [0], seed=1).u[:, 0], np.float64)
    errors = []
    with jax.enable_x64(True):
        def end(dt):
            walled = generator.get_pde("allen_cahn1d", n=64, bc="neumann", nu=0.005, t_end=1.0, n_frames=2, dt=dt)
            out, _ = generator.interactive.advance(walled, jax.numpy.asarray(u0), {"nu": np.array([0.005])}, 1)
            return np.asarray(out)

        ref = end(1 / 256)
        for dt in (1 / 4, 1 / 8, 1 / 16):
            errors.append(np.abs(end(dt) - ref).max())
    slope = np.polyfit(np.log([1 / 4, 1 / 8, 1 / 16]), np.log(errors), 1)[0]
    assert 3.6 < slope < 4.6, (slope, errors)
