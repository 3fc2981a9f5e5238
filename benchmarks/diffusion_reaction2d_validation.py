"""pdebench_diffusion_reaction2d against PDEBench's generator: ``python -m benchmarks.diffusion_reaction2d_validation
[--n 128] [--samples 32] [--pdebench DIR] [--only same_ic,stats]``.

same_ic: one white-noise IC (PDEBench's draw: numpy seeded per sample, a standard normal per cell) given to our
solver and to a finite-volume reference of PDEBench's scheme (``fv_solve``: written here from its description,
the 5-point Laplacian with no-flux walls and scipy's RK45; with --pdebench, PDEBench's own Simulator too, which
must match it to its tolerance); each measured against a run of itself on the grid twice as fine from the same
(piecewise-constant) IC, restricted back (finite volumes: 2 x 2 cell averages; ours: the first n x n cosine
modes), and the two against each other: relative L2 per field at a few frames. stats: per-field mean / std of
``--samples`` samples of the recipe against as many of PDEBench's generator (or the reference with its draw),
with the sampling error of the mean over samples. Figures, not pass/fail (docs/results/recipes.md).

--pdebench DIR: a directory holding PDEBench's ``pdebench`` package (e.g. the pdebench 0.1.0 wheel unpacked; it
needs numpy and scipy only for this module). PDEBench is not part of pdestream and is not imported otherwise.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

DU, DV, K = 1e-3, 5e-3, 5e-3  # PDEBench's diff-react.yaml
LENGTH, T_END, N_FRAMES = 2.0, 5.0, 101
REPORT_T = (0.0, 0.05, 0.25, 0.5, 1.0, 2.5, 5.0)


def fv_laplacian(u: np.ndarray, dx: float) -> np.ndarray:
    """The 5-point Laplacian of cell averages u [..., n, n] with no-flux walls (a ghost cell equal to its
    neighbour: zero flux through the wall), float64."""
    p = np.pad(u, [(0, 0)] * (u.ndim - 2) + [(1, 1), (1, 1)], mode="edge")
    return (p[..., :-2, 1:-1] + p[..., 2:, 1:-1] + p[..., 1:-1, :-2] + p[..., 1:-1, 2:] - 4 * u) / dx**2


def fv_solve(u0: np.ndarray, n: int, rtol: float = 1e-3, atol: float = 1e-6) -> np.ndarray:
    """PDEBench's scheme: u0 [2, n, n] (u, v) -> frames [T, 2, n, n] at linspace(0, 5, 101), RK45 (scipy's
    adaptive Dormand-Prince) at ``rtol`` / ``atol`` (PDEBench passes none: scipy's defaults 1e-3 / 1e-6)."""
    from scipy.integrate import solve_ivp

    dx = LENGTH / n

    def rhs(t, y):
        u, v = y.reshape(2, n, n)
        return np.stack([DU * fv_laplacian(u, dx) + u - u**3 - K - v, DV * fv_laplacian(v, dx) + u - v]).ravel()

    t = np.linspace(0, T_END, N_FRAMES)
    sol = solve_ivp(rhs, (0, T_END), np.asarray(u0, np.float64).ravel(), t_eval=t, rtol=rtol, atol=atol)
    return sol.y.T.reshape(N_FRAMES, 2, n, n)


def pdebench_ic(seed: int, n: int) -> np.ndarray:
    """The published set's draw (PDEBench 2f71cb8 / pdebench 0.1.0): np.random.seed(seed), randn for u then v,
    row-major [y, x] as its reshape reads them: [2, n, n]."""
    rng = np.random.RandomState(seed)
    return np.stack([rng.randn(n * n).reshape(n, n), rng.randn(n * n).reshape(n, n)])


def pdebench_solve(root: str, seed: int, n: int) -> np.ndarray:
    """PDEBench's own Simulator (src/sim_diff_react.py) for ``seed`` on n x n: frames [T, 2, n, n] ([y, x])."""
    if root not in sys.path:
        sys.path.insert(0, root)
    from pdebench.data_gen.src.sim_diff_react import Simulator

    sim = Simulator(Du=DU, Dv=DV, k=K, t=T_END, tdim=N_FRAMES, x_left=-1.0, x_right=1.0, xdim=n, y_bottom=-1.0,
                    y_top=1.0, ydim=n, n=1, seed=seed)
    return np.moveaxis(sim.generate_sample(), -1, 1)  # [T, y, x, 2] -> [T, 2, y, x]


def ours(u0: np.ndarray, n: int) -> np.ndarray:
    """Our recipe's solver from u0 [S, 2, n, n] on n x n: frames [S, T, 2, n, n], float64 copy."""
    from pdestream import generator

    pde = generator.get_pde("pdebench_diffusion_reaction2d", n=n)
    p = {name: [float(pde.param_domains[name].bounds[0])] * len(u0) for name in ("Du", "Dv", "k")}
    return np.asarray(generator.solve(pde, u0, p).u, np.float64)


def refine(u: np.ndarray) -> np.ndarray:
    """A piecewise-constant field [..., n, n] on the grid twice as fine: [..., 2n, 2n]."""
    return np.repeat(np.repeat(u, 2, -2), 2, -1)


def cell_average(u: np.ndarray) -> np.ndarray:
    """2 x 2 block means: [..., 2n, 2n] -> [..., n, n] (finite volumes' restriction)."""
    return 0.25 * (u[..., ::2, ::2] + u[..., 1::2, ::2] + u[..., ::2, 1::2] + u[..., 1::2, 1::2])


def cosine_restrict(u: np.ndarray, n: int) -> np.ndarray:
    """The first n x n cosine modes of cell-centred u [..., N, N], evaluated at the n x n cell centres (the
    spectral solver's own restriction: its cosine amplitudes do not depend on the grid)."""
    from scipy.fft import dctn, idctn

    big = u.shape[-1]
    c = dctn(u, type=2, norm="ortho", axes=(-2, -1))[..., :n, :n] * (n / big)
    return idctn(c, type=2, norm="ortho", axes=(-2, -1))


def rel(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative L2 of a against b over the last two axes: [..., T, C]."""
    return np.sqrt(((a - b) ** 2).sum((-2, -1)) / (b**2).sum((-2, -1)))


def same_ic(n: int, seed: int, pdebench: str | None) -> None:
    frames = [int(round(t / T_END * (N_FRAMES - 1))) for t in REPORT_T]
    u0 = pdebench_ic(seed, n)
    clock = {}
    t0 = time.perf_counter()
    fv = fv_solve(u0, n)
    clock["fv"] = time.perf_counter() - t0
    fv_tight = fv_solve(u0, n, rtol=1e-8, atol=1e-10)
    fv_fine = fv_solve(refine(u0), 2 * n, rtol=1e-8, atol=1e-10)
    ours(u0[None], n)  # compile
    t0 = time.perf_counter()
    sp = ours(u0[None], n)[0]
    clock["ours"] = time.perf_counter() - t0
    sp_fine = ours(refine(u0)[None], 2 * n)[0]
    rows = {
        "FV(n, rtol 1e-3) vs FV(n, rtol 1e-8): PDEBench's time error": rel(fv, fv_tight),
        "FV(n) vs FV(2n) averaged: the finite-volume space error": rel(fv_tight, cell_average(fv_fine)),
        "ours(n) vs ours(2n) restricted: our space error": rel(sp, cosine_restrict(sp_fine, n)),
        "ours(n) vs FV(n, rtol 1e-3): the recipe vs PDEBench's scheme": rel(sp, fv),
        "ours(2n) vs FV(2n), both restricted by averages": rel(cell_average(sp_fine), cell_average(fv_fine)),
        "ours(n) vs FV(2n) averaged": rel(sp, cell_average(fv_fine)),
        "FV(n, rtol 1e-3) vs FV(2n) averaged": rel(fv, cell_average(fv_fine)),
    }
    if pdebench:
        t0 = time.perf_counter()
        pb = pdebench_solve(pdebench, seed, n)
        clock["pdebench"] = time.perf_counter() - t0
        rows = {"PDEBench's Simulator vs FV(n, rtol 1e-3) (this script's reading of it)": rel(pb, fv),
                "PDEBench's Simulator vs ours(n)": rel(sp, pb), **rows}
    print(f"same IC (PDEBench's seed {seed}), n = {n}: relative L2 per field (u / v) at t = "
          + ", ".join(f"{t:g}" for t in REPORT_T))
    for name, err in rows.items():
        print(f"  {name}")
        print("    u: " + " ".join(f"{err[f, 0]:.2e}" for f in frames) + "   v: "
              + " ".join(f"{err[f, 1]:.2e}" for f in frames))
    print("  std of u, v per frame: FV(n) " + " ".join(f"{fv[f, 0].std():.3f}/{fv[f, 1].std():.3f}" for f in frames))
    print("                         ours(n) " + " ".join(f"{sp[f, 0].std():.3f}/{sp[f, 1].std():.3f}" for f in frames))
    fv2, sp2 = cell_average(fv_fine), cosine_restrict(sp_fine, n)
    print("             FV(2n) averaged to n " + " ".join(f"{fv2[f, 0].std():.3f}/{fv2[f, 1].std():.3f}" for f in frames))
    print("          ours(2n) restricted to n " + " ".join(f"{sp2[f, 0].std():.3f}/{sp2[f, 1].std():.3f}" for f in frames))
    print("  seconds per sample (this process, 2 shared cores): "
          + ", ".join(f"{k} {v:.2f}" for k, v in clock.items()))
    # The two Laplacians' symbols at the highest mode our 2/3 rule keeps (m = 2n/3) and at the grid's last (n - 1)
    for m in ((2 * n) // 3, n - 1):
        spectral = (np.pi * m / LENGTH) ** 2
        fvol = 4 / (LENGTH / n) ** 2 * np.sin(np.pi * m / (2 * n)) ** 2
        print(f"  Laplacian symbol at mode {m}: spectral {spectral:.4g}, finite volume {fvol:.4g} "
              f"(ratio {spectral / fvol:.2f})")


def stats(n: int, samples: int, pdebench: str | None) -> None:
    from pdestream import generator

    frames = [int(round(t / T_END * (N_FRAMES - 1))) for t in REPORT_T]
    t0 = time.perf_counter()
    ref = np.stack([pdebench_solve(pdebench, s, n) if pdebench else fv_solve(pdebench_ic(s, n), n)
                    for s in range(samples)])
    t_ref = time.perf_counter() - t0
    pde = generator.get_pde("pdebench_diffusion_reaction2d", n=n)
    t0 = time.perf_counter()
    us = np.asarray(generator.sample(pde, range(samples), seed=0).u, np.float64)
    t_us = time.perf_counter() - t0
    who = "PDEBench's Simulator" if pdebench else "the FV reference (PDEBench's draw)"
    print(f"stats, {samples} samples at n = {n}: per-field mean (sampling error) / std (sampling error); ours: the "
          f"recipe's seed 0 ({t_us:.1f} s incl. compile), {who} seeds 0..{samples - 1} ({t_ref:.1f} s)")
    for f, t in zip(frames, REPORT_T):
        line = f"  t = {t:<4g}"
        for c, name in enumerate("uv"):
            for label, data in (("ours", us), ("ref", ref)):
                x = data[:, f, c].reshape(samples, -1)
                m, s = x.mean(1), x.std(1)
                line += (f"  {name} {label} {m.mean():+.4f} ({m.std() / np.sqrt(samples):.4f}) / "
                         f"{s.mean():.4f} ({s.std() / np.sqrt(samples):.4f})")
        print(line)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=128)
    parser.add_argument("--seed", type=int, default=0, help="PDEBench's seed of the same-IC comparison")
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--pdebench", default=None, help="a directory holding PDEBench's pdebench package")
    parser.add_argument("--only", default="same_ic,stats")
    args = parser.parse_args(argv)
    parts = args.only.split(",")
    if "same_ic" in parts:
        same_ic(args.n, args.seed, args.pdebench)
    if "stats" in parts:
        stats(args.n, args.samples, args.pdebench)


if __name__ == "__main__":
    main()
