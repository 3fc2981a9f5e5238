"""pdebench_cfd1d_* against PDEBench's own 1D compressible generator: ``python -m benchmarks.cfd1d_validation
--pdebench DIR [--samples 2] [--t-end 0.3] [--eta 0.01] [--parts ic_stats,ours,theirs] [--out DIR]``.

- ``ic_stats``: --ic-samples (1024) initial states from each generator (PDEBench's ``init_multi_HD`` as its CFD_multi_Hydra.py
  calls it, and our ``ic=sines``): per-field moments (mean of the per-sample mean, std, min, max and their
  spread), the share of windowed samples and the low-wavenumber power, each with its standard error.
- ``same_ic``: PDEBench's initial states (init_key 2022, drawn on 2048 cells and averaged to 1024 and 512) given
  to both solvers at 1024 cells, and at 512 and 2048 to each, t in [0, t_end] at 0.01 (its draws do not depend
  on nx, but its wavenumbers 2 pi k / (2 - dx) do: states drawn on each grid would differ by 0.24% between 512 and
  1024 cells, more than the solvers' own differences). Reported per frame: the relative L2 distance between the two
  solvers at 1024, and each solver's own space error at 1024 (its 1024 run against its 2048 run averaged to 1024
  cells), all fields stacked. PDEBench's solver runs through its Hydra entry point (``main(cfg)``), unchanged.

--pdebench DIR: a directory holding PDEBench's ``pdebench`` package (the pdebench 0.1.0 wheel unpacked); it
needs ``hydra-core`` and ``omegaconf`` importable. Each part's results are saved under --out as they finish
(npz of the trajectories outside the repository, json of the figures inside), so a rerun resumes.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

GAMMA = 5.0 / 3.0
KEY = 2022  # PDEBench's default init_key (its train files use 2020..2029)
FINEST = 2048  # initial states are drawn here and averaged to 1024 and 512 cells, for both solvers


def _pdebench_paths(root: str) -> tuple[str, str]:
    gen = os.path.join(root, "pdebench", "data_gen", "data_gen_NLE")
    return gen, os.path.join(gen, "CompressibleFluid")


def pdebench_ic(root: str, n: int, count: int, key: int = KEY) -> np.ndarray:
    """PDEBench's 1D_rand initial states [count, 3, n] (rho, u, p) on its cell centres of [-1, 1], as
    CFD_multi_Hydra.py:657-669 draws them."""
    gen, _ = _pdebench_paths(root)
    sys.path.insert(0, gen)
    import jax.numpy as jnp
    from utils import init_multi_HD  # PDEBench's own

    xe = jnp.linspace(-1.0, 1.0, n + 1)
    xc = xe[:-1] + 0.5 * (2.0 / n)
    yc = zc = jnp.zeros(1)
    rho = init_multi_HD(xc, yc, zc, numbers=count, k_tot=3, init_key=key, num_choise_k=2, umin=1.0, umax=10.0,
                        if_renorm=True)
    p = init_multi_HD(xc, yc, zc, numbers=count, k_tot=3, init_key=key + 1, num_choise_k=2, umin=10.0, umax=100.0,
                      if_renorm=True)
    u = init_multi_HD(xc, yc, zc, numbers=count, k_tot=3, init_key=key + 2, num_choise_k=2, if_renorm=False)
    return np.stack([np.asarray(a)[..., 0, 0] for a in (rho, u, p)], axis=1).astype(np.float32)


def pdebench_run(root: str, u0: np.ndarray, t_end: float, eta: float, scratch: Path) -> np.ndarray:
    """PDEBench's solver from the initial states u0 [count, 3, n] (rho, u, p): frames [count, T, 3, n] at t = 0,
    0.01, ..., t_end (its Hydra entry point with 1D_Multi.yaml's settings, numbers, nx, fin_time and eta = zeta
    changed; its IC function, called as init_multi_HD(..., init_key=KEY + j) for rho, p, u, hands it u0's fields)."""
    gen, cfd_dir = _pdebench_paths(root)
    for d in (gen, cfd_dir):
        sys.path.insert(0, d)
    import CFD_multi_Hydra as cfd  # PDEBench's own
    import jax.numpy as jnp
    from omegaconf import OmegaConf

    count, n = u0.shape[0], u0.shape[-1]
    fields = {KEY: u0[:, 0], KEY + 1: u0[:, 2], KEY + 2: u0[:, 1]}  # its order of calls: rho, p, u

    def given_ic(xc, yc, zc, numbers, init_key, **_):
        assert numbers == count and xc.shape[0] == n
        return jnp.asarray(fields[init_key])[..., None, None]

    cfd.init_multi_HD = given_ic  # its solver unchanged; only where its initial states come from
    save = scratch / f"pdebench_n{n}_eta{eta:g}_t{t_end:g}_given/"
    save.mkdir(parents=True, exist_ok=True)
    args = dict(save=str(save) + "/", dt_save=0.01, ini_time=0.0, fin_time=t_end, nx=n, ny=1, nz=1, xL=-1.0, xR=1.0,
                yL=-1.0, yR=1.0, zL=-1.0, zR=1.0, bc="periodic", gamma=GAMMA, eta=eta, zeta=eta, CFL=0.3,
                if_second_order=1.0, if_show=0, show_steps=100, p_floor=1e-4, numbers=count,
                init_mode_Multi="1D_rand", init_key=KEY, if_rand_param=False, M0=0.0)
    cfd.main(OmegaConf.create({"args": args}))
    stem = f"HD_Sols_1D_rand_Eta{str(eta)[:5]}_Zeta{str(eta)[:5]}_M0.0_key{KEY}_"
    fields = [np.load(save / f"{stem}{f}.npy")[..., 0, 0] for f in ("D", "Vx", "P")]  # [count, T, n] each
    return np.stack(fields, axis=2).astype(np.float32)


def ours_run(u0: np.ndarray, t_end: float, eta: float) -> np.ndarray:
    """pdebench_cfd1d_rand's solver (compressible_ns1d) from given states u0 [B, 3, n]: frames [B, T, 3, n]."""
    from pdestream import generator as g

    n = u0.shape[-1]
    pde = g.get_pde("pdebench_cfd1d_rand_eta1e-2", n=n, t_end=t_end, n_frames=int(round(t_end / 0.01)) + 1,
                    eta=str(eta), zeta=str(eta))
    return np.asarray(g.solve(pde, u0, {"gamma": GAMMA, "eta": eta, "zeta": eta}).u, np.float32)


def coarsen(u: np.ndarray, factor: int) -> np.ndarray:
    """Cell averages [..., n / factor] of [..., n] (the finer run on the coarser grid)."""
    return u.reshape(*u.shape[:-1], u.shape[-1] // factor, factor).mean(-1)


def rel_l2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative L2 distance per frame [T] over samples, fields (each scaled by b's rms) and cells."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    scale = np.sqrt((b ** 2).mean(axis=(0, 1, 3), keepdims=True))  # per field
    d = ((a - b) / scale) ** 2
    return np.sqrt(d.mean(axis=(0, 2, 3)) / ((b / scale) ** 2).mean(axis=(0, 2, 3)))


def moments(u0: np.ndarray) -> dict:
    """Per-field statistics of initial states [S, 3, n] with their standard errors over samples."""
    out = {}
    spec = np.abs(np.fft.rfft(u0, axis=-1)) ** 2 / u0.shape[-1] ** 2
    for i, name in enumerate(("rho", "u", "p")):
        f = u0[:, i].astype(np.float64)
        per = {"mean": f.mean(-1), "std": f.std(-1), "min": f.min(-1), "max": f.max(-1),
               "power_k1_3": spec[:, i, 1:4].sum(-1), "power_k4_12": spec[:, i, 4:13].sum(-1)}
        if name == "u":
            per["flat_half"] = (np.abs(f[:, : f.shape[-1] // 2]).max(-1) < 1e-3).astype(np.float64)
        out[name] = {k: [float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v)))] for k, v in per.items()}
    return out


def pdebench_ic_2d(root: str, n: int, count: int, mach: float, key: int = KEY) -> np.ndarray:
    """PDEBench's 2D_rand initial states [count, 4, n, n] (rho, u, v, p) on [0, 1]^2, as CFD_multi_Hydra.py:696-700
    draws them (init_multi_HD_2DRand, k_tot 4)."""
    gen, _ = _pdebench_paths(root)
    sys.path.insert(0, gen)
    import jax.numpy as jnp
    from utils import init_multi_HD_2DRand  # PDEBench's own

    edges = jnp.linspace(0.0, 1.0, n + 1)
    xc = edges[:-1] + 0.5 / n
    q = jnp.zeros([count, 5, n + 4, n + 4, 5])
    q = init_multi_HD_2DRand(q, xc, xc, jnp.zeros(1), numbers=count, init_key=key, M0=mach, k_tot=4, gamma=GAMMA)
    q = np.asarray(q[:, :, 2:-2, 2:-2, 2], np.float32)  # [count, 5, n, n]: rho, u, v, w, p
    return q[:, [0, 1, 2, 4]]


def moments_2d(u0: np.ndarray) -> dict:
    """Per-field statistics of 2D states [S, 4, n, n] and the Mach number of the mean speed (standard errors)."""
    out = {}
    for i, name in enumerate(("rho", "u", "v", "p")):
        f = u0[:, i].reshape(len(u0), -1).astype(np.float64)
        per = {"mean": f.mean(-1), "std": f.std(-1), "min": f.min(-1), "max": f.max(-1)}
        out[name] = {k: [float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v)))] for k, v in per.items()}
    rho, u, v, p = (u0[:, i].astype(np.float64) for i in range(4))
    mach = np.sqrt(u * u + v * v).mean((1, 2)) / np.sqrt(GAMMA * p.mean((1, 2)) / rho.mean((1, 2)))
    moving = np.abs(u[:, : u.shape[1] // 20]).max((1, 2)) > 1e-6  # not at rest near x = 0: no window
    out["mean_speed_over_c"] = [float(mach.mean()), float(mach.std(ddof=1) / np.sqrt(len(mach)))]
    out["unwindowed_share"] = [float(moving.mean()), float(moving.std(ddof=1) / np.sqrt(len(moving)))]
    return out


def part_ic_stats_2d(root: str, n: int, count: int, mach: float) -> dict:
    import jax

    from pdestream import generator as g

    pde = g.get_pde(f"pdebench_cfd2d_rand_m{mach:g}_eta1e-2", n=n)
    keys = jax.random.split(jax.random.PRNGKey(0), count)
    sample = jax.jit(lambda k: pde.ic.sample(k, pde.grid))
    ours = np.stack([np.asarray(sample(k)) for k in keys])
    theirs = pdebench_ic_2d(root, n, count, mach)
    a, b = moments_2d(ours), moments_2d(theirs)
    z = {f: ({k: (a[f][k][0] - b[f][k][0]) / np.hypot(a[f][k][1], b[f][k][1]) for k in a[f]}
             if isinstance(a[f], dict) else (a[f][0] - b[f][0]) / np.hypot(a[f][1], b[f][1])) for f in a}
    return {"samples": count, "n": n, "mach": mach, "ours": a, "pdebench": b, "z": z}


def part_ic_stats(root: str, n: int, count: int) -> dict:
    import jax

    from pdestream import generator as g

    pde = g.get_pde("pdebench_cfd1d_rand_eta1e-2", n=n)
    keys = jax.random.split(jax.random.PRNGKey(0), count)
    ours = np.asarray(jax.jit(jax.vmap(lambda k: pde.ic.sample(k, pde.grid)))(keys))
    theirs = pdebench_ic(root, n, count)
    a, b = moments(ours), moments(theirs)
    z = {f: {k: (a[f][k][0] - b[f][k][0]) / np.hypot(a[f][k][1], b[f][k][1]) for k in a[f]} for f in a}
    return {"samples": count, "n": n, "ours": a, "pdebench": b, "z": z}


def plot(ours: np.ndarray, theirs: np.ndarray, path: str, sample: int = 0, frames=(0, 10, 30)) -> None:
    """rho, u, p of one sample at a few frames (t = 0.01 each): ours (lines) over PDEBench's (dots), 1024 cells."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = ours.shape[-1]
    x = -1 + (np.arange(n) + 0.5) * 2 / n  # PDEBench's coordinates
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    for f, (ax, name) in enumerate(zip(axes, ("rho", "u", "p"))):
        for j, i in enumerate(frames):
            ax.plot(x, ours[sample, i, f], color=f"C{j}", lw=1.2, label=f"pdestream t = {i / 100:g}")
            ax.plot(x[::16], theirs[sample, i, f, ::16], ".", color=f"C{j}", ms=3.5,
                    label=f"PDEBench t = {i / 100:g}")
        ax.set_title(name)
        ax.set_xlabel("x (PDEBench's [-1, 1])")
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle("The same initial state in both generators (pdebench_cfd1d, 1024 cells; PDEBench every 16th cell)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pdebench", required=True)
    ap.add_argument("--samples", type=int, default=2)
    ap.add_argument("--t-end", type=float, default=0.3)
    ap.add_argument("--eta", type=float, default=0.01)
    ap.add_argument("--parts", default="ic_stats,ours,theirs1024,theirs512,theirs2048",
                    help="ic_stats, ic_stats_2d_m0.1, ic_stats_2d_m1; ours (every n) or ours1024 / ours512 / ours2048; theirs1024 / theirs512 / theirs2048")
    ap.add_argument("--ic-samples", type=int, default=1024)
    ap.add_argument("--plot", default="", help="a PNG of sample 0 from both generators at 1024 cells")
    ap.add_argument("--scratch", default="/tmp/cfd1d_validation")
    ap.add_argument("--out", default="benchmarks/results/cfd1d")
    a = ap.parse_args(argv)
    out, scratch = Path(a.out), Path(a.scratch)
    out.mkdir(parents=True, exist_ok=True)
    scratch.mkdir(parents=True, exist_ok=True)
    summary_path = out / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    parts = a.parts.split(",")
    tag = f"eta{a.eta:g}_t{a.t_end:g}_s{a.samples}_avg{FINEST}"
    initial = pdebench_ic(a.pdebench, FINEST, a.samples)

    def save():
        summary_path.write_text(json.dumps(summary, indent=1))

    if "ic_stats" in parts and summary.get("ic_stats", {}).get("samples") != a.ic_samples:
        t0 = time.time()
        summary["ic_stats"] = part_ic_stats(a.pdebench, 1024, a.ic_samples)
        print(f"ic_stats done in {time.time() - t0:.0f} s", flush=True)
        save()

    for mach in (0.1, 1.0):
        name = f"ic_stats_2d_m{mach:g}"
        if name in parts and summary.get(name, {}).get("samples") != 256:
            t0 = time.time()
            summary[name] = part_ic_stats_2d(a.pdebench, 128, 256, mach)
            print(f"{name} done in {time.time() - t0:.0f} s", flush=True)
            save()
    if not any(p.startswith(("ours", "theirs")) for p in parts):
        return

    def traj(who: str, n: int) -> np.ndarray | None:
        path = scratch / f"{who}_n{n}_{tag}.npy"
        if path.exists():
            return np.load(path)
        if f"{who}{n}" not in parts and not (who == "ours" and "ours" in parts):
            return None
        t0 = time.time()
        u0 = coarsen(initial, FINEST // n)  # the finest grid's states as cell averages
        u = ours_run(u0, a.t_end, a.eta) if who == "ours" else pdebench_run(a.pdebench, u0, a.t_end, a.eta, scratch)
        np.save(path, u)
        summary.setdefault("wall_s", {})[f"{who}_n{n}_{tag}"] = round(time.time() - t0, 1)
        print(f"{who} n={n}: {time.time() - t0:.0f} s, finite {bool(np.isfinite(u).all())}", flush=True)
        save()
        return u

    runs = {(w, n): traj(w, n) for n in (1024, 512, 2048) for w in ("ours", "theirs")}
    res = summary.setdefault("same_ic", {}).setdefault(tag, {})
    times = np.arange(int(round(a.t_end / 0.01)) + 1) * 0.01
    pick = [i for i, t in enumerate(times) if round(t * 100) % 5 == 0]

    def record(name, x, y):
        if x is not None and y is not None:
            m = min(x.shape[1], y.shape[1])
            res[name] = {f"{times[i]:.2f}": round(float(v), 5) for i, v in enumerate(rel_l2(x[:, :m], y[:, :m]))
                         if i in pick}

    o, t = runs[("ours", 1024)], runs[("theirs", 1024)]
    record("apart_1024 (ours vs pdebench)", o, t)
    for who in ("ours", "theirs"):
        fine, mid, coarse = runs[(who, 2048)], runs[(who, 1024)], runs[(who, 512)]
        record(f"{who}_space_error_1024 (vs its 2048)", mid, None if fine is None else coarsen(fine, 2))
        record(f"{who}_space_error_512 (vs its 1024)", coarse, None if mid is None else coarsen(mid, 2))
    if runs[("ours", 2048)] is not None and runs[("theirs", 2048)] is not None:
        record("apart_2048 (ours vs pdebench)", runs[("ours", 2048)], runs[("theirs", 2048)])
    save()
    print(json.dumps(res, indent=1))
    if a.plot and o is not None and t is not None:
        plot(o, t, a.plot)


if __name__ == "__main__":
    main()
