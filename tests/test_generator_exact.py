"""Solvers against closed-form solutions and a fitted convergence order (nothing here is the solver's own output)."""

import numpy as np
import pytest

from pdestream import generator as g


def rel_err(a, b):
    return float(np.linalg.norm(np.asarray(a) - b) / np.linalg.norm(b))


def test_advection_is_an_exact_shift():
    pde = g.get_pde("advection1d", n=64, t_end=1.0, n_frames=5)
    x = pde.grid.coords().astype(np.float64)
    c = 0.37
    u0 = np.sin(2 * np.pi * 3 * x) + 0.5 * np.cos(2 * np.pi * 7 * x)
    traj = g.solve(pde, u0, {"c": c})
    for j, t in enumerate(pde.times()):
        exact = np.sin(2 * np.pi * 3 * (x - c * t)) + 0.5 * np.cos(2 * np.pi * 7 * (x - c * t))
        assert rel_err(traj.u[0, j, 0], exact) < 2e-5


def test_diffusion_modes_decay_exponentially():
    pde = g.get_pde("diffusion1d", n=64, t_end=2.0, n_frames=3)
    x = pde.grid.coords().astype(np.float64)
    nu = 4e-3
    traj = g.solve(pde, np.sin(2 * np.pi * 2 * x) + np.cos(2 * np.pi * 5 * x), {"nu": nu})
    for j, t in enumerate(pde.times()):
        exact = (np.exp(-nu * (4 * np.pi) ** 2 * t) * np.sin(4 * np.pi * x)
                 + np.exp(-nu * (10 * np.pi) ** 2 * t) * np.cos(10 * np.pi * x))
        assert rel_err(traj.u[0, j, 0], exact) < 2e-5


def kdv_soliton(x, t, c, alpha, beta, x0, length):
    xi = (x - x0 - c * t + length / 2) % length - length / 2  # periodic image nearest the crest
    return 3 * c / alpha / np.cosh(0.5 * np.sqrt(c / beta) * xi) ** 2


def test_kdv_soliton_travels_unchanged():
    length, c, alpha, beta = 40.0, 1.5, 6.0, 1.0
    pde = g.get_pde("kdv1d", n=128, length=length, t_end=6.0, n_frames=4, alpha=alpha, beta=beta)
    x = pde.grid.coords().astype(np.float64)
    traj = g.solve(pde, kdv_soliton(x, 0.0, c, alpha, beta, 10.0, length), {"alpha": alpha, "beta": beta})
    for j, t in enumerate(pde.times()):
        assert rel_err(traj.u[0, j, 0], kdv_soliton(x, t, c, alpha, beta, 10.0, length)) < 2e-3


def test_a_burn_in_starts_the_frames_at_t_start_on_the_exact_soliton():
    """t_start: the IC is at t = 0, the burn-in (its own ETDRK4 step) is not recorded, frames at [t_start, t_end]."""
    length, c, alpha, beta = 40.0, 1.5, 6.0, 1.0
    pde = g.get_pde("kdv1d", n=128, length=length, t_start=2.5, t_end=6.0, n_frames=3, alpha=alpha, beta=beta)
    assert np.allclose(pde.times(), [2.5, 4.25, 6.0]) and pde.burn_in_steps > 0 and pde.burn_in_dt != pde.step_dt
    x = pde.grid.coords().astype(np.float64)
    traj = g.solve(pde, kdv_soliton(x, 0.0, c, alpha, beta, 10.0, length), {"alpha": alpha, "beta": beta})
    assert traj.u.shape[1] == 3
    for j, t in enumerate(pde.times()):
        assert rel_err(traj.u[0, j, 0], kdv_soliton(x, t, c, alpha, beta, 10.0, length)) < 2e-3


def test_a_burn_in_keeps_sample_identity_and_old_configs():
    pde = g.get_pde("ks1d", n=64, length=32.0, t_start=4.0, t_end=6.0, n_frames=3)
    batch = g.sample(pde, range(3), seed=1)
    alone = g.sample(pde, [1], seed=1)
    assert np.array_equal(np.asarray(alone.u[0]), np.asarray(batch.u[1]))  # alone == in a batch, bit for bit
    plain = g.get_pde("ks1d", n=64, length=32.0, t_end=6.0, n_frames=3)
    assert pde.config()["t_start"] == 4.0 and g.from_config(pde.config()) == pde
    assert "t_start" not in plain.config()  # the configs (and hashes) of caches written before are unchanged
    with pytest.raises(ValueError, match=r"^ks1d: t_start=6\.0 not allowed: need 0 <= t_start < t_end") as err:
        g.get_pde("ks1d", t_start=6.0, t_end=6.0)
    assert "\n" not in str(err.value)


def cole_hopf(x, t, nu, a=0.5, k=2 * np.pi):
    """Burgers solution u = -2 nu phi_x / phi with phi = 1 + a exp(-nu k^2 t) cos(k x) solving the heat equation."""
    e = a * np.exp(-nu * k**2 * t)
    return 2 * nu * k * e * np.sin(k * x) / (1 + e * np.cos(k * x))


def burgers_for(n, t_end, n_frames, nu, dt=None):
    # the default GRF IC only sets the CFL bound; solve() is given the Cole-Hopf IC (max|u| ~ 2 nu k)
    return g.get_pde("burgers1d", n=n, t_end=t_end, n_frames=n_frames, nu=nu, dt=dt, **{"ic.sigma": 2.0})


def test_burgers_matches_cole_hopf():
    nu = 0.05
    pde = burgers_for(128, 0.5, 6, nu)
    x = pde.grid.coords().astype(np.float64)
    traj = g.solve(pde, cole_hopf(x, 0.0, nu), {"nu": nu})
    for j, t in enumerate(pde.times()):
        assert rel_err(traj.u[0, j, 0], cole_hopf(x, t, nu)) < 1e-4


def test_etdrk4_converges_at_fourth_order_in_time():
    # a = 0.9 makes the nonlinear term strong enough that the time error stays well above float32 round-off
    nu, t_end = 0.1, 0.32
    errors, steps = [], [4, 8, 16, 32]
    for n_steps in steps:
        pde = burgers_for(64, t_end, n_steps + 1, nu, dt=t_end / n_steps)
        assert pde.steps_per_frame == 1
        x = pde.grid.coords().astype(np.float64)
        traj = g.solve(pde, cole_hopf(x, 0.0, nu, a=0.9), {"nu": nu})
        errors.append(rel_err(traj.u[0, -1, 0], cole_hopf(x, t_end, nu, a=0.9)))
    slope = -np.polyfit(np.log(steps), np.log(errors), 1)[0]
    assert 3.6 < slope < 4.6, (errors, slope)


def test_taylor_green_vortex_decays_at_the_viscous_rate():
    nu = 0.05
    pde = g.get_pde("ns2d", n=32, forcing="none", drag=0.0, nu=nu, t_end=2.0, n_frames=3)
    x = pde.grid.coords().astype(np.float64)
    X, Y = np.meshgrid(x, x, indexing="ij")
    w0 = 2 * np.sin(X) * np.sin(Y)
    traj = g.solve(pde, w0, {"nu": nu})
    for j, t in enumerate(pde.times()):
        assert rel_err(traj.u[0, j, 0], w0 * np.exp(-2 * nu * t)) < 1e-5


def test_kolmogorov_laminar_flow_is_steady():
    # w_s = -A cos(k_f y) / (nu k_f + drag / k_f) balances forcing, viscosity and drag; (u.grad) w = 0 for a shear flow
    nu, drag, amp = 0.05, 0.1, 1.0
    pde = g.get_pde("ns2d", n=32, nu=nu, drag=drag, forcing_amplitude=amp, t_end=3.0, n_frames=3)
    k_f = pde.forcing_wavenumber
    y = pde.grid.coords().astype(np.float64)
    w_s = np.broadcast_to(-amp * np.cos(k_f * y) / (nu * k_f + drag / k_f), (32, 32))
    traj = g.solve(pde, w_s, {"nu": nu})
    assert rel_err(traj.u[0, -1, 0], w_s) < 1e-5


@pytest.mark.parametrize("name", ["advection1d", "burgers1d", "kdv1d"])
def test_mass_is_conserved(name):
    pde = g.get_pde(name, n=64, n_frames=6)
    u = np.asarray(g.sample(pde, range(3), seed=1).u, np.float64)
    mass = u.mean(axis=-1)  # [B, T, C]
    scale = np.abs(u).max()
    assert np.abs(mass - mass[:, :1]).max() < 1e-5 * scale


def test_burgers_energy_never_grows():
    u = np.asarray(g.sample(g.get_pde("burgers1d", n=64, n_frames=11), range(4), seed=2).u, np.float64)
    energy = (u**2).mean(axis=(-1, -2))  # [B, T]
    assert np.all(np.diff(energy, axis=1) <= 1e-6 * energy[:, :1])
    assert np.all(energy[:, -1] < energy[:, 0])  # viscosity dissipates


def test_ns2d_advection_term_matches_a_direct_computation():
    # -(u w_x + v w_y) with (u, v) = (psi_y, -psi_x), -Lap psi = w, by plain numpy on a field of low modes
    # (products stay below the 2/3 cutoff, so no aliasing enters either side)
    pde = g.get_pde("ns2d", n=32, forcing="none")
    x = pde.grid.coords().astype(np.float64)
    X, Y = np.meshgrid(x, x, indexing="ij")
    w = np.sin(X) * np.cos(2 * Y) + 0.7 * np.cos(3 * X + Y) + 0.3 * np.sin(2 * X - 3 * Y)
    m = np.fft.fftfreq(32, 1 / 32)
    KX, KY = np.meshgrid(m, m, indexing="ij")
    k2 = np.where(KX**2 + KY**2 > 0, KX**2 + KY**2, 1.0)
    wh = np.fft.fft2(w)
    deriv = lambda f_hat: np.real(np.fft.ifft2(f_hat))  # noqa: E731
    u, v = deriv(1j * KY * wh / k2), deriv(-1j * KX * wh / k2)
    expected = -(u * deriv(1j * KX * wh) + v * deriv(1j * KY * wh))
    nonlinear = pde.nonlinear(pde.grid, {"nu": 0.01})
    got = np.fft.irfft2(np.asarray(nonlinear(np.fft.rfft2(w)[None].astype(np.complex64)))[0], s=(32, 32))
    assert rel_err(got, expected) < 1e-5


def test_inviscid_ns2d_conserves_energy_and_enstrophy():
    # The dealiased Galerkin truncation of 2D Euler conserves both quadratic invariants; only time error remains.
    pde = g.get_pde("ns2d", n=32, forcing="none", drag=0.0, nu="1e-9", t_end=1.0, n_frames=3)
    w = np.asarray(g.sample(pde, [0, 1], seed=5).u, np.float64)[:, :, 0]  # [B, T, n, n]
    wh = np.fft.fft2(w)
    m = np.fft.fftfreq(32, 1 / 32)
    k2 = sum(x**2 for x in np.meshgrid(m, m, indexing="ij"))
    enstrophy = (np.abs(wh) ** 2).sum(axis=(-1, -2))
    energy = (np.abs(wh) ** 2 / np.where(k2 > 0, k2, np.inf)).sum(axis=(-1, -2))
    assert np.abs(w[:, -1] - w[:, 0]).max() > 0.1 * np.abs(w[:, 0]).max()  # the flow really evolved
    for invariant in (energy, enstrophy):
        assert np.abs(invariant / invariant[:, :1] - 1).max() < 1e-4
