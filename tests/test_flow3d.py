"""The 3D MAC solver (generator.flow.mac3d) against exact Navier-Stokes solutions, and the plume3d entry.

Exact solutions: the Arnold-Beltrami-Childress flow on the periodic [0, 2 pi]^3 (curl u = u, so (u.grad)u =
grad |u|^2 / 2 is balanced by the pressure and u decays as exp(-nu t): the nonlinear term, the pressure and the
viscosity all act), and shear modes between two no-slip walls (u = sin(pi y) e^{-nu pi^2 t}, w = sin(2 pi y)
e^{-4 nu pi^2 t}: the wall ghosts' order). Grid studies are marked slow; the quick tests run one small grid each.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pdestream import generator
from pdestream.generator.flow import mac3d
from tests.reference_samples import SMALL


def _abc(box, t, nu, dtype):
    """The ABC flow (A = B = C = 1, k = 1) on each component's faces at time t."""
    out = []
    for k in range(3):
        x, y, z = mac3d.points(box, box.face_shape(k), box.offsets(k), dtype)
        f = (jnp.sin(z) + jnp.cos(y), jnp.sin(x) + jnp.cos(z), jnp.sin(y) + jnp.cos(x))[k]
        out.append(f * math.exp(-nu * t))
    return tuple(out)


def _shear(box, t, nu, dtype):
    """Two decaying shear modes between no-slip walls at y = 0 and 1 (x and z periodic)."""
    out = []
    for k in range(3):
        _, y, _ = mac3d.points(box, box.face_shape(k), box.offsets(k), dtype)
        f = (jnp.sin(math.pi * y) * math.exp(-nu * math.pi**2 * t), 0 * y,
             jnp.sin(2 * math.pi * y) * math.exp(-4 * nu * math.pi**2 * t))[k]
        out.append(f)
    return tuple(out)


def _error(case: str, n: int):
    """(RMS velocity error at t = 1, max |divergence|) of the solver against an exact solution on n cells (float64)."""
    with jax.enable_x64(True):
        if case == "abc":
            nu, exact = 0.1, _abc
            box = mac3d.Box((n,) * 3, 2 * math.pi / n, (True,) * 3)
            dt = 0.5 * box.h / 2  # CFL 0.5 at |u| <= 2
        else:
            nu, exact = 0.05, _shear
            box = mac3d.Box((4, n, 4), 1.0 / n, (True, False, True))
            dt = min(0.5 * box.h, 0.9 * box.h**2 / (6 * nu))
        steps = math.ceil(1.0 / dt)
        s = mac3d.initial_state(box, jnp.float64)
        s = s._replace(vel=mac3d.apply_bc(box, exact(box, 0.0, nu, jnp.float64)))
        s = jax.jit(mac3d.run, static_argnums=(0, 4))(box, s, mac3d.Params3(nu=nu), 1.0 / steps, steps)
        want = exact(box, 1.0, nu, jnp.float64)
        rms = math.sqrt(sum(float(jnp.mean((a - b) ** 2)) for a, b in zip(s.vel, want)) / 3)
        return rms, float(jnp.max(jnp.abs(mac3d.divergence(box, s.vel))))


def test_the_abc_flow_decays_as_the_exact_solution_and_stays_divergence_free():
    rms, div = _error("abc", 8)
    assert rms < 0.02 and div < 1e-12  # 8^3: 1.7e-2 of a speed ~1.4 (second order: tests below, slow)


@pytest.mark.slow
@pytest.mark.parametrize("case, grids", [("abc", (16, 32, 64)), ("shear", (8, 16, 32))])
def test_second_order_in_space_over_three_grids(case, grids):
    errors = [_error(case, n) for n in grids]
    orders = [math.log2(a[0] / b[0]) for a, b in zip(errors, errors[1:])]
    assert min(orders) > 1.8 and max(d for _, d in errors) < 1e-11, (errors, orders)


def test_the_closed_box_projection_is_exact_and_idempotent():
    box = mac3d.Box((6, 4, 8), 0.25, (False, False, False))
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    with jax.enable_x64(True):
        vel = mac3d.apply_bc(box, tuple(jax.random.normal(k, box.face_shape(i), jnp.float64)
                                        for i, k in enumerate(keys)))
        out, p = jax.jit(mac3d.project, static_argnums=0)(box, vel, 0.1)
        assert float(jnp.max(jnp.abs(mac3d.divergence(box, vel)))) > 1  # there was something to remove
        assert float(jnp.max(jnp.abs(mac3d.divergence(box, out)))) < 1e-12
        again, _ = jax.jit(mac3d.project, static_argnums=0)(box, out, 0.1)
        assert max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(again, out)) < 1e-12
        assert all(float(jnp.abs(v.take(jnp.array([0, -1]), axis=k)).max()) == 0 for k, v in enumerate(out))  # walls


def test_plume3d_rises_keeps_its_scalar_in_bounds_and_samples_alone_equal_batches():
    pde = generator.get_pde("plume3d", **SMALL["plume3d"])
    batch = generator.sample(pde, [0, 1, 2], seed=3)
    u = np.asarray(batch.u)
    assert u.shape == (3, 3, 5, 12, 12, 12) and np.isfinite(u).all()
    smoke = u[:, :, pde.FIELDS.index("smoke")]
    assert smoke.min() >= 0 and smoke.max() <= 1 and smoke[:, -1].max() > 0.5
    z = pde.grid.coords(2)
    height = (smoke[:, -1] * z).sum((1, 2, 3)) / smoke[:, -1].sum((1, 2, 3))
    top = np.array([z[np.nonzero((s > 0.05).any((0, 1)))[0].max()] for s in smoke[:, -1]])
    # the scalar's centre of mass above the heater's centre, its top above the heater's (t = 1: the jet is starting)
    assert np.all(height > pde.source_z + 0.02) and np.all(top > pde.source_z + pde.radius), (height, top)
    w = u[:, -1, pde.FIELDS.index("w")]
    assert np.all(w.max((1, 2, 3)) > 0.1) and np.all(w.max((1, 2, 3)) > -w.min((1, 2, 3)))  # upward jet
    alone = generator.sample(pde, [2], seed=3)
    np.testing.assert_array_equal(np.asarray(alone.u[0]), u[2])
