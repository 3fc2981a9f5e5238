"""Flow solver numerics (generator/flow, a draft for issue 18): projection divergence, wall/obstacle faces,
bit-identity alone and in batches (run_batch: per-sample programs under jax.lax.map, the house's way), blow-up
flag. Slow: the multigrid-preconditioned CG compiles for about a minute on 2 cores."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pdestream.generator.flow import Geometry, Params, divergence, initial_state, is_finite, project
from pdestream.generator.flow.batch import run_batch


def _random_field(geom, key):
    k1, k2 = jax.random.split(key)
    return (jax.random.normal(k1, (geom.ny, geom.nx + 1)), jax.random.normal(k2, (geom.ny + 1, geom.nx)))


pytestmark = pytest.mark.slow


@pytest.mark.parametrize("body", ["staircase", "sharp"])
def test_projection_divergence_free_and_closed_faces(body):
    geom = Geometry(32, 16, 2.0, 1.0, left="inflow", right="outflow", body=body)
    params = Params(nu=0.01, inflow=1.0, circle=(0.6, 0.5, 0.2))
    s = initial_state(geom, params)
    u, v = _random_field(geom, jax.random.PRNGKey(0))
    from pdestream.generator.flow.grid import circle_apertures, velocity_masks
    from pdestream.generator.flow.step import apply_bc, body_faces, solid_mask
    u, v = apply_bc(geom, params, u, v)
    u, v, p, it = project(geom, params, u, v, 0.1, tol=1e-6)
    fluid = 1 - body_faces(geom, params).solid
    assert float(jnp.abs(divergence(geom, u, v, params) * fluid).max()) < 1e-3  # sharp: through open fractions
    assert float(jnp.abs(v[0]).max()) == 0 and float(jnp.abs(v[-1]).max()) == 0
    assert int(jnp.sum(1 - fluid)) > 0
    if body == "staircase":  # every face touching a solid cell is closed
        mu, mv = velocity_masks(geom, solid_mask(geom, params))
    else:  # a face the circle covers whole carries no flux (a ghost value, or 0 deeper inside)
        mu, mv = (a > 0 for a in circle_apertures(geom, *params.circle))
    assert float(jnp.abs(divergence(geom, u * mu, v * mv, params) * fluid).max()) < 1e-3
    if body == "staircase":
        assert float(jnp.abs(u * (1 - mu)).max()) == 0 and float(jnp.abs(v * (1 - mv)).max()) == 0
    assert s.u.shape == (16, 33)


def test_batch_bits_and_finite_flag():
    geom = Geometry(16, 16, 1.0, 1.0)
    lids = jnp.array([0.5, 1.0, 2.0, 1.5, 0.7])
    alone = run_batch(geom, Params(lid=lids[1:2]), 0.01, 5)
    for b in (3, 5):
        batch = run_batch(geom, Params(lid=lids[:b]), 0.01, 5)
        for field in ("u", "v", "p"):
            np.testing.assert_array_equal(np.asarray(getattr(batch, field)[1]), np.asarray(getattr(alone, field)[0]))
    one = jax.tree_util.tree_map(lambda a: a[0], alone)
    assert float(jnp.abs(one.u).max()) > 0.1  # the lid really drove the flow
    assert bool(is_finite(one))
    bad = one._replace(u=one.u.at[0, 0].set(jnp.nan))
    assert not bool(is_finite(bad))


def test_vcycle_preconditioner_symmetric_positive_definite():
    # CG needs an SPD preconditioner: the V-cycle's matrix over fluid cells of a cylinder channel (the coarse
    # correction weighted by COARSE_WEIGHT, 3 Jacobi sweeps before and after) is symmetric to float32 rounding
    # and its smallest eigenvalue positive; a V-cycle with pre-smoothing only is measurably asymmetric.
    from pdestream.generator.flow import pressure
    from pdestream.generator.flow.step import operator
    geom = Geometry(32, 16, 2.0, 1.0, left="inflow", right="outflow")
    op = operator(geom, Params(circle=(0.5, 0.52, 0.15)))
    fluid = np.flatnonzero(1 - np.asarray(op.levels[0].solid).reshape(-1))
    eye = jnp.eye(geom.nx * geom.ny).reshape(-1, geom.ny, geom.nx)

    def matrix(cycle):
        b = np.asarray(jax.jit(jax.vmap(cycle))(eye), np.float64).reshape(eye.shape[0], -1)
        return b[np.ix_(fluid, fluid)]

    b = matrix(lambda e: pressure.vcycle(op, e, False, False))
    assert np.abs(b - b.T).max() < 1e-5 * np.abs(b).max()
    assert np.linalg.eigvalsh(0.5 * (b + b.T))[0] > 1e-3 * np.abs(b).max()
    lopsided = matrix(lambda e: pressure.vcycle(op, e, False, False, sweeps=1) + pressure._jacobi(
        op.levels[0], e, e, 0.5 / pressure.diagonal(op.levels[0], False, False), False, False, 1))
    assert np.abs(lopsided - lopsided.T).max() > 1e-3 * np.abs(lopsided).max()


def test_batch_bits_with_maccormack():
    geom = Geometry(16, 16, 1.0, 1.0)
    lids = jnp.array([0.5, 1.0, 2.0])
    alone = run_batch(geom, Params(lid=lids[1:2]), 0.01, 4, advection="maccormack")
    batch = run_batch(geom, Params(lid=lids), 0.01, 4, advection="maccormack")
    for field in ("u", "v", "p"):
        np.testing.assert_array_equal(np.asarray(getattr(batch, field)[1]), np.asarray(getattr(alone, field)[0]))
    semi = run_batch(geom, Params(lid=lids[1:2]), 0.01, 4)
    assert float(jnp.abs(semi.u - alone.u).max()) > 1e-6  # the keyword reaches the step


def test_no_xla_eigen_decomposition_in_a_rollout_and_the_host_pseudo_inverse_is_one():
    """The coarsest level's pseudo-inverse is computed on the host: XLA's CPU eigh kernel blocks on XLA's own
    thread pool, and two programs decomposing at once (the stream sampling flows while solver-in-the-loop's step
    runs) hung both pool threads for good. No eigh primitive may come back into the rollout."""
    from pdestream.generator.flow import pressure
    from pdestream.generator.flow.step import operator, run

    geom = Geometry(32, 16, 2.0, 1.0, left="inflow", right="outflow")
    params = Params(nu=1e-2, inflow=1.0, circle=(0.5, 0.5, 0.15))
    state = initial_state(geom, params)
    text = str(jax.make_jaxpr(lambda s: run(geom, s, params, 0.01, 2))(state))
    assert "eigh" not in text and "pure_callback" in text
    op = operator(geom, params)
    coarse = op.levels[-1]
    m = coarse.solid.size
    eye = jnp.eye(m).reshape(m, *coarse.solid.shape)
    a = np.asarray(jax.vmap(lambda e: pressure.apply(coarse, e, False, False).reshape(m))(eye), np.float64)
    x = np.asarray(op.coarse_inverse, np.float64)
    assert np.allclose(a @ x @ a, a, atol=1e-4 * np.abs(a).max())  # a pseudo-inverse: A X A = A
    assert np.allclose(x, x.T, atol=1e-6 * np.abs(x).max())



def _closed_box_laplacian(ny=8, nx=16, seed=0):
    """float64 [ny nx, ny nx]: a closed box's graph Laplacian, random face weights in [0.5, 1.5], with a 2x2 block
    cut off (its outer faces closed) and the corner cell cut off with a solid term (diagonal +1): the null space
    is spanned by the constants of the box's rest and of the block; the corner is not singular."""
    rng = np.random.default_rng(seed)
    idx = np.arange(ny * nx).reshape(ny, nx)
    part = np.zeros((ny, nx), int)
    part[2:4, 5:7], part[-1, -1] = 1, 2
    faces = [((i, j), (i, j + 1)) for i, j in np.ndindex(ny, nx - 1)]
    faces += [((i, j), (i + 1, j)) for i, j in np.ndindex(ny - 1, nx)]
    a = np.zeros((ny * nx, ny * nx))
    for f, g in faces:
        if part[f] == part[g]:
            w, p, q = rng.uniform(0.5, 1.5), idx[f], idx[g]
            a[[p, q], [p, q]] += w
            a[[p, q], [q, p]] -= w
    a[idx[-1, -1], idx[-1, -1]] += 1.0
    return a


def test_the_host_pseudo_inverse_is_exact_and_the_same_on_every_blas_kernel():
    """The coarse pseudo-inverse uses elementwise numpy only: LAPACK's eigh differs in the last bits between the
    CPU kernels OpenBLAS picks (1e-14 relative on the flows' coarse operators), which changed float64 flows."""
    import subprocess
    import sys

    from pdestream.generator.flow import pressure

    a = _closed_box_laplacian()
    x = pressure._pseudo_inverse(a)
    assert x.dtype == np.float64
    np.testing.assert_allclose(x, np.linalg.pinv(a, rcond=1e-10, hermitian=True), rtol=0, atol=1e-10 * np.abs(x).max())
    code = ("import sys, numpy as np; from pdestream.generator.flow import pressure; from tests.test_flow_numerics import "
            "_closed_box_laplacian as f; sys.stdout.write(pressure._pseudo_inverse(f()).tobytes().hex())")
    for core in ("Prescott", "Haswell"):  # OpenBLAS kernels any x86-64 CPU can run
        env = {**os.environ, "OPENBLAS_CORETYPE": core}
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert bytes.fromhex(out.stdout) == x.tobytes(), core


def _outputs_at_vector_widths(code: str) -> set:
    """The distinct stdouts of ``python -c code`` run with XLA's CPU vector width at 128 and at 512 bits."""
    import subprocess
    import sys

    outs = set()
    for width in (128, 512):
        env = {**os.environ, "XLA_FLAGS": f"--xla_cpu_prefer_vector_width={width}"}
        outs.add(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                check=True).stdout)
    return outs


def test_the_pressure_solve_has_the_same_bits_at_every_vector_width():
    """CG's sums are added in a fixed order (pressure._tree_sum): with jnp.sum the solve's bits followed the vector
    width XLA prefers on the host CPU (three widths, three results at 64x32), so the flows' bits differed between
    CPUs of one instruction set."""
    code = ("import hashlib, jax, numpy as np; from pdestream.generator.flow import Geometry, Params, pressure;"
            "from pdestream.generator.flow.step import faces, solid_mask;"
            "g = Geometry(64, 32, 2.0, 1.0, left='inflow', right='outflow');"
            "fc = faces(g, solid_mask(g, Params(nu=1e-2, inflow=1.0, circle=(0.5, 0.5, 0.15))));"
            "b = jax.random.normal(jax.random.PRNGKey(0), (32, 64)) * (1 - fc.solid);"
            "p = jax.jit(lambda b: pressure.solve(fc, b, False, False, g.singular).p)(b);"
            "print(hashlib.sha256(np.asarray(p).tobytes()).hexdigest())")
    assert len(_outputs_at_vector_widths(code)) == 1


def test_the_sharp_circle_geometry_has_the_same_bits_at_every_vector_width():
    """The cut faces' centroids, their weights along the face and the inflow profile hold no product that feeds a
    sum: XLA's CPU backend lets LLVM contract one into a fused multiply-add, and whether it did followed the vector
    width (karman2d's centroid weights had different last bits at --xla_cpu_prefer_vector_width 128 and 512, in a
    single sample's program and in a vectorised batch, at n=32 and n=48)."""
    code = ("import hashlib, jax, jax.numpy as jnp, numpy as np; from pdestream.generator.flow import Geometry, Params;"
            "import importlib; from pdestream.generator.flow import grid; step = importlib.import_module("
            "'pdestream.generator.flow.step');"
            "k = jax.random.PRNGKey(1); out = [];\n"
            "for n in (32, 48):\n"
            " g = Geometry(2 * n, n, 2.0, 1.0, left='inflow', right='outflow', body='sharp')\n"
            " cx, cy, r, plug = (jax.random.uniform(jax.random.fold_in(k, i), (16,), minval=a, maxval=b)"
            " for i, (a, b) in enumerate(((0.4, 0.6), (0.42, 0.46), (0.08, 0.2), (0.0, 0.3))))\n"
            " f = lambda cx, cy, r, plug: (grid.circle_cut_faces(g, cx, cy, r), step.inflow_profile(g, Params("
            "nu=1e-2, inflow=1.0, plug=plug)), [w[:3] for w in step._centroid_weights(g, Params(nu=1e-2, inflow=1.0,"
            " circle=(cx, cy, r)), jnp.float32)])\n"
            " out += jax.tree_util.tree_leaves((jax.jit(jax.vmap(f))(cx, cy, r, plug), jax.jit(f)(cx[0], cy[0], r[0],"
            " plug[0])))\n"
            "print(hashlib.sha256(b''.join(np.asarray(a).tobytes() for a in out)).hexdigest())")
    assert len(_outputs_at_vector_widths(code)) == 1
