"""Solver-in-the-loop on the vortex street (Um et al. 2020, the PBDL book's "reducing numerical errors"):
karman2d with the Reynolds number varied per trajectory, four arms over several seeds, rolled out on held-out
Reynolds numbers inside the training range and beyond it.

    nice python -m benchmarks.karman_sitl [--seeds 3] [--steps 300] [--fine-n 64] [--coarse-n 32] [--unroll 3]
        [--out /tmp/karman_sitl] [--quick]
    nice python -m benchmarks.karman_sitl --small --coarse-only [--test-samples 8] [--seeds 1]
    nice python -m benchmarks.karman_sitl --small --window 4 --only-seed 0 --out DIR   # t = 2..6 s, 41 frames
    nice python -m benchmarks.karman_sitl --small --re 60,100 --t-start 8 --window 4 --only-seed 0 --out DIR

Per seed, ``surrogate.interactive_compare`` (the same code as ``pdestream compare karman2d --modes
solver-in-the-loop``) trains the pairs-trained correction (unroll 1: precomputed (coarse step, fine) pairs,
no interaction), the same with the coarse start state perturbed (``--noise``, the fine target clean) and the solver-in-the-loop correction (unrolled through the differentiable coarse solver) from
the same initial weights and stream, and rolls them out, with the coarse solver alone, from the first frame of
held-out trajectories; then the saved models are rolled out on a second held-out set whose Reynolds numbers lie
beyond the training range (``--shift``: the domain moved by that fraction of its width). Printed per test set
and arm: the error over the whole rollout (mean over frames and trajectories) and the p95 over trajectories of
their rollout-mean error, as mean +- spread (half the range) over seeds, and whether solver-in-the-loop beats
each other arm on every seed, then pairs / solver-in-the-loop per frame and averaged up to the frame (each
seed's frames.json: error per frame per test set and arm). Figures, not pass/fail; rollouts.png of each seed's
run shows vorticity.

``--coarse-only`` trains nothing: it rolls out the coarse solver alone with each body treatment
(``generator.flow.grid.BODIES``: the fine reference keeps the PDE's own, sharp by default) on the same held-out
sets, and prints the rollout error per body with each field's part (||e_field|| / ||truth||, all fields together),
so what the coarse grid's staircase costs the coarse solver is measured apart from any training; the last column
is the same rollout had the step put the coarse grid's own mask in the solid channel (as it did before 2026-11-27)
instead of the given, restricted one.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np

FINE = dict(t_start=4.0, t_end=8.0, n_frames=41)  # frames 0.1 s apart: ~10 coarse steps per frame at n=32


def _summary(errors: np.ndarray) -> tuple[float, float]:
    """errors [N, T] -> (mean over frames and trajectories, p95 over trajectories of their mean)."""
    per = errors.mean(1)
    return float(errors.mean()), float(np.percentile(per, 95))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.karman_sitl", description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--only-seed", type=int, help="run this one seed (parallel runs), then --summarize their --out")
    ap.add_argument("--summarize", action="store_true", help="only print the table of the seeds already in --out")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--fine-n", type=int, default=64)
    ap.add_argument("--coarse-n", type=int, default=32)
    ap.add_argument("--unroll", type=int, default=3)
    ap.add_argument("--noise", type=float, default=0.01,
                    help="the pairs + noise arm: std of the noise on the coarse start state, x the data's std")
    ap.add_argument("--test-samples", type=int, default=8)
    ap.add_argument("--shift", type=float, default=0.25, help="held-out Re beyond the range by this share of its width")
    ap.add_argument("--out", default="/tmp/karman_sitl")
    ap.add_argument("--device", default="cpu", help="where the models train (cpu, cuda)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: --small, 20 steps, 1 seed")
    ap.add_argument("--small", action="store_true", help="n 32 -> 16, larger cylinders, Re 40-80, 1 s windows")
    ap.add_argument("--window", type=float, help="--small: the rollout window in seconds from --t-start (default 1; "
                    "frames 0.1 s apart)")
    ap.add_argument("--re", help="--small: the training Re range LO,HI (default 40,80; the beyond set follows --shift)")
    ap.add_argument("--t-start", type=float, help="--small: the window's first frame in seconds (default 2)")
    ap.add_argument("--coarse-only", action="store_true",
                    help="no training: the coarse solver alone with a staircase and a sharp body, against the fine solve")
    a = ap.parse_args(argv)
    import torch

    from pdestream import datasets, generator
    from pdestream.experiments.budget import stratified_test_set
    from pdestream.experiments.interactive_compare import InteractiveConfig, _identity_norm, interactive_compare
    from pdestream.surrogate.checkpoint import load_checkpoint
    from pdestream.surrogate.evaluate import rollout_errors
    from pdestream.surrogate.modes import make_mode

    torch.set_num_threads(1)
    settings = dict(FINE, n=a.fine_n)
    if a.quick:
        a.seeds, a.steps, a.test_samples, a.small = 1, 20, 4, True
    if a.window is not None and not (a.small and 0.2 <= a.window <= 60):
        ap.error(f"--window {a.window:g}: allowed with --small only, 0.2 to 60 seconds")
    re_lo, re_hi = _re_range(ap, a)
    if a.t_start is not None and not (a.small and 0 < a.t_start <= 60):
        ap.error(f"--t-start {a.t_start:g}: allowed with --small only, above 0 and at most 60 seconds")
    if a.small:
        a.fine_n, a.coarse_n = 32, 16
        window = 1.0 if a.window is None else a.window
        t0 = 2.0 if a.t_start is None else a.t_start
        settings = dict(n=32, radius="uniform(0.13, 0.16)", re=f"uniform({re_lo:g}, {re_hi:g})", t_start=t0,
                        t_end=t0 + window, n_frames=round(window / 0.1) + 1)
    pde = generator.get_pde("karman2d", **settings)
    lo, hi = pde.re.bounds
    shifted = pde.replace(re=f"uniform({hi + (a.shift - 0.1) * (hi - lo):g}, {hi + a.shift * (hi - lo):g})")
    print(f"fine: {pde.describe()}\nshifted test Re: {shifted.re}; coarse n={a.coarse_n}, unroll {a.unroll}, "
          f"{a.steps} steps x batch {a.batch_size}, {a.seeds} seeds", flush=True)
    if a.summarize:
        if not list(Path(a.out).glob("seed*/summary.json")):
            print(f"--summarize: no seed*/summary.json under {a.out}")
            return 1
        return _print_table(_load(Path(a.out)), Path(a.out))
    if a.coarse_only:
        return _coarse_bodies(pde, shifted, a)
    results: dict[tuple[str, str], list[tuple[float, float]]] = {}
    frames: dict[str, dict[str, list[float]]] = {}  # per seed: {test set: {arm: error per frame, mean over trajectories}}
    for seed in [a.only_seed] if a.only_seed is not None else range(a.seeds):
        out = Path(a.out) / f"seed{seed}"
        cfg = InteractiveConfig(modes=("solver-in-the-loop",), unroll=a.unroll, steps=a.steps,
                                batch_size=a.batch_size, seed=seed, n_test=a.test_samples, coarse_n=a.coarse_n,
                                noise=a.noise, device=a.device)
        interactive_compare(pde, out, cfg, log=lambda s: print(f"  seed {seed}: {s}", flush=True))
        runs = {"coarse solver": None, "pairs (unroll 1)": out / "sitl_unroll1",
                "pairs + noise (unroll 1)": out / "sitl_unroll1_noise",
                f"solver-in-the-loop (unroll {a.unroll})": out / f"sitl_unroll{a.unroll}"}
        for where, test_pde in (("inside", pde), ("beyond", shifted)):
            # the coarse solver of the test set's config (the solver refuses parameters outside its domains)
            mode = make_mode({"name": "solver-in-the-loop", "unroll": 1, "coarse_n": a.coarse_n}).bind(test_pde)
            test = stratified_test_set(test_pde, a.test_samples, seed)
            for arm, run in runs.items():
                model, norm = (None, _identity_norm(pde)) if run is None else load_checkpoint(run / "model.pt")[:2]
                if model is not None:
                    model.to(a.device)
                errors = rollout_errors(model, norm, test, datasets.NextStep(1, 1), mode).relative()  # [N, T - 1]
                results.setdefault((where, arm), []).append(_summary(errors))
                frames.setdefault(where, {})[arm] = errors.mean(0).tolist()
        mine = {f"{k[0]}|{k[1]}": v[-1] for k, v in results.items()}
        (out / "frames.json").write_text(json.dumps(frames))
        (out / "summary.json").write_text(json.dumps(mine))
    return _print_table(_load(Path(a.out)), Path(a.out))


def _re_range(ap, a) -> tuple[float, float]:
    """--re "LO,HI" -> (LO, HI), the --small training Re range (default (40, 80)); bad values end in ap.error."""
    if a.re is None:
        return 40.0, 80.0
    try:
        lo, hi = (float(x) for x in a.re.split(","))
    except ValueError:
        ap.error(f"--re {a.re}: two numbers LO,HI, e.g. --re 60,100")
    if not a.small:
        ap.error(f"--re {a.re}: allowed with --small only")
    if not (0 < lo < hi and np.isfinite(hi)):
        ap.error(f"--re {a.re}: needs 0 < LO < HI")
    return lo, hi


def _coarse_bodies(pde, shifted, a) -> int:
    """The coarse solver alone with each body treatment on the held-out sets (seeds 0 .. --seeds - 1): a table of
    the rollout error (mean, p95 over trajectories) and each field's part of the mean."""
    import torch

    from pdestream.experiments.budget import stratified_test_set
    from pdestream.generator.flow.grid import BODIES
    from pdestream.surrogate.modes import make_mode

    print("\n| test Re | coarse body | rollout error | p95 over trajectories | "
          + " | ".join(f"part {f}" for f in pde.FIELDS) + " | mean / p95, the coarse grid's own mask |")
    print("| --- | --- | --- | --- |" + " --- |" * (len(pde.FIELDS) + 1))
    for where, test_pde in (("inside", pde), ("beyond", shifted)):
        # (solved in chunks of --test-samples, not the default 32 the trained arms' sets are padded to)
        tests = [stratified_test_set(test_pde, a.test_samples, seed, chunk=a.test_samples) for seed in range(a.seeds)]
        for body in BODIES:
            mode = make_mode({"name": "solver-in-the-loop", "unroll": 1, "coarse_n": a.coarse_n}).bind(
                test_pde.replace(body=body))  # the coarse solver's body; the fine reference stays the PDE's
            diff, parts, ref, old = [], [], [], []
            for test in tests:
                for batch in test:
                    pred, truth = mode.rollout(None, None, batch["u"], batch["params"])  # [B, T-1, C, *coarse]
                    e, t = (pred - truth).double(), truth.double()
                    ref.append(t.flatten(2).norm(dim=2))
                    diff.append(e.flatten(2).norm(dim=2))
                    parts.append(torch.stack([e[:, :, c].flatten(2).norm(dim=2) for c in range(e.shape[2])], -1))
                    # the step before it kept the given mask: its own coarse staircase (centres inside the circle)
                    # in the solid channel; the flow channels are the same bits (karman2d's flow ignores the mask)
                    k = pde.FIELDS.index("solid")
                    own = _coarse_mask(mode.step.pde, batch["params"], pde.PARAMS).double()  # [B, nx, ny]
                    floor = (own[:, None] - truth[:, :, k].double()).flatten(2).norm(dim=2)
                    old.append((diff[-1] ** 2 + floor ** 2).sqrt())
            diff, ref, parts, old = torch.cat(diff), torch.cat(ref), torch.cat(parts), torch.cat(old)
            mean, p95 = _summary((diff / ref).numpy())
            share = (parts / ref[..., None]).mean((0, 1)).tolist()
            before = _summary((old / ref).numpy())
            print(f"| {where} | {body} | {mean:.4f} | {p95:.4f} | " + " | ".join(f"{x:.4f}" for x in share)
                  + f" | {before[0]:.4f} / {before[1]:.4f} |", flush=True)
    return 0


def _coarse_mask(coarse, params, names):
    """The coarse grid's own cylinder mask [B, nx, ny] (cell centres inside the circle), generator order."""
    import torch

    col = {n: params[:, j].double()[:, None, None] for j, n in enumerate(names)}
    h = coarse.length / coarse.n
    x = (torch.arange(coarse.grid.shape[0], dtype=torch.float64) + 0.5) * h
    y = (torch.arange(coarse.grid.shape[1], dtype=torch.float64) + 0.5) * h
    xx, yy = torch.meshgrid(x, y, indexing="ij")
    return ((xx - col["cx"]) ** 2 + (yy - col["cy"]) ** 2 < col["radius"] ** 2).double()


def _load(out: Path) -> dict:
    """{(test set, arm): [(rollout mean, p95) per seed]} from every seed*/summary.json under out."""
    results: dict = {}
    for f in sorted(out.glob("seed*/summary.json")):
        for key, v in json.loads(f.read_text()).items():
            results.setdefault(tuple(key.split("|")), []).append(tuple(v))
    return results


def _print_table(results: dict, out: Path) -> int:
    print("\n| test Re | arm | rollout error (mean +- spread over seeds) | p95 over trajectories |")
    print("| --- | --- | --- | --- |")
    for (where, arm), vals in results.items():
        means = np.array([v[0] for v in vals])
        p95 = np.array([v[1] for v in vals])
        print(f"| {where} | {arm} | {means.mean():.4f} +- {np.ptp(means) / 2:.4f} | "
              f"{p95.mean():.4f} +- {np.ptp(p95) / 2:.4f} |")
    for where in ("inside", "beyond"):
        arms = [k for k in results if k[0] == where]
        for j, what in ((0, "mean"), (1, "p95")):
            loop = np.array([v[j] for v in results[arms[-1]]])
            for other in arms[:-1]:
                base = np.array([v[j] for v in results[other]])
                print(f"{where}, {what}: solver-in-the-loop vs {other[1]}: {np.mean(base / loop):.2f}x lower rollout "
                      f"error (range {np.min(base / loop):.2f}..{np.max(base / loop):.2f} over seeds; beats it on "
                      f"{int(np.sum(loop < base))} of {len(loop)} seeds)")
    return _print_frames(out)


def _frames(out: Path) -> dict:
    """{test set: [{arm: error per frame} per seed]} from seed*/frames.json under out; a seed dir without one (runs
    before frames.json) gives its inside curve from curves.csv (interactive_compare's mean per frame, same test set)."""
    per: dict = {}
    for d in sorted(out.glob("seed*/")):
        if (d / "frames.json").exists():
            for where, arms in json.loads((d / "frames.json").read_text()).items():
                per.setdefault(where, []).append(arms)
        elif (d / "curves.csv").exists():
            arms: dict = {}
            for row in csv.DictReader((d / "curves.csv").open()):
                arms.setdefault(row["arm"], []).append(float(row["mean"]))
            per.setdefault("inside", []).append(arms)
    return per


def _print_frames(out: Path) -> int:
    """Per frame: pairs / solver-in-the-loop error (each the mean over trajectories), and the same of the errors
    averaged from frame 1 to that frame (the rollout mean a window ending there would give); mean over seeds of
    the per-seed ratio, with its range."""
    for where, seeds in _frames(out).items():
        pairs = next(k for k in seeds[0] if k.startswith("pairs ("))
        loop = next(k for k in seeds[0] if k.startswith("solver-in-the-loop"))
        n = min(len(s[loop]) for s in seeds)
        at = sorted({1, 5, n} | set(range(10, n + 1, 10)))
        print(f"\n{where}, {pairs} / {loop} per frame (mean over {len(seeds)} seeds, range; frames 0.1 s apart)")
        print("| frame | error at the frame: ratio | error averaged over frames 1..frame: ratio |\n| --- | --- | --- |")
        for f in at:
            r = np.array([np.mean(s[pairs][:f]) / np.mean(s[loop][:f]) for s in seeds])
            e = np.array([s[pairs][f - 1] / s[loop][f - 1] for s in seeds])
            print(f"| {f} | {e.mean():.2f} ({e.min():.2f}-{e.max():.2f}) | {r.mean():.2f} ({r.min():.2f}-{r.max():.2f}) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
