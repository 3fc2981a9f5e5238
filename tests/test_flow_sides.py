"""The flow solver's side kinds beyond no-slip walls (issue 28, boundaries users ask for), each against a case
with a known answer: free-slip walls ('slip'), a pulsed inflow (Params.pulse) and a convective outflow
('convective', against the same flow in a channel twice as long). Small grids."""

import jax
import numpy as np
import pytest

from pdestream.generator.flow import Geometry, Params, initial_state, run


def _shear_mode_error(n, bottom, top, nu=0.05, t_end=0.5):
    """Max error of u against u = cos(pi y) exp(-nu pi^2 t): a shear wave between the sides of the unit box
    (periodic in x), an exact Navier-Stokes solution where both sides are free of shear stress (du/dy = 0 there)."""
    geom = Geometry(4, n, 4 / n, 1.0, left="periodic", right="periodic", bottom=bottom, top=top)
    params = Params(nu=nu)
    y = (np.arange(n) + 0.5) / n
    u0 = np.broadcast_to(np.cos(np.pi * y)[:, None], (n, 5)).astype(np.float32)
    s = initial_state(geom, params)._replace(u=jax.numpy.asarray(u0))
    dt = 0.9 * geom.h ** 2 / (4 * nu)
    steps = int(round(t_end / dt))
    s = jax.jit(run, static_argnums=(0, 4))(geom, s, params, dt, steps)
    exact = np.cos(np.pi * y)[:, None] * np.exp(-nu * np.pi ** 2 * steps * dt)
    return float(np.abs(np.asarray(s.u) - exact).max()), float(np.abs(np.asarray(s.v)).max())


def test_free_slip_walls_carry_the_exact_shear_wave_at_second_order():
    errors = [_shear_mode_error(n, "slip", "slip") for n in (8, 16)]
    assert all(ev < 1e-6 for _, ev in errors)  # no flow through the walls, none made across
    order = np.log2(errors[0][0] / errors[1][0])
    assert errors[1][0] < 2e-3 and order > 1.8, errors  # (no-slip walls there: 0.72 off at n = 16)


def test_a_pulsed_plug_inflow_between_free_slip_walls_moves_the_whole_channel_with_it():
    """Between free-slip walls a plug inflow U(t) = 2/3 inflow (1 + A sin(2 pi f t)) is the flow everywhere at
    once (incompressible: what enters leaves; no wall to slow it): u = U(t), v = 0 exactly, at every phase."""
    geom = Geometry(16, 8, 2.0, 1.0, left="inflow", right="outflow", bottom="slip", top="slip")
    params = Params(nu=0.01, inflow=1.5, plug=1.0, pulse=(0.4, 0.5))
    dt = 0.05
    go = jax.jit(run, static_argnums=(0, 4))
    s = initial_state(geom, params)
    t = 0.0
    steps = 9  # one program: phases 0.45, 0.9 and 1.35 s of the 2 s period (rising, past the top, falling)
    for _ in range(3):
        s = go(geom, s, params, dt, steps)
        t += steps * dt
        speed = 1.0 * (1 + 0.4 * np.sin(2 * np.pi * 0.5 * t))
        np.testing.assert_allclose(np.asarray(s.u), speed, rtol=0, atol=2e-5 * speed)
        assert float(np.abs(np.asarray(s.v)).max()) < 1e-5
    assert float(s.t) == pytest.approx(t)


def test_a_pulsed_inflow_needs_the_time_and_a_steady_one_is_the_program_it_was():
    from pdestream.generator.flow.step import apply_bc, inflow_profile

    geom = Geometry(8, 4, 2.0, 1.0, left="inflow", right="outflow")
    steady = Params(inflow=1.5)
    with pytest.raises(ValueError, match="needs the time t"):
        inflow_profile(geom, steady._replace(pulse=(0.2, 1.0)))
    np.testing.assert_array_equal(inflow_profile(geom, steady), inflow_profile(geom, steady, t=3.0))
    u, _ = apply_bc(geom, steady._replace(pulse=(0.5, 0.25)), *initial_state(geom, steady)[:2], 1.0)
    np.testing.assert_allclose(np.asarray(u[:, 0]), 1.5 * np.asarray(inflow_profile(geom, steady)), rtol=1e-6)


def _vortex_leaving(nx: int, right: str, lx: float, n: int = 16, t_end: float = 1.6):
    """u [ny, nx+1] at t_end of a Gaussian vortex (amplitude 1 m/s) carried by a uniform 1 m/s stream from x 0.6
    out through the right side of a channel periodic in y (h = 1/n), and the final state."""
    geom = Geometry(nx, n, lx, 1.0, left="inflow", right=right, bottom="periodic", top="periodic")
    params = Params(nu=2e-3, inflow=1.5, plug=1.0)  # plug: 2/3 of 1.5
    h, r = geom.h, 0.15
    x, y = np.meshgrid(np.arange(nx + 1) * h, np.arange(n + 1) * h)
    psi = y + r * np.exp(-((x - 0.6) ** 2 + (y - 0.5) ** 2) / r ** 2)  # at the corners: discretely div-free
    s = initial_state(geom, params)._replace(u=jax.numpy.asarray(np.diff(psi, axis=0) / h, np.float32),
                                             v=jax.numpy.asarray(-np.diff(psi, axis=1) / h, np.float32))
    dt = 0.25 * h
    s = jax.jit(run, static_argnums=(0, 4), static_argnames="advection")(geom, s, params, dt, int(round(t_end / dt)),
                                                                        advection="maccormack")
    return geom, s


@pytest.mark.slow  # three channel programs: ~40 CPU s
def test_a_convective_outflow_lets_a_vortex_leave_with_less_reflection_than_a_fixed_pressure():
    """The same vortex through a channel of length 2 and of length 4 (its outlet far away: the reference); on
    x < 1.5 the short channel's convective outflow stays closer to the long one than the zero-gradient outflow
    with p = 0 does, loses no mass and stays divergence-free."""
    from pdestream.generator.flow.step import divergence

    _, long = _vortex_leaving(64, "outflow", 4.0)
    reference = np.asarray(long.u)[:, :24]
    off = {}
    for right in ("convective", "outflow"):
        geom, s = _vortex_leaving(32, right, 2.0)
        off[right] = float(np.abs(np.asarray(s.u)[:, :24] - reference).max())
        if right == "convective":
            assert float(s.u[:, -1].sum()) == pytest.approx(float(s.u[:, 0].sum()), rel=1e-6)  # what enters leaves
            assert float(np.abs(np.asarray(divergence(geom, s.u, s.v))).max()) < 1e-5
    assert off["convective"] < 1.5e-3 and off["convective"] < 0.7 * off["outflow"], off  # measured 1.0e-3, 1.9e-3


def test_a_convective_side_is_right_or_top():
    with pytest.raises(ValueError, match="a convective outflow is a right or top side"):
        Geometry(8, 8, 1.0, 1.0, left="convective")
