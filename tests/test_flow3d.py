"""The 3D MAC solver (generator.flow.mac3d) against exact Navier-Stokes solutions, and the plume3d entry.

Exact solutions: the Arnold-Beltrami-Childress flow on the periodic [0, 2 pi]^3 (curl u = u, so (u.grad)u =
grad |u|^2 / 2 is balanced by the pressure and u decays as exp(-nu t): the nonlinear term, the pressure and the
viscosity all act), and shear modes between two no-slip walls (u = sin(pi y) e^{-nu pi^2 t}, w = sin(2 pi y)
e^{-4 nu pi^2 t}: the wall ghosts' order), in benchmarks/flow3d_validation.py. Grid studies are marked slow; the
quick tests run one small grid each.
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.flow3d_validation import error as _error
from pdestream import cli, generator
from pdestream.generator.flow import mac3d
from tests.reference_samples import SMALL
from tests.test_flows import stream_equals_cache

pytestmark = pytest.mark.xdist_group("plume3d")  # one worker: the small plume's programs compile once


def test_the_abc_flow_decays_as_the_exact_solution_and_stays_divergence_free():
    # (the closed box's projection: test_plume3d_rises...)
    rms, div = _error("abc", 8)
    assert rms < 0.02 and div < 1e-12  # 8^3: 1.7e-2 of a speed ~1.4 (second order: tests below, slow)


@pytest.mark.slow
# (abc: 16 -> 32 only, 1.86; the 64^3 grid alone took 168 s: benchmarks/flow3d_validation.py has the three grids)
@pytest.mark.parametrize("case, grids", [("abc", (16, 32)), ("shear", (8, 16, 32))])
def test_second_order_in_space(case, grids):
    errors = [_error(case, n) for n in grids]
    orders = [math.log2(a[0] / b[0]) for a, b in zip(errors, errors[1:])]
    assert min(orders) > 1.8 and max(d for _, d in errors) < 1e-11, (errors, orders)


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
    # the closed box's projection (DCT on all three axes) leaves float32 rounding: |div| h < 1e-5 of the speed
    vel = pde.state_of(jnp.asarray(u[0, -1]), None).vel
    assert float(jnp.abs(mac3d.divergence(pde.geometry(), vel)).max()) * pde.h < 1e-5 * np.abs(u[0, -1, :3]).max()
    alone = generator.sample(pde, [2], seed=3)
    np.testing.assert_array_equal(np.asarray(alone.u[0]), u[2])


def test_plume3d_stream_equals_its_cache_which_records_the_closed_box(tmp_path):
    plain, _ = stream_equals_cache(generator.get_pde("plume3d", **SMALL["plume3d"]), tmp_path / "p.zarr", 3)
    assert dict(plain.sizes) == {"sample": 3, "time": 3, "z": 12, "y": 12, "x": 12}
    assert plain.attrs["bc"] == "dirichlet dirichlet dirichlet" and plain.attrs["bc_type"] == "wall wall wall"
    assert set(plain.data_vars) >= {"u", "v", "w", "p", "smoke"}


@pytest.mark.slow
def test_compare_trains_on_plume3d(capsys, tmp_path):
    # the small plume (n=12) through compare's cache and stream arms: the 3D FNO trains on a 3D flow (batches of
    # 2: the stream's 2 steps then draw 4 samples beyond its calibration draw, not 64)
    sets = [a for k, v in SMALL["plume3d"].items() for a in ("--set", f"{k}={v}")]
    code = cli.main(["compare", "plume3d", "--steps", "2", "--seeds", "1", "--test-samples", "4",
                     "--cache-samples", "4", "--batch-size", "2", *sets,
                     "--shift-set", "sx=uniform(0.34, 0.35)", "--shift-set", "sy=uniform(0.34, 0.35)",
                     "--out", str(tmp_path / "c")])
    out = capsys.readouterr().out
    assert code == 0 and "| cache |" in out and "| stream |" in out


@pytest.mark.slow
def test_plume3d_frames_continue_through_the_oracle_and_its_vjp():
    # a frame is the solver's whole state: advancing frame 0 one frame gives frame 1 (another compiled program:
    # to rounding), and the differentiable step's VJP reaches the frame and every parameter
    from pdestream.generator.spectral import interactive

    pde = generator.get_pde("plume3d", **SMALL["plume3d"])
    traj = generator.sample(pde, [0, 1], seed=5)
    u = np.asarray(traj.u)
    got, finite = interactive.advance(pde, u[:, 0], traj.params, 1)
    scale = np.abs(u[:, 1]).max()
    assert finite.all() and np.abs(np.asarray(got) - u[:, 1]).max() < 1e-4 * scale
    out, _, vjp = interactive.advance_vjp(pde, u[:, 0], traj.params, 1)
    g_u, g_p = vjp(np.ones_like(np.asarray(out)))
    assert np.isfinite(np.asarray(g_u)).all() and np.abs(np.asarray(g_u)).max() > 0
    assert all(np.isfinite(np.asarray(v)).all() for v in g_p.values()) and np.abs(np.asarray(g_p["buoyancy"])).max() > 0
