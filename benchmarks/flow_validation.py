"""Flow solver validation figures (issue 18): pressure iterations over refinement, advection order, and the
published benchmarks (lid-driven cavity, Ghia, Ghia & Shin 1982; cylinder in a channel, Schaefer & Turek 1996).

    nice python -m benchmarks.flow_validation [--parts iterations,cavity,cylinder] [--cavity-n 64]
        [--cylinder-n 24] [--cylinder-t 12]

Figures, not pass/fail; each part says its case, grid and what it measured.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.experimental
import jax.numpy as jnp
import numpy as np

from generator.flow import Geometry, Params, initial_state, run_batch, step


def iterations(grids=((64, 32), (128, 64), (256, 128)), tol=1e-5):
    """Pressure-solve iterations on a karman-like channel (2 x 1, cylinder r 0.1 at (0.5, 0.52), parabolic
    inflow peak 1.5): the first step's projection from rest (cold start) and a warm-started step later."""
    from generator.flow import pressure  # noqa: PLC0415 (the speed part also runs on trees without predict)
    from generator.flow.step import operator, predict  # noqa: PLC0415

    rows = []
    for nx, ny in grids:
        geom = Geometry(nx, ny, 2.0, 1.0, left="inflow", right="outflow")
        params = Params(nu=1e-3, inflow=1.5, circle=(0.5, 0.52, 0.1))
        dt = 0.5 * geom.h / 1.5
        op = operator(geom, params)
        fc = op.levels[0]
        s0 = initial_state(geom, params)
        u, v, _ = predict(geom, s0, params, dt)
        b = -geom.h * (u[:, 1:] - u[:, :-1] + v[1:] - v[:-1]) * (1 - fc.solid)
        cold = jax.jit(lambda b: pressure.solve(fc, b, False, False, False, tol, 500, op))(b)
        s = jax.jit(lambda s: jax.lax.fori_loop(0, 20, lambda _, s: step(geom, s, params, dt, tol, 500, op), s))(s0)
        with jax.experimental.enable_x64():  # the algorithm's count, below float32's rounding floor
            op64 = pressure.Operator([jax.tree_util.tree_map(lambda a: a.astype(jnp.float64), lv) for lv in op.levels],
                                     op.coarse_inverse.astype(jnp.float64))
            b64 = jnp.asarray(np.asarray(b), jnp.float64)
            c64 = jax.jit(lambda b: pressure.solve(op64.levels[0], b, False, False, False, tol, 500, op64))(b64)
            c64 = (int(c64.iterations), float(c64.residual))
        rows.append((nx, ny, int(cold.iterations), float(cold.residual), int(s.iterations), *c64))
    print(f"pressure iterations, karman-like channel, tol {tol}, {len(op.levels)} levels at the finest grid")
    print("  grid      float32: cold(step 1) residual  warm(step 20) | float64: cold residual")
    for nx, ny, c, r, w, c64, r64 in rows:
        print(f"  {nx}x{ny:<7} {c:>13}    {r:.1e} {w:>10}     | {c64:>13} {r64:.1e}")
    for name, col in (("float32 warm", 4), ("float64 cold", 5), ("float32 cold", 2)):
        c = [r[col] for r in rows]
        print(f"  {name}: per refinement {', '.join(f'{b / a:.2f}x' for a, b in zip(c, c[1:]))};"
              f" first -> last grid {c[-1] / c[0]:.2f}x")
    print("  (float32 cold solves from rest stop at the rounding floor of ||b - A p|| (eps ||A|| ||p|| with ||p|| ~ 200"
          " ||b|| at 256x128) after their 4 true-residual checks)")
    return rows


def speed(nx=128, ny=64, batches=(1, 8), n_steps=100, reps=3):
    """Steps/s of run_batch on the karman-like channel (sample-steps per second of wall time, best of reps)."""
    geom = Geometry(nx, ny, 2.0, 1.0, left="inflow", right="outflow")
    dt = 0.5 * geom.h / 1.5
    for b in batches:
        params = Params(nu=1e-3, inflow=jnp.linspace(1.0, 1.5, b), circle=(0.5, 0.52, 0.1))
        jax.block_until_ready(run_batch(geom, params, dt, n_steps))
        best = float("inf")
        for _ in range(reps):
            t = time.perf_counter()
            out = jax.block_until_ready(run_batch(geom, params, dt, n_steps))
            best = min(best, time.perf_counter() - t)
        print(f"  run_batch {nx}x{ny} batch {b}: {b * n_steps / best:.0f} sample-steps/s "
              f"(last pressure iterations {np.asarray(out.iterations).tolist()})")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="iterations,cavity,cylinder")
    args = ap.parse_args(argv)
    parts = args.parts.split(",")
    if "iterations" in parts:
        t = time.perf_counter()
        iterations()
        print(f"  ({time.perf_counter() - t:.0f} s)")
    if "speed" in parts:
        speed()


if __name__ == "__main__":
    main()
