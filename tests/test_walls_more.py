"""More walled-entry checks, each against something other than the code under test: two 2D nonlinear entries
(Allen-Cahn on Neumann walls, Burgers with Dirichlet x and periodic y) and KS between hinged walls against independent float64 DOP853 solvers of
their sine / cosine / Fourier coefficients written on scipy's transforms; Burgers with non-zero wall values against
finite differences; what zero-flux walls must conserve
(exact ODE solutions of spatially constant states, the mean's balance law, Allen-Cahn's energy, KS's dropped mean);
the spatial convergence in n (exponential where the walls are a symmetry of the equation, algebraic where not); and
mixed periodic / wall grids (bit identity, pickling, agreement with the 1D entry on an x-independent state)."""

import pickle

import jax
import numpy as np
import pytest
import scipy.fft as sf
from scipy.integrate import simpson, solve_ivp

from pdestream import generator


def rel(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# --- independent float64 references (scipy's transforms and integrator; nothing from generator/) -----------------
def allen_cahn2d_neumann_reference(u0: np.ndarray, nu: float, times: np.ndarray) -> np.ndarray:
    """u_t = nu Lap u + u - u^3 on [0, 1]^2 with u_x = u_y = 0 on the walls, cell-centred u0 [n, n]: orthonormal 2D
    DCT-II coefficients (cos(pi k x) cos(pi l y) are the Laplacian's eigenfunctions), the cubic formed at the points,
    2/3 rule per axis (k <= 2n/3), DOP853 at rtol 1e-11. Returns [T, n, n]."""
    n = u0.shape[0]
    k = np.arange(n)
    lam = -nu * np.pi**2 * (k[:, None] ** 2 + k[None, :] ** 2) + 1.0
    keep = ((k <= 2 * n // 3)[:, None] & (k <= 2 * n // 3)[None, :]).astype(float)

    def rhs(t, c):
        c = c.reshape(n, n)
        u = sf.idctn(c, type=2, norm="ortho")
        return (keep * (lam * c + sf.dctn(-u**3, type=2, norm="ortho"))).ravel()

    c0 = keep * sf.dctn(u0, type=2, norm="ortho")
    sol = solve_ivp(rhs, (0, times[-1]), c0.ravel(), method="DOP853", t_eval=times, rtol=1e-11, atol=1e-13)
    return np.stack([sf.idctn(sol.y[:, i].reshape(n, n), type=2, norm="ortho") for i in range(len(times))])


def burgers2d_mixed_reference(u0: np.ndarray, nu: float, times: np.ndarray) -> np.ndarray:
    """u_t + (u . grad) u = nu Lap u for u = (u, v) on [0, 1]^2, u = v = 0 on the walls x = 0, 1 and periodic in y;
    cell centres in x, cell-left points in y, u0 [2, n, n]. Sine amplitudes b_m (m = 1..n) in x (scipy's DST-II)
    times the full complex FFT in y; d/dx of a sine series is the cosine series pi m b_m (scipy's DCT-III); the
    products formed at the points; 2/3 rule (m <= 2n/3, |l| <= n/3); DOP853 at rtol 1e-10. Returns [T, 2, n, n]."""
    n = u0.shape[-1]
    m = np.arange(1, n + 1)[:, None]
    ky = 2 * np.pi * np.fft.fftfreq(n, 1.0 / n)[None, :]
    keep = (m <= 2 * n // 3) & (np.abs(np.fft.fftfreq(n, 1.0 / n))[None, :] <= n // 3)
    lam = -nu * ((np.pi * m) ** 2 + ky**2)
    last = np.where(m == n, 2.0, 1.0)  # the DST-II's m = n amplitude carries half weight in scipy's convention

    def to_c(f):  # [.., n, n] real -> sine x Fourier coefficients
        b = sf.dst(f, type=2, axis=-2) / n / last
        return np.fft.fft(b, axis=-1)

    def to_f(c):
        return sf.idst(np.fft.ifft(c, axis=-1).real * last * n, type=2, axis=-2)

    def ddx(c):  # cosine amplitudes a_k = pi k b_k (k = 1..n-1; m = n vanishes at the cell centres), a_0 = 0
        a = np.concatenate([np.zeros_like(c[..., :1, :]), (np.pi * m * c)[..., :-1, :]], axis=-2)
        a = np.fft.ifft(a, axis=-1).real
        return sf.idct(a * np.where(np.arange(n) == 0, 2.0, 1.0)[:, None] * n, type=2, axis=-2)

    def rhs(t, y):
        c = y.reshape(2, n, n)
        f, fx, fy = to_f(c), ddx(c), to_f(1j * ky * c)
        adv = -(f[0] * fx + f[1] * fy)  # -(u d/dx + v d/dy) applied to both components
        return (keep * (lam * c + to_c(adv))).ravel()

    c0 = keep * to_c(u0)
    sol = solve_ivp(rhs, (0, times[-1]), c0.ravel(), method="DOP853", t_eval=times, rtol=1e-10, atol=1e-12)
    return np.stack([to_f(sol.y[:, i].reshape(2, n, n)) for i in range(len(times))])


def test_allen_cahn2d_on_neumann_walls_matches_an_independent_float64_solver():
    pde = generator.get_pde("allen_cahn2d", n=24, bc="neumann", nu=0.005, t_end=1.0, n_frames=5)
    traj = generator.sample(pde, [0], seed=3)
    u = np.asarray(traj.u[0, :, 0], np.float64)
    ref = allen_cahn2d_neumann_reference(u[0], 0.005, pde.times().astype(np.float64))
    errors = [rel(u[i], ref[i]) for i in range(1, pde.n_frames)]
    assert max(errors) < 1e-5, errors
    assert rel(u[-1], u[0]) > 0.1  # the phases separated: not a test of a constant


@pytest.mark.slow
def test_burgers2d_with_dirichlet_x_and_periodic_y_matches_an_independent_float64_solver():
    pde = generator.get_pde("burgers2d", n=24, bc="x=dirichlet,y=periodic", nu=0.05, t_end=0.2, n_frames=5)
    traj = generator.sample(pde, [0], seed=5)
    u = np.asarray(traj.u[0], np.float64)  # [T, 2, n, n]
    ref = burgers2d_mixed_reference(u[0], 0.05, pde.times().astype(np.float64))
    errors = [rel(u[i], ref[i]) for i in range(1, pde.n_frames)]
    assert max(errors) < 1e-5, errors
    assert rel(u[-1], u[0]) > 0.05


def ks1d_hinged_reference(u0: np.ndarray, nu: float, length: float, times: np.ndarray) -> np.ndarray:
    """u_t + u u_x + u_xx + nu u_xxxx = 0 on [0, length] with u = u_xx = 0 on the walls (hinged), float64: sine
    amplitudes (scipy's DST-II), linear symbol k^2 - nu k^4 with k = pi m / length, u u_x formed at the points from
    the cosine series of u_x (scipy's DCT-III), 2/3 rule, DOP853 at rtol 1e-10. Returns [T, n]."""
    n = u0.size
    m = np.arange(1, n + 1)
    k = np.pi * m / length
    keep = m <= 2 * n // 3
    last = np.where(m == n, 2.0, 1.0)

    def to_u(b):
        return sf.idst(b * last * n, type=2)

    def rhs(t, b):
        a = np.concatenate([[0.0], (k * b)[:-1]])  # d/dx: cosine amplitudes k_m b_m at index m
        ux = sf.idct(a * np.where(np.arange(n) == 0, 2.0, 1.0) * n, type=2)
        return keep * ((k**2 - nu * k**4) * b + sf.dst(-to_u(b) * ux, type=2) / n / last)

    b0 = keep * sf.dst(u0, type=2) / n / last
    sol = solve_ivp(rhs, (0, times[-1]), b0, method="DOP853", t_eval=times, rtol=1e-10, atol=1e-12)
    return np.stack([to_u(sol.y[:, i]) for i in range(len(times))])


def test_ks1d_on_hinged_dirichlet_walls_matches_an_independent_float64_solver():
    pde = generator.get_pde("ks1d", n=64, bc="dirichlet", nu=1.0, t_end=10.0, n_frames=6)
    u = np.asarray(generator.sample(pde, [0], seed=2).u[0, :, 0], np.float64)
    ref = ks1d_hinged_reference(u[0], 1.0, pde.length, pde.times().astype(np.float64))
    errors = [rel(u[i], ref[i]) for i in range(1, pde.n_frames)]
    assert max(errors) < 1e-5, errors
    assert rel(u[-1], u[0]) > 0.1


# --- what zero-flux walls conserve ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name, params, exact", [
    ("fisher_kpp1d", {"D": 0.01, "r": 1.5}, lambda t: 1.0 / (1.0 + (1.0 / 0.2 - 1.0) * np.exp(-1.5 * t))),
    ("allen_cahn1d", {"nu": 0.01}, lambda t: 0.2 * np.exp(t) / np.sqrt(1.0 + 0.04 * (np.exp(2 * t) - 1.0))),
])
def test_a_constant_state_on_neumann_walls_follows_its_reaction_ode_exactly(name, params, exact):
    """No flux through the walls: u = const stays constant and obeys u' = f(u) (logistic; u' = u - u^3). At dt = 0.05
    the measured error is 6.7e-7 (Fisher-KPP) and 4.2e-7 (Allen-Cahn); at the default steps (1/3, 1/2) it is 9e-4
    and 4e-3, the same as on the periodic box (the constant mode does not see the walls)."""
    pde = generator.get_pde(name, n=32, bc="neumann", t_end=4.0, n_frames=5, dt=0.05)
    u = np.asarray(generator.solve(pde, np.full(32, 0.2), params).u[0, :, 0], np.float64)
    want = exact(pde.times().astype(np.float64))
    np.testing.assert_allclose(np.ptp(u, axis=1), 0.0, atol=1e-7)
    np.testing.assert_allclose(u, np.broadcast_to(want[:, None], u.shape), rtol=2e-6)
    assert want[-1] > 0.8  # it moved


@pytest.mark.parametrize("name, settings, reaction, walls", [
    ("fisher_kpp2d", {"n": 16, "D": 0.01, "r": 1.5}, lambda u: 1.5 * u * (1 - u), "neumann"),
    ("allen_cahn1d", {"n": 64, "nu": 0.01}, lambda u: u - u**3, "neumann"),
    ("allen_cahn1d", {"n": 64, "nu": 0.01}, lambda u: u - u**3, "dirichlet"),  # flux through the walls: must fail
])
def test_the_mean_changes_only_by_the_reaction_on_neumann_walls(name, settings, reaction, walls):
    """d/dt mean(u) = mean(f(u)) when no flux crosses the walls: the change of the mean over [0, 1] against
    Simpson's rule on 81 frames of the reaction's mean (quadrature error ~1e-10). Dirichlet walls let the
    diffusive flux nu u_x through, so there the same balance must be off (the check can fail)."""
    pde = generator.get_pde(name, bc=walls, t_end=1.0, n_frames=81, **settings)
    u = np.asarray(generator.sample(pde, [0], seed=7).u[0, :, 0], np.float64)
    space = tuple(range(1, u.ndim))
    change = u[-1].mean() - u[0].mean()
    integral = simpson(reaction(u).mean(axis=space), x=pde.times().astype(np.float64))
    residual = abs(change - integral) / np.abs(u[0]).mean()
    if walls == "neumann":
        assert residual < 2e-5, (change, integral)
    else:
        assert residual > 1e-3, (change, integral)


def test_allen_cahn_energy_never_increases_on_neumann_walls():
    """E(u) = int nu/2 u_x^2 + (u^2 - 1)^2 / 4 dx is a Lyapunov function with zero-flux walls (u_x by scipy's DCT)."""
    pde = generator.get_pde("allen_cahn1d", n=64, bc="neumann", nu=0.004, t_end=5.0, n_frames=21)
    u = np.asarray(generator.sample(pde, [2], seed=0).u[0, :, 0], np.float64)
    n, k = 64, np.arange(64)
    a = sf.dct(u, type=2, axis=-1) / n  # d/dx of sum a_k cos(pi k x) is -sum pi k a_k sin(pi k x): DST-III
    ux = -sf.idst(np.concatenate([np.pi * k[1:] * a[:, 1:], np.zeros((len(u), 1))], axis=1) * n, type=2, axis=-1)
    energy = (0.5 * 0.004 * ux**2 + 0.25 * (u**2 - 1) ** 2).mean(axis=1)
    assert np.all(np.diff(energy) <= 1e-6 * energy[0]), np.diff(energy)
    assert energy[-1] < 0.7 * energy[0]


@pytest.mark.slow
def test_ks2d_on_neumann_walls_keeps_its_mean():
    pde = generator.get_pde("ks2d", n=32, bc="neumann", t_end=5.0, n_frames=6)
    u = np.asarray(generator.sample(pde, [0], seed=1).u[0, :, 0], np.float64)
    np.testing.assert_allclose(u.mean(axis=(1, 2)), u[0].mean(), atol=1e-6 * np.abs(u).max())
    assert rel(u[-1], u[0]) > 0.05


# --- spatial convergence ---------------------------------------------------------------------------------------------
def _refine(u: np.ndarray, fine: int, parity: str) -> np.ndarray:
    """The cosine / sine series of cell-centred u [n] evaluated at ``fine`` cell centres (scipy, zero padding)."""
    n = u.size
    if parity == "neumann":
        a = sf.dct(u, type=2, norm="ortho") * np.sqrt(fine / n)
        return sf.idct(np.concatenate([a, np.zeros(fine - n)]), type=2, norm="ortho")
    b = sf.dst(u, type=2, norm="ortho") * np.sqrt(fine / n)
    b[-1] *= np.sqrt(2.0)  # the orthonormal DST-II scales its last amplitude by 1/sqrt(2): undo it before padding
    return sf.idst(np.concatenate([b, np.zeros(fine - n)]), type=2, norm="ortho")


def _errors_in_n(name, bc, u0, params, t_end, dt, ns, fine=128, **settings):
    """Relative L2 error at t_end of the solution on n points (evaluated as a series on the fine grid) against
    the solution on ``fine`` points; float64 (x64), the same dt for all, so what is left is the spatial error."""
    out = {}
    with jax.enable_x64(True):
        for n in [*ns, fine]:
            pde = generator.get_pde(name, n=n, bc=bc, t_end=t_end, n_frames=2, dt=dt, **settings)
            x = (np.arange(n) + 0.5) / n
            u, _ = generator.interactive.advance(pde, jax.numpy.asarray(u0(x)[None, None]),
                                                 {k: np.array([v]) for k, v in params.items()}, 1)
            out[n] = np.asarray(u, np.float64)[0, 0]
    return [rel(_refine(out[n], fine, bc), out[fine]) for n in ns]


@pytest.mark.slow
@pytest.mark.parametrize("name, bc, u0, params, t_end, dt, settings", [
    ("allen_cahn1d", "neumann", lambda x: np.tanh(2 * np.cos(np.pi * x) + 0.3 * np.cos(2 * np.pi * x) + 0.2),
     {"nu": 0.01}, 1.0, 1 / 64, {"ic.max_mode": 2}),
    ("burgers1d", "dirichlet", lambda x: np.sin(np.pi * x) + 0.5 * np.sin(2 * np.pi * x),
     {"nu": 0.05, "bc_lo": 0.0, "bc_hi": 0.0}, 0.2, 1 / 2048, {}),
])
def test_spatial_convergence_is_exponential_where_the_walls_are_a_symmetry(name, bc, u0, params, t_end, dt, settings):
    """Allen-Cahn is invariant under reflection (the even extension about a Neumann wall solves it) and Burgers under
    u(x) -> -u(-x) (the odd extension about a Dirichlet wall): the extended solutions are smooth periodic ones, so
    the sine / cosine series converge like a Fourier series, faster than any power of n."""
    ns = [12, 16, 24, 32, 48]
    errors = _errors_in_n(name, bc, u0, params, t_end, dt, ns, **settings)
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 1e-9 and errors[1] / errors[3] > 100, errors  # 16 -> 32: far more than any low power
    # exponential: log error is closer to linear in n than in log n
    lin = np.polyfit(ns, np.log(errors), 1, full=True)[1][0]
    pow_ = np.polyfit(np.log(ns), np.log(errors), 1, full=True)[1][0]
    assert lin < pow_, (lin, pow_, errors)


@pytest.mark.slow
def test_advection_diffusion_on_dirichlet_walls_converges_algebraically_to_its_exact_steady_state():
    """u_t + c u_x = nu u_xx, u(0) = 0, u(1) = 1 has the steady state (e^{c x / nu} - 1) / (e^{c / nu} - 1). u_xx is
    not 0 at the walls (c u_x = nu u_xx there), so the odd extension is not smooth and the sine series converges
    only algebraically: the measured order is ~2 (this pins it, so a change in either direction is seen)."""
    errors = []
    for n in (16, 32, 64):
        pde = generator.get_pde("advection_diffusion1d", n=n, bc="dirichlet", c=1.0, nu=0.2, bc_lo=0.0, bc_hi=1.0,
                                t_end=40.0, n_frames=2)
        x = pde.grid.coords(0).astype(np.float64)
        u = np.asarray(generator.sample(pde, [0], seed=0).u[0, -1, 0], np.float64)
        errors.append(rel(u, np.expm1(x / 0.2) / np.expm1(1 / 0.2)))
    order = -np.polyfit(np.log([16, 32, 64]), np.log(errors), 1)[0]
    assert errors[-1] < 1e-2 and 1.5 < order < 3.5, (order, errors)


def burgers_fd_reference(u0, nu: float, lo: float, hi: float, t_end: float, n: int) -> np.ndarray:
    """u_t + (u^2/2)_x = nu u_xx on [0, 1], u(0) = lo, u(1) = hi, float64: second-order central differences on n
    cell centres (ghost values 2 lo - u_0, 2 hi - u_{n-1}), DOP853 at rtol 1e-10. Returns u [n] at t_end."""
    x, h = (np.arange(n) + 0.5) / n, 1.0 / n

    def rhs(t, u):
        e = np.concatenate([[2 * lo - u[0]], u, [2 * hi - u[-1]]])
        return -(e[2:] ** 2 - e[:-2] ** 2) / (4 * h) + nu * (e[2:] - 2 * e[1:-1] + e[:-2]) / h**2

    sol = solve_ivp(rhs, (0, t_end), u0(x), method="DOP853", rtol=1e-10, atol=1e-12, t_eval=[t_end],
                    first_step=0.1 * h**2 / nu)  # the default first try overflows on this stiff system
    return sol.y[:, -1]


@pytest.mark.slow
def test_burgers_with_lifted_wall_values_converges_to_a_finite_difference_reference_at_second_order():
    """Non-zero wall values break Burgers' odd symmetry (u_xx = u u_x / nu != 0 at a wall), so the lifted sine
    series converges algebraically. Measured against finite differences on 1024 cells (their own error ~2e-6):
    5.4e-4, 1.2e-4, 2.9e-5 at n = 32, 64, 128, order ~2.1 (float64 under x64, dt = 1/4096 for all)."""
    nu, lo, hi, t_end = 0.05, 0.5, -0.3, 0.2

    def u0(x):
        return np.sin(np.pi * x) + lo + (hi - lo) * x

    ref = burgers_fd_reference(u0, nu, lo, hi, t_end, 1024)
    fine = (np.arange(1024) + 0.5) / 1024
    errors = []
    with jax.enable_x64(True):
        for n in (32, 64, 128):
            pde = generator.get_pde("burgers1d", n=n, bc="dirichlet", t_end=t_end, n_frames=2, dt=1 / 4096)
            x = (np.arange(n) + 0.5) / n
            u, _ = generator.interactive.advance(pde, jax.numpy.asarray(u0(x)[None, None]),
                                                 {"nu": np.array([nu]), "bc_lo": np.array([lo]),
                                                  "bc_hi": np.array([hi])}, 1)
            w = np.asarray(u, np.float64)[0, 0] - (lo + (hi - lo) * x)  # minus the lifting: a sine series
            errors.append(rel(_refine(w, 1024, "dirichlet") + lo + (hi - lo) * fine, ref))
    order = -np.polyfit(np.log([32, 64, 128]), np.log(errors), 1)[0]
    assert errors[-1] < 5e-5 and 1.7 < order < 2.7, (order, errors)


# --- mixed periodic / wall grids -------------------------------------------------------------------------------------
MIXED = [
    ("allen_cahn2d", {"bc": "x=periodic,y=dirichlet", "bc_lo": "uniform(-0.5, 0.5)", "bc_hi": "uniform(-0.5, 0.5)"}),
    ("burgers2d", {"bc": "x=dirichlet,y=periodic"}),
    ("diffusion2d", {"bc": "x=neumann,y=periodic"}),
]


@pytest.mark.parametrize("name, walls", MIXED)
def test_mixed_samples_are_bit_identical_alone_in_batches_with_explicit_params_and_pickle(name, walls):
    pde = generator.get_pde(name, n=16, n_frames=3, t_end=0.1, **walls)
    batch = generator.sample(pde, range(5), seed=4)
    alone = generator.sample(pde, [3], seed=4)
    np.testing.assert_array_equal(np.asarray(batch.u[3]), np.asarray(alone.u[0]))
    given = generator.sample(pde, [3], seed=4, params={k: np.asarray(v[3:4]) for k, v in batch.params.items()})
    np.testing.assert_array_equal(np.asarray(given.u[0]), np.asarray(alone.u[0]))
    again = pickle.loads(pickle.dumps(pde))
    assert again == pde and type(again) is type(pde) and generator.from_config(pde.config()) == pde
    np.testing.assert_array_equal(np.asarray(generator.sample(again, [3], seed=4).u), np.asarray(alone.u))
    assert float(np.abs(np.asarray(batch.u[:, -1] - batch.u[:, 0])).max()) > 1e-3  # it moved


@pytest.mark.parametrize("walls, axis", [("x=periodic,y=neumann", 1), ("x=neumann,y=periodic", 0)])
def test_a_state_constant_along_the_periodic_axis_evolves_as_the_1d_entry(walls, axis):
    """Allen-Cahn on a mixed grid from u0(x, y) = f(wall coordinate) stays constant along the periodic axis and
    equals allen_cahn1d on Neumann walls from f (a different code path: 1D transforms, no periodic axis)."""
    one = generator.get_pde("allen_cahn1d", n=32, bc="neumann", nu=0.005, t_end=2.0, n_frames=5)
    two = generator.get_pde("allen_cahn2d", n=32, bc=walls, nu=0.005, t_end=2.0, n_frames=5, dt=one.step_dt)
    assert two.steps_per_frame == one.steps_per_frame
    f = np.asarray(generator.sample(one, [0], seed=2).u[0, 0, 0])
    u1 = np.asarray(generator.solve(one, f, {"nu": 0.005}).u[0, :, 0])
    u0 = np.expand_dims(f, 1 - axis).repeat(32, axis=1 - axis)
    u2 = np.asarray(generator.solve(two, u0, {"nu": 0.005}).u[0, :, 0])  # [T, n, n]
    np.testing.assert_allclose(np.ptp(u2, axis=2 - axis), 0.0, atol=1e-6)
    np.testing.assert_allclose(u2.mean(axis=2 - axis), u1, atol=2e-6)
    assert rel(u1[-1], u1[0]) > 0.05
