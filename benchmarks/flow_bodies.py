"""Bodies below the cell (issue 28 part 1): Schaefer & Turek (1996) 2D-1 with the staircase and the sharp circle.

    nice python -m benchmarks.flow_bodies [--ny 16,32,64] [--bodies staircase,sharp] [--t 6] [--out FILE]
        [--cfl 0.4] [--tol 1e-5] [--force-distances 0.75,1.5,2] [--shift-x 0.5] [--save DIR] [--start-from FILE]

2D-1: channel 2.2 x 0.41 (lx = nx h, nx = 86 ny / 16: 0.17% longer), cylinder (0.2, 0.2) r 0.05, parabolic inflow
peak 0.3 (U_mean 0.2), nu 1e-3 (Re 20, steady), maccormack, dt = min(0.4 h / 0.3, 0.9 h^2 / (4 nu)), run to t 6 from rest (steady: Cd
moves < 1e-4 after t 5 at 172x32). Published (Schaefer & Turek 1996, Table 4): Cd 5.57-5.59, Cl 0.0104-0.0110,
Delta p = p(0.15, 0.2) - p(0.25, 0.2) 0.1172-0.1176. Per case: the library's force (staircase: forces.body_force
over the mask's faces; sharp: forces.circle_force, the surface integral on the exact circle), a momentum balance
over a square 5 radii wide around the cylinder (the steady control-volume force, a cross-check that does not
sample the wall),
Delta p (the wall pressure extrapolated along the normal, forces.circle_surface, for both bodies) and the
observed order between successive grids (log2 of the ratio of the errors against the published interval's middle).
Resumable: each finished case is appended to --out (JSON lines) and skipped on the next run; each case is one
jitted rollout (344x64: ~2 min on 2 cores). --save DIR keeps each case's final (u, v, p) (npz); --start-from FILE
starts the (single) case from such a state of a coarser grid, interpolated (a finer grid continued for --t instead
of run from rest). --shift-x F moves the cylinder F cells downstream (the cut cells' alignment with the grid, the
flow itself hardly: the inflow is developed). The three-grid table gives each quantity's observed order without
the published value, p = log2((f1 - f2) / (f2 - f3)) over successive grids, and its Richardson limit
f3 + (f3 - f2) / (2^p - 1): a quantity whose successive differences change sign is not in its asymptotic range.
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
    return edge_flux(u, v, p, h, box, NU, np)


def edge_flux(u, v, p, h, box, nu, xp=np):
    """Minus the flux of momentum, pressure and viscous stress (kinematic viscosity ``nu``) out of the square of
    cell index bounds box = (i0, i1, j0, j1), (Sx, Sy) per unit depth and density, the MAC values u [ny, nx + 1],
    v [ny + 1, nx], p [ny, nx] averaged to its edges; ``xp`` numpy or jax.numpy (traced in a jitted scan)."""
    uc, vc = 0.5 * (u[:, 1:] + u[:, :-1]), 0.5 * (v[1:] + v[:-1])
    i0, i1, j0, j1 = box
    fx = fy = 0.0
    js = slice(j0, j1)
    for i, sign in ((i0, -1), (i1, 1)):  # vertical edges x = i h: u on its faces
        un, vv, pp = u[js, i], 0.5 * (vc[js, i - 1] + vc[js, i]), 0.5 * (p[js, i - 1] + p[js, i])
        dudx = (u[js, i + 1] - u[js, i - 1]) / (2 * h)
        dvdx = (vc[js, i] - vc[js, i - 1]) / h
        dudy = (u[j0 + 1:j1 + 1, i] - u[j0 - 1:j1 - 1, i]) / (2 * h)
        fx += sign * h * xp.sum(un * un + pp - 2 * nu * dudx)
        fy += sign * h * xp.sum(un * vv - nu * (dvdx + dudy))
    is_ = slice(i0, i1)
    for j, sign in ((j0, -1), (j1, 1)):  # horizontal edges y = j h: v on its faces
        vn, uu, pp = v[j, is_], 0.5 * (uc[j - 1, is_] + uc[j, is_]), 0.5 * (p[j - 1, is_] + p[j, is_])
        dvdy = (v[j + 1, is_] - v[j - 1, is_]) / (2 * h)
        dudy = (uc[j, is_] - uc[j - 1, is_]) / h
        dvdx = (v[j, i0 + 1:i1 + 1] - v[j, i0 - 1:i1 - 1]) / (2 * h)
        fx += sign * h * xp.sum(vn * uu - nu * (dudy + dvdx))
        fy += sign * h * xp.sum(vn * vn + pp - 2 * nu * dvdy)
    return -fx, -fy


def weighted_force(u, v, p, h, cx, cy, r1, r2):
    """Steady force (Fx, Fy) per unit depth and density on whatever lies inside the disc of radius r1 about
    (cx, cy): the momentum balance weighted by phi (1 inside r1, 0 beyond r2, a cosine ramp between),
    F_i = int T_ij d_j phi dV with T_ij = u_i u_j + p delta_ij - nu d_j u_i (a control volume smeared over the
    ring, so no wall value and no single line of cells enters; midpoint rule on the cell centres, numpy float64).
    """
    u, v, p = (np.asarray(a, np.float64) for a in (u, v, p))
    ny, nx = p.shape
    uc, vc = 0.5 * (u[:, 1:] + u[:, :-1]), 0.5 * (v[1:] + v[:-1])
    dudx, dvdy = (u[:, 1:] - u[:, :-1]) / h, (v[1:] - v[:-1]) / h
    dudy, dvdx = np.gradient(uc, h, axis=0), np.gradient(vc, h, axis=1)
    y, x = (np.arange(ny)[:, None] + 0.5) * h - cy, (np.arange(nx)[None, :] + 0.5) * h - cx
    rho = np.hypot(x, y)
    ring = (rho > r1) & (rho < r2)
    dphi = np.where(ring, -0.5 * np.pi / (r2 - r1) * np.sin(np.pi * (rho - r1) / (r2 - r1)), 0.0)
    gx, gy = dphi * x / np.maximum(rho, h), dphi * y / np.maximum(rho, h)
    fx = np.sum((uc * uc + p - NU * dudx) * gx + (uc * vc - NU * dudy) * gy) * h * h
    fy = np.sum((vc * uc - NU * dvdx) * gx + (vc * vc + p - NU * dvdy) * gy) * h * h
    return fx, fy


def _prolong(a, shape, ox, oy):
    """A MAC array a of a grid h to the grid of ``shape`` (any spacing): bilinear in the cell-index coordinates,
    (ox, oy) the array's offset in cells (0.5: centres, 0: faces); the edges extended (numpy)."""
    from scipy.ndimage import map_coordinates  # noqa: PLC0415 (only for --start-from)

    a = np.asarray(a, np.float64)
    k = (shape[1] - (1 - 2 * ox)) / (a.shape[1] - (1 - 2 * ox))  # the ratio of the cell counts along x
    ys = (np.arange(shape[0]) + oy) / k - oy
    xs = (np.arange(shape[1]) + ox) / k - ox
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    return map_coordinates(a, [yy, xx], order=1, mode="nearest")


def case(ny: int, body: str, t_end: float, cfl: float = 0.4, tol: float = 1e-5,
         force_distances: tuple = (), shift_x: float = 0.0, start: dict | None = None) -> dict:
    h = 0.41 / ny
    # nested grids (86 x 16 doubled): 2 round(2.2 / h / 2) gives 686 at ny 128, whose multigrid stops halving at
    # 343 x 64 and whose dense coarsest pseudo-inverse (pressure.prepare) then needs > 9 GB
    nx = 86 * ny // 16 if ny % 16 == 0 else 2 * round(2.2 / h / 2)
    geom = Geometry(nx, ny, nx * h, 0.41, left="inflow", right="outflow", body=body)
    cx = CX + shift_x * h
    params = Params(nu=NU, inflow=PEAK, circle=(cx, CY, R))
    # the viscous step is explicit (stable for nu dt / h^2 <= 1/4): it binds from 688 x 128 on (there CFL 0.4 is
    # nu dt / h^2 = 0.42, and the run blew up within 59 steps); 16 to 64 keep dt = CFL h / 0.3
    dt = min(cfl * h / PEAK, 0.9 * h * h / (4 * NU))
    n = int(round(t_end / dt))

    @jax.jit
    def go(s):
        op = operator(geom, params)
        s = jax.lax.fori_loop(0, n, lambda _, s: step(geom, s, params, dt, tol, op=op, advection="maccormack"), s)
        if body == "sharp":
            f = forces.circle_force(geom, s, NU, cx, CY, R)
        else:
            f = forces.body_force(geom, solid_mask(geom, params), s, NU)
        pw, _ = forces.circle_surface(geom, s, NU, cx, CY, R, jnp.array([math.pi, 0.0], s.p.dtype))
        return s, jnp.stack(forces.force_coefficients(*f, U_MEAN, D)), pw[0] - pw[1]

    s0 = initial_state(geom, params)
    if start is not None:  # a coarser grid's final state, interpolated: the first projection makes it solenoidal
        s0 = s0._replace(**{k: jnp.asarray(_prolong(start[k], a.shape, ox, oy), a.dtype) for k, a, ox, oy in
                            (("u", s0.u, 0.0, 0.5), ("v", s0.v, 0.5, 0.0), ("p", s0.p, 0.5, 0.5))})
    t0 = time.perf_counter()
    s, coef, dp = go(s0)
    coef = np.asarray(coef)
    wall = time.perf_counter() - t0
    c, cj = int(round(cx / h)), int(round(CY / h))
    # a square 5 radii wide (2 radii of fluid around the cylinder): 3 radii wide moved Cd by 0.02 at 172x32 (its
    # edges in the wall layer), 6 radii wide by < 1e-4 from this; 7 radii wide as a second check
    scale = 2 / (U_MEAN ** 2 * D)
    (fx, fy), (fx7, fy7) = (_box_balance(s, h, c, cj, nx, ny, radii, scale) for radii in (2.5, 3.5))
    extra = {"cd_vol": 0.0, "cl_vol": 0.0}
    extra["cd_vol"], extra["cl_vol"] = (scale * a for a in weighted_force(s.u, s.v, s.p, h, cx, CY, 1.5 * R, 3 * R))
    for d in force_distances if body == "sharp" else ():  # the sharp force with its wall samples d cells out (forces.FORCE_DISTANCE) instead
        default, forces.FORCE_DISTANCE = forces.FORCE_DISTANCE, d
        try:
            extra[f"cd_cl_at_{d:g}"] = [float(c) for c in forces.force_coefficients(
                *forces.circle_force(geom, s, NU, cx, CY, R), U_MEAN, D)]
        finally:
            forces.FORCE_DISTANCE = default
    return extra | {"ny": ny, "nx": nx, "body": body, "cells_per_d": D / h, "steps": n, "cd": float(coef[0]),
            "cl": float(coef[1]), "dp": float(dp), "cd_cv": fx, "cl_cv": fy,
            "cd_cv7": fx7, "cl_cv7": fy7, "shift_x": shift_x, "t": t_end,
            "continued": start is not None, "finite": bool(jnp.isfinite(s.u).all()), "capped": int(s.capped),
            "wall_s": wall, "_state": {k: np.asarray(getattr(s, k)) for k in ("u", "v", "p")}}


def _box_balance(s, h, c, cj, nx, ny, radii, scale):
    """(Cd, Cl) of the momentum balance over the square ``radii`` cylinder radii from cell (c, cj) on each side,
    or (None, None) where the square (with the one cell its differences reach) leaves the nx x ny grid (the
    7-radii square at 86x16 with the body shifted upstream)."""
    half = int(round(radii * R / h))
    box = (c - half, c + half, cj - half, cj + half)
    if min(box[0], box[2]) < 1 or box[1] + 1 > nx or box[3] + 1 > ny:
        return None, None
    fx, fy = momentum_balance(s.u, s.v, s.p, h, box)
    return fx * scale, fy * scale


def _err(x, lo_hi):
    return abs(x - 0.5 * sum(lo_hi))


def table(rows: list[dict]) -> str:
    lines = ["| body | grid | D/h | Cd | Cl | Delta p | Cd (momentum balance) | Cl (momentum balance) | order Cd | "
             "order Cl | order Delta p | order Cd (m. b.) | order Cl (m. b.) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for body in ("staircase", "sharp"):
        prev = None
        for r in sorted((r for r in rows if r["body"] == body), key=lambda r: r["ny"]):
            orders = ["", "", "", "", ""]
            if prev is not None and prev["ny"] * 2 == r["ny"]:
                orders = [f"{math.log2(_err(prev[k], ref) / max(_err(r[k], ref), 1e-12)):.2f}"
                          for k, ref in (("cd", CD), ("cl", CL), ("dp", DP), ("cd_cv", CD), ("cl_cv", CL))]
            lines.append(f"| {body} | {r['nx']}x{r['ny']} | {r['cells_per_d']:.1f} | {r['cd']:.4f} | {r['cl']:.4f} | "
                         f"{r['dp']:.4f} | {r['cd_cv']:.4f} | {r['cl_cv']:.4f} | {' | '.join(orders)} |")
            prev = r
    lines.append(f"| published | | | {CD[0]}-{CD[1]} | {CL[0]}-{CL[1]} | {DP[0]}-{DP[1]} | | | | | | | |")
    return "\n".join(lines)


RICHARDSON = ("cd", "cl", "dp", "cd_cv", "cl_cv", "cd_cv7", "cl_cv7", "cd_vol", "cl_vol")


def richardson(rows: list[dict]) -> str:
    """Per three successive grids (each twice the last) of one body and shift: each quantity's observed order
    log2((f1 - f2) / (f2 - f3)) and Richardson limit, or 'sign' where the differences change sign (not
    asymptotic)."""
    lines = ["| body | shift | grids | " + " | ".join(f"{k}: order, limit" for k in RICHARDSON) + " |",
             "|---|---|---|" + "---|" * len(RICHARDSON)]
    keys = sorted({(r["body"], r.get("shift_x", 0.0)) for r in rows})
    for body, shift in keys:
        rs = sorted((r for r in rows if r["body"] == body and r.get("shift_x", 0.0) == shift), key=lambda r: r["ny"])
        for a, b, c in zip(rs, rs[1:], rs[2:]):
            if not (a["ny"] * 2 == b["ny"] and b["ny"] * 2 == c["ny"]):
                continue
            cells = []
            for k in RICHARDSON:
                if not all(r.get(k) is not None for r in (a, b, c)):
                    cells.append("")
                    continue
                d1, d2 = a[k] - b[k], b[k] - c[k]
                if d1 * d2 <= 0:
                    cells.append("sign")
                    continue
                p = math.log2(d1 / d2)
                cells.append(f"{p:.2f}, {c[k] - d2 / (2 ** p - 1):.4f}" if p > 0 else f"{p:.2f}, grows")
            lines.append(f"| {body} | {shift:g} | {a['ny']}/{b['ny']}/{c['ny']} | " + " | ".join(cells) + " |")
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
    ap.add_argument("--shift-x", type=float, default=0.0, help="the cylinder this many cells downstream of x = 0.2")
    ap.add_argument("--save", type=Path, default=None, help="keep each case's final u, v, p in DIR/<body>_<ny>[_shift].npz")
    ap.add_argument("--start-from", type=Path, default=None,
                    help="start from this saved state of a coarser grid (one --ny, one body) and run it --t more")
    ap.add_argument("--out", type=Path, default=Path("flow_bodies.jsonl"))
    args = ap.parse_args(argv)
    bodies = args.bodies.split(",")
    if args.start_from is not None and (len(args.ny) != 1 or len(bodies) != 1):
        raise SystemExit(f"--start-from continues one case: got --ny {args.ny} and --bodies {args.bodies}")
    done = [json.loads(line) for line in args.out.read_text().splitlines()] if args.out.exists() else []
    for ny in args.ny:
        for body in bodies:
            if any(r["ny"] == ny and r["body"] == body and r.get("shift_x", 0.0) == args.shift_x for r in done):
                continue
            start = dict(np.load(args.start_from)) if args.start_from is not None else None
            r = case(ny, body, args.t, args.cfl, args.tol, tuple(args.force_distances), args.shift_x, start)
            state = r.pop("_state")
            if args.save is not None:
                args.save.mkdir(parents=True, exist_ok=True)
                tag = f"_{args.shift_x:g}" if args.shift_x else ""
                np.savez(args.save / f"{body}_{ny}{tag}.npz", **state)
            print(json.dumps(r), flush=True)
            with args.out.open("a") as f:
                f.write(json.dumps(r) + "\n")
            done.append(r)
    print(table([r for r in done if r.get("shift_x", 0.0) == 0.0]))
    print(richardson(done))


if __name__ == "__main__":
    main()
