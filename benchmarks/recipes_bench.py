"""Recipes against their published set-ups: ``python -m benchmarks.recipes_bench [--samples 256] [--only a,b]``.

pdebench_advection1d: our solution against the exact translate u0(x - c t) of the same initial condition (the IC
function evaluated at the shifted points), per sample; the IC statistics of 256 regenerated samples against an
independent numpy draw of PDEBench's measure as its generator writes it (utils.py init_multi: cell centres,
wavenumbers 2 pi k / (1 - dx)). fno_burgers1d: u0's pointwise std against the measure's
sqrt(sum_{k != 0} 625 (4 pi^2 k^2 + 25)^-2), the conserved mean, and u(t = 1) against a 4x finer solve of the same
u0. fno_ns2d_nu1e-3: w0's std against sqrt(sum_{k != 0} 7^3 (4 pi^2 |k|^2 + 49)^-2.5) and w(t = 50) against a
2x finer solve of the same w0. Figures, not pass/fail (docs/results/recipes.md).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def rel(a, b, axes) -> np.ndarray:
    """Relative L2 error of a against b over ``axes``, per sample."""
    return np.sqrt(((a - b) ** 2).sum(axes) / (b**2).sum(axes))


def pdebench_measure(rng: np.random.Generator, n_samples: int, n: int, normalise: bool = False) -> np.ndarray:
    """PDEBench's init_multi as its code draws it (k_tot 4, two picks), independent draws, numpy: [S, n]."""
    dx = 1.0 / n
    xc = (np.arange(n) + 0.5) * dx
    picks = rng.integers(0, 4, (n_samples, 2))
    count = np.stack([(picks == k).sum(1) for k in range(4)], 1)  # [S, 4]
    kk = 2 * np.pi * np.arange(1, 5) * count / (xc[-1] - xc[0])
    amp = rng.uniform(size=(n_samples, 4, 1))
    phase = 2 * np.pi * rng.uniform(size=(n_samples, 4, 1))
    u = (amp * np.sin(kk[:, :, None] * xc + phase)).sum(1)
    u = np.where(rng.uniform(size=(n_samples, 1)) < 0.1, np.abs(u), u)
    u = u * rng.choice([1, -1], size=(n_samples, 1))
    xl, xr = rng.uniform(0.1, 0.45, (n_samples, 1)), rng.uniform(0.55, 0.9, (n_samples, 1))
    window = 0.5 * (np.tanh((xc - xl) / 0.01) - np.tanh((xc - xr) / 0.01))
    u = np.where(rng.uniform(size=(n_samples, 1)) < 0.1, u * window, u)
    if normalise:
        u = u - u.min(1, keepdims=True)
        u = u / u.max(1, keepdims=True)
    return u


def moments(u: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, its standard error over samples, std, its standard error): u [S, ...] pooled over space."""
    per_mean, per_std = u.reshape(len(u), -1).mean(1), u.reshape(len(u), -1).std(1)
    s = len(u)
    return float(u.mean()), float(per_mean.std() / np.sqrt(s)), float(u.std()), float(per_std.std() / np.sqrt(s))


def advection(samples: int) -> None:
    import jax

    from pdestream import generator
    from pdestream.generator.ics import RandomSines

    t0 = time.perf_counter()
    pde = generator.get_pde("pdebench_advection1d")
    x = np.asarray(pde.grid.coords(), np.float64)
    ic, speeds = RandomSines(), np.array([0.1, 0.4, 1.0, 4.0])
    keys = [jax.random.fold_in(jax.random.PRNGKey(7), i) for i in range(samples)]
    u0 = np.stack([np.asarray(ic._one(k, jax.numpy.asarray(x, jax.numpy.float32), 1.0)) for k in keys])
    c = speeds[np.arange(samples) % 4]
    ours = np.asarray(generator.solve(pde, u0[:, None], {"c": c.astype(np.float32)}).u)[:, :, 0]  # [S, T, n]
    times = np.asarray(pde.times())
    errs = {}
    for j in (1, 100, 200):
        exact = np.stack([np.asarray(ic._one(k, jax.numpy.asarray((x - ci * times[j]) % 1.0, jax.numpy.float32), 1.0))
                          for k, ci in zip(keys, c)])
        errs[j] = rel(ours[:, j], exact, 1)
    print(f"pdebench_advection1d: {samples} samples, n={pde.n}, 201 frames, c in {{0.1, 0.4, 1, 4}} "
          f"({time.perf_counter() - t0:.0f} s)")
    for j, e in errs.items():
        print(f"  t={times[j]:.2f}: rel L2 vs the exact translate: median {np.median(e):.2e}, "
              f"99th percentile {np.percentile(e, 99):.2e}, max {e.max():.2e}")
    traj = np.asarray(generator.sample(pde, range(samples), seed=0).u)[:, :, 0]
    ref = pdebench_measure(np.random.default_rng(0), 40 * samples, pde.n)
    subsets = ref.reshape(40, samples, -1)  # the spread of the moments of `samples` draws: the sampling error
    spread_m, spread_s = subsets.mean((1, 2)).std(), subsets.std((1, 2)).std()
    print(f"  u0 ours (recipe, seed 0): mean {traj[:, 0].mean():+.4f}, std {traj[:, 0].std():.4f}; PDEBench's measure "
          f"({40 * samples} numpy draws): mean {ref.mean():+.4f}, std {ref.std():.4f}; sampling error of "
          f"{samples} draws: mean +- {spread_m:.4f}, std +- {spread_s:.4f}")
    m, dm, s, ds = moments(traj[:, -1])
    print(f"  u(t=2) ours: mean {m:+.4f} +- {dm:.4f}, std {s:.4f} +- {ds:.4f} (advection keeps each sample's moments)")


def fno_burgers(samples: int) -> None:
    from pdestream import generator

    t0 = time.perf_counter()
    pde = generator.get_pde("fno_burgers1d")
    traj = np.asarray(generator.sample(pde, range(samples), seed=0).u)[:, :, 0]  # [S, 2, 1024]
    k = np.arange(1, 100000)
    exact_std = np.sqrt(2 * (625 * (4 * np.pi**2 * k**2 + 25.0) ** -2).sum())
    m0, dm0, s0, ds0 = moments(traj[:, 0])
    m1, dm1, s1, ds1 = moments(traj[:, 1])
    drift = np.abs(traj[:, 1].mean(1) - traj[:, 0].mean(1)).max()
    print(f"fno_burgers1d: {samples} samples, n=1024, nu=0.1, t=0 and 1 ({time.perf_counter() - t0:.0f} s)")
    print(f"  u0: mean {m0:+.4f} +- {dm0:.4f}, std {s0:.4f} +- {ds0:.4f}; the measure's std {exact_std:.4f}")
    print(f"  u(t=1): mean {m1:+.4f} +- {dm1:.4f}, std {s1:.4f} +- {ds1:.4f}; max |mean drift| per sample {drift:.1e}")
    few = 16
    fine = generator.get_pde("fno_burgers1d", n=4096)
    u0 = traj[:few, 0]
    hat = np.fft.rfft(u0, axis=-1)
    padded = np.zeros((few, 4096 // 2 + 1), complex)
    padded[:, : hat.shape[1]] = hat * 4
    u0_fine = np.fft.irfft(padded, n=4096, axis=-1)
    coarse = np.asarray(generator.solve(pde, u0[:, None], {"nu": np.full(few, 0.1, np.float32)}).u)[:, -1, 0]
    fine_end = np.asarray(generator.solve(fine, u0_fine[:, None], {"nu": np.full(few, 0.1, np.float32)}).u)[:, -1, 0]
    e = rel(coarse, fine_end[:, ::4], 1)
    print(f"  u(t=1) on 1024 vs a 4096 solve of the same u0 ({few} samples): rel L2 median {np.median(e):.1e}, "
          f"max {e.max():.1e}")


def fno_ns(samples: int) -> None:
    from pdestream import generator

    t0 = time.perf_counter()
    pde = generator.get_pde("fno_ns2d_nu1e-3")
    traj = np.asarray(generator.sample(pde, range(samples), seed=0).u)[:, :, 0]  # [S, 51, 64, 64]
    m = np.fft.fftfreq(64, 1 / 64)
    k2 = sum(x**2 for x in np.meshgrid(m, m, indexing="ij"))
    band = np.maximum.reduce(np.abs(np.meshgrid(m, m, indexing="ij"))) <= 64 // 3
    lam = np.where(k2 > 0, 7.0**3 * (4 * np.pi**2 * k2 + 49.0) ** -2.5, 0.0)
    print(f"fno_ns2d_nu1e-3: {samples} samples, 64^2, t = 0..50 ({time.perf_counter() - t0:.0f} s)")
    print(f"  the measure's w0 std {np.sqrt(lam.sum()):.4f} (all modes), {np.sqrt((lam * band).sum()):.4f} "
          "(our 2/3 band)")
    for j in (0, 10, 50):
        mu, dmu, s, ds = moments(traj[:, j])
        print(f"  w(t={j}): mean {mu:+.4f} +- {dmu:.4f}, std {s:.4f} +- {ds:.4f}, max |w| {np.abs(traj[:, j]).max():.3f}")
    few = 4
    fine = generator.get_pde("fno_ns2d_nu1e-3", n=128)
    hat = np.fft.fft2(traj[:few, 0])
    pad = np.zeros((few, 128, 128), complex)
    idx = np.r_[0:32, 96:128]
    pad[:, idx[:, None], idx[None, :]] = hat * 4  # modes m = 0..31, -32..-1 into the 128-point layout
    w0_fine = np.fft.ifft2(pad).real
    nu = {"nu": np.full(few, 1e-3, np.float32)}
    end = np.asarray(generator.solve(fine, w0_fine[:, None], nu).u)[:, :, 0, ::2, ::2]
    for j in (10, 50):
        e = rel(traj[:few, j], end[:, j], (1, 2))
        print(f"  w(t={j}) on 64^2 vs a 128^2 solve of the same w0 ({few} samples): rel L2 max {e.max():.1e}")
    bound = pde.derived_velocity_bound()
    for factor in (5, 20):  # the CFL step is dx / velocity_bound: a larger bound, a smaller step
        small = generator.get_pde("fno_ns2d_nu1e-3", velocity_bound=factor * bound)
        w = np.asarray(generator.solve(small, traj[:few, :1], nu).u)[:, -1, 0]
        print(f"  w(t=50) at the recipe's step vs 1/{factor} of it ({few} samples): rel L2 max "
              f"{rel(traj[:few, -1], w, (1, 2)).max():.1e}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--only", default="advection,burgers,ns")
    args = parser.parse_args(argv)
    runs = {"advection": advection, "burgers": fno_burgers, "ns": fno_ns}
    for name in args.only.split(","):
        runs[name](args.samples)


if __name__ == "__main__":
    main()
