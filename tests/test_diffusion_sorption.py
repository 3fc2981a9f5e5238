"""diffusion_sorption1d (PDEBench's diffusion-sorption equation) and its recipe against what the solver did not
produce: the boundary conditions read off the cells by polynomial extrapolation, the retarded mass balanced by
the boundary fluxes (numpy, the retardation written here), the Boltzmann similarity solution of the half-line
problem (scipy's solve_bvp), the exact steady state, bits alone and in a batch, refusals in one line."""

import numpy as np
import pytest
from scipy.integrate import solve_bvp

from pdestream import cli, recipes
from pdestream import generator as g

PDEBENCH = {"D": 5e-4, "por": 0.29, "rho_s": 2880.0, "k_f": 3.5e-4, "n_f": 0.874}
K = (1 - PDEBENCH["por"]) / PDEBENCH["por"] * PDEBENCH["rho_s"] * PDEBENCH["k_f"]  # 2.47


def retardation(u, k=K, nf=0.874, eps=1e-6):
    return 1 + k * nf * (np.maximum(u, 0) + eps) ** (nf - 1)


def retarded_mass(u, k=K, nf=0.874, eps=1e-6):
    """S(u) = u + K u^n_f (regularised as the entry states): the dissolved plus sorbed amount per pore volume."""
    return u + k * ((np.maximum(u, 0) + eps) ** nf - eps**nf)


def solve(pde, u0, **p):
    """One trajectory from the constant u0 under PDEBench's constants (p: overrides): [T, n] float64."""
    values = {**PDEBENCH, **p}
    u = g.solve(pde, np.full((1, 1, pde.n), u0, np.float32), {k: [v] for k, v in values.items()}).u
    return np.asarray(u[0, :, 0], np.float64)


def centres(n, length=1.0):
    return (np.arange(n) + 0.5) * length / n


@pytest.mark.slow
def test_both_boundary_conditions_hold_at_every_frame():
    # u(0) = 1 and u(1) = -D u_x(1), read off the cells by cubic extrapolation (the solver imposes them on faces)
    n = 256
    u = solve(g.get_pde("diffusion_sorption1d", n=n, t_end=100.0, n_frames=21), 0.1)
    x = centres(n)[-4:]
    left = (15 * u[1:, 0] - 10 * u[1:, 1] + 3 * u[1:, 2]) / 8  # the quadratic through the first three centres
    assert np.abs(left - 1).max() < 1e-3, left  # the cells start at 0.1
    for frame in u[1:]:
        fit = np.polyfit(x, frame[-4:], 3)
        at, slope = np.polyval(fit, 1.0), np.polyval(np.polyder(fit), 1.0)
        assert slope < 0 and abs(at + PDEBENCH["D"] * slope) < 0.01 * at, (at, -PDEBENCH["D"] * slope)


@pytest.mark.slow
def test_the_retarded_mass_changes_by_the_boundary_fluxes():
    # d/dt int S(u) dx = -D u_x(0) - (-D u_x(1)) = -D u_x(0) - u(1); the fluxes from polynomials through the cells
    # and the boundary value, integrated by the trapezoidal rule from t = 1 (the first second's flux is singular)
    n, d = 256, PDEBENCH["D"]
    pde = g.get_pde("diffusion_sorption1d", n=n, t_end=50.0, n_frames=501)
    u, t, h = solve(pde, 0.1), pde.times().astype(np.float64), 1.0 / n
    flux_in = -d * (-8.0 + 9 * u[:, 0] - u[:, 1]) / (3 * h)  # the quadratic through (0, 1), (h/2, u0), (3h/2, u1)
    x = centres(n)[-4:]
    flux_out = np.array([np.polyval(np.polyfit(x, f[-4:], 3), 1.0) for f in u])  # -D u_x = u at x = 1
    i = 10
    balance = np.trapezoid(flux_in[i:] - flux_out[i:], t[i:])
    gained = (retarded_mass(u[-1]) - retarded_mass(u[i])).sum() * h
    assert gained > 0.2 and abs(gained / balance - 1) < 0.01, (gained, balance)
    # what the balance tells apart: the dissolved mass alone (R dropped) gains a third of it
    dissolved = (u[-1] - u[i]).sum() * h
    assert abs(dissolved / balance - 1) > 0.5


def similarity(c0, eta):
    """The half-line problem u(0, t) = 1, u(x, 0) = c0 has u = f(x / sqrt t) with D f'' + (eta / 2) R(f) f' = 0,
    f(0) = 1, f(inf) = c0: solved by collocation on [0, 0.4] (f is c0 to 1e-12 well before)."""
    d = PDEBENCH["D"]
    grid = np.linspace(0, 0.4, 4001)
    guess = np.vstack([c0 + (1 - c0) * np.exp(-grid / 0.02), -(1 - c0) / 0.02 * np.exp(-grid / 0.02)])
    sol = solve_bvp(lambda e, y: np.vstack([y[1], -e / (2 * d) * retardation(y[0]) * y[1]]),
                    lambda a, b: np.array([a[0] - 1, b[0] - c0]), grid, guess, tol=1e-8, max_nodes=200000)
    assert sol.status == 0, sol.message
    return sol.sol(eta)[0]


@pytest.mark.slow
def test_early_fronts_follow_the_boltzmann_similarity_solution():
    # before the right boundary's outflow reaches x = 0.6 the column is a half-line: u(x, t) = f(x / sqrt t)
    n, c0 = 256, 0.1
    u = solve(g.get_pde("diffusion_sorption1d", n=n, t_end=50.0, n_frames=6), c0)
    x = centres(n)
    inside = x < 0.6
    for frame, t in ((2, 20.0), (5, 50.0)):
        err = np.abs(u[frame, inside] - similarity(c0, x[inside] / np.sqrt(t))).max()
        assert err < 5e-4, (t, err)  # measured 1.5e-4, 6e-5 (n = 512: 4e-5)
    # without sorption (k_f = 0: R = 1) the front runs sqrt(3-4) times as far: far from the sorbing solution
    plain = solve(g.get_pde("diffusion_sorption1d", n=n, t_end=50.0, n_frames=6), c0, k_f=0.0)
    assert np.abs(plain[5, inside] - similarity(c0, x[inside] / np.sqrt(50.0))).max() > 0.1


def test_the_steady_state_is_the_exact_linear_profile():
    # u_xx = 0 with u(0) = 1, u(1) = -D u_x(1): u = 1 - x / (1 + D) whatever R is; D = 0.5 puts u(1) at 1/3 (a
    # Dirichlet u = 0 or a no-flux end, or the Robin sign flipped, would give 1 - x, 1 or 1 + 2x); t = 200 is ~30
    # diffusion times R / D
    n = 64
    u = solve(g.get_pde("diffusion_sorption1d", n=n, t_end=200.0, n_frames=3), 0.1, D=0.5)
    assert np.abs(u[-1] - (1 - centres(n) / 1.5)).max() < 1e-5


def test_bits_alone_and_in_a_batch_and_across_chunks():
    pde = g.get_pde("diffusion_sorption1d", n=32, t_end=20.0, n_frames=3, dt=1.0)
    batch = np.asarray(g.sample(pde, [0, 5, 3, 9, 2], seed=4).u)
    for b, i in enumerate([0, 5, 3, 9, 2]):
        alone = np.asarray(g.sample(pde, [i], seed=4).u[0])
        assert np.array_equal(alone, batch[b]), i
    assert np.isfinite(batch).all() and len({float(u[0, 0, 0]) for u in batch}) == 5
    # frame 0 is the constant the IC drew, inside PDEBench's U(0, 0.2)
    assert all(np.ptp(u[0]) == 0 and 0 <= u[0, 0, 0] <= 0.2 for u in batch)


def test_a_frame_advanced_by_the_oracle_is_the_next_frame():
    from pdestream.generator.spectral import interactive

    pde = g.get_pde("diffusion_sorption1d", n=32, t_end=20.0, n_frames=3, dt=1.0)
    traj = g.sample(pde, [1, 2], seed=0)
    u = np.asarray(traj.u)
    nxt, ok = interactive.advance(pde, u[:, 1], traj.params, 1)
    assert np.asarray(ok).all() and np.array_equal(np.asarray(nxt), u[:, 2])  # one step of state: the same steps
    out, ok, vjp = interactive.advance_vjp(pde, u[:, 1], traj.params, 1)
    assert np.allclose(np.asarray(out), u[:, 2], atol=1e-6)  # a vmapped scan: equal to rounding
    g_u, g_p = vjp(np.ones_like(np.asarray(out)))
    assert np.isfinite(np.asarray(g_u)).all() and all(np.isfinite(np.asarray(v)).all() for v in g_p.values())


def test_a_step_too_large_for_newton_fails_with_its_cause_and_writes_no_nan():
    # one step of the whole window at n_f = 0.3 (R grows as u^-0.7 towards the dry end): 4 Newton iterations do not
    # converge; the sample is marked failed, held at its last good state, and the cause says when
    pde = g.get_pde("diffusion_sorption1d", n=64, t_end=500.0, n_frames=2, dt=500.0, n_f="0.3")
    p = len(pde.PARAMS)
    u, _, ok, _ = pde.run_keys(g.sample_keys(0, np.arange(2)), np.zeros((2, p), np.float32), np.zeros((2, p), bool))
    assert not np.asarray(ok).any() and np.isfinite(np.asarray(u)).all()
    assert np.array_equal(np.asarray(u)[:, 1], np.asarray(u)[:, 0])  # held at the IC
    assert pde.failure_causes() == ["Newton did not converge in a stage at t = 0"] * 2
    with pytest.raises(g.BlowUpError, match="a smaller dt avoids this"):
        g.sample(pde, [0], seed=0)
    assert pde.replace(dt=5.0).n_frames == 2 and np.isfinite(np.asarray(g.sample(pde.replace(dt=5.0), [0]).u)).all()


@pytest.mark.parametrize("setting, words", [
    ({"por": "1.2"}, "por=1.2 not allowed: the porosity must be in (0, 1)"),
    ({"k_f": "-1"}, "k_f=-1.0 not allowed: the Freundlich coefficient must be >= 0"),
    ({"n_f": "uniform(-1, 1)"}, "n_f=uniform(-1.0, 1.0) not allowed: Freundlich exponent must be > 0"),
    ({"eps": 0.0}, "eps=0.0 not allowed: must be a finite number > 0"),
    ({"dt": -1.0}, "dt=-1.0 not allowed"),
    ({"u_left": -1.0}, "u_left=-1 not allowed: a concentration must be >= 0"),
    ({"ic.low": 0.3}, "ic.low=0.3, ic.high=0.2 not allowed: need 0 <= low <= high"),
    ({"ic": "grf"}, "unknown ic kind 'grf'; allowed: constant"),
])
def test_bad_settings_are_refused_in_one_line(setting, words):
    with pytest.raises(ValueError) as err:
        g.get_pde("diffusion_sorption1d", setting)
    msg = str(err.value)
    assert msg.startswith("diffusion_sorption1d: ") and words in msg and "\n" not in msg, msg


def test_the_recipe_states_pdebench_and_makes_its_grid(capsys):
    pde = g.get_pde("pdebench_diffusion_sorption1d")
    assert (pde.n, pde.t_end, pde.n_frames, pde.recipe) == (1024, 500.0, 101, "pdebench_diffusion_sorption1d")
    assert pde.ic == g.get_pde("diffusion_sorption1d").ic and (pde.ic.low, pde.ic.high) == (0.0, 0.2)
    assert {k: float(pde.param_domains[k].bounds[0]) for k in PDEBENCH} == pytest.approx(PDEBENCH)
    assert np.allclose(pde.times()[:3], [0, 5, 10]) and pde.step_dt == 0.25
    assert cli.main(["recipes", "show", "pdebench_diffusion_sorption1d"]) == 0
    out = capsys.readouterr().out
    assert "Appendix D.8" in out and "RK45" in out and "U(0, 0.2)" in out
    assert "pdebench_diffusion_sorption1d" in recipes.listing()
    with pytest.raises(ValueError, match="^unknown recipe 'pdebench_diffusion_sorption'; did you mean "):
        recipes.get_recipe("pdebench_diffusion_sorption")
