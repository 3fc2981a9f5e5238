"""PDEArena's smoke set (Gupta & Brandstetter 2022) in PhiFlow 2.1 and in our MAC-grid solver, side by side.

PDEArena's set-up (github.com/pdearena/pdearena, pdedatagen/navier_stokes.py, pdedatagen/configs/
navierstokes2dsmoke.yaml, pdedatagen/scripts/navierstokes_jobs.sh; written here from its settings, not copied):
a closed 32 x 32 box, 128^2 cells, velocity zero on every side (PhiFlow's extrapolation.ZERO), smoke
|Noise(scale 11, smoothness 6)| with BOUNDARY extrapolation, no source; each step of dt 1.5: smoke advected
semi-Lagrangian by the old velocity, buoyancy (0, 0.5) * smoke added at the faces, velocity advected
semi-Lagrangian by itself, explicit diffusion (nu 0.01), pressure projection; the published set keeps the
states after steps 9, 13, ..., 61 (skip_nt 8, sample_rate 4: 14 frames at t = 13.5, 19.5, ..., 91.5 s).

Parts (each writes JSON under benchmarks/results/smoke_phiflow/, resumable: a finished part is not rerun):
  trajectories: from the same initial smoke (drawn with our law, generator.flow.noise), PhiFlow at dt 1.5
    (PDEArena) and at dt 1.5 / 4 (its own time-step error), ours at dt 1.5 (PDEArena's step), at our recipe
    step (cfl 1) on 128^2 and on 256^2 (its own grid error; 256^2 averaged onto 128^2); relative L2 distances
    of smoke and velocity per frame.
  statistics: PhiFlow drawing its own Noise (phi.math.seed per sample, as PDEArena) vs our sampler with the
    recipe's settings: smoke mean / std and velocity magnitude per frame, mean over samples with standard errors.

PhiFlow 2.1 (PDEArena's pin, setup.py: phiflow==2.1) needs numpy < 1.24 (np.object), jax needs a newer numpy:
PhiFlow runs in its own interpreter (``--phi-python``, e.g. a venv with numpy==1.23.5 phiflow==2.1.0), this file
calling itself with ``--phiflow-worker`` and exchanging .npz files. Run:
  python -m benchmarks.smoke_phiflow_validation --part trajectories --samples 3 --phi-python .venv-phi/bin/python
  python -m benchmarks.smoke_phiflow_validation --part statistics --ours 64 --phi 32 --phi-python ...
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

L, N, DT, NU, BUOYANCY = 32.0, 128, 1.5, 0.01, 0.5  # PDEArena's box, cells, step, viscosity, buoyancy
FRAME_STEPS = [9 + 4 * j for j in range(14)]  # PDEArena's kept states: after these steps of DT
SCALE, SMOOTHNESS = 11.0, 6.0
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "smoke_phiflow")


# --- PhiFlow side (runs under PhiFlow's interpreter: numpy and phi only) -----------------------------------
def phiflow_worker(inp: str, out: str) -> None:
    """Run PDEArena's loop in PhiFlow 2.1 for each row of ``inp`` (npz: smoke0 [B, n, n] (x, y) or seeds [B],
    n, substeps); write smoke, u, v [B, 14, n, n] (x, y; u on left faces, v on bottom faces) and smoke0."""
    from phi import math
    from phi.flow import Box, CenteredGrid, Noise, StaggeredGrid, advect, diffuse, extrapolation, fluid
    from phi.math import seed as phi_seed

    d = np.load(inp)
    n, sub = int(d["n"]), int(d["substeps"])
    dt = DT / sub
    bounds = Box[0:L, 0:L]
    rows = len(d["smoke0"]) if "smoke0" in d else len(d["seeds"])
    res = {k: np.zeros((rows, len(FRAME_STEPS), n, n), np.float32) for k in ("smoke", "u", "v")}
    res["smoke0"] = np.zeros((rows, n, n), np.float32)
    res["seconds"] = np.zeros(rows)
    for b in range(rows):
        t0 = time.time()
        if "smoke0" in d:
            smoke = CenteredGrid(math.tensor(d["smoke0"][b], math.spatial("x,y")), extrapolation.BOUNDARY,
                                 bounds=bounds)
        else:  # PDEArena's draw: phi's global seed, then |Noise| sampled at the cell centres
            phi_seed(int(d["seeds"][b]))
            smoke = abs(CenteredGrid(Noise(scale=SCALE, smoothness=SMOOTHNESS), extrapolation.BOUNDARY, x=n, y=n,
                                     bounds=bounds))
        res["smoke0"][b] = smoke.values.numpy("x,y")
        velocity = StaggeredGrid(0, extrapolation.ZERO, x=n, y=n, bounds=bounds)
        j = 0
        for i in range(1, FRAME_STEPS[-1] * sub + 1):
            smoke = advect.semi_lagrangian(smoke, velocity, dt)
            force = (smoke * (0, BUOYANCY)).at(velocity)
            velocity = advect.semi_lagrangian(velocity, velocity, dt) + dt * force
            velocity = diffuse.explicit(velocity, NU, dt)
            velocity, _ = fluid.make_incompressible(velocity)
            if i == FRAME_STEPS[j] * sub:
                st = velocity.staggered_tensor().numpy("x,y,vector")[:-1, :-1]
                res["smoke"][b, j], res["u"][b, j], res["v"][b, j] = smoke.values.numpy("x,y"), st[..., 0], st[..., 1]
                j += 1
        res["seconds"][b] = time.time() - t0
        print(f"phiflow row {b + 1}/{rows}: {res['seconds'][b]:.1f} s", flush=True)
    np.savez(out, **res)


def run_phiflow(python: str, n: int, substeps: int, smoke0=None, seeds=None) -> dict:
    """PhiFlow's runs through ``python`` (an interpreter with phiflow 2.1): {smoke, u, v, smoke0, seconds}."""
    with tempfile.TemporaryDirectory() as tmp:
        inp, out = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        data = {"n": n, "substeps": substeps}
        data.update({"smoke0": np.asarray(smoke0, np.float32)} if smoke0 is not None else {"seeds": np.asarray(seeds)})
        np.savez(inp, **data)
        subprocess.run([python, os.path.abspath(__file__), "--phiflow-worker", inp, out], check=True)
        with np.load(out) as f:
            return {k: f[k] for k in f.files}


# --- our side ------------------------------------------------------------------------------------------------
def _flow():
    import importlib

    import jax
    import jax.numpy as jnp

    step = importlib.import_module("pdestream.generator.flow.step")  # the package exports a function `step`
    from pdestream.generator.flow.grid import Geometry, Params
    return jax, jnp, step, Geometry, Params


def run_ours(smoke0: np.ndarray, n: int, substeps: int, advection: str = "semi_lagrangian", frames: int = 14) -> dict:
    """Our solver from initial smoke [B, n, n] (x, y) in the closed box, steps of DT / substeps: smoke, u, v
    [B, frames, n, n] at PDEArena's first ``frames`` frame times (u on left faces, v on bottom faces, as
    PhiFlow's)."""
    jax, jnp, step, Geometry, Params = _flow()
    geom = Geometry(n, n, L, L, "wall", "wall", "wall", "wall")
    fp = Params(nu=jnp.float32(NU), buoyancy=jnp.float32(BUOYANCY), source=(0.0, 0.0, 0.0, 0.0))
    op = step.operator(geom, fp)
    dt = jnp.float32(DT / substeps)
    advance = jax.jit(lambda s, k: step.run_counted(geom, s, fp, dt, k, op, max_iter=200, advection=advection))
    out = {k: np.zeros((len(smoke0), frames, n, n), np.float32) for k in ("smoke", "u", "v")}
    out["seconds"] = np.zeros(len(smoke0))
    out["capped"] = np.zeros(len(smoke0), np.int64)
    for b, s0 in enumerate(smoke0):
        t0 = time.time()
        state = step.initial_state(geom, fp)._replace(smoke=jnp.asarray(s0.T, jnp.float32))
        done = 0
        for j, k in enumerate(FRAME_STEPS[:frames]):
            state = advance(state, jnp.int32((k - done) * substeps))
            done = k
            out["smoke"][b, j], out["u"][b, j], out["v"][b, j] = (np.asarray(state.smoke).T, np.asarray(state.u)[:, :-1].T,
                                                                  np.asarray(state.v)[:-1].T)
        out["seconds"][b], out["capped"][b] = time.time() - t0, int(state.capped)
    return out


def coarsen(run: dict) -> dict:
    """A 2n run on n cells: smoke averaged over 2 x 2 cells, u and v over the 2 fine faces of each coarse face."""
    s, u, v = run["smoke"], run["u"], run["v"]
    return {"smoke": 0.25 * (s[..., 0::2, 0::2] + s[..., 1::2, 0::2] + s[..., 0::2, 1::2] + s[..., 1::2, 1::2]),
            "u": 0.5 * (u[..., 0::2, 0::2] + u[..., 0::2, 1::2]), "v": 0.5 * (v[..., 0::2, 0::2] + v[..., 1::2, 0::2])}


def initial_smoke(n_samples: int, seed: int = 0, factor: int = 2):
    """Signed noise drawn with our law at 128^2 (keys fold_in(key(seed), i)), and |.| on 128^2 and on (factor 128)^2
    (the same field, Fourier-interpolated: the draw is band-limited)."""
    import jax

    from pdestream.generator.flow.noise import signed_noise
    f = np.stack([np.asarray(signed_noise(jax.random.fold_in(jax.random.key(seed), i), (N, N), (L, L), SCALE,
                                          SMOOTHNESS)) for i in range(n_samples)]).astype(np.float64)
    hat = np.fft.fftshift(np.fft.fft2(f), axes=(-2, -1))
    big = np.zeros((n_samples, factor * N, factor * N), complex)
    at = (factor - 1) * N // 2  # where the zero mode of the 128^2 spectrum goes in the finer one (fftshift order)
    big[:, at: at + N, at: at + N] = hat
    fine = factor**2 * np.real(np.fft.ifft2(np.fft.ifftshift(big, axes=(-2, -1))))
    return np.abs(f).astype(np.float32), np.abs(fine).astype(np.float32)


def restrict(run: dict, factor: int) -> dict:
    """A (factor 128)^2 run on 128^2 through the recipe's own restriction (``FlowProblem.restrict``: block means,
    face fluxes): {smoke, u, v} [B, T, 128, 128]."""
    from pdestream import generator

    if factor == 1:
        return {k: run[k] for k in ("smoke", "u", "v")}
    # (the restriction reads only the fields' places and the factor: a viscosity any refine accepts builds it)
    pde = generator.get_pde("smoke_box2d", n=N, length=L, refine=factor, nu="1")
    stacked = np.stack([run["u"], run["v"], np.zeros_like(run["u"]), run["smoke"]], axis=2)  # FIELDS: u, v, p, smoke
    out = np.asarray(pde.restrict(stacked))
    return {"u": out[:, :, 0], "v": out[:, :, 1], "smoke": out[:, :, 3]}


def resolution(args) -> dict:
    """The recipe's grid against finer and coarser ones from the same initial smoke (drawn on 128^2, Fourier-
    interpolated), each at its own CFL-0.5 step with the recipe's MacCormack advection, restricted to 128^2 like
    the recipe: relative L2 distances per frame to the finest run. Each grid's run is kept (npz, resumable)."""
    factors = [int(k) for k in args.factors.split(",")]
    runs, seconds = {}, {}
    for k in factors:
        path = os.path.join(OUT, f"resolution_x{k}_s{args.samples}_f{args.frames}.npz")
        if not os.path.exists(path):
            smoke0 = initial_smoke(args.samples, factor=k)[1] if k > 1 else initial_smoke(args.samples)[0]
            substeps = 48 * k  # steps per 1.5 s: CFL 0.5 at 4 m/s on (128 k)^2 (h 0.25 / k m, step 1.5 / (48 k) s)
            run = run_ours(smoke0, N * k, substeps, advection="maccormack", frames=args.frames)
            np.savez(path, **restrict(run, k), seconds=run["seconds"], capped=run["capped"])
            print(f"x{k}: {np.mean(run['seconds']):.0f} s a sample", flush=True)
        with np.load(path) as f:
            runs[k] = {name: f[name] for name in f.files}
        seconds[k] = float(np.mean(runs[k]["seconds"]))
    finest = max(factors)
    return {"samples": args.samples, "frame_times": [DT * k for k in FRAME_STEPS[:args.frames]],
            "steps_s": {f"{N * k}^2": DT / (48 * k) for k in factors},
            "seconds_per_sample": {f"{N * k}^2": seconds[k] for k in factors},
            "capped_solves": {f"{N * k}^2": int(runs[k]["capped"].sum()) for k in factors},
            "distance_to_finest": {f"{N * k}^2 vs {N * finest}^2": rel(runs[k], runs[finest])
                                   for k in factors if k != finest},
            "distance_to_next": {f"{N * a}^2 vs {N * b}^2": rel(runs[a], runs[b])
                                 for a, b in zip(factors, factors[1:])}}


def rel(a: dict, b: dict) -> dict:
    """Relative L2 distances per frame, mean over samples: smoke, and velocity (u and v together), of a against b."""
    ds = np.sqrt(((a["smoke"] - b["smoke"]) ** 2).sum((-2, -1)) / (b["smoke"] ** 2).sum((-2, -1)))
    num = ((a["u"] - b["u"]) ** 2 + (a["v"] - b["v"]) ** 2).sum((-2, -1))
    dv = np.sqrt(num / (b["u"] ** 2 + b["v"] ** 2).sum((-2, -1)))
    return {"smoke": ds.mean(0).round(4).tolist(), "velocity": dv.mean(0).round(4).tolist()}


def trajectories(args) -> dict:
    """Same-IC comparison (see the module docstring)."""
    s128, s256 = initial_smoke(args.samples)
    t0 = time.time()
    runs = {"phiflow_dt1.5": run_phiflow(args.phi_python, N, 1, smoke0=s128),
            "phiflow_dt0.375": run_phiflow(args.phi_python, N, 4, smoke0=s128),
            "ours_dt1.5": run_ours(s128, N, 1),
            "ours_128": run_ours(s128, N, args.substeps),
            "ours_256": run_ours(s256, 2 * N, 2 * args.substeps)}
    fine = coarsen(runs["ours_256"])
    out = {"samples": args.samples, "frame_times": [DT * k for k in FRAME_STEPS],
           "our_step_128": DT / args.substeps, "our_step_256": DT / (2 * args.substeps),
           "seconds_per_sample": {k: float(np.mean(r["seconds"])) for k, r in runs.items()},
           "capped_solves": {k: int(r["capped"].sum()) for k, r in runs.items() if "capped" in r},
           "max_speed": {k: float(max(np.abs(r["u"]).max(), np.abs(r["v"]).max())) for k, r in runs.items()},
           "distance": {
               "phiflow_dt1.5 vs phiflow_dt0.375 (PhiFlow's step error)": rel(runs["phiflow_dt1.5"], runs["phiflow_dt0.375"]),
               "ours_128 vs ours_256 (our grid error)": rel(runs["ours_128"], fine),
               "ours_dt1.5 vs ours_128 (our step error at PDEArena's dt)": rel(runs["ours_dt1.5"], runs["ours_128"]),
               "ours_dt1.5 vs phiflow_dt1.5 (same dt, same grid)": rel(runs["ours_dt1.5"], runs["phiflow_dt1.5"]),
               "ours_128 vs phiflow_dt1.5 (recipe vs PDEArena)": rel(runs["ours_128"], runs["phiflow_dt1.5"]),
               "ours_128 vs phiflow_dt0.375": rel(runs["ours_128"], runs["phiflow_dt0.375"]),
               "ours_256 vs phiflow_dt0.375": rel(fine, runs["phiflow_dt0.375"]),
           },
           "smoke_total_change": {k: float(np.mean(r["smoke"][:, -1].sum((-2, -1)) / (4 if k == "ours_256" else 1)
                                                   / s128.sum((-2, -1)) - 1)) for k, r in runs.items()},
           "wall_s": time.time() - t0}
    return out


def moments(smoke, u, v) -> dict:
    """Per frame over samples: mean and standard error of the spatial smoke mean, smoke std, mean speed."""
    uc = 0.5 * (u + np.concatenate([u[..., 1:, :], np.zeros_like(u[..., :1, :])], -2))  # face -> centre (wall 0)
    vc = 0.5 * (v + np.concatenate([v[..., 1:], np.zeros_like(v[..., :1])], -1))
    per = {"smoke_mean": smoke.mean((-2, -1)), "smoke_std": smoke.std((-2, -1)),
           "speed_mean": np.sqrt(uc**2 + vc**2).mean((-2, -1))}
    b = smoke.shape[0]
    return {k: {"mean": x.mean(0).round(4).tolist(), "stderr": (x.std(0, ddof=1) / math.sqrt(b)).round(4).tolist()}
            for k, x in per.items()}


def statistics(args) -> dict:
    """PhiFlow's own draws (PDEArena's seeding) against our recipe's samples (the sampler's pipeline)."""
    path = os.path.join(OUT, "statistics_phiflow_rows.npz")
    if os.path.exists(path):  # resumable: PhiFlow rows done so far
        with np.load(path) as f:
            phi = {k: f[k] for k in f.files}
    else:
        phi = None
    t0 = time.time()
    seeds = np.random.RandomState(1234).randint(np.iinfo(np.int32).max, size=args.phi) + np.arange(args.phi)
    done = 0 if phi is None else len(phi["smoke"])
    for start in range(done, args.phi, 8):
        part = run_phiflow(args.phi_python, N, 1, seeds=seeds[start:start + 8])
        phi = part if phi is None else {k: np.concatenate([phi[k], part[k]]) for k in ("smoke", "u", "v", "smoke0", "seconds")}
        np.savez(path, **{k: phi[k] for k in ("smoke", "u", "v", "smoke0", "seconds")})
    phi_s = time.time() - t0
    if args.phi_only:
        return {"phiflow_rows": int(len(phi["smoke"]))}
    t1 = time.time()
    ours = sample_recipe(args.ours, args.substeps)
    phi = {k: v[:args.phi] for k, v in phi.items()}
    return {"phiflow_samples": int(len(phi["smoke"])), "our_samples": int(len(ours["smoke"])),
            "frame_times": [DT * k for k in FRAME_STEPS], "our_step": DT / args.substeps,
            "phiflow": moments(phi["smoke"], phi["u"], phi["v"]), "ours": moments(ours["smoke"], ours["u"], ours["v"]),
            "initial_smoke_mean": {"phiflow": float(phi["smoke0"].mean()),
                                   "ours (the law, 256 draws)": float(initial_smoke(256)[0].mean())},
            "phiflow_seconds_per_sample": float(np.mean(phi["seconds"])), "phiflow_wall_s_this_run": phi_s,
            "ours_wall_s": time.time() - t1, "ours_failed": ours["failed"]}


def sample_recipe(count: int, substeps: int) -> dict:
    """``count`` samples (seed 0) of smoke_box2d with PDEArena's settings through the sampler, in PDEArena's layout.
    The family refuses these settings (cell Reynolds number 100 > 40: docs/results/recipes.md); here its guard is
    lifted for the measurement, which changes no bit of a sample."""
    import dataclasses

    from pdestream.generator.flow.entries import SmokeBox2D
    from pdestream.generator.sampler import sample

    @dataclasses.dataclass(frozen=True)
    class Unguarded(SmokeBox2D):
        MAX_CELL_REYNOLDS = 1e9  # a class attribute, not a setting (no annotation)

    pde = Unguarded().replace({"n": N, "length": L, "buoyancy": "0.5", "nu": "0.01",
                               "ic": {"kind": "noise", "scale": SCALE, "smoothness": SMOOTHNESS},
                               "advection": "semi_lagrangian", "t_start": DT * FRAME_STEPS[0],
                               "t_end": DT * FRAME_STEPS[-1], "n_frames": len(FRAME_STEPS),
                               "cfl": math.sqrt(BUOYANCY * L) * (DT / substeps) / (L / N)})  # step DT / substeps
    path = os.path.join(OUT, "statistics_ours_rows.npz")  # resumable: our rows done so far
    u = np.load(path)["u"] if os.path.exists(path) else np.zeros((0, len(FRAME_STEPS), 4, N, N), np.float32)
    failed = 0
    for start in range(len(u), count, 8):  # in pieces of 8, each saved
        part = np.asarray(sample(pde, np.arange(start, min(count, start + 8)), seed=0, on_blowup="skip").u)
        failed += min(count, start + 8) - start - len(part)
        u = np.concatenate([u, part])
        np.savez(path, u=u)
        print(f"ours: {len(u)}/{count}", flush=True)
    u = u[:count]
    return {"smoke": u[:, :, 3], "u": u[:, :, 0], "v": u[:, :, 1], "failed": failed}


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--phiflow-worker":
        phiflow_worker(sys.argv[2], sys.argv[3])
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--part", choices=("trajectories", "statistics", "resolution"), required=True)
    ap.add_argument("--samples", type=int, default=3, help="same-IC trajectories")
    ap.add_argument("--phi", type=int, default=32, help="PhiFlow samples for the statistics")
    ap.add_argument("--ours", type=int, default=64, help="our samples for the statistics")
    ap.add_argument("--substeps", type=int, default=24, help="our steps per 1.5 s on 128^2 (24: 0.0625 s, CFL 1 at 4 m/s)")
    ap.add_argument("--phi-only", action="store_true", help="statistics: make the PhiFlow rows only (resumable)")
    ap.add_argument("--phi-python", default=os.environ.get("PHIFLOW_PYTHON", ".venv-phi/bin/python"))
    ap.add_argument("--factors", default="1,2,3,4", help="resolution: grids 128 k for these k (the last the reference)")
    ap.add_argument("--frames", type=int, default=3, help="resolution: PDEArena's first frames run (3: t <= 25.5)")
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    path = os.path.join(OUT, f"{args.part}{'_phiflow_rows' if args.phi_only else ''}.json")
    if args.part == "resolution":
        path = os.path.join(OUT, f"resolution_s{args.samples}_f{args.frames}.json")
    result = {"trajectories": trajectories, "statistics": statistics, "resolution": resolution}[args.part](args)
    result["load_average"] = os.getloadavg()
    with open(path, "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
