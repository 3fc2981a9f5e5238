"""Bodies below the cell (issue 28 part 1): Schaefer & Turek (1996) 2D-1 with the staircase and the sharp circle.

    nice python -m benchmarks.flow_bodies [--ny 16,32,64] [--bodies staircase,sharp] [--t 6] [--out FILE]
        [--cfl 0.4] [--tol 1e-5] [--force-distances 0.75,1.5,2]

2D-1: channel 2.2 x 0.41 (lx = nx h, nx even: <= 0.2% longer), cylinder (0.2, 0.2) r 0.05, parabolic inflow
peak 0.3 (U_mean 0.2), nu 1e-3 (Re 20, steady), maccormack, dt = 0.4 h / 0.3, run to t 6 from rest (steady: Cd
moves < 1e-4 after t 5 at 172x32). Published (Schaefer & Turek 1996, Table 4): Cd 5.57-5.59, Cl 0.0104-0.0110,
Delta p = p(0.15, 0.2) - p(0.25, 0.2) 0.1172-0.1176. Per case: the library's force (staircase: forces.body_force
over the mask's faces; sharp: forces.circle_force, the surface integral on the exact circle), a momentum balance
over a square 5 radii wide around the cylinder (the steady control-volume force, a cross-check that does not
sample the wall),
Delta p (the wall pressure extrapolated along the normal, forces.circle_surface, for both bodies) and the
observed order between successive grids (log2 of the ratio of the errors against the published interval's middle).
Resumable: each finished case is appended to --out (JSON lines) and skipped on the next run; each case is one
jitted rollout (344x64: ~2 min on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from pdestream.generator.flow import Geometry, Params, forces, initial_state, step
from pdestream.generator.flow.step import operator, solid_mask

CD, CL, DP = (5.57, 5.59), (0.0104, 0.0110), (0.1172, 0.1176)
NU, PEAK, CX, CY, R = 1e-3, 0.3, 0.2, 0.2, 0.05
U_MEAN, D = 0.2, 0.1


def momentum_balance(u, v, p, h, box):
    """Steady control-volume force (Fx, Fy) per unit depth and density on whatever lies inside the square of cell
    index bounds box = (i0, i1, j0, j1): minus the flux of momentum, pressure and viscous stress out of it (the
    MAC values averaged to the square's edges, numpy float64)."""
    u, v, p = (np.asarray(a, np.float64) for a in (u, v, p))
    uc, vc = 0.5 * (u[:, 1:] + u[:, :-1]), 0.5 * (v[1:] + v[:-1])
    i0, i1, j0, j1 = box
    fx = fy = 0.0
    js = slice(j0, j1)
    for i, sign in ((i0, -1), (i1, 1)):  # vertical edges x = i h: u on its faces
        un, vv, pp = u[js, i], 0.5 * (vc[js, i - 1] + vc[js, i]), 0.5 * (p[js, i - 1] + p[js, i])
        dudx = (u[js, i + 1] - u[js, i - 1]) / (2 * h)
        dvdx = (vc[js, i] - vc[js, i - 1]) / h
        dudy = (u[j0 + 1:j1 + 1, i] - u[j0 - 1:j1 - 1, i]) / (2 * h)
        fx += sign * h * np.sum(un * un + pp - 2 * NU * dudx)
        fy += sign * h * np.sum(un * vv - NU * (dvdx + dudy))
    is_ = slice(i0, i1)
    for j, sign in ((j0, -1), (j1, 1)):  # horizontal edges y = j h: v on its faces
        vn, uu, pp = v[j, is_], 0.5 * (uc[j - 1, is_] + uc[j, is_]), 0.5 * (p[j - 1, is_] + p[j, is_])
        dvdy = (v[j + 1, is_] - v[j - 1, is_]) / (2 * h)
        dudy = (uc[j, is_] - uc[j - 1, is_]) / h
        dvdx = (v[j, i0 + 1:i1 + 1] - v[j, i0 - 1:i1 - 1]) / (2 * h)
        fx += sign * h * np.sum(vn * uu - NU * (dudy + dvdx))
        fy += sign * h * np.sum(vn * vn + pp - 2 * NU * dvdy)
    return -fx, -fy


def case(ny: int, body: str, t_end: float, cfl: float = 0.4, tol: float = 1e-5,
         force_distances: tuple = ()) -> dict:
    h = 0.41 / ny
    nx = 2 * round(2.2 / h / 2)
    geom = Geometry(nx, ny, nx * h, 0.41, left="inflow", right="outflow", body=body)
    params = Params(nu=NU, inflow=PEAK, circle=(CX, CY, R))
    dt = cfl * h / PEAK
    n = int(round(t_end / dt))

    @jax.jit
    def go(s):
        op = operator(geom, params)
        s = jax.lax.fori_loop(0, n, lambda _, s: step(geom, s, params, dt, tol, op=op, advection="maccormack"), s)
        if body == "sharp":
            f = forces.circle_force(geom, s, NU, CX, CY, R)
        else:
            f = forces.body_force(geom, solid_mask(geom, params), s, NU)
        pw, _ = forces.circle_surface(geom, s, NU, CX, CY, R, jnp.array([math.pi, 0.0], s.p.dtype))
        return s, jnp.stack(forces.force_coefficients(*f, U_MEAN, D)), pw[0] - pw[1]

    t0 = time.perf_counter()
    s, coef, dp = go(initial_state(geom, params))
    coef = np.asarray(coef)
    wall = time.perf_counter() - t0
    c = int(round(CX / h))
    # a square 5 radii wide (2 radii of fluid around the cylinder): 3 radii wide moved Cd by 0.02 at 172x32 (its
    # edges in the wall layer), 6 radii wide by < 1e-4 from this
    half = int(round(2.5 * R / h))
    fx, fy = momentum_balance(s.u, s.v, s.p, h, (c - half, c + half, c - half, c + half))
    scale = 2 / (U_MEAN ** 2 * D)
    extra = {}
    for d in force_distances if body == "sharp" else ():  # the sharp force with its wall samples d cells out (forces.FORCE_DISTANCE) instead
        default, forces.FORCE_DISTANCE = forces.FORCE_DISTANCE, d
        try:
            extra[f"cd_cl_at_{d:g}"] = [float(c) for c in forces.force_coefficients(
                *forces.circle_force(geom, s, NU, CX, CY, R), U_MEAN, D)]
        finally:
            forces.FORCE_DISTANCE = default
    return extra | {"ny": ny, "nx": nx, "body": body, "cells_per_d": D / h, "steps": n, "cd": float(coef[0]),
            "cl": float(coef[1]), "dp": float(dp), "cd_cv": fx * scale, "cl_cv": fy * scale,
            "finite": bool(jnp.isfinite(s.u).all()), "capped": int(s.capped), "wall_s": wall}


def _err(x, lo_hi):
    return abs(x - 0.5 * sum(lo_hi))


def table(rows: list[dict]) -> str:
    lines = ["| body | grid | D/h | Cd | Cl | Delta p | Cd (momentum balance) | Cl (momentum balance) | order Cd | "
             "order Cl | order Delta p |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for body in ("staircase", "sharp"):
        prev = None
        for r in sorted((r for r in rows if r["body"] == body), key=lambda r: r["ny"]):
            orders = ["", "", ""]
            if prev is not None and prev["ny"] * 2 == r["ny"]:
                orders = [f"{math.log2(_err(prev[k], ref) / max(_err(r[k], ref), 1e-12)):.2f}"
                          for k, ref in (("cd", CD), ("cl", CL), ("dp", DP))]
            lines.append(f"| {body} | {r['nx']}x{r['ny']} | {r['cells_per_d']:.1f} | {r['cd']:.4f} | {r['cl']:.4f} | "
                         f"{r['dp']:.4f} | {r['cd_cv']:.4f} | {r['cl_cv']:.4f} | {' | '.join(orders)} |")
            prev = r
    lines.append(f"| published | | | {CD[0]}-{CD[1]} | {CL[0]}-{CL[1]} | {DP[0]}-{DP[1]} | | | | | |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ny", type=lambda a: [int(n) for n in a.split(",")], default=[16, 32, 64])
    ap.add_argument("--bodies", default="staircase,sharp")
    ap.add_argument("--t", type=float, default=6.0)
    ap.add_argument("--cfl", type=float, default=0.4, help="dt = CFL h / 0.3 (the inflow peak)")
    ap.add_argument("--tol", type=float, default=1e-5, help="the pressure solve's relative tolerance")
    ap.add_argument("--force-distances", type=lambda a: [float(d) for d in a.split(",")], default=[],
                    help="also the sharp force with its wall samples these many cells out (forces.FORCE_DISTANCE)")
    ap.add_argument("--out", type=Path, default=Path("flow_bodies.jsonl"))
    args = ap.parse_args(argv)
    done = [json.loads(line) for line in args.out.read_text().splitlines()] if args.out.exists() else []
    for ny in args.ny:
        for body in args.bodies.split(","):
            if any(r["ny"] == ny and r["body"] == body for r in done):
                continue
            r = case(ny, body, args.t, args.cfl, args.tol, tuple(args.force_distances))
            print(json.dumps(r), flush=True)
            with args.out.open("a") as f:
                f.write(json.dumps(r) + "\n")
            done.append(r)
    print(table(done))


if __name__ == "__main__":
    main()
