"""The penalised body and the fringe of the 3D MAC solver (generator.flow.body3d); the drag of a sphere at Re 100
against Johnson & Patel 1999 is benchmarks/sphere_drag.py (docs/results/flows.md, "Sphere drag at Re 100")."""

import math

import jax
import jax.numpy as jnp
import pytest

from pdestream.generator.flow import body3d, mac3d

pytestmark = pytest.mark.xdist_group("plume3d")


def test_the_ball_fraction_holds_the_ball_volume():
    box = mac3d.Box((16, 16, 16), 1.0 / 8, (True,) * 3)
    for k in range(3):
        chi = body3d.ball_fraction(box, (1.0, 1.0, 1.0), 0.5, k)
        assert chi.shape == box.face_shape(k) and float(chi.min()) == 0 and float(chi.max()) == 1
        volume = float(jnp.sum(chi)) * box.h**3
        assert abs(volume / (4 / 3 * math.pi * 0.5**3) - 1) < 0.02, (k, volume)


def test_the_body_stops_the_fluid_inside_and_its_force_is_the_momentum_it_removes():
    # a stream U = 0.1 through a periodic 12^3 box (no fringe) holding a ball of radius 2 cells: the projection
    # and the viscosity conserve the total momentum, so the body's force must account for all that is lost
    box = mac3d.Box((12, 12, 12), 0.25, (True,) * 3)
    dt, speed = 0.05, 0.1
    chi = tuple(body3d.ball_fraction(box, (1.5, 1.5, 1.5), 0.5, k) for k in range(3))
    rest = tuple(jnp.zeros(box.face_shape(k)) for k in range(3))
    relax = body3d.Relax(chi, 0.25 * dt, rest, (0.0, 0.0, 0.0))
    s0 = body3d.stream_state(box, speed)
    s1, force = jax.jit(body3d.run, static_argnums=(0, 5))(box, s0, mac3d.Params3(nu=0.1), relax, dt, 20)
    assert force.shape == (20, 2, 3) and float(jnp.abs(force[:, 1]).max()) == 0  # no fringe
    momentum = [float(jnp.sum(s.vel[0][:-1])) * box.h**3 for s in (s0, s1)]  # the last face copies the first
    lost = momentum[0] - momentum[1]
    assert lost > 0.1 * momentum[0]  # the body took a tenth of the stream's momentum
    assert abs(float(jnp.sum(force[:, 0, 0])) * dt / lost - 1) < 1e-3, (lost, float(jnp.sum(force[:, 0, 0])) * dt)
    inside = jnp.where(chi[0] >= 1, jnp.abs(s1.vel[0]), 0)
    assert float(inside.max()) < 0.05 * speed


def test_the_fringe_relaxes_the_stream_to_its_target():
    box = mac3d.Box((16, 4, 4), 0.25, (True,) * 3)
    lam = tuple(body3d.fringe_rate(box, 2.0, 4.0, 0.5, 10.0, k) for k in range(3))
    assert float(lam[0].max()) == pytest.approx(10.0) and float(lam[0][:8].max()) == 0  # x < 2: no fringe
    zero = tuple(jnp.zeros(box.face_shape(k)) for k in range(3))
    vel = body3d.relax(zero, body3d.Relax(zero, 1.0, lam, (1.0, 0.0, 0.0)), 0.1)
    # implicit: a / (1 + a) of the way to the target, a = dt rate = 1 where the rate is full
    assert float(vel[0].max()) == pytest.approx(0.5) and float(vel[0][:8].max()) == 0


@pytest.mark.slow
def test_a_periodic_array_of_penalised_spheres_converges_to_hasimotos_stokes_drag():
    # Stokes flow through a simple cubic array (period 3 D): Hasimoto 1959's drag, an exact figure that tests the
    # body alone (no advection, no fringe); the penalised ball converges at first order (-13.6% / -8.3% at 4 / 6
    # cells per diameter, docs/results/flows.md)
    from benchmarks.sphere_drag import stokes_array

    errors = []
    for n in (4, 6):
        ratio, want, steady = stokes_array(n)
        assert abs(steady - 1) < 0.02  # steady: the body takes what the push gives
        errors.append(ratio / want - 1)
    order = math.log(errors[0] / errors[1]) / math.log(6 / 4)
    assert abs(errors[1]) < 0.1 and order > 0.9, (errors, order)


def test_the_richardson_fit_recovers_a_power_law_through_unequal_grid_ratios():
    # Cd = 1.09 + 3 h^p on 10 / 12 / 14 cells (ratios 1.2 and 1.17): the order and the limit come back; a sequence
    # whose differences change sign has no fit
    from benchmarks.sphere_drag import richardson

    for p in (1.0, 2.0, 2.7):
        cells = (14, 10, 12)  # any order
        order, limit = richardson(cells, [1.09 + 3 * n**-p for n in cells])
        assert order == pytest.approx(p, abs=1e-6) and limit == pytest.approx(1.09, abs=1e-9)
    assert richardson((8, 10, 12), (1.29, 1.23, 1.25)) is None


def test_the_drag_record_keeps_one_row_per_setting(tmp_path):
    from benchmarks.sphere_drag import KEY, load_record, save_row

    path = str(tmp_path / "runs.json")
    assert load_record(path) == []
    row = dict.fromkeys(KEY, 1.0) | dict(cd_body=[1.3], cd_push=[1.2], done=False)
    save_row(path, row)
    save_row(path, row | dict(cd_body=[1.3, 1.25], done=True))  # the same settings: replaced
    save_row(path, row | dict(width=2.0))
    rows = load_record(path)
    assert len(rows) == 2 and rows[0]["cd_body"] == [1.3, 1.25] and rows[0]["done"] and rows[1]["width"] == 2.0
