"""Flow solver numerics (generator/flow, a draft for issue 18): projection divergence, wall/obstacle faces,
bit-identity alone and in batches (per-sample programs under jax.lax.map, the house's way), blow-up flag. Slow:
the multigrid-preconditioned CG compiles for about a minute on 2 cores."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from generator.flow import Geometry, Params, divergence, initial_state, is_finite, project, run
from generator.flow.step import State


def _random_field(geom, key):
    k1, k2 = jax.random.split(key)
    return (jax.random.normal(k1, (geom.ny, geom.nx + 1)), jax.random.normal(k2, (geom.ny + 1, geom.nx)))


@pytest.mark.slow
def test_projection_divergence_free_and_closed_faces():
    geom = Geometry(32, 16, 2.0, 1.0, left="inflow", right="outflow")
    params = Params(nu=0.01, inflow=1.0, circle=(0.6, 0.5, 0.2))
    s = initial_state(geom, params)
    u, v = _random_field(geom, jax.random.PRNGKey(0))
    from generator.flow.step import apply_bc, solid_mask
    u, v = apply_bc(geom, params, u, v)
    u, v, p, it = project(geom, params, u, v, 0.1, tol=1e-6)
    fluid = 1 - solid_mask(geom, params)
    assert float(jnp.abs(divergence(geom, u, v) * fluid).max()) < 1e-3
    assert float(jnp.abs(v[0]).max()) == 0 and float(jnp.abs(v[-1]).max()) == 0
    assert int(jnp.sum(1 - fluid)) > 0
    from generator.flow.grid import velocity_masks
    mu, mv = velocity_masks(geom, solid_mask(geom, params))
    assert float(jnp.abs(u * (1 - mu)).max()) == 0 and float(jnp.abs(v * (1 - mv)).max()) == 0
    assert s.u.shape == (16, 33)


@pytest.mark.slow
def test_batch_bits_and_finite_flag():
    geom = Geometry(16, 16, 1.0, 1.0)
    def one(lid):
        return run(geom, initial_state(geom, Params(lid=lid)), Params(lid=lid), 0.01, 5)

    mapped = jax.jit(lambda lids: jax.lax.map(one, lids))  # one sample per loop step: its bits whatever the batch
    alone, five = mapped(jnp.array([1.0])), mapped(jnp.array([0.3, 0.5, 1.0, 2.0, 0.7]))
    np.testing.assert_array_equal(np.asarray(five.u[2]), np.asarray(alone.u[0]))
    alone = jax.tree_util.tree_map(lambda x: x[0], alone)
    assert bool(is_finite(alone))
    bad = State(alone.u.at[0, 0].set(jnp.nan), alone.v, alone.p, alone.smoke, alone.t, alone.iterations)
    assert not bool(is_finite(bad))
