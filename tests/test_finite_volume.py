"""euler1d (generator.finite_volume) against things other than its own code: an exact Riemann solver written here
(Toro, Riemann Solvers and Numerical Methods for Fluid Dynamics, ch. 4: Newton on the pressure function, then the
wave pattern sampled at x / t), a translated density wave, and the conservation laws themselves."""

import math

import numpy as np
import pytest

from pdestream import generator as g

GAMMA = 1.4


# --- the exact solution of a Riemann problem (numpy, float64) ---------------------------------------------------
def _pressure_function(p, rho, pk, gamma):
    """Toro's f_K(p) and its derivative: a shock where p > p_K, a rarefaction otherwise."""
    c = math.sqrt(gamma * pk / rho)
    if p > pk:
        a, b = 2 / ((gamma + 1) * rho), (gamma - 1) / (gamma + 1) * pk
        root = math.sqrt(a / (p + b))
        return (p - pk) * root, root * (1 - 0.5 * (p - pk) / (p + b))
    ratio = p / pk
    return (2 * c / (gamma - 1) * (ratio ** ((gamma - 1) / (2 * gamma)) - 1),
            ratio ** (-(gamma + 1) / (2 * gamma)) / (rho * c))


def star_state(left, right, gamma=GAMMA):
    """(p*, u*) of the Riemann problem between primitive states left and right (rho, u, p)."""
    (rl, ul, pl), (rr, ur, pr) = left, right
    cl, cr = math.sqrt(gamma * pl / rl), math.sqrt(gamma * pr / rr)
    p = max(1e-8, 0.5 * (pl + pr) - 0.125 * (ur - ul) * (rl + rr) * (cl + cr))
    for _ in range(100):
        fl, dl = _pressure_function(p, rl, pl, gamma)
        fr, dr = _pressure_function(p, rr, pr, gamma)
        new = max(1e-10, p - (fl + fr + ur - ul) / (dl + dr))
        if abs(new - p) < 1e-14 * (new + p):
            p = new
            break
        p = new
    fl, _ = _pressure_function(p, rl, pl, gamma)
    fr, _ = _pressure_function(p, rr, pr, gamma)
    return p, 0.5 * (ul + ur) + 0.5 * (fr - fl)


def exact_riemann(left, right, x, x0, t, gamma=GAMMA):
    """Exact (rho, u, p) [3, len(x)] at time t > 0 of the jump left | right at x0 (no vacuum)."""
    p_star, u_star = star_state(left, right, gamma)
    g1, g2 = (gamma - 1) / (gamma + 1), (gamma - 1) / (2 * gamma)
    out = np.empty((3, len(x)))
    for i, s in enumerate((np.asarray(x, float) - x0) / t):
        # mirror a right-side point into a left-side problem: u -> -u, s -> -s
        if s <= u_star:
            (rho, u, p), sign = left, 1.0
        else:
            (rho, u, p), sign = (right[0], -right[1], right[2]), -1.0
        ss, us = sign * s, sign * u_star
        c = math.sqrt(gamma * p / rho)
        if p_star > p:  # shock
            speed = u - c * math.sqrt((gamma + 1) / (2 * gamma) * p_star / p + g2)
            w = (rho, u, p) if ss <= speed else (rho * (p_star / p + g1) / (g1 * p_star / p + 1), us, p_star)
        else:  # rarefaction
            c_star = c * (p_star / p) ** g2
            if ss <= u - c:
                w = (rho, u, p)
            elif ss >= us - c_star:
                w = (rho * (p_star / p) ** (1 / gamma), us, p_star)
            else:  # inside the fan
                uf = 2 / (gamma + 1) * (c + (gamma - 1) / 2 * u + ss)
                cf = 2 / (gamma + 1) * (c + (gamma - 1) / 2 * (u - ss))
                w = (rho * (cf / c) ** (2 / (gamma - 1)), uf, p * (cf / c) ** (2 * gamma / (gamma - 1)))
        out[:, i] = (w[0], sign * w[1], w[2])
    return out


def test_the_exact_solver_gives_toros_star_states():
    # Toro's table 4.3 (p*, u*) for his tests 1-3 (test 1 is Sod's states with the jump at 0.3)
    for left, right, want in [((1, 0, 1), (0.125, 0, 0.1), (0.30313, 0.92745)),
                              ((1, -2, 0.4), (1, 2, 0.4), (0.00189, 0.0)),
                              ((1, 0, 1000), (1, 0, 0.01), (460.894, 19.5975))]:
        p, u = star_state(left, right)
        assert p == pytest.approx(want[0], rel=3e-3) and u == pytest.approx(want[1], abs=1e-3 * max(1, want[1]))


# --- the solver -----------------------------------------------------------------------------------------------------
def last_frame(ic, n, t_end, **settings):
    pde = g.get_pde("euler1d", ic=ic, n=n, t_end=t_end, n_frames=2, **settings)
    traj = g.sample(pde, [0], seed=0)
    return pde, np.asarray(traj.u[0, -1], np.float64)


CLASSICS = {"sod": ((1.0, 0.0, 1.0), (0.125, 0.0, 0.1), 0.2), "lax": ((0.445, 0.698, 3.528), (0.5, 0.0, 0.571), 0.14)}


@pytest.fixture(scope="module")
def shock_tube_errors():
    """{case: [L1 error of rho at n = 100, 200, 400]} against the exact solution."""
    out = {}
    for ic, (left, right, t) in CLASSICS.items():
        errs = []
        for n in (100, 200, 400):
            pde, u = last_frame(ic, n, t)
            exact = exact_riemann(left, right, pde.grid.coords().astype(float), 0.5, t)
            errs.append(float(np.sum(np.abs(u[0] - exact[0])) * pde.h))
        out[ic] = errs
    return out


@pytest.mark.parametrize("ic", list(CLASSICS))
def test_shock_tubes_converge_to_the_exact_solution(shock_tube_errors, ic):
    errs = shock_tube_errors[ic]
    orders = [math.log2(a / b) for a, b in zip(errs, errs[1:])]
    print(ic, "L1(rho)", errs, "orders", orders)
    assert errs[0] < 0.04 and all(o >= 0.6 for o in orders), (errs, orders)


def test_a_shock_tube_keeps_its_velocity_and_pressure_near_the_exact_ones():
    pde, u = last_frame("sod", 200, 0.2)
    exact = exact_riemann(*CLASSICS["sod"][:2], pde.grid.coords().astype(float), 0.5, 0.2)
    # the plateau between the rarefaction's tail and the shock (x ~ 0.6 .. 0.8): u* and p* to 1%
    mid = (pde.grid.coords() > 0.55) & (pde.grid.coords() < 0.65)
    assert np.allclose(u[1:, mid], exact[1:, mid], rtol=1e-2)


def test_two_strong_rarefactions_keep_density_and_pressure_positive():
    pde = g.get_pde("euler1d", ic="123", n=100, t_end=0.15, n_frames=6)
    u = np.asarray(g.sample(pde, [0], seed=0).u[0])
    assert (u[:, 0] > 0).all() and (u[:, 2] > 0).all()
    exact = exact_riemann((1, -2, 0.4), (1, 2, 0.4), pde.grid.coords().astype(float), 0.5, 0.15)
    assert np.sum(np.abs(u[-1, 0] - exact[0])) * pde.h < 0.05


def totals(pde, u):
    """Mass, momentum and energy [T, 3] of primitive frames u [T, 3, n] (float64)."""
    u = np.asarray(u, np.float64)
    rho, vel, p = u[:, 0], u[:, 1], u[:, 2]
    gamma = float(pde.gamma.value)
    q = np.stack([rho, rho * vel, p / (gamma - 1) + 0.5 * rho * vel**2], 1)
    return q.sum(-1) * pde.h


@pytest.mark.parametrize("bc", ["periodic", "wall"])
def test_mass_momentum_and_energy_are_conserved(bc):
    pde = g.get_pde("euler1d", ic="smooth", bc=bc, n=100, t_end=0.3, n_frames=4)
    sums = totals(pde, g.sample(pde, [1], seed=0).u[0])
    scale = np.abs(sums[0]).max()
    drift = np.abs(sums - sums[0]) / scale
    # float32 rounding: under one float32 ulp (2^-24 relative) per step taken (the drift grows with the steps,
    # 1.1e-6 for mass after 126; in float64 the same run keeps mass and energy to 5e-15); momentum only on a
    # periodic box (walls push)
    bound = np.arange(4)[:, None] * pde.steps_per_frame * 2.0**-24
    assert (drift[:, [0, 2]] <= bound).all(), drift
    if bc == "periodic":
        assert (drift[:, 1] <= bound[:, 0]).all(), drift


def wave_error(n, limiter):
    """L1 error of rho after t = 0.25 of rho = 1 + 0.2 sin(2 pi x), u = 1, p = 1 on a periodic box."""
    pde = g.get_pde("euler1d", ic="smooth", bc="periodic", n=n, t_end=0.25, n_frames=2, limiter=limiter)
    x = pde.grid.coords().astype(np.float64)
    u0 = np.stack([1 + 0.2 * np.sin(2 * np.pi * x), np.ones(n), np.ones(n)])
    u = np.asarray(g.solve(pde, u0, {"gamma": GAMMA}).u[0, -1], np.float64)
    return float(np.sum(np.abs(u[0] - (1 + 0.2 * np.sin(2 * np.pi * (x - 0.25))))) / n)


@pytest.mark.parametrize("limiter, order", [("minmod", 1.6), ("mc", 1.8)])
def test_a_translated_density_wave_converges_at_about_second_order(limiter, order):
    errs = [wave_error(n, limiter) for n in (100, 200, 400)]  # the shock tubes' grids: no new compilation
    orders = [math.log2(a / b) for a, b in zip(errs, errs[1:])]
    print(limiter, "L1(rho)", errs, "orders", orders)
    # minmod clips the wave's extrema (1.90, 1.90); MC keeps second order (2.03) until float32 rounding over ~400
    # steps sets a floor near 1e-5 at n = 400 (in float64: 2.03, 2.01)
    assert orders[0] >= order and (limiter == "mc" or orders[1] >= order), (errs, orders)


def test_a_sample_alone_equals_it_in_a_batch_bit_for_bit():
    pde = g.get_pde("euler1d", n=100, n_frames=3, t_end=0.05, gamma="uniform(1.3, 1.67)")
    batch = np.asarray(g.sample(pde, range(6), seed=5).u)
    for i in (0, 3, 5):
        assert np.array_equal(np.asarray(g.sample(pde, [i], seed=5).u[0]), batch[i])
    assert np.array_equal(np.asarray(g.sample(pde, [4, 2], seed=5).u), batch[[4, 2]])


def test_a_failing_sample_is_named_with_its_cause_not_written_as_nan():
    # CFL 0.8 at Sod's initial speed: the waves behind the forming shock soon run ~1.5x faster and outrun the step
    pde = g.get_pde("euler1d", ic="sod", n=100, t_end=0.2, n_frames=3, cfl=0.8)
    with pytest.raises(g.BlowUpError, match=r"^euler1d: 1 of 1 trajectories failed .*index 0: the waves outran "
                                            r"the step at t = 0\.0\d+ \(CFL 1\.\d+\)"):
        g.sample(pde, [0])
    traj = g.sample(pde, [0, 1], on_blowup="skip")
    assert len(traj.indices) == 0 and "the waves outran the step" in traj.skipped[0]
    # a caller's own initial state: the same cause, not "blew up"
    u0 = np.asarray(g.sample(pde.replace(cfl=0.4), [0]).u[0, 0])
    with pytest.raises(g.BlowUpError, match=r"^euler1d: solve: trajectories failed .* for batch entries 0: the waves "
                                            r"outran the step at t = 0\.0\d+ \(CFL 1\.\d+\); a smaller cfl"):
        g.solve(pde, u0, {"gamma": 1.4})


def test_unsupported_settings_are_refused_in_one_line():
    for settings, said in [({"bc": "dirichlet"}, "bc='dirichlet' not allowed; allowed: outflow, periodic, wall"),
                           ({"bc": "periodic,wall"}, "periodic ends come in pairs"),
                           ({"limiter": "superbee"}, "limiter='superbee' not allowed"),
                           ({"gamma": "uniform(0.9, 1.4)"}, "lies in (1, 3]"),
                           ({"gamma": "1e10"}, "gamma=10000000000.0 not allowed"),
                           ({"ic.rho_l": "uniform(-1, 1)"}, "ic.rho_l=uniform(-1.0, 1.0) not allowed"),
                           ({"ic.p_r": "inf"}, "ic.p_r='inf' not allowed: must be a finite number"),
                           ({"ic.x0": "uniform(0.2, nan)"}, "ic.x0='uniform(0.2, nan)' not allowed: must be a finite"),
                           ({"ic": "grf"}, "unknown ic kind 'grf'; allowed: riemann, sod, lax, 123, smooth")]:
        with pytest.raises(ValueError, match="^euler1d: ") as err:
            g.get_pde("euler1d", **settings)
        assert said in str(err.value) and "\n" not in str(err.value), str(err.value)
    assert g.get_pde("euler1d", **{"bc.x": "wall"}).grid.bc == ("dirichlet",)
    assert g.get_pde("euler1d", bc="wall,outflow").grid.sides == ("wall", "outflow")


@pytest.mark.slow  # ~30 s on 2 cores: torch, and compiling the reverse-mode scan
def test_the_oracle_and_the_differentiable_step_continue_sampled_frames():
    import torch

    from pdestream.datasets import SolverOracle, SolverStep, _bridge

    pde = g.get_pde("euler1d", n=100, t_end=0.1, n_frames=3, gamma="uniform(1.3, 1.67)")
    t = _bridge.sample_tensors(pde, range(3), seed=2)
    u, params = t["u"], t["params"]
    oracle = SolverOracle(pde)
    # the primitive frame re-enters the solver as conserved variables: equal to float32 rounding, not bit for bit
    got = oracle(u[:, 0], params)
    assert float((got - u[:, 1]).abs().max() / u[:, 1].abs().max()) < 1e-5
    assert torch.equal(oracle(u[1:2, 0], params[1:2])[0], got[1])  # alone as in the batch
    x = u[:, 0].clone().requires_grad_(True)
    p = params.clone().requires_grad_(True)
    out = SolverStep(pde)(x, p)
    assert float((out.detach() - got).abs().max() / got.abs().max()) < 1e-5
    out[:, 0].sum().backward()  # total density after a frame: its gradient flows back through HLLC and minmod
    assert torch.isfinite(x.grad).all() and torch.isfinite(p.grad).all() and x.grad[:, 0].abs().sum() > 0
