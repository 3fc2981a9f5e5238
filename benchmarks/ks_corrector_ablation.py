"""Tables, figure and gradient check of the ks1d corrector ablation (issue 29; docs/results/interactive.md,
"Ablation from the attractor").

``python -m benchmarks.ks_corrector_ablation [--runs runs/abl] [--figure PNG] [--horizon 9] [--gradients]
[--amplitude]``

Reads the compare.json of each `pdestream compare ks1d --modes solver-in-the-loop ... --out RUNS/<name>` run of
the ablation (zero_u4, zero_u8, zero_u16, random_u16, zero_u4_1000, zero_u4_1500; those present) and prints, per
arm, the mean relative L2 at t - t_start = 1, 2, 4, 6, 8, 9, its mean over frames 1..horizon (about 2 Lyapunov times at ks1d's
e-fold time of ~4.5), the whole window's rollout mean and p95 and the end mean; then solver-in-the-loop against
pairs and pairs + noise (e_other / e_sitl). ``--figure``: error against time of the corrector arms (left: the
unroll lengths at 500 steps; right: 500 against 1500 steps). ``--gradients``: the gradient of the
solver-in-the-loop loss at unroll 1, 4 and 16 on 16 batches of 32 held-out windows (seed 7), at the zero start and
at RUNS/zero_u4's trained pairs correction: mean per-batch norm and coherence ||mean g||^2 / mean ||g||^2 (1: the
batches agree; 1/16: independent zero-mean batches). ``--amplitude``: per corrector arm of RUNS/zero_u4 and
RUNS/zero_u4_1500, the rolled-out field's L2 norm over the truth's (mean over the 32 test trajectories) at a few
frames: a correction that damps the field would show a ratio below 1 where the errors saturate. Figures, not
pass/fail.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

RUNS = ("zero_u4", "zero_u8", "zero_u16", "random_u16", "zero_u4_1000", "zero_u4_1500")
FRAMES = (1, 2, 4, 6, 8, 9)
PAIRS, NOISE = "pairs (unroll 1)", "pairs + noise (unroll 1)"


def horizon_mean(arm: dict, h: int) -> float:
    return sum(arm["curve"][:h]) / h


def tables(runs: Path, h: int) -> None:
    for name in RUNS:
        path = runs / name / "compare.json"
        if not path.is_file():
            continue
        arms = json.loads(path.read_text())["arms"]
        base = horizon_mean(arms[0], h)
        print(f"\n{name}\n| arm | " + " | ".join(map(str, FRAMES)) + f" | mean t<={h} | vs coarse | rollout mean | "
              "rollout p95 | end mean | wall s |")
        for a in arms:
            m = horizon_mean(a, h)
            print(f"| {a['arm']} | " + " | ".join(f"{a['curve'][t - 1]:.4f}" for t in FRAMES)
                  + f" | {m:.4f} | {base / m:.2f}x | {a['rollout_mean']:.4f} | {a['rollout_p95']:.4f} | "
                  f"{a['end_mean']:.4f} | {a['wall_s']:.0f} |")
        by = {a["arm"]: a for a in arms}
        sitl = next(a for a in arms if a["arm"].startswith("solver-in-the-loop"))
        for other in (PAIRS, NOISE):
            o = by[other]
            print(f"{sitl['arm']} vs {other}: t<={h} mean {horizon_mean(o, h) / horizon_mean(sitl, h):.2f}x, whole "
                  f"mean {o['rollout_mean'] / sitl['rollout_mean']:.2f}x, whole p95 "
                  f"{o['rollout_p95'] / sitl['rollout_p95']:.2f}x")


def figure(runs: Path, out: str, h: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def curve(run: str, arm: str):
        r = json.loads((runs / run / "compare.json").read_text())
        a = next(a for a in r["arms"] if a["arm"] == arm)
        return [r["frame_dt"] * (i + 1) for i in range(len(a["curve"]))], a["curve"]

    left = [("zero_u4", "coarse solver", "coarse solver n=128", "k", "--"), ("zero_u4", PAIRS, "pairs", "C0", "-"),
            ("zero_u4", NOISE, "pairs + noise", "C1", "-")] + [
        (f"zero_u{k}", f"solver-in-the-loop (unroll {k})", f"SITL unroll {k}", c, "-")
        for k, c in ((4, "C2"), (8, "C3"), (16, "C4"))]
    right = [("zero_u4_1500", "coarse solver", "coarse solver n=128", "k", "--"),
             ("zero_u4", PAIRS, "pairs, 500 steps", "C0", ":"), ("zero_u4_1500", PAIRS, "pairs, 1500 steps", "C0", "-"),
             ("zero_u4_1500", NOISE, "pairs + noise, 1500", "C1", "-"),
             ("zero_u4", "solver-in-the-loop (unroll 4)", "SITL unroll 4, 500 steps", "C2", ":"),
             ("zero_u4_1500", "solver-in-the-loop (unroll 4)", "SITL unroll 4, 1500 steps", "C2", "-")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, spec, title in ((axes[0], left, "zero start, 500 steps: unroll 1 / 4 / 8 / 16"),
                            (axes[1], right, "zero start, unroll 4: 500 vs 1500 steps")):
        for run, arm, label, color, ls in spec:
            t, c = curve(run, arm)
            black = color == "k"
            ax.plot(t, c, ls, color=color, label=label, lw=2.2 if black else 1.4, zorder=3 if black else 2)
        ax.axvspan(0, h, color="0.92", zorder=0)
        ax.set_yscale("log")
        ax.set_xlabel("t - t_start (time units; shaded: <= 2 Lyapunov times)")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("mean relative L2 (32 held-out trajectories)")
    fig.suptitle("ks1d from the attractor (t in [50, 80]), fine n=512 -> coarse n=128, corrector arms", fontsize=11)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"figure: {out}")


def gradients(runs: Path, batches: int = 16) -> None:
    import torch

    from pdestream.experiments.budget import stratified_test_set
    from pdestream.settings import build_pde
    from pdestream.surrogate.checkpoint import load_checkpoint
    from pdestream.surrogate.models import build_model
    from pdestream.surrogate.modes import make_mode

    torch.set_num_threads(1)
    fine = build_pde("ks1d", {"n": "512", "t_start": "50", "t_end": "80", "n_frames": "31"})
    data = stratified_test_set(fine, 64, 7)  # held out from the runs' training (stream) and test (seed 0) ICs
    u, params = torch.cat([d["u"] for d in data]), torch.cat([d["params"] for d in data])
    pairs, norm, _ = load_checkpoint(runs / "zero_u4" / "sitl_unroll1" / "model.pt")
    torch.manual_seed(0)  # the runs' initial weights (seed 0)
    zero = build_model("fno", 1, 1, 1, 1, bc=tuple(fine.grid.bc), width=32, modes=12, layers=3)
    make_mode({"name": "solver-in-the-loop", "coarse_n": 128, "corrector_start": "zero"}).init_model(zero)
    g = torch.Generator().manual_seed(3)
    for label, model in (("zero start", zero), ("trained pairs", pairs)):
        model.train(False)
        for k in (1, 4, 16):
            mode = make_mode({"name": "solver-in-the-loop", "unroll": k, "coarse_n": 128}).bind(fine, 0)
            grads, losses = [], []
            for b in range(batches):
                i = torch.randint(0, u.shape[0], (32,), generator=g)
                j = torch.randint(0, u.shape[1] - k, (32,), generator=g)
                x = torch.stack([u[a, c:c + 1] for a, c in zip(i, j)])
                y = torch.stack([u[a, c + 1:c + 1 + k] for a, c in zip(i, j)])
                model.zero_grad()
                loss, _ = mode.step_loss(model, {"x": x, "y": y, "params": params[i]}, norm, b)
                loss.backward()
                grads.append(torch.cat([p.grad.flatten() for p in model.parameters() if p.grad is not None]))
                losses.append(float(loss.detach()))
            G = torch.stack(grads)
            coherence = float(G.mean(0).norm() ** 2 / (G.norm(dim=1) ** 2).mean())
            print(f"{label:14s} unroll {k:2d}: loss mean {sum(losses) / batches:.3g} (min {min(losses):.3g}, max "
                  f"{max(losses):.3g}); grad norm mean {float(G.norm(dim=1).mean()):.3g}; coherence {coherence:.3f}")


def amplitude(runs: Path) -> None:
    import torch

    from pdestream.experiments.budget import stratified_test_set
    from pdestream.settings import build_pde
    from pdestream.surrogate.checkpoint import load_checkpoint
    from pdestream.surrogate.modes import make_mode

    torch.set_num_threads(1)
    fine = build_pde("ks1d", {"n": "512", "t_start": "50", "t_end": "80", "n_frames": "31"})
    test = stratified_test_set(fine, 32, 0)  # the compare runs' test set (seed 0)
    u, params = torch.cat([d["u"] for d in test]), torch.cat([d["params"] for d in test])
    mode = make_mode({"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 128}).bind(fine, 0)
    frames = (1, 9, 15, 20, 25, 30)
    print("arm: rolled-out norm / true norm at t - t_start = " + ", ".join(map(str, frames)))
    for run in ("zero_u4", "zero_u4_1500"):
        for label, arm in (("coarse solver", None), ("pairs", "sitl_unroll1"), ("pairs + noise", "sitl_unroll1_noise"),
                           ("solver-in-the-loop", "sitl_unroll4")):
            if arm is None and run != "zero_u4":
                continue
            model, norm = (None, None) if arm is None else load_checkpoint(runs / run / arm / "model.pt")[:2]
            pred, truth = mode.rollout(model, norm, u, params)  # [N, T-1, 1, 128] each
            ratio = (pred.flatten(2).norm(dim=2) / truth.flatten(2).norm(dim=2)).mean(0)  # [T-1]
            print(f"{run if arm else '':12s} {label:18s} " + " ".join(f"{float(ratio[t - 1]):.3f}" for t in frames))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.ks_corrector_ablation", description=__doc__.split("\n")[0])
    p.add_argument("--runs", default="runs/abl", help="the folder of the ablation's compare runs")
    p.add_argument("--figure", metavar="PNG", help="draw the error against time of the corrector arms here")
    p.add_argument("--horizon", type=int, default=9, help="frames in the horizon mean (time units at frame dt 1)")
    p.add_argument("--gradients", action="store_true", help="measure the gradient coherence against the unroll")
    p.add_argument("--amplitude", action="store_true", help="the rolled-out field's norm over the truth's per arm")
    args = p.parse_args(argv)
    runs = Path(args.runs)
    if not any((runs / name / "compare.json").is_file() for name in RUNS):
        print(f"--runs {runs}: no compare.json of {', '.join(RUNS)} there; run the commands in "
              "docs/results/interactive.md first", file=sys.stderr)
        return 2
    tables(runs, args.horizon)
    if args.figure:
        figure(runs, args.figure, args.horizon)
    if args.gradients:
        gradients(runs)
    if args.amplitude:
        amplitude(runs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
