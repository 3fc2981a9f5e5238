"""3D flow solver figures (issue 28, item 5): generator.flow.mac3d against exact Navier-Stokes solutions.

    nice python -m benchmarks.flow3d_validation [--abc 16,32,64] [--shear 8,16,32]

``abc``: the Arnold-Beltrami-Childress flow (A = B = C = 1, k = 1) on the periodic [0, 2 pi]^3, nu 0.1, to t 1 (the
step: CFL 0.5 at |u| <= 2 and 0.9 of the explicit viscous limit h^2 / (6 nu), which binds from 64^3 on): curl u = u, so (u.grad)u = grad |u|^2 / 2 is balanced by the pressure and u decays as
exp(-nu t) exactly (the nonlinear term, the projection and the viscosity all act). ``shear``: u = sin(pi y)
e^{-nu pi^2 t}, w = sin(2 pi y) e^{-4 nu pi^2 t} between no-slip walls at y = 0 and 1 (x, z periodic, 4 cells),
nu 0.05, the step at the CFL 0.5 and 0.9 of the viscous limit: the wall ghosts' order. Prints per grid the RMS
velocity error at t 1 (float64), the order against the grid before and the largest |divergence|. Figures, not
pass/fail (tests/test_flow3d.py asserts them); measured figures in docs/results/flows.md ("3D").
"""

from __future__ import annotations

import argparse
import math
import time

import jax
import jax.numpy as jnp

from pdestream.generator.flow import mac3d


def abc(box, t, nu, dtype):
    """The ABC flow (A = B = C = 1, k = 1) on each component's faces at time t."""
    out = []
    for k in range(3):
        x, y, z = mac3d.points(box, box.face_shape(k), box.offsets(k), dtype)
        f = (jnp.sin(z) + jnp.cos(y), jnp.sin(x) + jnp.cos(z), jnp.sin(y) + jnp.cos(x))[k]
        out.append(f * math.exp(-nu * t))
    return tuple(out)


def shear(box, t, nu, dtype):
    """Two decaying shear modes between no-slip walls at y = 0 and 1 (x and z periodic)."""
    out = []
    for k in range(3):
        _, y, _ = mac3d.points(box, box.face_shape(k), box.offsets(k), dtype)
        f = (jnp.sin(math.pi * y) * math.exp(-nu * math.pi**2 * t), 0 * y,
             jnp.sin(2 * math.pi * y) * math.exp(-4 * nu * math.pi**2 * t))[k]
        out.append(f)
    return tuple(out)


def error(case: str, n: int) -> tuple[float, float]:
    """(RMS velocity error at t = 1, max |divergence| [1/s]) of the solver on n cells against ``case`` (float64)."""
    with jax.enable_x64(True):
        if case == "abc":
            nu, exact = 0.1, abc
            box = mac3d.Box((n,) * 3, 2 * math.pi / n, (True,) * 3)
            speed = 2.0  # |u| <= 2
        else:
            nu, exact, speed = 0.05, shear, 1.0
            box = mac3d.Box((4, n, 4), 1.0 / n, (True, False, True))
        dt = min(0.5 * box.h / speed, 0.9 * box.h**2 / (6 * nu))  # CFL 0.5, 0.9 of the explicit viscous limit
        steps = math.ceil(1.0 / dt)
        s = mac3d.initial_state(box, jnp.float64)
        s = s._replace(vel=mac3d.apply_bc(box, exact(box, 0.0, nu, jnp.float64)))
        s = jax.jit(mac3d.run, static_argnums=(0, 4))(box, s, mac3d.Params3(nu=nu), 1.0 / steps, steps)
        want = exact(box, 1.0, nu, jnp.float64)
        rms = math.sqrt(sum(float(jnp.mean((a - b) ** 2)) for a, b in zip(s.vel, want)) / 3)
        return rms, float(jnp.max(jnp.abs(mac3d.divergence(box, s.vel))))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--abc", default="16,32,64")
    ap.add_argument("--shear", default="8,16,32")
    args = ap.parse_args(argv)
    for case in ("abc", "shear"):
        prev = None
        for n in (int(v) for v in getattr(args, case).split(",") if v):
            t0 = time.perf_counter()
            rms, div = error(case, n)
            order = f"{math.log2(prev / rms):.2f}" if prev else "-"
            print(f"{case} n={n}: rms {rms:.3e}  order {order}  max|div| {div:.1e}  ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
            prev = rms


if __name__ == "__main__":
    main()
