"""pdebench_diffusion_sorption1d against PDEBench's generator: ``python -m benchmarks.diffusion_sorption1d_validation
--pdebench DIR [--only pdebench_stats,tight_stats,same_ic,stats,report] [--samples 256] [--minutes 10]``.

pdebench_stats: PDEBench's own Simulator (src/sim_diff_sorp.py of the pdebench 0.1.0 wheel: np.random.seed(seed),
u0 = U(0, 0.2) in every cell, scipy's RK45 at its default tolerances) for seeds 0, 1, ...; per seed its draw and
the spatial mean / std of u at every REPORT_EVERY-th frame, one JSON line each in RESULTS/pdebench_seeds.jsonl
(resumable: seeds already there are skipped; ``--minutes`` bounds one call). tight_stats: the same with PDEBench's
scheme solved tightly (below), RESULTS/pdebench_tight_seeds.jsonl. same_ic: PDEBench's seed-0 IC given to both
solvers: PDEBench's Simulator as published (RK45 at scipy's default rtol 1e-3) and the same Simulator with its
solve_ivp swapped for Radau at rtol 1e-8 (its scheme solved tightly) at 1024, 2048, 4096 cells; ours at the same
grids and at dt / 4; relative L2 of each against its own finer or tighter run, and of the two against each other,
with the bound the two errors set (triangle inequality), RESULTS/same_ic.json. stats: the recipe's samples (its
train split's seed 0) summarised like PDEBench's, RESULTS/ours_seeds.jsonl (resumable in blocks). report: the
sets' per-frame mean and std across samples with their sampling errors, and ours and the tight scheme re-run at
PDEBench's own draws (paired: the solvers' difference without sampling error), RESULTS/stats.json. Figures, and
one verdict each (docs/results/recipes.md).

--pdebench DIR: a directory holding PDEBench's ``pdebench`` package (the pdebench 0.1.0 wheel unpacked, or its git
tag: ``git archive v0.1.0 pdebench | tar -x -C DIR``; this module needs numpy and scipy only). Not its later code:
from 2025 on ``sim_diff_sorp`` draws u0 with ``np.random.default_rng(seed)``, another sample per seed than the
published set's (``pdebench_draw``), which the rows here would then mislabel. PDEBench is not part of pdestream and is not imported otherwise.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

# PDEBench's diff-sorp.yaml (sim:) and the published set's time sampling (101 frames: config_diff-sorp.yaml t_train)
CONSTS = {"D": 5e-4, "por": 0.29, "rho_s": 2880.0, "k_f": 3.5e-4, "n_f": 0.874, "sol": 1.0}
T_END, N_FRAMES, N = 500.0, 101, 1024
REPORT_EVERY = 5  # frames kept in the per-seed summaries: t = 0, 25, ..., 500
RESULTS = Path(__file__).parent / "results" / "diffusion_sorption1d"


def pdebench_solve(root: str, seed: int, n: int = N, u0: float | None = None) -> np.ndarray:
    """PDEBench's own Simulator for ``seed`` on n cells: frames [T, n] float64 at linspace(0, 500, 101). ``u0``:
    its constant initial value instead of the seed's draw (the draw is replaced after the Simulator makes it)."""
    if root not in sys.path:
        sys.path.insert(0, root)
    from pdebench.data_gen.src.sim_diff_sorp import Simulator

    sim = Simulator(**CONSTS, t=T_END, tdim=N_FRAMES, x_left=0.0, x_right=1.0, xdim=n, seed=seed)
    if u0 is None:
        return sim.generate_sample()[..., 0]
    real = np.random.uniform  # its draw is np.random.uniform(0, 0.2) after np.random.seed(seed)
    try:
        np.random.uniform = lambda *a, **k: u0
        return sim.generate_sample()[..., 0]
    finally:
        np.random.uniform = real


def pdebench_tight(root: str, seed: int, n: int, u0: float | None = None, rtol: float = 1e-8) -> np.ndarray:
    """``pdebench_solve`` with PDEBench's solve_ivp call made Radau (implicit) at ``rtol`` (atol rtol / 100) and a
    tridiagonal Jacobian pattern: its own right-hand side (rc_ode) and IC, solved to ~rtol: frames [T, n]."""
    import functools

    from scipy.integrate import solve_ivp
    from scipy.sparse import diags

    if root not in sys.path:
        sys.path.insert(0, root)
    from pdebench.data_gen.src import sim_diff_sorp

    pattern = diags([np.ones(n - 1), np.ones(n), np.ones(n - 1)], [-1, 0, 1])
    real = sim_diff_sorp.solve_ivp
    try:
        sim_diff_sorp.solve_ivp = functools.partial(solve_ivp, method="Radau", rtol=rtol, atol=rtol / 100,
                                                    jac_sparsity=pattern)
        return pdebench_solve(root, seed, n, u0)
    finally:
        sim_diff_sorp.solve_ivp = real


def ours(u0: np.ndarray, n: int, dt: float = 0.25) -> np.ndarray:
    """The recipe's solver (float32, as shipped) from constants u0 [S] on n cells at step dt: frames [S, T, n]."""
    from pdestream import generator

    pde = generator.get_pde("pdebench_diffusion_sorption1d", n=n, dt=dt)
    p = {k: [float(pde.param_domains[k].bounds[0])] * len(u0) for k in pde.PARAMS}
    start = np.repeat(np.asarray(u0, np.float32)[:, None, None], n, -1)
    return np.asarray(generator.solve(pde, start, p).u[:, :, 0], np.float64)


def restrict(u: np.ndarray, n: int) -> np.ndarray:
    """Cell averages [..., m] -> [..., n] (m a multiple of n): the finite-volume restriction."""
    return u.reshape(*u.shape[:-1], n, u.shape[-1] // n).mean(-1)


def rel(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative L2 of a against b over space: [T]."""
    return np.sqrt(((a - b) ** 2).sum(-1) / (b**2).sum(-1))


def pdebench_draw(seed: int) -> float:
    """The published set's u0 value for ``seed`` (pdebench 0.1.0: np.random.seed(seed); np.random.uniform(0, 0.2))."""
    return float(np.random.RandomState(seed).uniform(0, 0.2))


def summary(u: np.ndarray) -> dict:
    """Frames [T, n] -> {"mean": [T'], "std": [T']} over x at every REPORT_EVERY-th frame (6 significant digits)."""
    keep = u[::REPORT_EVERY]
    return {"mean": [float(f"{v:.6g}") for v in keep.mean(-1)], "std": [float(f"{v:.6g}") for v in keep.std(-1)]}


def _done(path: Path) -> dict[int, dict]:
    if not path.exists():
        return {}
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return {r["seed"]: r for r in rows}


def pdebench_stats(root: str, samples: int, minutes: float, tight: bool = False) -> None:
    """PDEBench's seeds 0..samples-1 summarised, one JSON line each (resumable); ``tight``: its scheme solved by
    Radau at rtol 1e-8 (``pdebench_tight``, ~1 s a seed) into pdebench_tight_seeds.jsonl instead."""
    path = RESULTS / ("pdebench_tight_seeds.jsonl" if tight else "pdebench_seeds.jsonl")
    done = _done(path)
    stop = time.monotonic() + 60 * minutes
    for seed in range(samples):
        if seed in done:
            continue
        if time.monotonic() > stop:
            print(f"pdebench_stats: stopped at --minutes {minutes:g}; {len(done)} of {samples} seeds done (rerun to go on)")
            return
        t0 = time.perf_counter()
        u = pdebench_tight(root, seed, N) if tight else pdebench_solve(root, seed)
        row = {"seed": seed, "u0": pdebench_draw(seed), "seconds": round(time.perf_counter() - t0, 2),
               "finite": bool(np.isfinite(u).all()), **summary(u)}
        with path.open("a") as f:
            f.write(json.dumps(row) + "\n")
        done[seed] = row
        if not tight:
            print(f"pdebench seed {seed}: u0 {row['u0']:.4f}, {row['seconds']:.1f} s", flush=True)
    print(f"pdebench_stats{' (tight)' if tight else ''}: {samples} seeds done")


REPORT_T = (5.0, 10.0, 25.0, 50.0, 100.0, 250.0, 500.0)


def same_ic(root: str, seed: int, with_2048: bool) -> None:
    """PDEBench's seed's IC in both solvers; writes RESULTS/same_ic.json and prints the table."""
    frames = [int(round(t / T_END * (N_FRAMES - 1))) for t in REPORT_T]
    u0 = pdebench_draw(seed)
    clock, runs = {}, {}
    for name, fn in (("pdebench 1024", lambda: pdebench_solve(root, seed, 1024)),
                     *((("pdebench 2048", lambda: pdebench_solve(root, seed, 2048)),) if with_2048 else ()),
                     *((f"pdebench tight {m}", functools.partial(pdebench_tight, root, seed, m)) for m in (1024, 2048, 4096)),
                     ("ours 1024 compile", lambda: ours([u0], 1024)[0]),
                     *((f"ours {m}", functools.partial(lambda m: ours([u0], m)[0], m)) for m in (1024, 2048, 4096)),
                     ("ours 1024 dt/4", lambda: ours([u0], 1024, 0.0625)[0])):
        t0 = time.perf_counter()
        runs[name] = fn()
        clock[name] = round(time.perf_counter() - t0, 2)
        print(f"  {name}: {clock[name]:.1f} s", flush=True)
    pb, pbt, us = runs["pdebench 1024"], runs["pdebench tight 1024"], runs["ours 1024"]
    rows = {
        "PDEBench's time error: Simulator(1024) vs the same, Radau rtol 1e-8": rel(pb, pbt),
        "PDEBench's space error: tight(1024) vs tight(2048) averaged": rel(pbt, restrict(runs["pdebench tight 2048"], 1024)),
        "  the same at 2048: tight(2048) vs tight(4096) averaged": rel(runs["pdebench tight 2048"],
                                                                      restrict(runs["pdebench tight 4096"], 2048)),
        "our space error: ours(1024) vs ours(2048) averaged": rel(us, restrict(runs["ours 2048"], 1024)),
        "  the same at 2048: ours(2048) vs ours(4096) averaged": rel(runs["ours 2048"], restrict(runs["ours 4096"], 2048)),
        "our time error: ours(dt 0.25) vs ours(dt 0.0625), 1024": rel(us, runs["ours 1024 dt/4"]),
        "ours(1024) vs PDEBench's Simulator(1024): the recipe vs the published generator": rel(us, pb),
        "ours(4096) vs PDEBench tight(4096), averaged to 1024: the two schemes' limits": rel(
            restrict(runs["ours 4096"], 1024), restrict(runs["pdebench tight 4096"], 1024)),
    }
    if with_2048:
        rows["PDEBench's Simulator(1024) vs Simulator(2048) averaged: its own finer run"] = rel(
            pb, restrict(runs["pdebench 2048"], 1024))
        rows["  Simulator(2048) vs tight(2048): its time error at 2048"] = rel(runs["pdebench 2048"],
                                                                             runs["pdebench tight 2048"])
    # first order at PDEBench's ends (the ratio of its two space rows ~2), second order ours (~4): the error of a
    # run is its difference from the finer run times 2 / (2 - 1) resp. 4 / (4 - 1)
    err_pb = rows["PDEBench's time error: Simulator(1024) vs the same, Radau rtol 1e-8"] + 2 * rows[
        "PDEBench's space error: tight(1024) vs tight(2048) averaged"]
    err_us = (4 / 3) * rows["our space error: ours(1024) vs ours(2048) averaged"] + rows[
        "our time error: ours(dt 0.25) vs ours(dt 0.0625), 1024"]
    gap = rows["ours(1024) vs PDEBench's Simulator(1024): the recipe vs the published generator"]
    rows["bound: PDEBench's error + ours (time + space, Richardson)"] = err_pb + err_us
    within = bool((gap[1:] <= err_pb[1:] + err_us[1:]).all())  # frames after t = 0 (t = 0: the IC in float32)
    print(f"same IC (PDEBench's seed {seed}: u0 = {u0:.5f}), relative L2 at t = " + ", ".join(f"{t:g}" for t in REPORT_T))
    for name, err in rows.items():
        print(f"  {err[frames][0]:.2e} " + " ".join(f"{e:.2e}" for e in err[frames][1:]) + f"  {name}")
    print(f"  the recipe within the two solvers' errors at every frame after t = 0: {within} (largest ratio "
          f"{(gap[1:] / (err_pb[1:] + err_us[1:])).max():.2f}); max u: PDEBench "
          f"{pb.max():.4f}, ours {us.max():.4f}" + (f", PDEBench at 2048 {runs['pdebench 2048'].max():.4f}" if with_2048 else ""))
    out = {"seed": seed, "u0": u0, "t": list(REPORT_T), "seconds": clock, "within_bound": within,
           "largest_gap_over_bound": round(float((gap[1:] / (err_pb[1:] + err_us[1:])).max()), 3),
           "max_u": {k: float(v.max()) for k, v in runs.items() if "compile" not in k},
           "rel_l2": {k: [float(f"{e:.4g}") for e in v[frames]] for k, v in rows.items()}}
    (RESULTS / "same_ic.json").write_text(json.dumps(out, indent=1) + "\n")


def ours_stats(samples: int, block: int = 16) -> None:
    """The recipe's train-split samples 0..samples-1 summarised (RESULTS/ours_seeds.jsonl, resumable by block)."""
    from pdestream import generator

    path = RESULTS / "ours_seeds.jsonl"
    done = _done(path)
    pde = generator.get_pde("pdebench_diffusion_sorption1d")
    for start in range(0, samples, block):
        todo = [i for i in range(start, min(start + block, samples)) if i not in done]
        if not todo:
            continue
        t0 = time.perf_counter()
        traj = generator.sample(pde, todo, seed=0)
        u = np.asarray(traj.u[:, :, 0], np.float64)
        with path.open("a") as f:
            for j, i in enumerate(todo):
                f.write(json.dumps({"seed": i, "u0": float(u[j, 0, 0]), "finite": bool(np.isfinite(u[j]).all()),
                                    **summary(u[j])}) + "\n")
        print(f"ours samples {todo[0]}..{todo[-1]}: {time.perf_counter() - t0:.1f} s", flush=True)


def report(root: str | None) -> None:
    """Per-frame mean over samples of each sample's spatial mean and std, with sampling errors, PDEBench's set
    against ours; and, at PDEBench's own draws (paired: no sampling error), ours and (with ``root``) PDEBench's
    scheme solved tightly against its Simulator's samples. Writes RESULTS/stats.json."""
    pb, us = _done(RESULTS / "pdebench_seeds.jsonl"), _done(RESULTS / "ours_seeds.jsonl")
    if not pb or not us:
        print("report: run pdebench_stats and stats first")
        return
    t = [float(v) for v in np.linspace(0, T_END, N_FRAMES)[::REPORT_EVERY]]
    out = {"t": t, "n_pdebench": len(pb), "n_ours": len(us)}
    for what in ("mean", "std"):
        a = np.array([r[what] for r in pb.values()])
        b = np.array([r[what] for r in us.values()])
        se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
        tiny = se <= 1e-9 + 1e-7 * np.abs(a.mean(0))  # t = 0's std: 0 in both up to float64 rounding
        z = np.where(tiny, 0.0, (b.mean(0) - a.mean(0)) / np.where(tiny, 1.0, se))
        out[what] = {"pdebench": a.mean(0).round(5).tolist(), "ours": b.mean(0).round(5).tolist(),
                     "se_pdebench": (a.std(0, ddof=1) / np.sqrt(len(a))).round(5).tolist(),
                     "se_ours": (b.std(0, ddof=1) / np.sqrt(len(b))).round(5).tolist(), "z": z.round(2).tolist()}
        out[f"{what}_within_sampling_error"] = bool((np.abs(z) < 3).all())
    tight_set = _done(RESULTS / "pdebench_tight_seeds.jsonl")
    if tight_set:  # PDEBench's scheme and draws, solved tightly: its law without the RK45 error, on as many seeds
        out["n_pdebench_tight"] = len(tight_set)
        for what in ("mean", "std"):
            a = np.array([r[what] for r in tight_set.values()])
            b = np.array([r[what] for r in us.values()])
            se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
            tiny = se <= 1e-9 + 1e-7 * np.abs(a.mean(0))
            z = np.where(tiny, 0.0, (b.mean(0) - a.mean(0)) / np.where(tiny, 1.0, se))
            out[f"tight_{what}"] = {"pdebench_tight": a.mean(0).round(5).tolist(), "z": z.round(2).tolist()}
            out[f"tight_{what}_within_sampling_error"] = bool((np.abs(z) < 3).all())
    # paired, at PDEBench's own u0 draws: the largest relative difference over samples of each per-frame statistic
    seeds = sorted(pb)
    paired = {"ours": ours([pb[s]["u0"] for s in seeds], N)}
    if root:
        paired["pdebench tight"] = np.stack([pdebench_tight(root, s, N) for s in seeds])
    for who, runs in paired.items():
        for what, fn in (("mean", lambda u: u.mean(-1)), ("std", lambda u: u.std(-1))):
            a = np.array([pb[s][what] for s in seeds])
            b = fn(runs[:, ::REPORT_EVERY])
            scale = np.maximum(np.abs(a).mean(0), 1e-6)
            out[f"paired {who} vs pdebench: {what} max rel diff"] = (np.abs(b - a).max(0) / scale).round(5).tolist()
    if root:
        tight = paired["pdebench tight"]
        for what, fn in (("mean", lambda u: u.mean(-1)), ("std", lambda u: u.std(-1))):
            a, b = fn(tight[:, ::REPORT_EVERY]), fn(paired["ours"][:, ::REPORT_EVERY])
            out[f"paired ours vs pdebench tight: {what} max rel diff"] = (
                np.abs(b - a).max(0) / np.maximum(np.abs(a).mean(0), 1e-6)).round(5).tolist()
    (RESULTS / "stats.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"stats: {len(pb)} PDEBench samples (seeds 0..{max(pb)}), {len(us)} of ours (train split, seed 0)")
    print("   t   mean PDEBench (se)   ours (se)       z  |  std PDEBench (se)   ours (se)       z")
    m, s = out["mean"], out["std"]
    for k, tt in enumerate(t):
        if k % 2 == 0:
            print(f"  {tt:5g}  {m['pdebench'][k]:.4f} ({m['se_pdebench'][k]:.4f})  {m['ours'][k]:.4f} "
                  f"({m['se_ours'][k]:.4f})  {m['z'][k]:+5.2f}  |  {s['pdebench'][k]:.4f} ({s['se_pdebench'][k]:.4f})  "
                  f"{s['ours'][k]:.4f} ({s['se_ours'][k]:.4f})  {s['z'][k]:+5.2f}")
    print(f"  means within sampling error (|z| < 3 at every frame): {out['mean_within_sampling_error']}; stds: "
          f"{out['std_within_sampling_error']}")
    if tight_set:
        print(f"  against PDEBench's scheme solved tightly on its seeds 0..{max(tight_set)} ({len(tight_set)} samples): "
              f"|z| of the mean at most {np.abs(out['tight_mean']['z']).max():.2f}, of the std "
              f"{np.abs(out['tight_std']['z']).max():.2f} (z of the std at t = 500: {out['tight_std']['z'][-1]:+.2f})")
    print("  paired, at PDEBench's draws: largest relative difference over samples (mean / std) at t = "
          + ", ".join(f"{t[k]:g}" for k in range(2, len(t), 4)))
    for key in [k for k in out if k.startswith("paired") and k.endswith("mean max rel diff")]:
        other = key.replace(": mean", ": std")
        print(f"    {key[7:-18]} " + "  ".join(f"{out[key][k]:.4f} / {out[other][k]:.4f}" for k in range(2, len(t), 4)))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--minutes", type=float, default=10.0, help="wall-clock bound of one call's PDEBench runs")
    parser.add_argument("--pdebench", default=None, help="a directory holding PDEBench's pdebench package")
    parser.add_argument("--only", default="pdebench_stats,tight_stats,same_ic,stats,report")
    parser.add_argument("--seed", type=int, default=0, help="PDEBench's seed of the same-IC comparison")
    parser.add_argument("--with-2048", action="store_true", help="same_ic: PDEBench's Simulator at 2048 cells too "
                        "(~7 min on a loaded core)")
    args = parser.parse_args(argv)
    parts = args.only.split(",")
    RESULTS.mkdir(parents=True, exist_ok=True)
    if "pdebench_stats" in parts:
        if not args.pdebench:
            raise SystemExit("pdebench_stats needs --pdebench DIR (a directory holding PDEBench's pdebench package)")
        pdebench_stats(args.pdebench, args.samples, args.minutes)
    if "tight_stats" in parts:
        if not args.pdebench:
            raise SystemExit("tight_stats needs --pdebench DIR (a directory holding PDEBench's pdebench package)")
        pdebench_stats(args.pdebench, args.samples, args.minutes, tight=True)
    if "same_ic" in parts:
        if not args.pdebench:
            raise SystemExit("same_ic needs --pdebench DIR (a directory holding PDEBench's pdebench package)")
        same_ic(args.pdebench, args.seed, args.with_2048)
    if "stats" in parts:
        ours_stats(args.samples)
    if "report" in parts:
        report(args.pdebench)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
