"""The sharp circle body (issue 28 part 1, generator.flow.grid's 'sharp' BODIES): cut-face apertures against the
exact circle, ghost velocities through no-slip on it, the surface-integral force on it, the setting's refusal.
The Schaefer-Turek 2D-1 check of the whole scheme is in tests/test_flow_forces.py (slow); the grid study in
benchmarks/flow_bodies.py. Each test here is a few small arrays (no rollout)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from pdestream import generator
from pdestream.generator.flow import Geometry, Params, forces, grid
from pdestream.generator.flow.step import (
    State,
    _centroid_weights,
    _fluxes,
    _from_centroid,
    _to_centroid,
    apply_bc,
    body_faces,
)

CX, CY, R = 0.537, 0.4619, 0.2034


def _open_exact(x0, y0, x1, y1, samples=20001):
    """Open fraction of the segment (x0, y0)-(x1, y1) outside the circle, by dense sampling (float64)."""
    s = np.linspace(0, 1, samples)
    x, y = x0 + s * (x1 - x0), y0 + s * (y1 - y0)
    return np.mean(np.hypot(x - CX, y - CY) >= R)


def test_apertures_are_the_open_fractions_of_the_faces_against_the_exact_circle():
    geom = Geometry(32, 16, 2.0, 1.0, left="inflow", right="outflow")
    h = geom.h
    ax, ay = (np.asarray(a) for a in grid.circle_apertures(geom, CX, CY, R))
    cut = 0
    for j in range(geom.ny):
        for i in range(geom.nx + 1):
            want = _open_exact(i * h, j * h, i * h, (j + 1) * h)
            want = 0.0 if want < grid.MIN_APERTURE else want
            assert ax[j, i] == pytest.approx(want, abs=2e-4), (j, i)
            cut += 0 < want < 1
    for j in range(geom.ny + 1):
        for i in range(geom.nx):
            want = _open_exact(i * h, j * h, (i + 1) * h, j * h)
            want = 0.0 if want < grid.MIN_APERTURE else want
            assert ay[j, i] == pytest.approx(want, abs=2e-4), (j, i)
    assert cut >= 8  # the circle cuts faces (not only whole or closed ones)
    fc = body_faces(geom, Params(circle=(CX, CY, R)))  # the pressure operator's coefficients are the apertures
    assert np.allclose(np.asarray(fc.cx)[:, 1:-1], ax[:, 1:-1]) and np.allclose(np.asarray(fc.cy)[1:-1], ay[1:-1])
    # a cell is solid (an identity row) exactly where the circle covers it whole: all 4 corners inside
    x, y = np.meshgrid(np.arange(geom.nx + 1) * h, np.arange(geom.ny + 1) * h)
    inside = np.hypot(x - CX, y - CY) < R
    covered = inside[:-1, :-1] & inside[1:, :-1] & inside[:-1, 1:] & inside[1:, 1:]
    assert np.array_equal(np.asarray(fc.solid) > 0.5, covered)


def test_a_cut_face_carries_its_open_fraction_times_the_velocity_at_its_open_centroid():
    """On a velocity linear along the faces, the flux through every open face is its aperture times the velocity at
    its open part's centroid (exact: the interpolation along the face is linear), and the projection's map back
    from centroid to face-centre velocities inverts it (its cut faces read whole neighbours only)."""
    geom = Geometry(32, 16, 2.0, 1.0, left="inflow", right="outflow")
    params = Params(circle=(CX, CY, R))
    h = geom.h
    yu = (np.arange(geom.ny) + 0.5)[:, None] * h + 0 * np.arange(geom.nx + 1)
    xv = (np.arange(geom.nx) + 0.5)[None, :] * h + 0 * np.arange(geom.ny + 1)[:, None]
    u, v = 1.0 + 2.0 * yu, 3.0 - 1.5 * xv
    fu, fv = (np.asarray(f) for f in _fluxes(geom, params, jnp.asarray(u), jnp.asarray(v)))
    ax, ay, my, mx = (np.asarray(a, np.float64) for a in grid.circle_cut_faces(geom, CX, CY, R))
    assert np.abs(fu - ax * (1.0 + 2.0 * my)).max() < 1e-5 and np.abs(fv - ay * (3.0 - 1.5 * mx)).max() < 1e-5
    cut = ((ax > 0) & (ax < 1)).sum() + ((ay > 0) & (ay < 1)).sum()
    moved = (np.abs(fu - ax * u) > 1e-3).sum() + (np.abs(fv - ay * v) > 1e-3).sum()
    assert moved > cut // 2  # the centroid is off the centre on most cut faces (at the centre: a different flux)
    (_, uu, ud, _), (_, vu, vd, _) = _centroid_weights(geom, params, jnp.float32)
    back = _from_centroid(_to_centroid(jnp.asarray(u, jnp.float32), uu, ud, 0), uu, ud, 0)
    assert np.abs(np.asarray(back) - u).max() < 1e-5


def _polar_field(geom, f):
    """u [ny, nx+1], v [ny+1, nx] on the MAC faces of the velocity f(rho - R, theta) -> (u, v) (float64)."""
    h = geom.h
    xu, yu = np.meshgrid(np.arange(geom.nx + 1) * h, (np.arange(geom.ny) + 0.5) * h)
    xv, yv = np.meshgrid((np.arange(geom.nx) + 0.5) * h, np.arange(geom.ny + 1) * h)
    u = f(np.hypot(xu - CX, yu - CY) - R, np.arctan2(yu - CY, xu - CX))[0]
    v = f(np.hypot(xv - CX, yv - CY) - R, np.arctan2(yv - CY, xv - CX))[1]
    return u, v


def _swirl(d, th, a=1.0, b=3.0):
    """A tangential velocity a d + b d^2 (d: distance outside the circle): no-slip on it, quadratic across it."""
    ut = a * d + b * d * d
    return -ut * np.sin(th), ut * np.cos(th)


def _ghost_error(n):
    """Largest error of the ghost faces of u for _swirl on a 2n x n grid, and the staircase's there (it zeroes them)."""
    geom = Geometry(2 * n, n, 2.0, 1.0, body="sharp")
    u, v = _polar_field(geom, _swirl)
    ghost = np.asarray(grid.circle_ghosts(geom, CX, CY, R, 0.0, 0.5, u.shape).ghost)
    filled, _ = apply_bc(geom, Params(circle=(CX, CY, R)), jnp.asarray(np.where(ghost, 99.0, u), jnp.float32),
                         jnp.asarray(v, jnp.float32))
    return np.abs(np.asarray(filled) - u)[ghost].max(), np.abs(u)[ghost].max(), ghost.sum()


def test_ghost_velocities_continue_a_no_slip_profile_through_the_circle():
    """The ghost faces of a flow quadratic in the distance to the circle (zero on it) take that flow's values
    inside, to the bilinear interpolation's O(h^2) (the staircase's masked faces take 0: an O(h) error)."""
    (e1, s1, k1), (e2, s2, k2) = _ghost_error(64), _ghost_error(128)  # R 13 and 26 cells (at 6.5: order 1.1)
    assert k1 > 10 and k2 > 2 * k1 - 10
    assert e1 < 0.1 * s1 and e2 < 0.1 * s2
    assert math.log2(e1 / e2) > 1.8  # second order (measured 2.1; the staircase's error s halves: first)


def test_surface_force_of_a_uniform_pressure_gradient_is_the_displaced_fluid_and_of_a_shear_its_integral():
    geom = Geometry(64, 32, 2.0, 1.0, body="sharp")
    h, grad_p, nu, a = geom.h, 0.7, 0.01, 2.0
    x, y = np.meshgrid((np.arange(geom.nx) + 0.5) * h, (np.arange(geom.ny) + 0.5) * h)
    zero_u, zero_v = np.zeros((geom.ny, geom.nx + 1)), np.zeros((geom.ny + 1, geom.nx))
    s = State(jnp.asarray(zero_u), jnp.asarray(zero_v), jnp.asarray(grad_p * x), None, None, None, None)
    fx, fy = forces.circle_force(geom, s, nu, CX, CY, R)
    assert float(fx) == pytest.approx(-grad_p * math.pi * R * R, rel=1e-5) and abs(float(fy)) < 1e-6
    # u_t = a d cos(theta): wall shear nu a cos(theta) along the tangent, F = (0, pi R nu a)
    u, v = _polar_field(geom, lambda d, th: _swirl(d * np.cos(th), th, a, 0.0))
    s = State(jnp.asarray(u), jnp.asarray(v), jnp.zeros((geom.ny, geom.nx)), None, None, None, None)
    fx, fy = forces.circle_force(geom, s, nu, CX, CY, R)
    # corrected interpolation: 1.8e-4 here, second order (plain bilinear: 1.4e-2, first order)
    assert float(fy) == pytest.approx(math.pi * R * nu * a, rel=1e-3) and abs(float(fx)) < 1e-3 * float(fy)


def test_a_bad_body_setting_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"body='cut'.*allowed are staircase, sharp"):
        generator.get_pde("karman2d", body="cut")
    with pytest.raises(ValueError, match=r"body='cut'"):
        Geometry(8, 8, 1.0, 1.0, body="cut")
    assert generator.get_pde("karman2d").body == grid.DEFAULT_BODY == "sharp"
    assert "sharp circle" in generator.get_pde("karman2d").describe()


def _prepared_case():
    """A sharp circle and a box row in a channel, a random velocity field with its boundary values (64x32)."""
    import jax

    geom = Geometry(64, 32, 2.0, 1.0, left="inflow", right="outflow", body="sharp")
    params = Params(nu=1e-2, inflow=1.0, circle=(CX, CY, R), obstacles=np.array([[2.0, 1.5, 0.5, 0.1, 0.15]], np.float32))
    k1, k2 = jax.random.split(jax.random.PRNGKey(3))
    u = jax.random.normal(k1, (geom.ny, geom.nx + 1), jnp.float32)
    v = jax.random.normal(k2, (geom.ny + 1, geom.nx), jnp.float32)
    return geom, params, u, v


def test_a_rollouts_prepared_geometry_is_what_each_step_computes():
    """step.prepare: the masks, faces, centroid weights and ghosts a rollout computes once are the bits each step
    computes for itself, and the fill from the listed ghost faces equals the fill at every face (to float32
    rounding: the two kernels may round a multiply-add differently) and leaves every other face alone."""
    import importlib

    step = importlib.import_module("pdestream.generator.flow.step")
    geom, params, u, v = _prepared_case()
    ready = step.prepare(geom, params).prepared
    assert bool(ready.listed_fits)
    assert all(np.array_equal(a, b) for a, b in zip(ready.faces, step.body_faces(geom, params)))
    for got, want in zip(ready.weights, step._centroid_weights(geom, params, jnp.float32)):
        assert all(np.array_equal(a, b) for a, b in zip(got, want[:3]))
    bodies = step.sharp_bodies(geom, params)
    assert np.array_equal(ready.ghosts[1].w1, grid.body_ghosts(geom, bodies, 0.5, 0.0, v.shape).w1)
    listed = step.fill_ghosts(geom, step.prepare(geom, params), u, v)
    everywhere = step.fill_ghosts(geom, params, u, v)
    for a, b, q, g in zip(listed, everywhere, (u, v), ready.ghosts):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
        assert not np.allclose(np.asarray(a)[np.asarray(g.ghost)], np.asarray(q)[np.asarray(g.ghost)])  # filled
        rest = ~np.asarray(g.ghost | g.deep)
        assert np.array_equal(np.asarray(a)[rest], np.asarray(q)[rest])  # untouched elsewhere
        assert np.all(np.asarray(a)[np.asarray(g.deep)] == 0)


def test_ghosts_beyond_the_list_fall_back_to_filling_every_face(monkeypatch):
    """Bodies with more ghost faces than the list holds (GHOST_LIST (nx + ny) per component) are filled at every
    face: the result is then the unprepared fill's (to float32 rounding: one compiled kernel against op by op);
    a list too short taken as whole would leave most ghosts unfilled."""
    import importlib

    step = importlib.import_module("pdestream.generator.flow.step")
    geom, params, u, v = _prepared_case()
    monkeypatch.setattr(step, "GHOST_LIST", 0.05)  # 4 faces: fewer than the bodies' ghosts
    prepared = step.prepare(geom, params)
    assert not bool(prepared.prepared.listed_fits)
    for a, b in zip(step.fill_ghosts(geom, prepared, u, v), step.fill_ghosts(geom, params, u, v)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


def test_without_the_list_the_prepared_fill_is_the_fill_at_every_face():
    """prepare(..., ghost_list=False) (a GPU's default: its batches are vectorised) fills every face from the
    prepared ghosts: the unprepared fill's values."""
    import importlib

    step = importlib.import_module("pdestream.generator.flow.step")
    geom, params, u, v = _prepared_case()
    prepared = step.prepare(geom, params, ghost_list=False)
    assert prepared.prepared.listed is None and prepared.prepared.ghosts is not None
    for a, b in zip(step.fill_ghosts(geom, prepared, u, v), step.fill_ghosts(geom, params, u, v)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
