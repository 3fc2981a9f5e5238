"""shallow_water2d and euler2d (generator.finite_volume) against things other than their own code: the exact
dam-break solution (Ritter's, on a dry bed), the exact isentropic vortex, euler1d's shock tube, and the
conservation laws themselves. Quick tests share one grid (n = 32: one compilation per entry)."""

import math

import numpy as np
import pytest

from pdestream import generator as g

pytestmark = pytest.mark.xdist_group("finite_volume_2d")  # one worker: each grid's programs compile once


# --- shallow_water2d ----------------------------------------------------------------------------------------------
def ritter(x, t, h0=1.0, x0=2.5, grav=1.0):
    """Ritter's dam break on a dry bed (depth h0 left of x0 at t = 0): (h, u) at positions x, time t > 0."""
    c0 = math.sqrt(grav * h0)
    xi = (np.asarray(x, float) - x0) / t
    fan = (xi >= -c0) & (xi <= 2 * c0)
    h = np.where(xi < -c0, h0, np.where(xi > 2 * c0, 0.0, (2 * c0 - xi) ** 2 / (9 * grav)))
    return h, np.where(fan, 2 / 3 * (xi + c0), 0.0)


def stoker(x, t, h_l=1.0, h_r=0.1, x0=2.5, grav=1.0):
    """Stoker's dam break on a wet bed (depths h_l | h_r > 0 at x0, at rest): (h, u) at positions x, time t > 0,
    and the middle state (h_m, u_m) and shock speed s. A left rarefaction to (h_m, u_m = 2 (c_l - c_m)), then a
    shock into h_r; h_m solves u_m = (h_m - h_r) sqrt(g (h_m + h_r) / (2 h_m h_r)) (bisection)."""
    c_l = math.sqrt(grav * h_l)

    def gap(hm):
        return 2 * (c_l - math.sqrt(grav * hm)) - (hm - h_r) * math.sqrt(grav * (hm + h_r) / (2 * hm * h_r))

    lo, hi = h_r, h_l
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap(mid) > 0 else (lo, mid)
    h_m = 0.5 * (lo + hi)
    c_m = math.sqrt(grav * h_m)
    u_m = 2 * (c_l - c_m)
    s = h_m * u_m / (h_m - h_r)  # the shock's mass balance
    xi = (np.asarray(x, float) - x0) / t
    fan = (xi >= -c_l) & (xi <= u_m - c_m)
    h = np.where(xi < -c_l, h_l, np.where(fan, (2 * c_l - xi) ** 2 / (9 * grav), np.where(xi < s, h_m, h_r)))
    u = np.where(xi < -c_l, 0.0, np.where(fan, 2 / 3 * (xi + c_l), np.where(xi < s, u_m, 0.0)))
    return h, u, (h_m, u_m, s)


def test_stokers_middle_state_satisfies_the_shock_conditions():
    _, _, (h_m, u_m, s) = stoker([0.0], 1.0)
    # momentum across the shock (the mass balance defined s): s h_m u_m = h_m u_m^2 + g (h_m^2 - h_r^2) / 2
    assert s * h_m * u_m == pytest.approx(h_m * u_m**2 + 0.5 * (h_m**2 - 0.1**2), rel=1e-12)
    assert 0.1 < h_m < 1 and u_m > 0 and s > u_m


def dam_break(n, h_r):
    """(pde, u [T, 3, n, n] float64) of the dam break along x (depth 1 | h_r at x = 2.5) at n x n cells, t = 1."""
    pde = g.get_pde("shallow_water2d", ic="dam", n=n, t_end=1.0, n_frames=3, bc="x=outflow,y=periodic",
                    **{"ic.h_r": h_r})
    return pde, np.asarray(g.sample(pde, [0], seed=0).u[0], np.float64)


def dam_break_errors(pde, u):
    """L1 errors (h, hu) of the last frame's first row against Ritter's (dry bed) or Stoker's solution."""
    h_r = pde.ic.h_r
    h, vel = ritter(pde.grid.coords(), pde.t_end) if h_r == 0 else stoker(pde.grid.coords(), pde.t_end, h_r=h_r)[:2]
    return (float(np.sum(np.abs(u[-1, 0, :, 0] - h)) * pde.h),
            float(np.sum(np.abs(u[-1, 1, :, 0] - h * vel)) * pde.h))


@pytest.mark.parametrize("h_r", [0.0, 0.1])
def test_a_dam_break_keeps_depth_non_negative_and_follows_the_exact_solution(h_r):
    pde, u = dam_break(32, h_r)
    assert (u[:, 0] >= 0).all()  # no clipping: the scheme keeps it (MUSCL-HLL under its CFL bound)
    assert (u == u[..., :1]).all() and (u[:, 2] == 0).all()  # uniform in y, no v
    err_h, err_m = dam_break_errors(pde, u)
    # n = 32: Ritter 0.044 and 0.042, Stoker 0.049 and 0.035 (the order test's first grid); an untouched dam
    # (the initial state) is off by 0.33 (Ritter)
    assert err_h < 0.06 and err_m < 0.06, (err_h, err_m)


@pytest.mark.slow  # ~30 s on 2 cores: three grids, three compilations
@pytest.mark.parametrize("h_r", [0.0, 0.1])
def test_the_dam_break_converges_to_the_exact_solution(h_r):
    errs = [dam_break_errors(*dam_break(n, h_r)) for n in (32, 64, 128)]
    orders = [[math.log2(a / b) for a, b in zip(e0, e1)] for e0, e1 in zip(errs, errs[1:])]
    print("h_r", h_r, "L1 (h, hu)", errs, "orders", orders)
    # first order at the front or shock and the fan's kinks: Ritter h 1.03, 1.10, hu 1.01, 1.17; Stoker h 0.92,
    # 0.94, hu 0.79, 1.20
    assert all(o >= 0.75 for pair in orders for o in pair), (errs, orders)


@pytest.mark.slow  # ~15 s on 2 cores: a 64^2 grid of its own
def test_radial_dam_breaks_on_a_dry_bed_keep_every_sample_and_depth_non_negative():
    # float32 rounding left front cells at -2.5e-9 and failed 6 of these 8 samples before rounded_dry
    pde = g.get_pde("shallow_water2d", n=64, g="uniform(0.5, 2)", bc="wall", **{"ic.h_out": "0"})
    traj = g.sample(pde, range(8), seed=1, on_blowup="skip")
    u = np.asarray(traj.u, np.float64)
    assert len(traj.indices) == 8 and (u[:, :, 0] >= 0).all()
    mass = u[:, :, 0].sum(axis=(-1, -2))
    assert (np.abs(mass / mass[:, :1] - 1) <= pde.steps_per_frame * (pde.n_frames - 1) * 2.0**-24).all()


def test_mass_and_momentum_are_conserved_on_a_periodic_box():
    pde = g.get_pde("shallow_water2d", ic="smooth", bc="periodic", n=32, t_end=1.0, n_frames=4)
    u = np.asarray(g.sample(pde, [1], seed=0).u[0], np.float64)
    sums = u.sum(axis=(-1, -2)) * pde.h**2  # [T, 3]: mass, x and y momentum
    drift = np.abs(sums - sums[0]) / np.abs(sums[0]).max()
    # float32 rounding: under one float32 ulp (2^-24 relative) per step taken
    bound = np.arange(4)[:, None] * pde.steps_per_frame * 2.0**-24
    assert (drift <= bound).all() and np.abs(u[-1] - u[0]).max() > 1e-2, drift  # and the state did change


def test_a_lake_at_rest_stays_at_rest():
    pde = g.get_pde("shallow_water2d", ic="smooth", bc="wall", n=32, t_end=1.0, n_frames=3)
    u0 = np.zeros((1, 3, 32, 32), np.float32)
    u0[:, 0] = 1.5
    u = np.asarray(g.solve(pde, u0, {"g": 1.0}).u[0])
    assert (u[:, 0] == 1.5).all() and (u[:, 1:] == 0).all()


def _batch_equal_to_its_samples_alone(pde) -> np.ndarray:
    """Samples 0..4 of seed 5 [5, T, C, n, n], each (and a reordered pair) checked equal to itself solved alone."""
    batch = np.asarray(g.sample(pde, range(5), seed=5).u)
    for i in (0, 4):
        assert np.array_equal(np.asarray(g.sample(pde, [i], seed=5).u[0]), batch[i])
    assert np.array_equal(np.asarray(g.sample(pde, [3, 1], seed=5).u), batch[[3, 1]])
    return batch


def test_a_shallow_water_sample_alone_equals_it_in_a_batch_bit_for_bit():
    batch = _batch_equal_to_its_samples_alone(
        g.get_pde("shallow_water2d", n=32, n_frames=3, t_end=0.2, g="uniform(0.5, 2)"))
    assert len({float(np.abs(b).sum()) for b in batch}) == 5  # five different samples


def test_unsupported_shallow_water_settings_are_refused_in_one_line():
    for settings, said in [({"bc": "dirichlet"}, "bc='dirichlet' not allowed; allowed: outflow, periodic, wall"),
                           ({"bc": "x=wall,z=periodic"}, "per axis x=KIND,y=KIND"),
                           ({"cfl": 0.6}, "cfl=0.6 not allowed: must be in (0, 0.5]"),
                           ({"ic.h_out": "uniform(-1, 1)"}, "need h_in > 0, h_out >= 0"),
                           ({"ic.cx": "uniform(4, 6)"}, "ic.cx=uniform(4.0, 6.0) not allowed: must lie in (0, 5)"),
                           ({"ic": "sod"}, "unknown ic kind 'sod'; allowed: radial, dam, smooth")]:
        with pytest.raises(ValueError, match="^shallow_water2d: ") as err:
            g.get_pde("shallow_water2d", **settings)
        assert said in str(err.value) and "\n" not in str(err.value), str(err.value)
    pde = g.get_pde("shallow_water2d", **{"bc.y": "wall"})
    assert pde.bc == "x=outflow,y=wall" and pde.grid.bc == ("neumann", "dirichlet")


# --- euler2d ------------------------------------------------------------------------------------------------------
GAMMA = 1.4


def isentropic_vortex(n, t, length=10.0, beta=5.0):
    """The isentropic vortex of strength beta (Shu 1998) centred at (5, 5) at t = 0 in the mean flow (1, 1) on the
    periodic box [0, length)^2: exact primitive (rho, u, v, p) [4, n, n] at the cell centres at time t."""
    x = (np.arange(n) + 0.5) * length / n
    xx, yy = np.meshgrid(x, x, indexing="ij")
    dx = (xx - 5 - t + length / 2) % length - length / 2
    dy = (yy - 5 - t + length / 2) % length - length / 2
    r2 = dx**2 + dy**2
    temp = 1 - (GAMMA - 1) * beta**2 / (8 * GAMMA * math.pi**2) * np.exp(1 - r2)
    rho = temp ** (1 / (GAMMA - 1))
    swirl = beta / (2 * math.pi) * np.exp((1 - r2) / 2)
    return np.stack([rho, 1 - swirl * dy, 1 + swirl * dx, rho**GAMMA])


@pytest.mark.slow  # ~40 s on 2 cores: three grids up to 128^2, three compilations
def test_the_isentropic_vortex_converges_at_second_order():
    errs = []
    for n in (32, 64, 128):
        # cfl 0.2 at the smooth IC's speed bound: the vortex's own |u| + c is ~2x it
        pde = g.get_pde("euler2d", ic="smooth", bc="periodic", n=n, length=10.0, t_end=1.0, n_frames=2, cfl=0.2,
                        limiter="mc")
        u0 = isentropic_vortex(n, 0.0)[None].astype(np.float32)
        u = np.asarray(g.solve(pde, u0, {"gamma": GAMMA}).u[0, -1], np.float64)
        errs.append(float(np.abs(u[0] - isentropic_vortex(n, 1.0)[0]).sum() * pde.h**2))
    orders = [math.log2(a / b) for a, b in zip(errs, errs[1:])]
    print("L1(rho)", errs, "orders", orders)
    # measured 0.156, 0.0328, 0.00690 (orders 2.25, 2.25); minmod: 0.303, 0.0907, 0.0251 (1.74, 1.85)
    assert all(o >= 1.9 for o in orders), (errs, orders)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_sod_along_either_axis_is_euler1ds_solution(axis):
    # the same scheme, grid and step (the 2D step sums two axes' speeds: euler1d at half the cfl)
    one = g.get_pde("euler1d", ic="sod", n=32, t_end=0.2, n_frames=3, cfl=0.2)
    want = np.asarray(g.sample(one, [0]).u[0])  # [T, (rho, u, p), n]
    two = g.get_pde("euler2d", ic="sod", n=32, t_end=0.2, n_frames=3, **{"ic.axis": axis},
                    bc="x=outflow,y=periodic" if axis == "x" else "x=wall,y=outflow")
    assert two.step_dt == one.step_dt
    u = np.asarray(g.sample(two, [0]).u[0])  # [T, (rho, u, v, p), n, n]
    if axis == "y":  # y as the first axis, v as the normal velocity
        u = np.swapaxes(u, -1, -2)[:, [0, 2, 1, 3]]
    # equal bit for bit on the build machine; asserted to float32 rounding, as the two programs are compiled
    # separately (XLA may fuse a 2D program's arithmetic otherwise on another instruction set)
    assert np.abs(u[:, [0, 1, 3]] - want[..., None]).max() <= 1e-6
    assert (u[:, 2] == 0).all() and np.abs(want[-1] - want[0]).max() > 0.1


def test_mass_momentum_and_energy_are_conserved_on_a_periodic_box():
    pde = g.get_pde("euler2d", ic="smooth", bc="periodic", n=32, t_end=0.3, n_frames=4)
    u = np.asarray(g.sample(pde, [1], seed=0).u[0], np.float64)
    rho, vx, vy, p = u[:, 0], u[:, 1], u[:, 2], u[:, 3]
    q = np.stack([rho, rho * vx, rho * vy, p / (GAMMA - 1) + 0.5 * rho * (vx**2 + vy**2)], 1)
    sums = q.sum(axis=(-1, -2)) * pde.h**2  # [T, 4]
    drift = np.abs(sums - sums[0]) / np.abs(sums[0]).max()
    # float32 rounding: under one float32 ulp (2^-24 relative) per step taken, the primitive round trip included
    bound = np.arange(4)[:, None] * pde.steps_per_frame * 2.0**-24
    assert (drift <= bound).all() and np.abs(u[-1] - u[0]).max() > 1e-2, drift


def test_two_strong_rarefactions_keep_density_and_pressure_positive():
    # Toro's 123 problem along y (u = -2 | 2 at y = 0.5, p = 0.4): near-vacuum between the fans
    pde = g.get_pde("euler2d", ic="sod", n=32, t_end=0.15, n_frames=4, cfl=0.2, bc="x=periodic,y=outflow")
    u0 = np.zeros((1, 4, 32, 32), np.float32)
    u0[:, 0], u0[:, 3] = 1.0, 0.4
    u0[:, 2] = np.where(pde.grid.coords() < 0.5, -2.0, 2.0)[None, :]
    traj = g.solve(pde, u0, {"gamma": GAMMA})
    u = np.asarray(traj.u[0])
    assert (u[:, 0] > 0).all() and (u[:, 3] > 0).all() and u[-1, 0].min() < 0.2  # the vacuum-like middle
    assert (u[:, :, :, :] == u[:, :, :1, :]).all()  # uniform in x


def test_an_euler2d_sample_alone_equals_it_in_a_batch_bit_for_bit():
    batch = _batch_equal_to_its_samples_alone(
        g.get_pde("euler2d", n=32, n_frames=3, t_end=0.05, gamma="uniform(1.3, 1.67)"))
    assert (batch[:, :, 0] > 0).all() and (batch[:, :, 3] > 0).all()


def test_unsupported_euler2d_settings_are_refused_in_one_line():
    for settings, said in [({"bc": "x=periodic,y=dirichlet"}, "per axis x=KIND,y=KIND"),
                           ({"bc": "x=wall,x=periodic"}, "bc='x=wall,x=periodic' not allowed: axis x given twice"),
                           ({"gamma": "uniform(0.9, 1.4)"}, "lies in (1, 3]"),
                           ({"ic.p": "uniform(-1, 1)"}, "densities and pressures must be > 0"),
                           ({"ic.y0": "uniform(0.2, 1.5)"}, "ic.y0=uniform(0.2, 1.5) not allowed: must lie in (0, 1)"),
                           ({"ic": "sod", "ic.axis": "z"}, "ic.axis='z' not allowed; allowed: x, y"),
                           ({"ic": "radial"}, "unknown ic kind 'radial'; allowed: riemann, config3, sod, smooth")]:
        with pytest.raises(ValueError, match="^euler2d: ") as err:
            g.get_pde("euler2d", **settings)
        assert said in str(err.value) and "\n" not in str(err.value), str(err.value)


@pytest.mark.slow  # ~40 s on 2 cores: compiling the reverse-mode scan of a 2D step
def test_shallow_waters_oracle_continues_the_frames_and_its_gradient_stays_finite_on_a_dry_bed():
    import jax.numpy as jnp

    # periodic: a second dam where the dry right end meets the wet left one, and the total depth exactly kept
    pde = g.get_pde("shallow_water2d", ic="dam", n=32, t_end=1.0, n_frames=3, bc="periodic")
    u = np.asarray(g.sample(pde, [0], seed=0).u)
    assert (u[-1, 0] < 1e-3).any()  # a dry stretch remains
    # the stored fields are the conserved state: frame 1 advanced once is frame 2, bit for bit
    got, ok = g.interactive.advance(pde, u[:, 1], {"g": np.ones(1, np.float32)}, 1)
    assert np.array_equal(np.asarray(got), u[:, 2]) and bool(np.asarray(ok).all())
    out, ok, back = pde.advance_frames_vjp(jnp.asarray(u[:, 1]), {"g": jnp.ones(1)}, 1, True)
    grad_u, grad_p = back(jnp.ones_like(out).at[:, 1:].set(0))  # d(total depth after a frame) / d(state, g)
    assert np.isfinite(np.asarray(grad_u)).all() and np.isfinite(np.asarray(grad_p["g"])).all()
    # the fluxes telescope: d(total h)/d(h) = 1 and d(total h)/d(hu, hv) = 0 in every cell, the dry ones included
    assert np.allclose(np.asarray(grad_u)[0, 0], 1.0, atol=1e-4) and np.abs(np.asarray(grad_u)[0, 1:]).max() < 1e-4
