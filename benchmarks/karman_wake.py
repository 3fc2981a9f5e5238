"""The street's physics in the corrected rollouts (issue 29: "for the street the corrected run's Strouhal number and
drag against the fine reference"): Strouhal number, mean drag and lift amplitude of every arm of a
``benchmarks.karman_sitl`` run, against the fine solve's own.

    nice python -m benchmarks.karman_wake --out DIR [--shift 0.25]

For each seed directory DIR/seedS written by ``karman_sitl`` (its compare.json names the fine PDE, its arms'
model.pt the trained corrections), the held-out sets of that run are rebuilt (the same Latin hypercube and ICs:
inside the training Re range, and beyond it by ``--shift`` as karman_sitl moves it), each arm rolled out on the
coarse grid from the first frame as karman_sitl does, and the karman2d entry's own outputs (``sample_outputs``:
the body force's surface integral on the exact circle, ``forces.shedding`` on the lift) computed from every
rollout's frames on the coarse grid, and from the fine solve's frames on the fine grid (the reference). Printed
per test set and arm, over trajectories and seeds: the mean relative error of the Strouhal number, of the
window's mean drag and of the lift amplitude against the fine solve's, and how many rollouts shed (the fine
reference's count beside). The same estimator on the fine solve restricted to the coarse grid ("reference on
the coarse grid") shows what the coarse grid's estimator alone costs. Figures, not pass/fail; DIR/wake.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ARMS = (("coarse solver", None), ("pairs (unroll 1)", "sitl_unroll1"),
        ("pairs + noise (unroll 1)", "sitl_unroll1_noise"))


_JITTED: dict = {}  # id(pde) -> (pde, its jitted sample_outputs)


def _outputs(pde, frames, params) -> dict[str, np.ndarray]:
    """karman2d's outputs of each trajectory: frames [B, T, C, *space] (torch, physical units) on ``pde``'s grid,
    params [B, P] -> {"strouhal", "sheds", "drag" (window mean), "lift_amplitude"} as numpy [B]."""
    import jax
    import jax.numpy as jnp

    if id(pde) not in _JITTED:  # one compiled program per grid (eager calls compiled one per trajectory: out of memory)
        _JITTED[id(pde)] = (pde, jax.jit(pde.sample_outputs))
    outputs = _JITTED[id(pde)][1]
    out = {k: [] for k in ("strouhal", "sheds", "drag", "lift_amplitude")}
    for b in range(frames.shape[0]):
        p = {name: jnp.asarray(float(params[b, i]), jnp.float32) for i, name in enumerate(pde.PARAMS)}
        o = outputs(jnp.asarray(frames[b].numpy()), p)
        out["strouhal"].append(float(o["strouhal"]))
        out["sheds"].append(bool(o["sheds"]))
        out["drag"].append(float(np.mean(o["drag"])))
        out["lift_amplitude"].append(float(o["lift_amplitude"]))
    return {k: np.array(v) for k, v in out.items()}


def _relative(a: np.ndarray, ref: np.ndarray) -> float:
    """Mean |a - ref| / |ref| over trajectories where the reference is nonzero (a non-shedding one: St 0)."""
    keep = np.abs(ref) > 0
    return float(np.mean(np.abs(a[keep] - ref[keep]) / np.abs(ref[keep]))) if keep.any() else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.karman_wake", description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="a karman_sitl --out directory (its seed*/ subdirectories)")
    ap.add_argument("--shift", type=float, default=0.25, help="the beyond set's shift, as karman_sitl's --shift")
    a = ap.parse_args(argv)
    import torch

    from pdestream.datasets import _bridge
    from pdestream.experiments.budget import stratified_test_set
    from pdestream.experiments.interactive_compare import _identity_norm
    from pdestream.surrogate.checkpoint import load_checkpoint
    from pdestream.surrogate.modes import make_mode, subsample

    torch.set_num_threads(1)
    seeds = sorted(Path(a.out).glob("seed*/compare.json"))
    if not seeds:
        print(f"no seed*/compare.json under {a.out}")
        return 1
    rows: dict[tuple[str, str], dict[str, list]] = {}
    for path in seeds:
        run, result = path.parent, json.loads(path.read_text())
        seed, cfg = int(run.name[4:]), result["config"]
        pde = _bridge.solver_pde(result["fine_pde"])
        lo, hi = pde.re.bounds
        shifted = pde.replace(re=f"uniform({hi + (a.shift - 0.1) * (hi - lo):g}, {hi + a.shift * (hi - lo):g})")
        unroll = max(int(p.name[len("sitl_unroll"):]) for p in run.glob("sitl_unroll*") if p.name[11:].isdigit())
        arms = (*ARMS, (f"solver-in-the-loop (unroll {unroll})", f"sitl_unroll{unroll}"))
        for where, test_pde in (("inside", pde), ("beyond", shifted)):
            coarse_pde = test_pde.replace(n=cfg["coarse_n"])
            mode = make_mode({"name": "solver-in-the-loop", "unroll": 1, "coarse_n": cfg["coarse_n"]}).bind(test_pde)
            test = stratified_test_set(test_pde, cfg["n_test"], seed)  # karman_sitl's held-out set of this seed
            u, params = torch.cat([t["u"] for t in test]), torch.cat([t["params"] for t in test])
            fine = _outputs(test_pde, u, params)
            restricted = subsample(u, mode.factor, 2, mode.walls, mode.locations)
            found = {"fine solve (reference)": fine, "reference on the coarse grid": _outputs(coarse_pde, restricted,
                                                                                               params)}
            for label, name in arms:
                model, norm = ((None, _identity_norm(test_pde)) if name is None else
                               load_checkpoint(run / name / "model.pt")[:2])
                pred, truth = mode.rollout(model, norm, u, params)
                frames = torch.cat([truth[:, :1], pred], 1)
                found[label] = _outputs(coarse_pde, frames, params)
            for label, o in found.items():
                r = rows.setdefault((where, label), {"st": [], "drag": [], "amp": [], "sheds": [], "ref_sheds": [],
                                                     "st_mean": [], "drag_mean": []})
                r["st_mean"] += o["strouhal"][o["sheds"]].tolist()
                r["drag_mean"].append(float(o["drag"].mean()))
                r["st"].append(_relative(o["strouhal"], fine["strouhal"]))
                r["drag"].append(_relative(o["drag"], fine["drag"]))
                r["amp"].append(_relative(o["lift_amplitude"], fine["lift_amplitude"]))
                r["sheds"].append(int(o["sheds"].sum()))
                r["ref_sheds"].append(int(fine["sheds"].sum()))
            print(f"seed {seed} {where}: done", flush=True)
    n = json.loads(seeds[0].read_text())["config"]["n_test"]
    print(f"\n{len(seeds)} seeds x {n} trajectories per set; relative error against the fine solve's own outputs, "
          "mean over trajectories (shedding in the reference) and seeds")
    print("| test Re | arm | St (mean of the shedding rollouts) | error: St | mean drag | error: mean drag | error: "
          "lift amplitude | rollouts that shed (reference) |\n| --- | --- | --- | --- | --- | --- | --- | --- |")

    def pct(values) -> str:
        v = np.array(values, float)
        return f"{np.nanmean(v):.1%}" if np.isfinite(v).any() else "- (no reference sheds)"

    for (where, label), r in rows.items():
        st = f"{np.mean(r['st_mean']):.3f}" if r["st_mean"] else "-"
        print(f"| {where} | {label} | {st} | {pct(r['st'])} | {np.mean(r['drag_mean']):.3f} | {pct(r['drag'])} | "
              f"{pct(r['amp'])} | {sum(r['sheds'])} of {len(r['sheds']) * n} ({sum(r['ref_sheds'])}) |")
    (Path(a.out) / "wake.json").write_text(json.dumps({f"{w}|{lab}": r for (w, lab), r in rows.items()}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
