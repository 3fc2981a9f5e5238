"""Vortex-street anchors (issue 18, speed): PhiFlow's and jax-cfd's trajectories/s on one stated case, in one
process, against which pdestream's flow solver (``generator.flow``) is to be timed.

    nice python -m benchmarks.flow_anchors [--grids 128x64,64x32] [--steps 1600] [--batch 4] [--reps 3]
        [--arms phiflow,jaxcfd,pdestream] [--scheme mac_cormack|semi_lagrangian] [--re 100]

The case (``VortexCase``) is the shared truth: a channel [0, lx] x [0, ly], uniform inflow ``u_in`` through the
left side, open outflow on the right (zero-gradient velocity, p = 0), no-penetration walls top and bottom, a
cylinder of ``radius`` at ``centre`` (a little off the centre line so shedding starts without noise),
kinematic viscosity nu = u_in * 2 radius / re, ``steps`` steps of ``dt``, ``frames`` frames saved.

Arms (each: compile/warm-up run first, then the median of ``reps`` timed trajectories; trajectories/s, steps/s):
- ``phiflow_trajectory``: PhiFlow 3 on its JAX backend (``phi.jax.flow``), staggered grid, semi-Lagrangian
  advection (first order), explicit diffusion, inflow imposed on a boundary strip as in PhiFlow's Karman demo,
  ``pf.fluid.make_incompressible`` with the cylinder as an ``Obstacle`` and CG to ``tol`` (abs and rel), warm-started
  from the last pressure. Batches through a PhiFlow batch dimension.
- ``jaxcfd_trajectory``: jax-cfd 0.2 cannot express this case: its advection (``convect_linear``, van Leer,
  semi-Lagrangian) raises NotImplementedError for any non-periodic velocity, and it has no obstacles. Its closest
  case is timed and labelled so: the same grid, lengths, nu, dt and steps in a doubly periodic box (van Leer
  advection, CG pressure to ``tol``), started from a perturbed shear flow, with its own stable step (forward
  Euler: k substeps of dt, Courant 0.5; steps/s counts case steps). Batches with ``jax.vmap``.
- ``pdestream_trajectory``: the hook for ``generator.flow`` (see its docstring).

Physics sanity printed per arm: max |div u| on fluid cells after the last projection (times dx / u_in, so
1e-5 means the projection met a 1e-5 tolerance), and for the vortex street the probe v(t) at two diameters
behind the cylinder: its rms and the Strouhal number St = f D / u_in from zero crossings over the second half.
Figures, not pass/fail.

Found on PhiFlow 3.4.0 / phiml 1.16.1 (JAX backend, CPU): this recipe (and PhiFlow's own Karman demo run as written)
does not shed. ``make_incompressible`` with an ``Obstacle`` stops the normal flow only, and the field settles in
a few hundred steps into a steady, nearly potential flow (one step then changes it by 1e-7; probe v = 0 to 3
decimals, Re 100 and 300, 64x32 and 128x64, MacCormack or semi-Lagrangian, with or without the initial kick and
the face mask). The timings are still PhiFlow's cost per step of this case; a vortex street from PhiFlow would
need a no-slip treatment it does not apply here. jax-cfd's periodic stand-in needs 3 (128x64) or 2 (64x32)
substeps of dt = 0.01 to stay stable.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np


@dataclasses.dataclass(frozen=True)
class VortexCase:
    """Channel flow past a cylinder. Lengths in m, speeds in m/s, time in s; grid is (nx, ny) cells."""

    nx: int = 128
    ny: int = 64
    lx: float = 2.0
    ly: float = 1.0
    re: float = 100.0  # u_in * (2 radius) / nu
    u_in: float = 1.0
    radius: float = 0.1
    centre: tuple[float, float] = (0.5, 0.52)
    dt: float = 0.01
    steps: int = 1600
    frames: int = 100  # saved states, evenly spaced; steps % frames == 0
    tol: float = 1e-5  # pressure solve, absolute and relative
    kick: float = 0.1  # peak of the initial transverse jet (1 + its Gaussian, width 2 radius, 3 radius behind), / u_in
    scheme: str = "mac_cormack"  # PhiFlow's velocity advection: "mac_cormack" (2nd order) or "semi_lagrangian" (1st)

    @property
    def nu(self) -> float:
        return self.u_in * 2 * self.radius / self.re

    @property
    def probe(self) -> tuple[float, float]:
        """Where the transverse velocity is recorded: two diameters behind the cylinder, on its centre line."""
        return (self.centre[0] + 4 * self.radius, self.centre[1])


def strouhal(signal: np.ndarray, dt_frame: float, case: VortexCase) -> float:
    """St = f D / u_in from the zero crossings of the second half of a [frames] signal (nan if < 3 crossings)."""
    s = signal[len(signal) // 2:]
    s = s - s.mean()
    if np.sqrt(np.mean(s**2)) < 1e-3 * case.u_in:  # no oscillation: crossings of rounding noise mean nothing
        return float("nan")
    crossings = np.nonzero(np.diff(np.sign(s)) != 0)[0]
    if len(crossings) < 3:
        return float("nan")
    period = 2 * (crossings[-1] - crossings[0]) * dt_frame / (len(crossings) - 1)
    return 2 * case.radius / (period * case.u_in)


def phiflow_trajectory(case: VortexCase, batch: int = 0):
    """Build PhiFlow's run: returns run() -> (probe v [frames] (first member), max |div| * dx / u_in)."""
    from phi.jax import flow as pf  # PhiFlow on its JAX backend

    INF, Box, StaggeredGrid, extrapolation = pf.INF, pf.Box, pf.StaggeredGrid, pf.extrapolation

    bounds = Box(x=case.lx, y=case.ly)
    ext = extrapolation.combine_sides(x=pf.ZERO_GRADIENT, y=0)  # open x (p = 0 at both ends), walls in y
    shape = dict(x=case.nx, y=case.ny)
    (xc, yc), r = case.centre, case.radius

    def start(pos):  # uniform flow plus a small transverse jet behind the cylinder, so shedding starts early
        x, y = pos.vector["x"], pos.vector["y"]
        kick = case.kick * case.u_in * pf.math.exp(-((x - xc - 3 * r) ** 2 + (y - yc) ** 2) / (2 * r) ** 2)
        return pf.vec(x=case.u_in + 0 * kick, y=kick)

    v0 = StaggeredGrid(start, ext, bounds=bounds, **shape)
    if batch:
        v0 = v0 * pf.math.ones(pf.batch(b=batch))
    cyl = pf.Obstacle(pf.Sphere(x=case.centre[0], y=case.centre[1], radius=case.radius))
    dx = case.lx / case.nx
    inflow = StaggeredGrid(Box(x=(-INF, dx), y=None), ext, bounds=bounds, **shape)  # first column of faces
    solid = StaggeredGrid(cyl.geometry, ext, bounds=bounds, **shape)  # fraction of each face's cell inside
    fluid_mask = 1 - pf.field.resample(cyl.geometry, v0.at_centers()).values  # cell centres outside the cylinder
    px, py = int(case.probe[0] / dx), int(case.probe[1] / (case.ly / case.ny))
    every = case.steps // case.frames

    @pf.jit_compile
    def step(v, p):
        v = getattr(pf.advect, case.scheme)(v, v, case.dt)
        v = pf.diffuse.explicit(v, case.nu, case.dt)
        v = v * (1 - inflow) + inflow * (case.u_in, 0)
        v = v * (1 - solid)  # no-slip on the cylinder: make_incompressible alone only stops the normal flow
        return pf.fluid.make_incompressible(v, [cyl], pf.Solve("CG", case.tol, case.tol, x0=p))

    def run():
        v, p, probe = v0, None, []
        for i in range(case.steps):
            v, p = step(v, p)
            if (i + 1) % every == 0:
                vy = v.at_centers().values.vector["y"]
                probe.append(vy.numpy(("b", "y", "x") if batch else ("y", "x"))[..., py, px].ravel()[0])
        div = pf.field.divergence(v).values * fluid_mask
        div = div.numpy(("b", "x", "y") if batch else ("x", "y"))[..., 2:-2, 2:-2]  # off the inflow/outflow
        return np.asarray(probe), float(np.abs(div).max()) * dx / case.u_in

    return run, step, v0


def jaxcfd_trajectory(case: VortexCase, batch: int = 0):
    """jax-cfd's closest case (periodic box, no cylinder): returns run() -> (None, max |div| * dx / u_in)."""
    import functools

    import jax
    import jax.numpy as jnp
    import jax_cfd.base as cfd

    grid = cfd.grids.Grid((case.nx, case.ny), domain=((0, case.lx), (0, case.ly)))
    bc = cfd.boundaries.periodic_boundary_conditions(2)
    ky = 2 * jnp.pi / case.ly

    def ux(x, y):
        return case.u_in * jnp.sin(ky * y)

    def uy(x, y):
        return 0.1 * case.u_in * jnp.sin(2 * jnp.pi * x / case.lx)

    v0 = cfd.initial_conditions.initial_velocity_field((ux, uy), grid, (bc, bc))
    solve = functools.partial(cfd.pressure.solve_cg, atol=case.tol, rtol=case.tol)
    # Its explicit (forward Euler, van Leer) step blows up at dt = 0.01 on 128x64 (inf by t = 3): take its own
    # stable step (Courant 0.5 at speed 2 u_in) as k substeps of case.dt, so the time window is the same.
    k = int(np.ceil(case.dt / cfd.equations.stable_time_step(2 * case.u_in, 0.5, case.nu, grid)))
    step = cfd.equations.semi_implicit_navier_stokes(
        density=1.0, viscosity=case.nu, dt=case.dt / k, grid=grid, pressure_solve=solve)
    traj = cfd.funcutils.trajectory(cfd.funcutils.repeated(step, k * (case.steps // case.frames)), case.frames)
    if batch:
        v0 = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch, *jnp.shape(a))), v0)
        traj = jax.vmap(traj)
    traj = jax.jit(traj)
    dx = case.lx / case.nx

    def run():
        last, _ = jax.block_until_ready(traj(v0))
        if batch:
            last = jax.tree_util.tree_map(lambda a: a[0], last)  # member 0
        u, v = (c.data for c in last)  # faces (i+1/2, j) and (i, j+1/2), periodic: div at centres by rolls
        div = (u - jnp.roll(u, 1, axis=0)) / dx + (v - jnp.roll(v, 1, axis=1)) / (case.ly / case.ny)
        err = float(jnp.abs(div).max()) * dx / case.u_in
        if not np.isfinite(err):
            raise FloatingPointError(f"jax-cfd blew up at dt = {case.dt / k:g}")
        return None, err

    run.substeps = k

    return run


ADVECTION = {"mac_cormack": "maccormack", "semi_lagrangian": "semi_lagrangian"}  # --scheme, in pdestream's words
VMAP = False  # --vmap: members vectorised (a GPU's way; bits then depend on the batch size)


def pdestream_trajectory(case: VortexCase, batch: int = 0):
    """pdestream's solver (``generator.flow``) on the case: the same grid, lengths, nu, uniform inflow (a plug
    profile), walls, cylinder, dt, steps and frames, pressure tolerance ``case.tol``; a batch runs each member's
    unbatched program in ``jax.lax.map`` (bit-identical to alone, as the sampler does). Starts from rest (the
    inflow switched on), not from the anchors' kick. Advection: the case's scheme (PhiFlow's and ours are both a
    limited MacCormack on a semi-Lagrangian backtrace, or both semi-Lagrangian). Returns run() -> (probe v [frames] of member 0, max |div| dx / u_in)."""
    import jax
    import jax.numpy as jnp

    from pdestream.generator.flow import Geometry, Params, divergence, initial_state, run
    from pdestream.generator.flow.step import solid_mask

    geom = Geometry(case.nx, case.ny, case.lx, case.ly, left="inflow", right="outflow")
    # float32 geometry: PhiFlow in the same process turns on jax_enable_x64, under which a Python float circle
    # would make the sharp body's apertures (and so the state) float64
    circle = tuple(jnp.float32(c) for c in (*case.centre, case.radius))
    params = Params(nu=case.nu, inflow=1.5 * case.u_in, plug=1.0, circle=circle)
    every = case.steps // case.frames
    h = geom.h
    px, py = int(case.probe[0] / h), int(case.probe[1] / h)

    def one(nu):
        p = params._replace(nu=nu)

        def frame(s, _):
            s = run(geom, s, p, case.dt, every, tol=case.tol, advection=ADVECTION[case.scheme])
            return s, 0.5 * (s.v[py, px] + s.v[py + 1, px])

        last, probe = jax.lax.scan(frame, initial_state(geom, p), None, length=case.frames)
        fluid = 1.0 - solid_mask(geom, p)
        # the sharp body's cut cells: the divergence of the fluxes through the open fractions (what the
        # projection makes zero), not of the face velocities (O(1) there by construction)
        div = jnp.abs(divergence(geom, last.u, last.v, p) * fluid)[2:-2, 2:-2].max()
        return probe, div * h / case.u_in

    nus = jnp.full((max(batch, 1),), case.nu, jnp.float32)
    program = jax.jit(jax.vmap(one) if VMAP else lambda nus: jax.lax.map(one, nus))

    def go():
        probe, div = jax.block_until_ready(program(nus))
        return np.asarray(probe[0]), float(div[0])

    return go


def bench(arm, case: VortexCase, batch: int, reps: int) -> dict:
    run = arm(case, batch)
    run = run[0] if isinstance(run, tuple) else run
    t0 = time.perf_counter()
    probe, div = run()  # compile + one full trajectory
    warm = time.perf_counter() - t0
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        probe, div = run()
        times.append(time.perf_counter() - t0)
    med, n = statistics.median(times), max(batch, 1)
    out = dict(substeps=getattr(run, "substeps", 1), first_s=warm, median_s=med, traj_per_s=n / med, steps_per_s=n * case.steps / med, div=div)
    if probe is not None:
        out["probe_rms"] = float(np.sqrt(np.mean(probe[len(probe) // 2:] ** 2)))
        out["St"] = strouhal(probe, case.dt * case.steps / case.frames, case)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--grids", default="128x64,64x32")
    ap.add_argument("--steps", type=int, default=1600)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--batch", default="4", help="batch sizes besides 1, comma-separated")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--arms", default="phiflow,jaxcfd,pdestream")
    ap.add_argument("--scheme", default="mac_cormack", choices=("mac_cormack", "semi_lagrangian"))
    ap.add_argument("--re", type=float, default=100.0)
    ap.add_argument("--vmap", action="store_true", help="pdestream: vectorise the batch (jax.vmap) instead of lax.map")
    a = ap.parse_args(argv)
    global VMAP
    VMAP = a.vmap
    import jax

    print(f"jax {jax.__version__} devices={jax.devices()}")
    arms = dict(phiflow=phiflow_trajectory, jaxcfd=jaxcfd_trajectory, pdestream=pdestream_trajectory)
    for g in a.grids.split(","):
        nx, ny = (int(s) for s in g.split("x"))
        case = VortexCase(nx=nx, ny=ny, steps=a.steps, frames=a.frames, scheme=a.scheme, re=a.re)
        print(f"case {case} nu={case.nu:g} cfl={case.u_in * case.dt * nx / case.lx:.2f}")
        for name in a.arms.split(","):
            for b in sorted({0, *(int(x) for x in str(a.batch).split(","))} - {1}):
                try:
                    r = bench(arms[name], case, b, a.reps)
                except (NotImplementedError, FloatingPointError) as e:
                    print(f"  {name:9s} batch={b:3d}  not run: {e}")
                    break
                sub = f"  ({r['substeps']} substeps of dt/{r['substeps']})" if r["substeps"] > 1 else ""
                extra = sub + f"  probe_rms={r['probe_rms']:.3f} St={r['St']:.3f}" if "St" in r else sub
                print(f"  {name:9s} batch={b:3d}  first {r['first_s']:.2f} s  median {r['median_s']:.3f} s  "
                      f"{r['traj_per_s']:.3f} traj/s  {r['steps_per_s']:.0f} steps/s  "
                      f"max|div|dx/U={r['div']:.1e}{extra}", flush=True)


if __name__ == "__main__":
    main()
