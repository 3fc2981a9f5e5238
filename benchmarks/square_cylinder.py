"""Sharp squares below the cell (issue 28, channel2d's body='sharp'): a square cylinder in a channel, staircase
against sharp.

    nice python -m benchmarks.square_cylinder [--parts offset,grid] [--ny 16,32,64] [--offset-ny 32]
        [--offsets 9] [--t 5] [--out benchmarks/results/square_cylinder.jsonl]

Case: channel [0, 2] x [0, 1] (inflow left, parabolic, mean speed U = 1; outflow right; no-slip walls), a square
of side D = 0.24 (blockage D / H = 0.24) centred at (0.507 + offset, 0.5), Re = U D / nu = 30 (steady, a
symmetric wake: lift 0 by symmetry), maccormack, dt = min(0.5 h / 1.5, 0.9 h^2 / (4 nu)), from rest to t = 5 (Cd
also at t = 4: its change says how steady it is). The square is an obstacle row (kind 2, a box) of
Params.obstacles: channel2d's own geometry path. Per case: Cd = 2 Fx / (U^2 D) from the library's force
(staircase: forces.body_force over the mask's faces; sharp: forces.bodies_force, the surface integral on the exact
square) and from a momentum balance over a square control volume 0.12 (half a side) outside the body
(benchmarks.flow_bodies.edge_flux: no wall value enters).

Parts: 'offset' moves the square downstream by offset = k / (offsets - 1) cells, k = 0..offsets-1, at
--offset-ny (the staircase's cells change only where an edge crosses a cell centre: jumps; the sharp body's
apertures change continuously); 'grid' runs offset 0 at each --ny (D = 0.24 never aligns with the faces there)
and prints each force's observed order log2((f1 - f2) / (f2 - f3)) and Richardson limit over three grids.
Resumable: each finished case is appended to --out (JSON lines) and skipped on the next run.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.flow_bodies import edge_flux
from pdestream.generator.flow import Geometry, Params, forces, initial_state, step
from pdestream.generator.flow.step import operator, solid_mask

SIDE, CX, CY, RE, U_MEAN = 0.24, 0.507, 0.5, 30.0, 1.0
NU = U_MEAN * SIDE / RE
OUT = Path(__file__).parent / "results" / "square_cylinder.jsonl"


@functools.lru_cache(maxsize=8)
def _program(ny: int, body: str, t_end: float):
    """(geom, dt, steps, go): go(state, params) -> (state at t_end, [Cd, Cl] at 4/5 t_end, at t_end), one compile
    per grid and body (the square's position is traced)."""
    h = 1.0 / ny
    geom = Geometry(2 * ny, ny, 2.0, 1.0, left="inflow", right="outflow", body=body)
    dt = min(0.5 * h / (1.5 * U_MEAN), 0.9 * h * h / (4 * NU))
    n4, n5 = int(round(4.0 / 5.0 * t_end / dt)), int(round(t_end / dt))

    def force(s, params):
        if body == "sharp":
            f = forces.bodies_force(geom, s, NU, params)
        else:
            f = forces.body_force(geom, solid_mask(geom, params), s, NU)
        return jnp.stack(forces.force_coefficients(*f, U_MEAN, SIDE))

    @jax.jit
    def go(s, params):
        op = operator(geom, params)
        adv = lambda s, k: jax.lax.fori_loop(0, k, lambda _, s: step(geom, s, params, dt, op=op,  # noqa: E731
                                                                      advection="maccormack"), s)
        s = adv(s, n4)
        c4 = force(s, params)
        s = adv(s, n5 - n4)
        return s, c4, force(s, params)

    return geom, n5, go


def case(ny: int, body: str, offset: float, t_end: float) -> dict:
    h = 1.0 / ny
    geom, n5, go = _program(ny, body, t_end)
    cx = CX + offset * h
    params = Params(nu=NU, inflow=1.5 * U_MEAN, obstacles=jnp.array([[2.0, cx, CY, SIDE / 2, SIDE / 2]]))
    t0 = time.perf_counter()
    s, c4, c5 = go(initial_state(geom, params), params)
    c4, c5 = np.asarray(c4), np.asarray(c5)
    wall = time.perf_counter() - t0
    margin = int(round(0.12 / h))  # the control volume: cells from the square's outermost cut cells
    box = (int(math.floor((cx - SIDE / 2) / h)) - margin, int(math.ceil((cx + SIDE / 2) / h)) + margin,
           int(math.floor((CY - SIDE / 2) / h)) - margin, int(math.ceil((CY + SIDE / 2) / h)) + margin)
    u, v, p = (np.asarray(a, np.float64) for a in (s.u, s.v, s.p))
    fx, fy = edge_flux(u, v, p, h, box, NU, np)
    scale = 2 / (U_MEAN ** 2 * SIDE)
    return {"ny": ny, "body": body, "offset": offset, "cells_per_side": SIDE / h, "steps": n5, "t": t_end,
            "cd": float(c5[0]), "cl": float(c5[1]), "cd_t4": float(c4[0]), "cd_cv": fx * scale, "cl_cv": fy * scale,
            "finite": bool(np.isfinite(u).all()), "capped": int(s.capped), "wall_s": wall}


def _order(f1, f2, f3):
    d1, d2 = f1 - f2, f2 - f3
    if d1 * d2 <= 0:
        return "sign", float("nan")
    p = math.log2(d1 / d2)
    return f"{p:.2f}", f3 + (f3 - f2) / (2 ** p - 1)


def tables(rows: list[dict], offset_ny: int, grid_ny: list[int]) -> str:
    out = ["offset sweep (ny = %d, D = %.2f cells):" % (offset_ny, SIDE * offset_ny),
           "| offset (cells) | Cd staircase | Cd sharp | Cd sharp (momentum balance) | Cd staircase (m. b.) |",
           "|---|---|---|---|---|"]
    sweep = {(r["body"], r["offset"]): r for r in rows if r["ny"] == offset_ny}
    for off in sorted({o for _, o in sweep}):
        st, sh = sweep.get(("staircase", off)), sweep.get(("sharp", off))
        cell = lambda r, k: f"{r[k]:.4f}" if r else ""  # noqa: E731
        out.append(f"| {off:.3f} | {cell(st, 'cd')} | {cell(sh, 'cd')} | {cell(sh, 'cd_cv')} | {cell(st, 'cd_cv')} |")
    for body in ("staircase", "sharp"):
        ser = [sweep[(body, o)]["cd"] for o in sorted({o for b, o in sweep if b == body})]
        if len(ser) > 2:
            jumps = np.abs(np.diff(ser))
            out.append(f"{body}: Cd range {max(ser) - min(ser):.4f}, largest step between neighbouring offsets "
                       f"{jumps.max():.4f}, median step {np.median(jumps):.4f}")
    out += ["", "grid study (offset 0):", "| body | ny | D/h | Cd | Cd at t 4 | Cl | Cd (momentum balance) | wall s |",
            "|---|---|---|---|---|---|---|---|"]
    for body in ("staircase", "sharp"):
        got = sorted((r for r in rows if r["body"] == body and r["offset"] == 0.0 and r["ny"] in grid_ny),
                     key=lambda r: r["ny"])
        for r in got:
            out.append(f"| {body} | {r['ny']} | {r['cells_per_side']:.2f} | {r['cd']:.4f} | {r['cd_t4']:.4f} | "
                       f"{r['cl']:.2e} | {r['cd_cv']:.4f} | {r['wall_s']:.0f} |")
        if len(got) >= 3:
            for key in ("cd", "cd_cv"):
                p, lim = _order(*(r[key] for r in got[-3:]))
                out.append(f"{body} {key}: observed order {p}, Richardson limit {lim:.4f}")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="offset,grid")
    ap.add_argument("--ny", type=lambda a: [int(n) for n in a.split(",")], default=[16, 32, 64])
    ap.add_argument("--offset-ny", type=int, default=32)
    ap.add_argument("--offsets", type=int, default=9)
    ap.add_argument("--bodies", default="staircase,sharp")
    ap.add_argument("--t", type=float, default=5.0)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    parts, bodies = args.parts.split(","), args.bodies.split(",")
    todo = []
    if "offset" in parts:
        todo += [(args.offset_ny, b, k / (args.offsets - 1)) for k in range(args.offsets) for b in bodies]
    if "grid" in parts:
        todo += [(ny, b, 0.0) for ny in args.ny for b in bodies]
    done = [json.loads(line) for line in args.out.read_text().splitlines()] if args.out.exists() else []
    for ny, body, off in todo:
        if any(r["ny"] == ny and r["body"] == body and abs(r["offset"] - off) < 1e-9 and r["t"] == args.t
               for r in done):
            continue
        r = case(ny, body, off, args.t)
        print(json.dumps(r), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("a") as f:
            f.write(json.dumps(r) + "\n")
        done.append(r)
    print(tables([r for r in done if r["t"] == args.t], args.offset_ny, args.ny))


if __name__ == "__main__":
    main()
