"""The FNO paper's generation algorithm (benchmarks/fno_ns_reproduction.py) against exact solutions."""

from __future__ import annotations

import numpy as np

from benchmarks import fno_ns_reproduction as ref

N = 16
X = np.arange(N) / N


def test_one_shell_decays_exactly():
    # modes of one shell |m|^2 = 5: psi is w / |k|^2, so u . grad w = 0 and w decays as exp(-nu 4 pi^2 5 t)
    w0 = np.cos(2 * np.pi * (X[:, None] + 2 * X[None, :])) + 0.5 * np.sin(2 * np.pi * (2 * X[:, None] + X[None, :]))
    nu, times = 1e-2, [0.5, 1.0]
    w = ref.solve_cn(w0[None], nu, 2e-2, times)[0]
    for j, t in enumerate(times):
        exact = w0 * np.exp(-nu * 4 * np.pi**2 * 5 * t)
        assert np.abs(w[j] - exact).max() < 1e-3 * np.abs(exact).max()


def test_advection_step_is_the_exact_jacobian():
    # w = a cos 2 pi x + b cos 4 pi y: u = psi_y = -b sin(4 pi y) / (4 pi), v = -psi_x = a sin(2 pi x) / (2 pi), so
    # u w_x + v w_y = -1.5 a b sin(2 pi x) sin(4 pi y); one explicit step of dt without viscosity or forcing adds
    # dt times its negative
    a, b, dt = 0.7, -1.3, 1e-3
    x, y = X[:, None], X[None, :]
    w0 = a * np.cos(2 * np.pi * x) + b * np.cos(4 * np.pi * y)
    w1 = ref.solve_cn(w0[None], 0.0, dt, [dt])[0, 0]
    exact = w0 + dt * 1.5 * a * b * np.sin(2 * np.pi * x) * np.sin(4 * np.pi * y)
    assert np.abs(w1 - exact).max() < 1e-12
    assert np.abs(w1 - w0).max() > 1e-3  # the step moved the field: the check above is not w1 = w0


def test_forced_spin_up_reaches_kolmogorov_state():
    # from rest, the paper's forcing (|m|^2 = 2) drives one shell: w = f / (nu |k|^2) (1 - exp(-nu |k|^2 t))
    nu, k2, times = 1e-2, 8 * np.pi**2, [1.0, 2.0]
    f = ref.forcing(N)
    w = ref.solve_cn(np.zeros((1, N, N)), nu, 2e-2, times, f)[0]
    for j, t in enumerate(times):
        exact = f / (nu * k2) * (1 - np.exp(-nu * k2 * t))
        assert np.abs(w[j] - exact).max() < 1e-3 * np.abs(exact).max()


def test_initial_measure_variance():
    # pointwise variance of N(0, 7^3 (-Lap + 49 I)^-2.5) on the 32^2 grid: the sum of its eigenvalues (m != 0)
    m = np.fft.fftfreq(32, 1 / 32)
    m2 = m[:, None] ** 2 + m[None, :] ** 2
    exact = np.sqrt(np.where(m2 > 0, 7.0**3 * (4 * np.pi**2 * m2 + 49.0) ** -2.5, 0.0).sum())
    w = ref.grf_w0(np.random.default_rng(0), 400, 32)
    assert abs(w.std() / exact - 1) < 0.03
    assert np.abs(w.mean((1, 2))).max() < 1e-12  # zero mean per draw
