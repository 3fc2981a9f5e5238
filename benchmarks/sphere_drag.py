"""Drag of a sphere at Re 100 (issue 28, item 5): the 3D MAC solver with a penalised body in a free stream.

    nice python -m benchmarks.sphere_drag [--d-cells 8,12] [--widths 6] [--length 10] [--t-max 15] [--stokes 4,6]
        [--record FILE] [--table]

A sphere of diameter D = 1 in a stream U = 1 (nu = 0.01: Re = U D / nu = 100), impulsively started. The box is
``length`` D along the stream and ``width`` D square across, periodic on every axis: a fringe over the last
``fringe`` D of the stream axis relaxes the velocity to (U, 0, 0) (rate ``--fringe-rate``), so the flow leaves the
box through it and re-enters at x = 0 as a uniform stream; the sphere's centre is ``--upstream`` D from x = 0. The
lateral period is the blockage (a periodic array of spheres): two widths measure what it adds. The body is
generator.flow.body3d's smoothed volume fraction relaxed to rest with eta = ``--eta`` dt. Cd = 2 F_x / (U^2 pi
D^2 / 4) over the last time unit, two ways: F the momentum the penalisation removes per unit time ("body"), and
F the momentum the fringe adds per unit time ("push": the whole box's momentum balance, steady, so it holds the
momentum the advection gains or loses besides the body's). The run stops when the body's Cd changes by < 0.1%
over one time unit (or at --t-max). Prints per (cells per D, width) the cells, both Cd, their relative errors
against Johnson & Patel 1999 (J. Fluid Mech. 378, 19-70: Cd 1.087 at Re 100, steady axisymmetric wake; the
Clift, Grace & Weber 1978 correlation 24/Re (1 + 0.1935 Re^0.6305) gives 1.0870 too) and the wall time.
``--stokes``: the body alone against an exact figure, Stokes flow through a periodic array of the penalised
spheres against Hasimoto 1959's drag (``stokes_array``). float32. Measured figures in docs/results/flows.md
("Sphere drag at Re 100").
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import jax
import jax.numpy as jnp

from pdestream.generator.flow import body3d, mac3d

REFERENCE_CD = 1.087  # Johnson & Patel 1999, Re 100
RECORD = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "results",
                      "sphere_drag_runs.json")
KEY = ("d_cells", "width", "length", "upstream", "fringe", "fringe_rate", "eta", "ramp", "cfl", "t_max")


def richardson(cells, cds):
    """Observed order p and limit C of Cd = C + a h^p through three (cells per D, Cd) points, h = 1 / cells (any
    ratios: p by bisection); None where no p in (0.05, 12) fits (not in the asymptotic range)."""
    (n1, c1), (n2, c2), (n3, c3) = sorted(zip(cells, cds))
    h1, h2, h3 = 1 / n1, 1 / n2, 1 / n3
    ratio = (c1 - c2) / (c2 - c3) if c2 != c3 else math.inf
    if not ratio > 0 or not math.isfinite(ratio):
        return None

    def gap(p):
        return (h1**p - h2**p) / (h2**p - h3**p) - ratio

    lo, hi = 0.05, 12.0
    if gap(lo) * gap(hi) > 0:
        return None
    for _ in range(100):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if gap(lo) * gap(mid) > 0 else (lo, mid)
    p = (lo + hi) / 2
    return p, c3 - (c2 - c3) * h3**p / (h2**p - h3**p)


def load_record(path):
    """The rows recorded so far (a list of dicts: KEY's settings, cells, the body's and the push's Cd per time
    unit, wall seconds, done); [] where the file does not exist."""
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return json.load(f)


def save_row(path, row):
    """Replace (or add) the row with row's settings in the record at ``path``, written whole, then renamed; under
    a lock where the system has one (two runs may share the record)."""
    try:
        import fcntl
    except ImportError:  # no POSIX locks: one run at a time
        fcntl = None
    with open(path + ".lock", "w") as lock:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)
        rows = [r for r in load_record(path) if tuple(r[k] for k in KEY) != tuple(row[k] for k in KEY)]
        rows.append(row)
        rows.sort(key=lambda r: tuple(r[k] for k in KEY))
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            json.dump(rows, f, indent=1)
            f.write("\n")
        os.replace(tmp, path)


def drag(d_cells: int, width: float, length: float = 10.0, upstream: float = 3.0, fringe: float = 2.0,
         fringe_rate: float = 4.0, eta: float = 0.25, cfl: float = 1.0, t_max: float = 15.0, re: float = 100.0,
         chunk_time: float = 1.0, ramp: float = 1.0, log=print, on_chunk=None):
    """Run one (cells per diameter, width in D) case to a steady drag: (Cd from the body's force, Cd from the
    fringe's push, t reached, cells, Cd per time unit). ``on_chunk(history, push_history)`` after every time
    unit (the lists of both Cd so far: a record that survives the run being stopped)."""
    h = 1.0 / d_cells
    n_x, n_w = round(length * d_cells), round(width * d_cells)
    box = mac3d.Box((n_x, n_w, n_w), h, (True, True, True))
    lx, lw = n_x * h, n_w * h
    centre = (upstream, lw / 2, lw / 2)
    nu = 1.0 / re
    dt = min(cfl * h / 1.2, 0.9 * h * h / (6 * nu))  # |u| <= ~1.2 around the sphere
    steps = max(1, round(chunk_time / dt))
    dt = chunk_time / steps
    start = lx - fringe
    r = body3d.Relax(
        chi=tuple(body3d.ball_fraction(box, centre, 0.5, k, ramp=ramp) for k in range(3)),
        eta=eta * dt,
        fringe=tuple(body3d.fringe_rate(box, start, lx, fringe / 3, fringe_rate, k) for k in range(3)),
        target=(1.0, 0.0, 0.0))
    state = body3d.stream_state(box, 1.0)
    params = mac3d.Params3(nu=nu)
    fn = jax.jit(body3d.run, static_argnums=(0, 5))
    area = math.pi / 4
    history, pushes = [], []
    t = 0.0
    while t < t_max - 1e-9:
        t0 = time.perf_counter()
        state, forces = fn(box, state, params, r, dt, steps)
        cd = float(jnp.mean(forces[:, 0, 0])) / (0.5 * area)
        cd_fringe = float(jnp.mean(forces[:, 1, 0])) / (0.5 * area)
        t += chunk_time
        history.append(cd)
        pushes.append(cd_fringe)
        pushed = cd_fringe
        if on_chunk is not None:
            on_chunk(history, pushes)
        if not math.isfinite(cd):
            raise RuntimeError(f"Cd not finite at t={t}")
        lateral = float(jnp.abs(jnp.mean(forces[:, 0, 1:], 0)).max()) / (0.5 * area)
        log(f"  t={t:5.1f} Cd {cd:.4f} (the fringe's push {cd_fringe:.4f}, |Cl| {lateral:.1e}; "
            f"{time.perf_counter() - t0:.1f} s)")
        if len(history) >= 5 and abs(history[-1] - history[-2]) < 1e-3 * abs(history[-1]):
            break
    return history[-1], pushed, t, box.shape, history


def hasimoto(c: float) -> float:
    """Stokes drag of a simple cubic array of spheres over a lone sphere's 6 pi mu R U at solid fraction c
    (Hasimoto 1959, with Sangani & Acrivos 1982's next terms; U the box-averaged velocity): valid for c << 0.2."""
    return 1 / (1 - 1.7601 * c ** (1 / 3) + c - 1.5593 * c**2)


def stokes_array(d_cells: int, period: float = 3.0, nu: float = 1.0, push: float = 0.01, t_end: float = 8.0,
                 eta: float = 0.25, ramp: float = 1.0):
    """The penalised sphere (D = 1) in a periodic cube of side ``period`` D, driven by a uniform body force ``push``
    [m/s^2] at Re ~ 0.02, to t_end (5 of the mean flow's time constants): (F / (6 pi nu R U), Hasimoto's value,
    F / (push L^3): 1 once steady). The body's own error, apart from the advection and the fringe."""
    n = round(period * d_cells)
    h, side = 1.0 / d_cells, n / d_cells
    box = mac3d.Box((n, n, n), h, (True, True, True))
    dt = 0.9 * h * h / (6 * nu)
    steps = math.ceil(t_end / dt)
    chi = tuple(body3d.ball_fraction(box, (side / 2,) * 3, 0.5, k, ramp=ramp) for k in range(3))
    zero = tuple(jnp.zeros(box.face_shape(k)) for k in range(3))
    r = body3d.Relax(chi, eta * dt, zero, (0.0, 0.0, 0.0))
    force = (jnp.full(box.face_shape(0), push),) + zero[1:]
    s, f = jax.jit(body3d.run, static_argnums=(0, 5))(box, mac3d.initial_state(box), mac3d.Params3(nu=nu, force=force),
                                                      r, dt, steps)
    u = float(jnp.mean(s.vel[0][:-1]))  # the box average (the last face copies the first)
    drag = float(f[-1, 0, 0])
    return drag / (6 * math.pi * nu * 0.5 * u), hasimoto(math.pi / 6 / side**3), drag / (push * side**3)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--d-cells", default="8,12", help="cells per diameter, comma-separated ('': none)")
    ap.add_argument("--widths", default="6", help="box widths in diameters, comma-separated")
    ap.add_argument("--length", type=float, default=10.0, help="box length along the stream [D]")
    ap.add_argument("--upstream", type=float, default=3.0, help="sphere centre from x = 0 (the fringe's exit) [D]")
    ap.add_argument("--fringe", type=float, default=2.0, help="fringe length [D]")
    ap.add_argument("--fringe-rate", type=float, default=4.0, help="fringe relaxation rate [U/D]")
    ap.add_argument("--eta", type=float, default=0.25, help="penalisation time [dt]")
    ap.add_argument("--ramp", type=float, default=1.0, help="the mask's ramp width [cells] (small: a staircase)")
    ap.add_argument("--cfl", type=float, default=1.0, help="the step: CFL at |u| = 1.2")
    ap.add_argument("--t-max", type=float, default=15.0)
    ap.add_argument("--record", default=RECORD, help="the JSON record each row is written to as it runs; a row "
                    "recorded done with the same settings is read from it, not run again ('': no record)")
    ap.add_argument("--table", action="store_true", help="print the recorded rows for these settings (a row still "
                    "running or stopped: its last time unit), run nothing")
    ap.add_argument("--stokes", default="", help="also the Stokes array check on these cells per D (e.g. 4,6,8)")
    args = ap.parse_args(argv)
    if args.stokes:
        prev = prev_n = None
        for n in (int(v) for v in args.stokes.split(",") if v):
            t0 = time.perf_counter()
            ratio, want, steady = stokes_array(n, eta=args.eta, ramp=args.ramp)
            err = ratio / want - 1
            order = f"{math.log(abs(prev / err)) / math.log(n / prev_n):.2f}" if prev else "-"
            print(f"stokes D = {n} cells: F / (6 pi mu R U) {ratio:.4f}, Hasimoto {want:.4f}: {100 * err:+.2f}% "
                  f"(order {order}; F / pushed {steady:.4f}; {time.perf_counter() - t0:.0f} s)", flush=True)
            prev, prev_n = err, n
    try:
        grids = [int(v) for v in args.d_cells.split(",") if v]
        widths = [float(v) for v in args.widths.split(",") if v]
    except ValueError:
        raise SystemExit(f"--d-cells {args.d_cells!r} --widths {args.widths!r}: comma-separated numbers") from None
    if not grids and args.stokes:
        return
    if not grids or min(grids) < 2:
        raise SystemExit(f"--d-cells {args.d_cells}: at least 2 cells per diameter")
    if not widths or min(widths) <= 1.5:
        raise SystemExit(f"--widths {args.widths}: widths > 1.5 diameters (the sphere and its side flow)")
    if not 0.5 < args.upstream < args.length - args.fringe - 0.5:
        raise SystemExit(f"--upstream {args.upstream}: the sphere must lie between x = 0.5 and the fringe "
                         f"(length - fringe - 0.5 = {args.length - args.fringe - 0.5:g})")
    for name in ("fringe", "fringe_rate", "eta", "ramp", "cfl", "t_max"):
        if not getattr(args, name) > 0:
            raise SystemExit(f"--{name.replace('_', '-')} {getattr(args, name)}: must be > 0")
    rows = []
    recorded = {tuple(r[k] for k in KEY): r for r in (load_record(args.record) if args.record else [])}
    done = {key: r for key, r in recorded.items() if r["done"] or args.table}
    for n in grids:
        for w in widths:
            settings = dict(d_cells=n, width=w, length=args.length, upstream=args.upstream, fringe=args.fringe,
                            fringe_rate=args.fringe_rate, eta=args.eta, ramp=args.ramp, cfl=args.cfl,
                            t_max=args.t_max)
            key = tuple(settings[k] for k in KEY)
            if key in done:
                state = "" if done[key]["done"] else f" (not finished: t = {len(done[key]['cd_body'])})"
                print(f"D = {n} cells, width {w:g} D: recorded in {args.record}{state}", flush=True)
                rows.append(done[key])
                continue
            if args.table:
                print(f"D = {n} cells, width {w:g} D: not recorded", flush=True)
                continue
            print(f"D = {n} cells, width {w:g} D:", flush=True)
            t0 = time.perf_counter()
            shape = (round(args.length * n), round(w * n), round(w * n))

            pushed_so_far = []

            def record(history, pushes, finished=False):
                pushed_so_far[:] = pushes
                row = dict(settings, cells=list(shape), cd_body=list(history), cd_push=list(pushes),
                           wall_s=round(time.perf_counter() - t0, 1), done=finished)
                if args.record:
                    save_row(args.record, row)
                return row

            cd, pushed, t, shape, history = drag(n, w, args.length, args.upstream, args.fringe, args.fringe_rate,
                                                 args.eta, args.cfl, args.t_max, ramp=args.ramp,
                                                 log=lambda s: print(s, flush=True), on_chunk=record)
            rows.append(record(history, list(pushed_so_far), finished=True))
    print_table(rows)


def print_table(rows):
    """The rows' table (Cd over the last time unit, its drift per time unit at the end) and, per width with three
    or more grids, the observed order and Richardson limit over the finest three."""
    print(f"\n{'D cells':>7} {'width':>5} {'cells':>14} {'Cd body':>7} {'vs 1.087':>8} {'Cd push':>7} {'vs 1.087':>8}"
          f" {'t':>5} {'drift/t':>7} {'wall s':>6}")
    for r in rows:
        cells = "x".join(map(str, r["cells"]))
        cd, pushed, hist = r["cd_body"][-1], r["cd_push"][-1], r["cd_body"]
        drift = f"{100 * (hist[-1] / hist[-2] - 1):+6.2f}%" if len(hist) > 1 else "-"
        print(f"{r['d_cells']:>7} {r['width']:>5g} {cells:>14} {cd:7.4f} {100 * (cd / REFERENCE_CD - 1):+7.2f}% "
              f"{pushed:7.4f} {100 * (pushed / REFERENCE_CD - 1):+7.2f}% {len(hist):5.1f} {drift:>7} "
              f"{r['wall_s']:6.0f}{'' if r['done'] else ' (not finished)'}")
    for w in sorted({r["width"] for r in rows}):
        same = sorted((r for r in rows if r["width"] == w), key=lambda r: r["d_cells"])[-3:]
        if len({r["d_cells"] for r in same}) < 3:
            continue
        t = min(len(r["cd_body"]) for r in same)  # compared at one time: Cd still drifts
        for name in ("cd_body", "cd_push"):
            fit = richardson([r["d_cells"] for r in same], [r[name][t - 1] for r in same])
            grids = "/".join(str(r["d_cells"]) for r in same)
            if fit is None:
                print(f"width {w:g}, {grids} cells, {name} at t = {t}: no fit C + a h^p with p in (0.05, 12), "
                      "no Richardson limit")
            else:
                print(f"width {w:g}, {grids} cells, {name} at t = {t}: observed order {fit[0]:.2f}, Richardson "
                      f"limit {fit[1]:.4f} ({100 * (fit[1] / REFERENCE_CD - 1):+.2f}% vs 1.087)")

if __name__ == "__main__":
    main()
