"""Generator benchmark: pdestream vs Exponax (ETDRK4, float32) on the issue-6 cases, in one process.

    python -m benchmarks.generator_bench [--quick] [--only burgers1d,ks1d] [--batch B] [--json OUT.json]

Per PDE: trajectories/s and frames/s of ``generator.sample`` (keys -> parameters -> IC -> rollout -> finite
check) and of Exponax (random ICs from the same distribution sampled inside the timed jit, then
``exponax.rollout(stepper, steps, include_init=True)`` vmapped over the batch), alternating runs, medians,
the ratio; compile time (first call minus a steady call); agreement of the two solvers on one initial
condition and each side's error against its own solver at dt/8; step time against the FFT floor (the
transforms our step does, timed alone); first batch and peak memory in fresh processes with a warm
persistent compilation cache; scaling with resolution and batch size. Figures, not pass/fail.

Where the catalog's stable-step rule refuses the issue's dt, the case is adjusted on both sides: Burgers
uses a GRF IC with sigma=20 (max|u0| bound below dx/dt), KS uses nu=1.05 (attractor bound), NS states its
velocity bound. Exponax's vorticity convection has the opposite sign convention (its velocity is
curl(-psi)), so it runs with convection_scale=-1 to solve the same equation.

The 2D and 3D cases (issue 11: burgers2d at 128^2 and burgers3d at 32^3, vector Burgers in advective form, Exponax's
Burgers with conservative=False; grayscott3d at 32^3) give Exponax our 2/3-rule mask (its dealiasing_fraction
keeps |m| <= fraction * (n // 2) - 1, so fraction = (n // 3 + 1.5) / (n // 2)): the same modes on both sides.
Exponax 0.2.0's 3D Burgers is wrong at n >= 24 (a flow independent of z with w = 0 grows a w of 0.3 within
t = 0.1; at n = 16 it agrees with ours to 3e-7, and ours reduces exactly to burgers2d there): its burgers3d
timings are of the same work, its "agree" column is that bug. grayscott3d is the 3D case that agrees.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from pdestream import generator


@dataclass(frozen=True)
class Case:
    overrides: dict  # get_pde overrides at the standard size (dt, t_end, n_frames give steps = n_frames - 1)
    batch: int
    exponax: Callable  # (exponax module, n, dt) -> stepper
    stage_ffts: tuple[int, int]  # (irffts, rffts) of fields our nonlinear term does per stage (FFT floor)
    scales: tuple[int, ...] = (1, 2, 4)  # resolution multiples of the scaling runs (3D: 4x would not fit)


def _our_mask(n: int) -> float:
    """Exponax's dealiasing_fraction that keeps exactly our 2/3-rule modes |m| <= n // 3."""
    return (n // 3 + 1.5) / (n // 2)


def _ns_bound(n: int, dt: float) -> float:
    return 0.999 * (2 * math.pi / n) / dt  # largest velocity bound the CFL rule accepts for this dt


CASES = {
    "burgers1d": Case(
        dict(n=1024, length=1.0, nu="0.01", dt=5e-4, t_end=0.1, n_frames=201, **{"ic.sigma": 20.0}), 64,
        lambda ex, n, dt: ex.stepper.Burgers(1, 1.0, n, dt, diffusivity=0.01, order=4), (1, 1)),
    "ks1d": Case(
        dict(n=256, length=100.0, nu="1.05", dt=0.1, t_end=20.0, n_frames=201), 64,
        lambda ex, n, dt: ex.stepper.KuramotoSivashinskyConservative(1, 100.0, n, dt, fourth_order_scale=1.05, order=4),
        (1, 1)),
    "ns2d": Case(
        dict(n=128, length=2 * math.pi, nu="0.01", dt=0.02, t_end=2.0, n_frames=101, forcing="kolmogorov",
             forcing_amplitude=1.0, forcing_wavenumber=4, drag=0.1, velocity_bound=_ns_bound(128, 0.02)), 16,
        lambda ex, n, dt: ex.stepper.KolmogorovFlowVorticity(
            2, 2 * math.pi, n, dt, diffusivity=0.01, drag=-0.1, injection_mode=4, injection_scale=1.0,
            convection_scale=-1.0, order=4), (2, 2)),
    # u, v and their 4 derivatives in, the 2 components of (u . grad) u out
    "burgers2d": Case(
        dict(n=128, nu="0.05", dt=2.5e-3, t_end=0.25, n_frames=101), 16,
        lambda ex, n, dt: ex.stepper.Burgers(2, 1.0, n, dt, diffusivity=0.05, conservative=False, order=4,
                                             dealiasing_fraction=_our_mask(n)), (6, 2)),
    # u, v, w and their 9 derivatives in, 3 components out
    "burgers3d": Case(
        dict(n=32, nu="0.05", dt=5e-3, t_end=0.5, n_frames=101), 8,
        lambda ex, n, dt: ex.stepper.Burgers(3, 1.0, n, dt, diffusivity=0.05, conservative=False, order=4,
                                             dealiasing_fraction=_our_mask(n)), (12, 3), scales=(1, 2)),
    # u, v in, u v^2 out (Exponax puts -F u, -(F + k) v in its explicit part, we in the exact one)
    "grayscott3d": Case(
        dict(n=32, F="0.04", k="0.06", dt=1.0, t_end=100.0, n_frames=101), 8,
        lambda ex, n, dt: ex.stepper.reaction.GrayScott(3, 0.32, n, dt, diffusivity_1=2e-5, diffusivity_2=1e-5,
                                                        feed_rate=0.04, kill_rate=0.06, order=4,
                                                        dealiasing_fraction=_our_mask(n)), (2, 1), scales=(1, 2)),
}


def case_pde(name: str, scale: int = 1, steps: int | None = None):
    """The case's PDE at resolution n*scale with dt/scale (same CFL number), ``steps`` steps (default: all)."""
    o = dict(CASES[name].overrides)
    dt = o["dt"] / scale
    steps = steps or o["n_frames"] - 1
    o.update(n=o["n"] * scale, dt=dt, t_end=dt * steps, n_frames=steps + 1)
    if name == "ns2d":
        o["velocity_bound"] = _ns_bound(o["n"], dt)
    return generator.get_pde(name, o)


def ours_fn(pde, batch: int):
    idx = np.arange(batch)
    return lambda: generator.sample(pde, idx).u.block_until_ready()


def exponax_stepper(name: str, pde, dt: float | None = None):
    import exponax as ex

    return CASES[name].exponax(ex, pde.n, dt or pde.step_dt)


def exponax_fn(name: str, pde, batch: int):
    import exponax as ex

    stepper, steps = exponax_stepper(name, pde), pde.n_frames - 1
    run = jax.jit(jax.vmap(lambda k: ex.rollout(stepper, steps, include_init=True)(pde.sample_ic(k))))
    keys = jax.random.split(jax.random.key(1), batch)
    return lambda: run(keys).block_until_ready()


def timed(fn, cpu: bool = False) -> float:
    """Wall seconds of fn() (or process CPU seconds: robust when other jobs load the machine)."""
    clock = time.process_time if cpu else time.perf_counter
    t0 = clock()
    fn()
    return clock() - t0


def compare(fns: dict[str, Callable], reps: int) -> dict:
    """First-call time and median steady wall and CPU time of each function, runs alternating."""
    first = {k: timed(f) for k, f in fns.items()}
    wall, cpu = {k: [] for k in fns}, {k: [] for k in fns}
    for _ in range(reps):
        for k, f in fns.items():
            t0, c0 = time.perf_counter(), time.process_time()
            f()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    out = {}
    for k in fns:
        med = statistics.median(wall[k])
        out[k] = {"first_s": first[k], "median_s": med, "cpu_s": statistics.median(cpu[k]),
                  "compile_s": max(first[k] - med, 0.0)}
    return out


def rel_l2(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def accuracy(name: str, pde) -> dict:
    """Both solvers on the IC of sample 0; each against its own solver at dt/8 (whole trajectory, rel. L2)."""
    import exponax as ex

    traj = generator.sample(pde, [0])
    u0, params = traj.u[0, 0], {k: v[0] for k, v in traj.params.items()}
    steps, dt = pde.n_frames - 1, pde.step_dt
    ours_ref = generator.solve(pde.replace(dt=dt / 8), u0, params).u[0]
    theirs = ex.rollout(exponax_stepper(name, pde), steps, include_init=True)(u0)
    fine = ex.RepeatedStepper(exponax_stepper(name, pde, dt / 8), 8)
    theirs_ref = ex.rollout(fine, steps, include_init=True)(u0)
    return {"agree": rel_l2(theirs, traj.u[0]), "err_ours": rel_l2(traj.u[0], ours_ref),
            "err_exponax": rel_l2(theirs, theirs_ref), "refs_agree": rel_l2(theirs_ref, ours_ref)}


def fft_floor_fn(name: str, pde, batch: int):
    """The transforms our rollout does, alone: per step 4 stages x (k irffts + m rffts), per frame 1 irfft."""
    grid, (k, m) = pde.grid, CASES[name].stage_ffts
    v0 = jnp.ones((batch, *grid.kshape), jnp.complex64)

    def step(v, _):
        for _stage in range(4):
            u = grid.irfft(jnp.broadcast_to(v[:, None], (batch, k, *grid.kshape)))
            w = grid.rfft(jnp.broadcast_to(u.sum(1, keepdims=True) * 1e-3, (batch, m, *grid.shape)))
            v = w.sum(1)  # keeps every transform live and the values bounded
        return v, grid.irfft(v)

    run = jax.jit(lambda v: jax.lax.scan(step, v, None, length=pde.n_frames - 1))
    return lambda: jax.block_until_ready(run(v0))


def child(name: str, batch: int | None = None) -> None:
    """(Run in a fresh process.) First batch with the persistent cache in $PDESTREAM_JAX_CACHE; peak memory."""
    generator.enable_compilation_cache(os.environ["PDESTREAM_JAX_CACHE"])
    pde = case_pde(name)
    hwm0 = _vmhwm()
    fn = ours_fn(pde, batch or CASES[name].batch)
    first = timed(fn)
    peak = (_vmhwm() - hwm0) / 2**20
    print(json.dumps({"first_batch_s": first, "second_batch_s": timed(fn), "peak_delta_mb": peak}))


def _vmhwm() -> int:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmHWM"))


def second_process(name: str, batch: int) -> dict:
    """Run ``child`` twice with a fresh cache directory: cold (fills the cache), then warm."""
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "PDESTREAM_JAX_CACHE": cache}
        for label in ("cold", "warm"):
            res = subprocess.run([sys.executable, "-m", "benchmarks.generator_bench", "--child", name,
                                  "--batch", str(batch)],
                                 env=env, capture_output=True, text=True, check=True)
            out[label] = json.loads(res.stdout.strip().splitlines()[-1])
    warm = out["warm"]
    return {"first_batch_cold_s": out["cold"]["first_batch_s"], "first_batch_warm_s": warm["first_batch_s"],
            "warm_start_overhead_s": warm["first_batch_s"] - warm["second_batch_s"], "peak_delta_mb": warm["peak_delta_mb"]}


def bench_case(name: str, reps: int, scaling: bool, batch: int | None = None) -> dict:
    case, pde = CASES[name], case_pde(name)
    steps, batch = pde.n_frames - 1, batch or case.batch
    fns = {"ours": ours_fn(pde, batch), "exponax": exponax_fn(name, pde, batch), "floor": fft_floor_fn(name, pde, batch)}
    t = compare(fns, reps)
    row = {"pde": name, "n": pde.n, "batch": batch, "steps": steps, "dt": pde.step_dt}
    for side in ("ours", "exponax"):
        row[f"{side}_traj_s"] = batch / t[side]["median_s"]
        row[f"{side}_frames_s"] = batch * pde.n_frames / t[side]["median_s"]
        row[f"{side}_cpu_traj_s"] = batch / t[side]["cpu_s"]
        row[f"{side}_compile_s"] = t[side]["compile_s"]
    row["ratio"] = row["ours_traj_s"] / row["exponax_traj_s"]
    row["cpu_ratio"] = row["ours_cpu_traj_s"] / row["exponax_cpu_traj_s"]
    row.update(accuracy(name, pde))
    row["step_us"] = t["ours"]["median_s"] / (batch * steps) * 1e6
    row["floor_us"] = t["floor"]["median_s"] / (batch * steps) * 1e6
    row["step_over_floor"] = row["step_us"] / row["floor_us"]
    row["cpu_step_over_floor"] = t["ours"]["cpu_s"] / t["floor"]["cpu_s"]
    row["bytes_per_traj"] = pde.n_frames * len(pde.FIELDS) * pde.n**pde.NDIM * 4
    row.update(second_process(name, batch))
    if scaling:
        row["resolution"] = scale_runs(name, [(s, max(1, batch // 4)) for s in case.scales], reps)
        row["batch_sizes"] = scale_runs(name, [(1, b) for b in (1, 4, 16, 64) if b <= batch], reps)
    return row


def scale_runs(name: str, grid: list[tuple[int, int]], reps: int, steps: int = 50) -> list[dict]:
    """us per step per sample for (resolution scale, batch) pairs, both sides, ``steps`` steps."""
    out = []
    for scale, batch in grid:
        pde = case_pde(name, scale, steps)
        t = compare({"ours": ours_fn(pde, batch), "exponax": exponax_fn(name, pde, batch)}, max(1, reps // 2))
        us = {k: v["median_s"] / (batch * steps) * 1e6 for k, v in t.items()}
        out.append({"n": pde.n, "batch": batch, "ours_us": us["ours"], "exponax_us": us["exponax"],
                    "ratio": us["exponax"] / us["ours"]})
    return out


def print_table(rows: list[dict]) -> None:
    print(f"{'pde':10} {'N':>5} {'B':>3} {'steps':>5} | {'traj/s ours':>11} {'exponax':>8} {'ratio':>6} | "
          f"{'CPU-s ratio':>11} | {'frames/s':>9} | {'compile s ours/ex':>17}")
    for r in rows:
        print(f"{r['pde']:10} {r['n']:5d} {r['batch']:3d} {r['steps']:5d} | {r['ours_traj_s']:11.1f} "
              f"{r['exponax_traj_s']:8.1f} {r['ratio']:6.2f} | {r['cpu_ratio']:11.2f} | {r['ours_frames_s']:9.0f} | "
              f"{r['ours_compile_s']:8.2f}/{r['exponax_compile_s']:<8.2f}")
    print(f"\n{'pde':10} | {'agree':>7} {'err ours':>8} {'err ex':>8} {'refs':>7} | {'step us':>8} {'floor us':>8} "
          f"{'x floor':>7} {'(CPU)':>6} | {'1st batch cold/warm s':>21} {'warm overhead s':>15} | {'peak MB':>7} {'MB/traj':>7}")
    for r in rows:
        print(f"{r['pde']:10} | {r['agree']:7.1e} {r['err_ours']:8.1e} {r['err_exponax']:8.1e} {r['refs_agree']:7.1e} | "
              f"{r['step_us']:8.2f} {r['floor_us']:8.2f} {r['step_over_floor']:7.2f} {r['cpu_step_over_floor']:6.2f} | "
              f"{r['first_batch_cold_s']:10.2f}/{r['first_batch_warm_s']:<10.2f} {r['warm_start_overhead_s']:15.2f} | "
              f"{r['peak_delta_mb']:7.0f} {r['bytes_per_traj'] / 2**20:7.2f}")
    for r in rows:
        for key in ("resolution", "batch_sizes"):
            if key in r:
                print(f"{r['pde']} {key} (us/step/sample ours/exponax): " + "  ".join(
                    f"N={s['n']} B={s['batch']}: {s['ours_us']:.1f}/{s['exponax_us']:.1f} ({s['ratio']:.2f}x)"
                    for s in r[key]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.generator_bench", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="3 timed runs per side, no scaling runs")
    p.add_argument("--only", default=",".join(CASES), help=f"comma-separated subset of {', '.join(CASES)}")
    p.add_argument("--reps", type=int, default=None, help="timed runs per side (default 7, quick 3)")
    p.add_argument("--batch", type=int, default=None, help="trajectories per batch for every case (default: the "
                   "case's own: 64 in 1D, 16 for ns2d/burgers2d, 8 in 3D)")
    p.add_argument("--json", metavar="OUT.json", help="write the figures as JSON")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.batch is not None and args.batch < 1:
        raise ValueError(f"--batch {args.batch} not allowed; must be >= 1")
    if args.child:
        child(args.child, args.batch)
        return 0
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    bad = [n for n in names if n not in CASES]
    if bad:
        raise ValueError(f"unknown benchmark case(s) {bad}; allowed: {', '.join(CASES)}")
    reps = args.reps or (3 if args.quick else 7)
    rows = []
    for name in names:
        rows.append(bench_case(name, reps, scaling=not args.quick, batch=args.batch))
        print(f"[{name} done]", file=sys.stderr, flush=True)
    print(f"jax {jax.__version__}, {os.cpu_count()} CPU cores, float32, medians of {reps} alternating runs; ratio = "
          "ours/exponax throughput (wall; CPU-s: process CPU time, robust to other load); agree/err: rel. L2 over the "
          "trajectory (ours vs exponax; each vs its own solver at dt/8; refs: the two dt/8 solutions); floor: the "
          "step's FFTs alone; warm overhead: first minus second batch in a fresh process with a warm cache")
    print_table(rows)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"jax": jax.__version__, "cpus": os.cpu_count(), "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
