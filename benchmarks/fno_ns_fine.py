"""The FNO paper's Navier-Stokes sets at nu = 1e-4 and 1e-5 (recipes ``fno_ns2d_nu1e-4`` / ``_nu1e-5``: solved on
256^2, every 4th point kept), checked on the grids and against the paper's own algorithm:

``python -m benchmarks.fno_ns_fine ladder [--nu 1e-4] [--samples 2] [--paper-dt 1e-3,5e-4] [--paper-t T]``: the same w0 (drawn on 512^2 from the paper's
measure by an independent numpy draw, ``fno_ns_reproduction.grf_w0``, then cut to each grid's modes) solved by
pdestream's ns2d on 64^2, 128^2, 256^2 (the recipe's grid) and 512^2; relative L2 at the 64^2 points kept, every
5 time units, against the 512^2 run; the recipe's grid at half its step (the time error) and that run against
512^2, whose CFL step it shares (the space error); the paper's scheme
(``fno_ns_reproduction.solve_cn``: Crank-Nicolson + forward Euler, float64) on the same 256^2 w0 at two steps; and
the largest |velocity| of each 256^2 frame against the velocity bound the recipe's step assumes.

``python -m benchmarks.fno_ns_fine stats [--nu 1e-4] [--samples 32] [--paper-samples 8]``: the recipe's w0 on
256^2 against the measure (1024 draws), then its train samples (generated in chunks) and the paper's algorithm on
independent draws: the per-frame spatial std of w (mean and its sampling error over samples) and the shell
spectrum at the last frame.

Every run is cached under ``--cache`` (a rerun solves only what is missing); figures go to ``--results`` as JSON.
Figures: docs/results/recipes.md (section fno_ns2d_nu1e-4, fno_ns2d_nu1e-5).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.fno_ns_reproduction import forcing, grf_w0, solve_cn

RESULTS = Path(__file__).resolve().parent / "results" / "fno_ns_fine"
T_END = {1e-4: 30, 1e-5: 20}
KEEP = 64  # the recipes' stored grid


def recipe_name(nu: float) -> str:
    return f"fno_ns2d_nu1e-{round(-np.log10(nu))}"


def cut(w: np.ndarray, n: int) -> np.ndarray:
    """Fields w [..., N, N] -> the same Fourier modes |m| < n/2 on the n x n grid (n <= N): [..., n, n], float64."""
    big = w.shape[-1]
    if n == big:
        return w.astype(np.float64)
    idx = np.r_[0 : n // 2, big - n // 2 : big]  # modes 0..n/2-1 and -n/2..-1 in the n-grid's fft order
    w_hat = np.fft.fft2(w)[..., idx, :][..., idx]
    w_hat[..., n // 2, :] = 0  # the n-grid's Nyquist modes (the 512^2 draw's -n/2 without its +n/2 twin)
    w_hat[..., :, n // 2] = 0
    return np.fft.ifft2(w_hat).real * (n / big) ** 2


def kept(w: np.ndarray) -> np.ndarray:
    """Frames [..., n, n] -> every (n / 64)-th point per axis: [..., 64, 64]."""
    r = w.shape[-1] // KEEP
    return w[..., ::r, ::r]


def peak_velocity(w: np.ndarray) -> np.ndarray:
    """max |u| of vorticity fields w [..., n, n] on the unit torus (u = (psi_y, -psi_x), -Lap psi = w): [...]."""
    n = w.shape[-1]
    k = 2 * np.pi * np.fft.fftfreq(n, 1.0 / n)
    kx, ky = k[:, None], k[None, :]
    k2 = kx**2 + ky**2
    psi = np.fft.fft2(w) / np.where(k2 > 0, k2, np.inf)
    u, v = np.fft.ifft2(1j * ky * psi).real, np.fft.ifft2(-1j * kx * psi).real
    return np.sqrt(u**2 + v**2).max((-2, -1))


def cached(path: Path, make):
    """np.load(path) if it exists, else make() saved there first (written whole, then renamed)."""
    if path.is_file():
        return np.load(path)
    t0 = time.perf_counter()
    out = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npy")
    np.save(tmp, out)
    tmp.replace(path)
    print(f"  {path.name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return out


def ours(nu: float, w0: np.ndarray, n: int, dt_scale: float = 1.0, full: bool = False) -> np.ndarray:
    """pdestream's ns2d with the recipe's settings on n^2 (refine 1) from w0 [S, n, n]: frames [S, T + 1, n, n]
    (``full``) or their 64^2 points kept; dt_scale < 1 takes that fraction of the recipe grid's step."""
    from pdestream import generator

    pde = generator.get_pde(recipe_name(nu)).replace(n=n, refine=1)
    if dt_scale != 1.0:
        pde = pde.replace(dt=pde.step_dt * dt_scale)
    u = np.asarray(generator.solve(pde, w0[:, None].astype(np.float32), {"nu": np.full(len(w0), nu)}).u)[:, :, 0]
    return u if full else kept(u)


def rel(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative L2 of a against b over the last two axes."""
    return np.sqrt(((a - b) ** 2).sum((-2, -1)) / (b**2).sum((-2, -1)))


def blew_up(w: np.ndarray) -> float | None:
    """The first frame time (time units, frames 1 apart) at which any of w [S, T, ...] is not finite; None: never."""
    bad = ~np.isfinite(w).all(tuple(i for i in range(w.ndim) if i != 1))
    return float(np.argmax(bad)) if bad.any() else None


def ladder(nu: float, samples: int, cache: Path, paper_dts=(1e-3, 5e-4), paper_t: int | None = None) -> dict:
    from pdestream import generator

    t_end = T_END[nu]
    paper_t = t_end if paper_t is None else paper_t
    tag = f"nu{nu:g}_s{samples}"
    w512 = np.concatenate([grf_w0(np.random.default_rng([200, i]), 1, 512) for i in range(samples)])
    runs = {}
    for n in (64, 128, 256, 512):
        if n == 256:  # the recipe's grid: its full frames, for the peak velocity
            full = cached(cache / f"ours_{tag}_n256_full.npy", lambda: ours(nu, cut(w512, 256), 256, full=True))
            runs[n] = kept(full)
        else:
            runs[n] = cached(cache / f"ours_{tag}_n{n}.npy", lambda n=n: ours(nu, cut(w512, n), n))
    half = cached(cache / f"ours_{tag}_n256_halfdt.npy", lambda: ours(nu, cut(w512, 256), 256, dt_scale=0.5))
    times = list(range(0, t_end + 1, 5))
    paper = {}
    for dt in paper_dts:
        whole = cache / f"paper_{tag}_n256_dt{dt:g}.npy"  # a run over the whole window serves a shorter one
        if whole.is_file():
            paper[dt] = np.load(whole)[:, : paper_t + 1]
            continue
        end = "" if paper_t == t_end else f"_t{paper_t}"
        paper[dt] = cached(cache / f"paper_{tag}_n256_dt{dt:g}{end}.npy", lambda dt=dt: kept(solve_cn(
            cut(w512, 256), nu, dt, range(paper_t + 1), forcing(256), label=f"paper's scheme, nu {nu:g}, dt {dt:g}")))
    ref = runs[512]
    pde = generator.get_pde(recipe_name(nu))
    out = {"nu": nu, "samples": samples, "times": times,
           "recipe_step": pde.solved.step_dt, "recipe_velocity_bound": pde.solved.derived_velocity_bound(),
           "vs_512": {str(n): rel(runs[n][:, times], ref[:, times]).max(0).tolist() for n in (64, 128, 256)},
           "256_vs_256_half_dt": rel(runs[256][:, times], half[:, times]).max(0).tolist(),
           # 512^2's CFL step is half of 256^2's: the 256^2 run at half its step differs from it only in space
           "256_half_dt_vs_512": rel(half[:, times], ref[:, times]).max(0).tolist(),
           "peak_velocity_256": peak_velocity(full).max(0).tolist(),
           "w_std_256": full.std((-2, -1)).mean(0).tolist(), "paper": {}}
    print(f"nu = {nu:g}: {samples} w0 drawn on 512^2; rel L2 (max over samples) at the 64^2 points, t = {times}")
    for n, errs in out["vs_512"].items():
        print(f"  ours {n}^2 against ours 512^2: " + " ".join(f"{e:.1e}" for e in errs))
    print("  ours 256^2 against its half step (the time error): "
          + " ".join(f"{e:.1e}" for e in out["256_vs_256_half_dt"]))
    print("  ours 256^2 at half its step against 512^2 at the same step (the space error): "
          + " ".join(f"{e:.1e}" for e in out["256_half_dt_vs_512"]))
    paper_times = [t for t in times if t <= paper_t]
    for dt, w in paper.items():
        entry = {"blew_up_by": blew_up(w), "times": paper_times,
                 "vs_ours_256": rel(w[:, paper_times], runs[256][:, paper_times]).max(0).tolist(),
                 "vs_ours_512": rel(w[:, paper_times], ref[:, paper_times]).max(0).tolist()}
        out["paper"][f"{dt:g}"] = entry
        print(f"  the paper's scheme at dt {dt:g} against ours 256^2 / 512^2 at t = {paper_times}: "
              + " ".join(f"{e:.1e}" for e in entry["vs_ours_256"]) + " / "
              + " ".join(f"{e:.1e}" for e in entry["vs_ours_512"])
              + (f"; not finite from t = {entry['blew_up_by']:g}" if entry["blew_up_by"] is not None else ""))
    if len(paper) > 1:
        (a, wa), (b, wb) = list(paper.items())[:2]
        out["paper_dt_vs_dt"] = rel(wa[:, paper_times], wb[:, paper_times]).max(0).tolist()
        print(f"  the paper's scheme at dt {a:g} against dt {b:g}: " + " ".join(f"{e:.1e}" for e in out["paper_dt_vs_dt"]))
    print(f"  largest |u| over the 256^2 frames: {max(out['peak_velocity_256']):.3f} (bound assumed by the step "
          f"{out['recipe_velocity_bound']:.3f}, step {out['recipe_step']:.4g})")
    return out


def shell_spectrum(w: np.ndarray, shells: int = 32) -> np.ndarray:
    """Mean over samples of the energy of w [S, n, n] in integer shells |m| = 0..shells-1: [shells]."""
    n = w.shape[-1]
    m = np.fft.fftfreq(n, 1.0 / n)
    shell = np.rint(np.sqrt(m[:, None] ** 2 + m[None, :] ** 2)).astype(int)
    e = (np.abs(np.fft.fft2(w)) ** 2).mean(0) / n**4
    return np.array([e[shell == s].sum() for s in range(shells)])


def initial_conditions(name: str, draws: int = 1024) -> dict:
    """The recipe's w0 on its 256^2 solve grid (``draws`` of its train split) against the measure: the pointwise
    std against sqrt(sum_{m != 0} 7^3 (4 pi^2 |m|^2 + 49)^-2.5) over the modes the 2/3 rule keeps (ours) and over
    every mode (the paper's draw, ``grf_w0``, as many draws)."""
    import jax

    from pdestream import generator
    from pdestream.recipes import RECIPES

    pde = generator.get_pde(name).solved
    keys = jax.random.split(jax.random.PRNGKey(RECIPES[name].splits["train"].seed), draws)
    draw = jax.jit(jax.vmap(pde.sample_ic))
    mine = np.concatenate([np.asarray(draw(keys[i : i + 32]))[:, 0] for i in range(0, draws, 32)])
    mine = np.fft.irfft2(np.asarray(pde.grid.dealias_mask()) * np.fft.rfft2(mine), s=(256, 256))  # frame 0's modes
    theirs = np.concatenate([grf_w0(np.random.default_rng([400, i]), 1, 256) for i in range(draws)])
    m = np.fft.fftfreq(256, 1.0 / 256)
    m2 = m[:, None] ** 2 + m[None, :] ** 2
    lam = np.where(m2 > 0, 7.0**3 * (4 * np.pi**2 * m2 + 49.0) ** -2.5, 0.0)
    band = np.maximum(np.abs(m)[:, None], np.abs(m)[None, :]) <= 256 // 3
    out = {"draws": draws, "ours": [float(mine.std()), float(mine.std((1, 2)).std() / np.sqrt(draws))],
           "paper_draw": [float(theirs.std()), float(theirs.std((1, 2)).std() / np.sqrt(draws))],
           "measure_in_band": float(np.sqrt(lam[band].sum())), "measure": float(np.sqrt(lam.sum()))}
    print(f"  w0 std on 256^2, {draws} draws: ours {out['ours'][0]:.5f} +- {out['ours'][1]:.5f} (the measure over "
          f"the 2/3 band {out['measure_in_band']:.5f}); the paper's draw {out['paper_draw'][0]:.5f} +- "
          f"{out['paper_draw'][1]:.5f} (every mode {out['measure']:.5f})")
    return out


def stats(nu: float, samples: int, cache: Path, chunk: int = 4, paper_samples: int = 8, paper_dt: float = 1e-3
          ) -> dict:
    from pdestream import generator
    from pdestream.recipes import RECIPES

    name, t_end = recipe_name(nu), T_END[nu]
    seed = RECIPES[name].splits["train"].seed
    pde = generator.get_pde(name)
    out = {"nu": nu, "samples": samples, "paper_samples": paper_samples, "paper_dt": paper_dt,
           "initial_conditions": initial_conditions(name), "frames": {}}
    mine, theirs = [], []
    for lo in range(0, samples, chunk):
        hi = min(lo + chunk, samples)
        mine.append(cached(cache / f"recipe_{name}_seed{seed}_{lo}-{hi}.npy", lambda lo=lo, hi=hi: np.asarray(
            generator.sample(pde, range(lo, hi), seed=seed).u)[:, :, 0]))
    for lo in range(0, paper_samples, chunk):
        hi = min(lo + chunk, paper_samples)
        theirs.append(cached(cache / f"paper_{name}_dt{paper_dt:g}_{lo}-{hi}.npy", lambda lo=lo, hi=hi: kept(solve_cn(
            np.concatenate([grf_w0(np.random.default_rng([300, i]), 1, 256) for i in range(lo, hi)]), nu, paper_dt,
            range(t_end + 1), forcing(256), label=f"paper's scheme, samples {lo}..{hi - 1}")).astype(np.float32)))
    mine = np.concatenate(mine)
    theirs = np.concatenate(theirs) if theirs else None
    for t in range(0, t_end + 1, 5):
        a = mine[:, t].std((-2, -1))
        out["frames"][t] = {"ours": [float(a.mean()), float(a.std() / np.sqrt(len(a)))]}
        if theirs is not None:
            b = theirs[:, t].std((-2, -1))
            out["frames"][t]["paper"] = [float(b.mean()), float(b.std() / np.sqrt(len(b)))]
            out["frames"][t]["z"] = float((a.mean() - b.mean()) / np.sqrt(a.var() / len(a) + b.var() / len(b)))
    spectrum = shell_spectrum(mine[:, -1])
    out["spectrum_t_end"] = spectrum[1:17].tolist()
    print(f"{name}: {samples} recipe samples, {paper_samples} of the paper's scheme (dt {paper_dt:g}); spatial std of "
          "w (mean +- sampling error over samples)")
    for t, f in out["frames"].items():
        theirs_text = (f", paper's scheme {f['paper'][0]:.4f} +- {f['paper'][1]:.4f}, z = {f['z']:+.2f}"
                       if "paper" in f else "")
        print(f"  t = {t:>2}: ours {f['ours'][0]:.4f} +- {f['ours'][1]:.4f}{theirs_text}")
    print("  shell energy at t_end, |m| = 1..16: " + " ".join(f"{e:.2e}" for e in out["spectrum_t_end"]))
    if theirs is not None:
        out["spectrum_ratio_t_end"] = (spectrum[1:17] / shell_spectrum(theirs[:, -1])[1:17]).tolist()
        print("  shell energy ours / paper's scheme at t_end: " + " ".join(f"{r:.2f}" for r in out["spectrum_ratio_t_end"]))
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=("ladder", "stats"))
    parser.add_argument("--nu", type=float, default=1e-4, choices=sorted(T_END))
    parser.add_argument("--samples", type=int, default=None, help="ladder: 2, stats: 32")
    parser.add_argument("--paper-samples", type=int, default=8, help="stats: samples of the paper's scheme")
    parser.add_argument("--paper-dt", default="1e-3,5e-4", help="the paper's scheme's steps (stats: the first)")
    parser.add_argument("--paper-t", type=int, default=None, help="ladder: run the paper's scheme to this time")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/fno_ns_fine"))
    parser.add_argument("--results", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    samples = args.samples or (2 if args.what == "ladder" else 32)
    dts = tuple(float(x) for x in args.paper_dt.split(","))
    if args.what == "ladder":
        out = ladder(args.nu, samples, args.cache, dts, args.paper_t)
    else:
        out = stats(args.nu, samples, args.cache, paper_samples=args.paper_samples, paper_dt=dts[0])
    args.results.mkdir(parents=True, exist_ok=True)
    short = f"_paper_t{args.paper_t}" if args.what == "ladder" and args.paper_t is not None else ""
    path = args.results / f"{args.what}_nu{args.nu:g}_s{samples}{short}.json"
    path.write_text(json.dumps(out, indent=1))
    print(f"  written: {path}")


if __name__ == "__main__":
    main()
