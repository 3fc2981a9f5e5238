"""Spin-up of karman2d's vortex street: when the lift amplitude stops drifting (issue 28, part 3).

    nice python -m benchmarks.karman_spinup [--rows "RE,RADIUS,CY,CX,PLUG;..."] [--t-end 16] [--dt 0.05]

Each row is one sample of karman2d at its default grid, run from rest to ``--t-end`` with frames every ``--dt``
(all rows in one vectorised batch); the lift per frame is the entry's own ``lift`` output. The detector
(``forces.shedding``) runs on sliding windows of 4 shedding periods (the period from the last 4 s), starting
every 0.25 s; a row's spin-up is the first window start from which every later window is ``developed`` (drift
< 2% over 3 periods). The table in docs/guides/flows.md came from the default rows below and, at Re 60, the 8
corners radius 0.08/0.12 x cy 0.42/0.48 x (cx, plug) (0.4, 0)/(0.6, 0.3) to t 20.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pdestream import generator
from pdestream.generator.flow import forces

ROWS = "80,.12,.42,.6,.3;80,.12,.46,.6,.3;80,.08,.46,.6,.3;90,.12,.46,.6,.3;100,.12,.46,.6,.3;120,.12,.46,.6,.3;" \
       "120,.08,.42,.4,0;120,.08,.46,.4,0"
NAMES = ("re", "radius", "cy", "cx", "plug")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.karman_spinup", description=__doc__.splitlines()[0])
    ap.add_argument("--rows", default=ROWS)
    ap.add_argument("--t-end", type=float, default=16.0)
    ap.add_argument("--dt", type=float, default=0.05)
    args = ap.parse_args(argv)
    rows = [[float(x) for x in r.split(",")] for r in args.rows.split(";")]
    pde = generator.get_pde("karman2d", t_start=0.0, t_end=args.t_end, n_frames=int(round(args.t_end / args.dt)) + 1)
    t = np.asarray(pde.times(), np.float32)
    params = {k: [r[j] for r in rows] for j, k in enumerate(NAMES)}
    params["speed"] = [1.0] * len(rows)
    start = time.time()
    lift = np.asarray(generator.sample(pde, list(range(len(rows))), seed=0, params=params).outputs["lift"])
    wall = time.time() - start
    last = t >= args.t_end - 4.0 - 1e-6
    for i, row in enumerate(rows):
        d = 2 * row[1]
        st, sheds, _, amp, _ = (float(x) for x in forces.shedding(lift[i][last], t[last], d, 1.0))
        windows = []
        if st > 0:
            w = 4 * d / st
            for ts in np.arange(0.0, args.t_end - w + 1e-6, 0.25):
                m = (t >= ts - 1e-6) & (t <= ts + w + 1e-6)
                s = forces.shedding(lift[i][m], t[m], d, 1.0)
                windows.append((float(ts), float(s[4]), bool(s[2])))
        spin = next((w[0] for k, w in enumerate(windows) if all(x[2] for x in windows[k:])), None)
        tail = f"last drift {windows[-1][1]:+.3f}" if windows else "no shedding"
        print(f"Re {row[0]:5.0f} radius {row[1]:.2f} cy {row[2]:.2f} cx {row[3]:.2f} plug {row[4]:.1f}: "
              f"sheds {sheds:.0f} St {st:.3f} amplitude {amp:.3f} developed from t {spin} ({tail})")
    print(f"{wall / len(rows):.1f} s per sample to t {args.t_end:g} (batch {len(rows)}, wall clock)")


if __name__ == "__main__":
    main()
