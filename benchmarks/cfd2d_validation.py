"""pdebench_cfd2d_rand_* against PDEBench's own 2D compressible generator, one state in both: ``python -m
benchmarks.cfd2d_validation --pdebench DIR [--samples 2] [--t-end 0.2] [--mach 0.1] [--eta 0.01]
[--parts ours,theirs128,theirs64] [--out DIR]``.

PDEBench's 2D_rand states (init_key 2022, ``init_multi_HD_2DRand``) are drawn on 256^2 and averaged to 128^2 and
64^2; both solvers start from them (PDEBench's through its Hydra entry point, its IC function handed the states,
as ``benchmarks.cfd1d_validation`` does in 1D). Reported per frame (every 0.05): the relative L2 distance between
the two at 128^2 (the recipes' grid), our space error at 128^2 (against our 256^2 run averaged to 128^2), and each
solver's 64^2 run against its own 128^2 run. Results resume from --out/summary.json and the scratch trajectories.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.cfd1d_validation import GAMMA, KEY, _pdebench_paths, pdebench_ic_2d, rel_l2

FINEST = 256


def coarsen2(u: np.ndarray, factor: int) -> np.ndarray:
    """Cell averages [..., n / f, n / f] of [..., n, n]."""
    *lead, nx, ny = u.shape
    return u.reshape(*lead, nx // factor, factor, ny // factor, factor).mean((-3, -1))


def pdebench_run_2d(root: str, u0: np.ndarray, t_end: float, eta: float, mach: float, scratch: Path) -> np.ndarray:
    """PDEBench's solver (2D_Multi_Rand.yaml's settings, nx = ny, numbers, fin_time, eta = zeta changed) from the
    states u0 [count, 4, n, n] (rho, u, v, p): frames [count, T, 4, n, n] at t = 0, 0.05, ..., t_end."""
    gen, cfd_dir = _pdebench_paths(root)
    for d in (gen, cfd_dir):
        sys.path.insert(0, d)
    import CFD_multi_Hydra as cfd  # PDEBench's own
    import jax.numpy as jnp
    from omegaconf import OmegaConf

    count, n = u0.shape[0], u0.shape[-1]

    def given_ic(q, xc, yc, zc, numbers, **_):
        assert numbers == count and xc.shape[0] == n
        state = jnp.asarray(u0)[..., None]  # [count, 4, n, n, 1]
        for slot, f in ((0, 0), (1, 1), (2, 2), (4, 3)):
            q = q.at[:, slot, 2:-2, 2:-2, 2:-2].set(state[:, f])
        return q

    cfd.init_multi_HD_2DRand = given_ic  # its solver unchanged; only where its initial states come from
    save = scratch / f"pdebench2d_n{n}_m{mach:g}_eta{eta:g}_t{t_end:g}_given/"
    save.mkdir(parents=True, exist_ok=True)
    args = dict(save=str(save) + "/", dt_save=0.05, ini_time=0.0, fin_time=t_end, nx=n, ny=n, nz=1, xL=0.0, xR=1.0,
                yL=0.0, yR=1.0, zL=0.0, zR=1.0, bc="periodic", gamma=GAMMA, eta=eta, zeta=eta, CFL=0.3,
                if_second_order=1.0, if_show=0, show_steps=100, p_floor=1e-4, numbers=count,
                init_mode_Multi="2D_rand", M0=mach, k_tot=4, init_key=KEY, if_rand_param=False)
    cfd.main(OmegaConf.create({"args": args}))
    stem = f"HD_Sols_2D_rand_Eta{str(eta)[:5]}_Zeta{str(eta)[:5]}_M{mach}_key{KEY}_"
    fields = [np.load(save / f"{stem}{f}.npy")[..., 0] for f in ("D", "Vx", "Vy", "P")]  # [count, T, n, n]
    return np.stack(fields, axis=2).astype(np.float32)


def ours_run_2d(u0: np.ndarray, t_end: float, eta: float, mach: float) -> np.ndarray:
    from pdestream import generator as g

    n = u0.shape[-1]
    pde = g.get_pde(f"pdebench_cfd2d_rand_m{mach:g}_eta1e-2", n=n, t_end=t_end,
                    n_frames=int(round(t_end / 0.05)) + 1, eta=str(eta), zeta=str(eta))
    return np.asarray(g.solve(pde, u0, {"gamma": GAMMA, "eta": eta, "zeta": eta}).u, np.float32)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pdebench", required=True)
    ap.add_argument("--samples", type=int, default=2)
    ap.add_argument("--t-end", type=float, default=0.2)
    ap.add_argument("--mach", type=float, default=0.1)
    ap.add_argument("--eta", type=float, default=0.01)
    ap.add_argument("--parts", default="ours128,theirs128,ours64,theirs64,ours256")
    ap.add_argument("--scratch", default="/tmp/cfd2d_validation")
    ap.add_argument("--out", default="benchmarks/results/cfd2d")
    a = ap.parse_args(argv)
    out, scratch = Path(a.out), Path(a.scratch)
    out.mkdir(parents=True, exist_ok=True)
    scratch.mkdir(parents=True, exist_ok=True)
    path = out / "summary.json"
    summary = json.loads(path.read_text()) if path.exists() else {}
    tag = f"m{a.mach:g}_eta{a.eta:g}_t{a.t_end:g}_s{a.samples}_avg{FINEST}"
    initial = pdebench_ic_2d(a.pdebench, FINEST, a.samples, a.mach)
    runs = {}
    for who, n in (("ours", 128), ("theirs", 128), ("ours", 64), ("theirs", 64), ("ours", 256)):
        file = scratch / f"{who}2d_n{n}_{tag}.npy"
        if file.exists():
            runs[(who, n)] = np.load(file)
        elif f"{who}{n}" in a.parts.split(","):
            t0 = time.time()
            u0 = coarsen2(initial, FINEST // n)
            u = (ours_run_2d(u0, a.t_end, a.eta, a.mach) if who == "ours"
                 else pdebench_run_2d(a.pdebench, u0, a.t_end, a.eta, a.mach, scratch))
            np.save(file, u)
            runs[(who, n)] = u
            summary.setdefault("wall_s", {})[f"{who}2d_n{n}_{tag}"] = round(time.time() - t0, 1)
            print(f"{who} n={n}: {time.time() - t0:.0f} s, finite {bool(np.isfinite(u).all())}", flush=True)
            path.write_text(json.dumps(summary, indent=1))
    res = summary.setdefault("same_ic_2d", {}).setdefault(tag, {})
    times = np.arange(int(round(a.t_end / 0.05)) + 1) * 0.05

    def flat(u):  # [S, T, C, n, n] -> [S, T, C, n * n] for rel_l2
        return u.reshape(*u.shape[:3], -1)

    def record(name, x, y):
        if x is not None and y is not None:
            res[name] = {f"{t:.2f}": round(float(v), 5) for t, v in zip(times, rel_l2(flat(x), flat(y)))}

    get = runs.get
    record("apart_128 (ours vs pdebench)", get(("ours", 128)), get(("theirs", 128)))
    fine = get(("ours", 256))
    record("ours_space_error_128 (vs its 256)", get(("ours", 128)), None if fine is None else coarsen2(fine, 2))
    for who in ("ours", "theirs"):
        mid = get((who, 128))
        record(f"{who}_64 (vs its 128)", get((who, 64)), None if mid is None else coarsen2(mid, 2))
    path.write_text(json.dumps(summary, indent=1))
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
