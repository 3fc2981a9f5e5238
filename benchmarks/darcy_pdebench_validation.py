"""pdebench_darcy2d_* against PDEBench's own 2D Darcy generator: ``python -m benchmarks.darcy_pdebench_validation
--pdebench DIR [--parts theirs,steady,same,stats] [--samples 32] [--ours 256] [--out DIR]``.

PDEBench's generator (reaction_diffusion_2D_multi_solution_Hydra.py, run through its Hydra entry point ``main(cfg)``,
unchanged) integrates u_t = div(nu grad u) + beta in pseudo-time from a random state (init_multi_2DRand) to t = 2
on 128 x 128 cell centres of (0, 1)^2 and keeps u(t = 2) as the steady state. Parts:

- ``theirs``: its runs at key 2020, beta = 1 with its own initial states (its data, unchanged) and beta = 1 from
  u = 0 (its IC function monkeypatched to return zeros: the pure response W to the forcing). u is linear in
  (u0, beta), so its data at any beta is R1 + (beta - 1) W, checked against a direct run at beta = 0.01 (4 samples,
  t = 0.05 and 2: float32 stalls make it 5% off at t = 2, so --direct-betas are also run directly, same samples).
  Also --coef-samples coefficient fields from its generator (runs to t = 1e-6).
- ``steady``: the steady state S of its own discrete system (five points, arithmetic face means, u = 0 in the ghost
  cells; assembled here and solved by a sparse LU, float64) for each of its coefficient fields: how far its
  u(t = 2) is from the state it approaches, per beta (its transient does not scale with beta, the answer does).
- ``same``: its coefficient fields (128 and, from the same key, 256 cells) given to our solver (darcy2d,
  points=cells); ours against its steady state S and its data u(t = 2), beside each solver's own space error
  (each at 128 cells against its 256-cell solution averaged to 128 cells).
- ``stats``: --ours samples of our recipe against its samples: the coefficient's fraction of high values and u's
  per-sample mean, std and max, each with its standard error.

--pdebench DIR: a directory holding PDEBench's ``pdebench`` package (the pdebench 0.1.0 wheel unpacked); the
``theirs`` part needs ``hydra-core`` and ``omegaconf`` importable. Its arrays go under --scratch (outside the
repository), the figures as json under --out; a part whose files exist is not rerun.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

KEY = 2020  # run_DarcyFlow2D.sh's first init_key
BETAS = (0.01, 0.1, 1.0, 10.0, 100.0)  # its five published files (pdebench_data_urls.csv)
N = 128


def _config(save: Path, n: int, count: int, beta: float, fin_time: float, key: int) -> dict:
    """config/multi/config_2D.yaml with nx = ny, numbers, beta, fin_time and init_key changed."""
    return dict(save=str(save) + "/", dt_save=0.25, ini_time=0.0, fin_time=fin_time, nx=n, ny=n, xL=0.0, xR=1.0,
                yL=0.0, yR=1.0, beta=beta, CFL=0.25, if_show=1, numbers=count, if_second_order=1.0, show_steps=100,
                init_key=key)


def pdebench_run(root: str, scratch: Path, tag: str, n: int, count: int, beta: float, fin_time: float,
                 zero_ic: bool = False, key: int = KEY) -> tuple[np.ndarray, np.ndarray]:
    """Its generator's (frames [count, 9, n, n] at t = 0, 0.25, ..., 2 (the last one u(fin_time)), nu [count, n, n]);
    with zero_ic its IC function returns u0 = 0 (nothing else changed). Cached under scratch/tag."""
    save = scratch / tag
    stem = f"beta{str(beta)[:5]}_key{key}"
    frames, coef = save / f"2D_ReacDiff_Multi_{stem}.npy", save / f"nu_diff_coef_{stem}.npy"
    if not coef.exists():  # its last file (it opens the frames' file before its asynchronous run has finished)
        gen = os.path.join(root, "pdebench", "data_gen", "data_gen_NLE")
        for d in (gen, os.path.join(gen, "ReactionDiffusionEq")):
            if d not in sys.path:
                sys.path.insert(0, d)
        import hydra.utils  # noqa: F401 (its module calls hydra.utils.get_original_cwd)
        import jax.numpy as jnp
        import reaction_diffusion_2D_multi_solution_Hydra as rd  # PDEBench's own
        from omegaconf import OmegaConf
        from utils import init_multi_2DRand

        rd.init_multi_2DRand = ((lambda xc, yc, numbers, **_: jnp.zeros((numbers, xc.shape[0], yc.shape[0])))
                                if zero_ic else init_multi_2DRand)
        rd.hydra.utils.get_original_cwd = lambda: ""  # outside a Hydra run: its save path is absolute here
        save.mkdir(parents=True, exist_ok=True)
        t0 = time.time()
        rd.main(OmegaConf.create({"multi": _config(save, n, count, beta, fin_time, key)}))
        print(f"  pdebench {tag}: {count} samples at {n}^2 to t = {fin_time:g} in {time.time() - t0:.0f} s", flush=True)
    return np.load(frames), np.load(coef)


def part_theirs(args) -> dict:
    root, scratch, b = args.pdebench, Path(args.scratch), args.samples
    out = {}
    # u is linear in (u0, beta): beta's data = R1 + (beta - 1) W, checked on a short window against a direct run
    for t in (0.05, 2.0):
        d1, _ = pdebench_run(root, scratch, f"check_data_n{N}_t{t:g}", N, 4, 1.0, t)
        dw, _ = pdebench_run(root, scratch, f"check_zero_n{N}_t{t:g}", N, 4, 1.0, t, zero_ic=True)
        dd, _ = pdebench_run(root, scratch, f"check_direct_n{N}_t{t:g}", N, 4, 0.01, t)
        comb = d1[:, -1] + (0.01 - 1.0) * dw[:, -1]
        out[f"linearity_check_t{t:g}_rel_l2"] = _summary(rel(comb, dd[:, -1]))
    # its fine coefficient fields from the same key (its bump draws do not depend on nx): t = 1e-6 only
    for n in (N, 2 * N):
        pdebench_run(root, scratch, f"coef_n{n}_b{b}", n, b, 1.0, 1e-6)
    pdebench_run(root, scratch, f"coef_n{N}_b{args.coef_samples}", N, args.coef_samples, 1.0, 1e-6)
    r1, nu = pdebench_run(root, scratch, f"data_n{N}_b{b}", N, b, 1.0, 2.0)
    w, nu_w = pdebench_run(root, scratch, f"zero_n{N}_b{b}", N, b, 1.0, 2.0, zero_ic=True)
    assert np.array_equal(nu, nu_w)
    # the combination cancels two O(0.1) states to make a small-beta one: their float32 stall (0.1%) grows by 1 / beta
    # (the t = 2 check: 5% at beta = 0.01), so small betas are also run directly (the same key: the same samples)
    for beta in (float(x) for x in args.direct_betas.split(",") if x):
        _, nu_d = pdebench_run(root, scratch, f"direct_n{N}_b{b}", N, b, beta, 2.0)
        assert np.array_equal(nu, nu_d)
    return out


def assemble_pdebench(nu: np.ndarray):
    """Its operator -div(nu grad .) on n x n cell centres, h = 1 / n: face coefficient (nu_P + nu_Q) / 2, u = 0 in
    the ghost cells (bc_2D 'Neumann' sets them to 0), nu copied into its ghosts (bc_2D 'trans'); float64 CSR."""
    import scipy.sparse as sp

    n = nu.shape[0]
    h = 1.0 / n
    p = np.pad(np.asarray(nu, np.float64), 1, mode="edge")
    ex = 0.5 * (p[1:-1, 1:-1] + p[2:, 1:-1])  # face to i + 1
    wx = 0.5 * (p[1:-1, 1:-1] + p[:-2, 1:-1])
    ny_ = 0.5 * (p[1:-1, 1:-1] + p[1:-1, 2:])
    sy = 0.5 * (p[1:-1, 1:-1] + p[1:-1, :-2])
    idx = np.arange(n * n).reshape(n, n)
    rows, cols, vals = [idx.ravel()], [idx.ravel()], [(ex + wx + ny_ + sy).ravel()]
    for c, di, dj in ((ex, 1, 0), (wx, -1, 0), (ny_, 0, 1), (sy, 0, -1)):
        i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        inside = (0 <= i + di) & (i + di < n) & (0 <= j + dj) & (j + dj < n)
        rows.append(idx[inside]), cols.append(idx[(i + di)[inside], (j + dj)[inside]]), vals.append(-c[inside])
    return sp.csr_matrix((np.concatenate(vals) / h**2, (np.concatenate(rows), np.concatenate(cols))), shape=(n * n,) * 2)


def pdebench_steady(nu: np.ndarray) -> np.ndarray:
    """S [count, n, n]: the steady state of its discrete system at beta = 1 for each coefficient field nu [count, n, n]."""
    import scipy.sparse.linalg as spl

    n = nu.shape[-1]
    return np.stack([spl.spsolve(assemble_pdebench(a).tocsc(), np.ones(n * n)).reshape(n, n) for a in nu])


def rel(a, b) -> np.ndarray:
    """Relative L2 distance per sample [count] of a [count, ...] from b."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    axes = tuple(range(1, a.ndim))
    return np.sqrt(((a - b) ** 2).sum(axes) / (b**2).sum(axes))


def coarsen(u: np.ndarray) -> np.ndarray:
    """[..., n/2, n/2] cell averages of [..., n, n] (a finer cell-centred solution on the coarser cells)."""
    *lead, n, _ = u.shape
    return u.reshape(*lead, n // 2, 2, n // 2, 2).mean((-3, -1))


def _summary(x: np.ndarray) -> dict:
    x = np.asarray(x, np.float64)
    return {"median": float(np.median(x)), "mean": float(x.mean()), "max": float(x.max()), "min": float(x.min())}


def their_data(scratch: Path, b: int, beta: float) -> tuple[np.ndarray, np.ndarray, str]:
    """Its u at t = 2 and t = 1.75 [b, n, n] at ``beta``: its direct run where one was made, else R1 + (beta - 1) W."""
    direct = scratch / f"direct_n{N}_b{b}" / f"2D_ReacDiff_Multi_beta{str(beta)[:5]}_key{KEY}.npy"
    if (direct.parent / f"nu_diff_coef_beta{str(beta)[:5]}_key{KEY}.npy").exists():
        u = np.load(direct)
        return u[:, -1], u[:, -2], "its run at this beta"
    r1 = np.load(scratch / f"data_n{N}_b{b}" / f"2D_ReacDiff_Multi_beta1.0_key{KEY}.npy")
    w = np.load(scratch / f"zero_n{N}_b{b}" / f"2D_ReacDiff_Multi_beta1.0_key{KEY}.npy")
    return r1[:, -1] + (beta - 1.0) * w[:, -1], r1[:, -2] + (beta - 1.0) * w[:, -2], "R1 + (beta - 1) W"


def part_steady(args) -> dict:
    scratch, b = Path(args.scratch), args.samples
    nu = np.load(scratch / f"data_n{N}_b{b}" / f"nu_diff_coef_beta1.0_key{KEY}.npy")
    w = np.load(scratch / f"zero_n{N}_b{b}" / f"2D_ReacDiff_Multi_beta1.0_key{KEY}.npy")
    s_path = scratch / f"steady_n{N}_b{b}.npy"
    if not s_path.exists():
        np.save(s_path, pdebench_steady(nu))
    s = np.load(s_path)
    out = {"samples": b, "per_beta": {}}
    for beta in BETAS:
        data, before, how = their_data(scratch, b, beta)  # its u(t = 2), u(t = 1.75)
        gap = rel(data, beta * s)
        out["per_beta"][f"{beta:g}"] = {
            "data": how,
            "rel_l2_u(t=2)_vs_steady": _summary(gap),
            "samples_over_1pct": int((gap > 0.01).sum()),
            "rel_l2_u(t=1.75)_vs_u(t=2)": _summary(rel(before, data))}
    out["response_W(t=2)_vs_steady"] = _summary(rel(w[:, -1], s))
    return out


def ours_solve(nu: np.ndarray, beta: float = 1.0) -> np.ndarray:
    """Our darcy2d (points=cells) on given coefficient fields nu [count, n, n]: u [count, n, n] (float32 CG)."""
    import jax.numpy as jnp

    from pdestream import generator as g
    from pdestream.generator.steady.darcy2d import _compiled_solve

    n = nu.shape[-1]
    pde = g.get_pde("pdebench_darcy2d_beta1e0", n=n)
    u, ok, _ = _compiled_solve(pde)(jnp.asarray(nu, jnp.float32), jnp.full(nu.shape[0], beta, jnp.float32))
    assert bool(np.all(np.asarray(ok)))
    return np.asarray(u)


def part_same(args) -> dict:
    scratch, b = Path(args.scratch), args.samples
    nu = {n: np.load(scratch / f"coef_n{n}_b{b}" / f"nu_diff_coef_beta1.0_key{KEY}.npy") for n in (N, 2 * N)}
    s = np.load(scratch / f"steady_n{N}_b{b}.npy")
    s_fine_path = scratch / f"steady_n{2 * N}_b{b}.npy"
    if not s_fine_path.exists():
        np.save(s_fine_path, pdebench_steady(nu[2 * N]))
    s_fine = np.load(s_fine_path)
    for n in (N, 2 * N):
        path = scratch / f"ours_on_theirs_{n}.npy"
        if not path.exists():
            np.save(path, ours_solve(nu[n]))
    ours, ours_fine = np.load(scratch / f"ours_on_theirs_{N}.npy"), np.load(scratch / f"ours_on_theirs_{2 * N}.npy")
    gap, err_ours, err_theirs = rel(ours, s), rel(ours, coarsen(ours_fine)), rel(s, coarsen(s_fine))
    out = {"samples": b,
           "cells_where_the_256_field_averaged_differs_from_128": float(np.mean(coarsen(nu[2 * N]) != nu[N])),
           "ours_vs_their_steady": _summary(gap),
           "our_space_error": _summary(err_ours),
           "their_space_error (steady)": _summary(err_theirs),
           "samples_where_gap_within_sum_of_space_errors": int((gap <= err_ours + err_theirs).sum()),
           "ours_256_vs_their_steady_256": _summary(rel(ours_fine, s_fine)),
           "ours_vs_their_data": {}}
    for beta in BETAS:
        data, _, how = their_data(scratch, b, beta)
        out["ours_vs_their_data"][f"{beta:g}"] = {"data": how, **_summary(rel(beta * ours, data))}
    return out


def _stats(a: np.ndarray, u: np.ndarray) -> dict:
    per = {"a_high_fraction": (a > 0.5).mean((-2, -1)), "u_mean": u.mean((-2, -1)), "u_std": u.std((-2, -1)),
           "u_max": u.max((-2, -1))}
    return {k: [float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v)))] for k, v in per.items()}


def part_stats(args) -> dict:
    from pdestream import generator as g

    scratch, b = Path(args.scratch), args.samples
    path = scratch / f"ours_{args.ours}.npz"
    if not path.exists():
        pde = g.get_pde("pdebench_darcy2d_beta1e0")
        t0 = time.time()
        traj = g.sample(pde, range(args.ours), seed=0)
        print(f"  ours: {args.ours} samples in {time.time() - t0:.0f} s", flush=True)
        np.savez(path, a=np.asarray(traj.inputs[:, 0]), u=np.asarray(traj.u[:, 0]), wall_s=time.time() - t0)
    ours = np.load(path)
    nu = np.load(scratch / f"data_n{N}_b{b}" / f"nu_diff_coef_beta1.0_key{KEY}.npy")
    s = np.load(scratch / f"steady_n{N}_b{b}.npy")
    r1 = np.load(scratch / f"data_n{N}_b{b}" / f"2D_ReacDiff_Multi_beta1.0_key{KEY}.npy")[:, -1]
    many = np.load(scratch / f"coef_n{N}_b{args.coef_samples}" / f"nu_diff_coef_beta1.0_key{KEY}.npy")
    # its scheme's steady state on the first --steady-samples of its coefficient fields (its data at beta >= 1 is
    # within 0.1% (median) of that state: part steady), for u's statistics on more samples than its runs afford
    m = args.steady_samples
    s_path = scratch / f"steady_coef_n{N}_{m}.npy"
    if not s_path.exists():
        np.save(s_path, pdebench_steady(many[:m]))
    s_many = np.load(s_path)
    return {"beta": 1.0, "ours_samples": args.ours, "ours_wall_s_with_compile": float(ours["wall_s"]) if "wall_s" in ours else None, "their_samples": b, "their_coef_samples": args.coef_samples,
            "ours": _stats(ours["a"], ours["u"]), "their_steady": _stats(nu, s), "their_data_t2": _stats(nu, r1),
            f"their_steady_{m}": _stats(many[:m], s_many),
            "their_coefficient_only": {"a_high_fraction": _stats(many, many)["a_high_fraction"]}}


PARTS = {"theirs": part_theirs, "steady": part_steady, "same": part_same, "stats": part_stats}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pdebench", default="/work/wt-dr2d/.venv/pdebench_dl/x")
    p.add_argument("--parts", default="theirs,steady,same,stats")
    p.add_argument("--samples", type=int, default=32, help="PDEBench samples run to t = 2 (one batch, key 2020)")
    p.add_argument("--coef-samples", type=int, default=2000, help="PDEBench coefficient fields drawn (no solve)")
    p.add_argument("--direct-betas", default="0.01,0.1", help="betas its generator also runs directly")
    p.add_argument("--ours", type=int, default=512)
    p.add_argument("--steady-samples", type=int, default=512, help="its coefficient fields solved to its steady state")
    p.add_argument("--scratch", default="/tmp/darcy_pdebench")
    p.add_argument("--out", default="benchmarks/results/darcy_pdebench")
    args = p.parse_args(argv)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    for part in args.parts.split(","):
        t0 = time.time()
        result = PARTS[part](args)
        result["wall_s"] = round(time.time() - t0, 1)
        result["load_avg"] = os.getloadavg()[0]
        path = Path(args.out) / f"{part}.json"
        path.write_text(json.dumps(result, indent=1) + "\n")
        print(f"{part}: {json.dumps(result)}", flush=True)


if __name__ == "__main__":
    main()
