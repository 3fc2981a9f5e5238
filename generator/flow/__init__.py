"""Incompressible 2D Navier-Stokes on a staggered MAC grid (JAX; float32, float64 under x64; jit/vmap-able).

Advection: step/run's ``advection=`` 'semi_lagrangian' (their default; first order overall) or 'maccormack' (limited
MacCormack with a half-step backtrace velocity and trapezoid forces: second order, Taylor-Green 2.15/2.19; the
catalog's flows use it, FlowProblem.advection),
explicit viscosity, a multigrid-preconditioned CG projection. Checked so far: closed wall and obstacle faces, a sample's bits alone and
in batches through run_batch (one per loop step, as the sampler does; vmap over samples rounds differently), the
finite flag, Couette flow to 2e-6 and the grid's discrete Poiseuille profile to 4e-6 (tests/test_flow_validation.py).
Divergence after every projection within the CG tolerance plus float32 rounding (the solve checks its true residual
before stopping and drops a warm-start guess worse than zero; tests/test_flow_validation.py). Pressure iterations
9/10/13 at 64x32/128x64/256x128 on a cylinder channel (float64 cold; float32 warm 7/7/10; weighted coarse
correction, benchmarks/flow_validation.py). Cavity Re 100, 400 and 1000 against Ghia 1982 and the Schaefer-Turek
2D-2 cylinder: benchmarks/flow_validation.py. Manufactured steady flow in a closed box (four no-slip walls,
stream function sin^2(pi x) sin^2(pi y), Params.force, nu 0.01, dt = 0.5 h / pi): maccormack's RMS velocity error
5.3e-2/6.8e-3/5.3e-4/8.4e-5 at 16/32/64/128 (orders 2.96/3.68/2.65; max 2.83/3.43/3.11; pressure 2.44/2.54/2.47),
semi-Lagrangian 0.73/0.61/0.47/0.33 (orders 0.28/0.37/0.49, rising: its O(h^2 / dt) interpolation error per
unit time at dt ~ h, still pre-asymptotic at Re ~ 300). Where the viscous limit sets dt ~ h^2 (nu 0.05) maccormack drops to ~1 (16 -> 32 RMS 0.75; a quarter of the dt at 32
raises the error 1.6x): the interpolation error per step over dt (tests/test_flow_validation.py, --parts mms).

API (geom is static, params traced: changing Reynolds number, inflow, lid or circle does not recompile)::

    from generator.flow import Geometry, Params, initial_state, step, run, stable_dt, vorticity, is_finite
    geom = Geometry(nx=128, ny=64, lx=2.0, ly=1.0, left="inflow", right="outflow")   # bottom/top walls
    params = Params(nu=1e-3, inflow=1.0, circle=(0.4, 0.5, 0.1))
    s = initial_state(geom, params)
    dt = 0.5 * stable_dt(geom, params, umax=1.5)
    s = jax.jit(run, static_argnums=(0, 4))(geom, s, params, dt, 100)
    w = vorticity(geom, s); p = s.p; ok = is_finite(s)
    sb = run_batch(geom, Params(nu=1e-3, inflow=jnp.array([0.5, 1.0])), dt, 100)  # bit-identical per sample

Modules: grid (Geometry, Params, obstacle masks, face coefficients), pressure (multigrid-preconditioned CG),
batch (run_batch: lax.map over fixed chunks, batch-invariant bits), step (advection, viscosity, buoyancy, projection, step/run, derived fields),
forces (body force on a staircase or on the exact bodies and C_d / C_l, signed distances, shedding detection:
karman2d's and channel2d's per-sample outputs). Geometry(body=) picks how Params.circle and Params.obstacles meet
the grid: 'sharp' (the default, grid.DEFAULT_BODY: cut faces and ghost velocities on the exact circles, boxes and
ellipses of grid's sharp-body protocol) or 'staircase' (masked cells).
"""

from .batch import run_batch
from .grid import Geometry, Params, box_solid, circle_solid, ellipse_solid
from .step import State, divergence, initial_state, is_finite, project, run, stable_dt, step, vorticity

__all__ = ["Geometry", "Params", "State", "box_solid", "circle_solid", "ellipse_solid", "divergence",
           "initial_state", "is_finite", "project", "run", "run_batch", "stable_dt", "step", "vorticity"]
