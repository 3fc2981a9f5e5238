"""darcy2d benchmark: samples/s of ``generator.sample`` (GRF draw, threshold, float32 Jacobi-PCG to relative
residual 1e-5) against a scipy sparse direct solve (SuperLU, float64) of the same discrete system, in one process.

    python -m benchmarks.darcy_bench [--quick] [--sizes 64,128,421] [--batch 16]

Per grid size (nodes per side, boundary included; FNO's data is 421): compile time, samples/s of the sampler
(median of repeated calls on fresh indices), CG iterations per sample (mean / max), the direct solve's
samples/s on the same coefficients (assembly + factorisation + solve, one sample at a time, as a per-sample
reference script would), the ratio, and the largest relative L2 difference between the two solutions.
Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from pdestream import generator


def _pde(n: int):
    return generator.get_pde("darcy2d", n=n) if "darcy2d" in generator.PDES else _darcy(n)


def _darcy(n: int):
    from pdestream.generator.steady.darcy2d import Darcy2D

    return Darcy2D(n=n)


def assemble(a: np.ndarray, h: float) -> sp.csr_matrix:
    """-div(a grad .) with harmonic-mean faces on the interior nodes (u = 0 on the boundary), float64."""
    m = a.shape[0] - 2
    ax = 2 * a[:-1] * a[1:] / (a[:-1] + a[1:])  # faces (i+1/2, j), [n-1, n]
    ay = 2 * a[:, :-1] * a[:, 1:] / (a[:, :-1] + a[:, 1:])  # faces (i, j+1/2), [n, n-1]
    east, west = ax[1:, 1:-1], ax[:-1, 1:-1]  # [m, m] each, per interior node
    north, south = ay[1:-1, 1:], ay[1:-1, :-1]
    idx = np.arange(m * m).reshape(m, m)
    rows, cols, vals = [idx.ravel()], [idx.ravel()], [(east + west + north + south).ravel()]
    for coef, di, dj in ((east, 1, 0), (west, -1, 0), (north, 0, 1), (south, 0, -1)):
        i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        inside = (0 <= i + di) & (i + di < m) & (0 <= j + dj) & (j + dj < m)
        rows.append(idx[inside]), cols.append(idx[(i + di)[inside], (j + dj)[inside]]), vals.append(-coef[inside])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m * m, m * m)) / h**2


def direct(a: np.ndarray, f: float, h: float) -> np.ndarray:
    m = a.shape[0] - 2
    return spl.spsolve(assemble(a.astype(np.float64), h).tocsc(), np.full(m * m, f)).reshape(m, m)


def bench(n: int, batch: int, repeats: int, direct_samples: int) -> dict:
    pde = _pde(n)
    keys = generator.sample_keys(0, np.arange(batch))
    zeros, none = np.zeros((batch, len(pde.PARAMS)), np.float32), np.zeros((batch, len(pde.PARAMS)), bool)
    t0 = time.perf_counter()
    jax.block_until_ready(pde.solve_keys(keys, zeros, none))
    first = time.perf_counter() - t0
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        traj = generator.sample(pde, np.arange(batch) + (r + 1) * batch, seed=0)
        jax.block_until_ready(traj.u)
        times.append(time.perf_counter() - t0)
    its = np.asarray(pde.solve_keys(generator.sample_keys(0, np.arange(batch)), zeros, none)[4])
    steady = statistics.median(times)
    a, u = np.asarray(traj.inputs[:, 0]), np.asarray(traj.u[:, 0])
    t0 = time.perf_counter()
    ref = [direct(a[b], 1.0, pde.grid.spacing) for b in range(direct_samples)]
    direct_time = (time.perf_counter() - t0) / direct_samples
    diff = max(np.linalg.norm(u[b, 1:-1, 1:-1] - ref[b]) / np.linalg.norm(ref[b]) for b in range(direct_samples))
    return {"n": n, "batch": batch, "compile_s": first - steady, "samples_per_s": batch / steady,
            "iter_mean": float(its.mean()), "iter_max": int(its.max()), "direct_per_s": 1 / direct_time,
            "rel_diff": float(diff)}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.darcy_bench", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="64^2 only, fewer repeats")
    p.add_argument("--sizes", default="64,128", help="nodes per side, comma-separated (FNO's data: 421)")
    p.add_argument("--batch", type=int, default=16, help="samples per sampler call (the stream's solve batch)")
    args = p.parse_args(argv)
    sizes = [64] if args.quick else [int(s) for s in args.sizes.split(",")]
    print(f"darcy2d, float32 Jacobi-PCG (tol 1e-5) vs scipy spsolve (float64), jax {jax.__version__}, "
          f"devices {jax.devices()}")
    print(f"{'grid':>8} {'batch':>5} {'compile s':>9} {'samples/s':>10} {'CG it mean/max':>15} "
          f"{'direct/s':>9} {'ratio':>7} {'max rel diff':>12}")
    for n in sizes:
        r = bench(n, args.batch, 2 if args.quick else 3, 2 if n > 200 else 4)
        print(f"{n:>4}^2   {r['batch']:>5} {r['compile_s']:>9.2f} {r['samples_per_s']:>10.2f} "
              f"{r['iter_mean']:>9.0f}/{r['iter_max']:<5} {r['direct_per_s']:>9.2f} "
              f"{r['samples_per_s'] / r['direct_per_s']:>6.2f}x {r['rel_diff']:>12.2e}", flush=True)


if __name__ == "__main__":
    main()
