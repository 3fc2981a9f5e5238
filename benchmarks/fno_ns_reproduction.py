"""The FNO paper's Navier-Stokes nu = 1e-3 task, trained on the recipe and on the original generation algorithm:
``python -m benchmarks.fno_ns_reproduction [--n-train 64 --n-test 32 --epochs 7 --seeds 0,1,2] [--draw 1]``
(``--sanity``: only the two solvers on the same w0).

Issue 31's CPU fallback: the same FNO, the same training loop and budget, two data arms:

- "recipe": ``fno_ns2d_nu1e-3`` from pdestream's generator (ETDRK4 on 64^2, train split seed, frames t = 0..50);
- "original": the paper's generation algorithm, written here from its description (Li et al. 2021, section 5.3
  and appendix A.3.3): vorticity form on the unit torus, f = 0.1 (sin 2 pi (x + y) + cos 2 pi (x + y)),
  w0 ~ N(0, 7^3 (-Lap + 49 I)^-2.5), pseudo-spectral, Crank-Nicolson for the viscous term and explicit (forward
  Euler) for the advection term and the forcing, 2/3 dealiasing of the advection term, frames at t = 1..50. It
  solves on 64^2 directly (the paper: 256^2, subsampled) at dt = 2e-3 (``--dt``; the paper: 1e-4, see
  docs/results/recipes.md on that solver's float32 rounding), in float64.

The task is the paper's: frames t = 1..10 in, t = 11..50 out, one frame per network call, autoregressive; the
error is the relative L2 over the 40 predicted frames of each test trajectory, mean over trajectories. Both arms
are evaluated on the same two test sets: the original algorithm's test trajectories and the recipe's (its test
split). ``--draw K`` trains on each arm's training samples K n_train .. (K + 1) n_train - 1 instead: another
training set of the same size, whose spread the model seeds do not show. Each (arm, draw, seed) result is written
to ``--results`` as it finishes and skipped on a rerun; generated data is cached under ``--cache-dir``. Figures: docs/results/recipes.md (section fno_ns2d_nu1e-3).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

NU = 1e-3
FRAMES = 50  # t = 1..50 (the paper drops w0)
K_IN = 10  # the paper's input frames: t = 1..10
RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results" / "fno_ns" / "results.json"


def progress(label: str, done: int, total: int, started: float) -> None:
    """One overwritten line: ``label done/total``, elapsed and an estimate of what is left (seconds)."""
    elapsed = time.perf_counter() - started
    left = elapsed / max(done, 1) * (total - done)
    end = "\n" if done >= total else ""
    print(f"\r  {label}: {done}/{total}, {elapsed:.0f} s, about {left:.0f} s left   ", end=end, file=sys.stderr,
          flush=True)


def grf_w0(rng: np.random.Generator, samples: int, n: int) -> np.ndarray:
    """Draws of N(0, 7^3 (-Lap + 49 I)^-2.5) on the unit torus, zero mean: float64 [samples, n, n].

    White noise filtered by the square root of the covariance's eigenvalues 7^3 (4 pi^2 |m|^2 + 49)^-2.5 on
    every mode m of the n^2 grid (the m = 0 one set to 0), so the pointwise variance is their sum."""
    m = np.fft.fftfreq(n, 1.0 / n)
    m2 = m[:, None] ** 2 + m[None, :] ** 2
    lam = np.where(m2 > 0, 7.0**3 * (4 * np.pi**2 * m2 + 49.0) ** -2.5, 0.0)
    noise = rng.standard_normal((samples, n, n))
    return np.fft.ifft2(np.sqrt(lam) * np.fft.fft2(noise)).real * n


def forcing(n: int, amplitude: float = 0.1) -> np.ndarray:
    """f(x, y) = amplitude (sin 2 pi (x + y) + cos 2 pi (x + y)) at x_i = i / n (axis 0: x, axis 1: y): [n, n]."""
    x = np.arange(n) / n
    s = 2 * np.pi * (x[:, None] + x[None, :])
    return amplitude * (np.sin(s) + np.cos(s))


def solve_cn(w0: np.ndarray, nu: float, dt: float, times, f: np.ndarray | None = None, label: str = "") -> np.ndarray:
    """The paper's scheme, vorticity form on the unit torus: w0 [B, n, n] -> w at ``times`` [B, len(times), n, n].

    w_t + u . grad w = nu Lap w + f, u = (psi_y, -psi_x), -Lap psi = w. Per step, in Fourier space (k = 2 pi m):
    w^ <- (dt (f^ - D (u . grad w)^) + (1 - dt nu |k|^2 / 2) w^) / (1 + dt nu |k|^2 / 2), D the 2/3 rule (modes
    |m_x|, |m_y| <= n / 3 kept). times: multiples of dt (time units); f: [n, n] forcing (None: none). float64.
    """
    w0 = torch.as_tensor(np.asarray(w0), dtype=torch.float64)
    n = w0.shape[-1]
    kx = 2 * np.pi * torch.fft.fftfreq(n, 1.0 / n, dtype=torch.float64)[:, None]  # [n, 1]
    ky = 2 * np.pi * torch.fft.rfftfreq(n, 1.0 / n, dtype=torch.float64)[None, :]  # [1, n/2+1]
    k2 = kx**2 + ky**2
    inv = torch.where(k2 > 0, 1.0 / torch.where(k2 > 0, k2, 1.0), 0.0)  # psi^ = w^ / |k|^2
    keep = (kx.abs() <= 2 * np.pi * n / 3) & (ky.abs() <= 2 * np.pi * n / 3)
    f_hat = torch.zeros_like(k2, dtype=torch.complex128) if f is None else torch.fft.rfft2(torch.as_tensor(f))
    half = 0.5 * dt * nu * k2
    a, b = (1 - half) / (1 + half), dt / (1 + half)
    steps = [round(t / dt) for t in times]
    if any(abs(s * dt - t) > 1e-9 * max(1.0, t) for s, t in zip(steps, times)) or steps != sorted(steps):
        raise ValueError(f"times={list(times)} must be increasing multiples of dt={dt}")
    w_hat, out, started = torch.fft.rfft2(w0), [], time.perf_counter()
    irfft = lambda z: torch.fft.irfft2(z, s=(n, n))  # noqa: E731
    for step in range(steps[-1] + 1):
        while len(out) < len(steps) and steps[len(out)] == step:
            out.append(irfft(w_hat))
            if label:
                progress(label, step, steps[-1], started)
        if step == steps[-1]:
            break
        psi = w_hat * inv
        adv = irfft(1j * ky * psi) * irfft(1j * kx * w_hat) - irfft(1j * kx * psi) * irfft(1j * ky * w_hat)
        w_hat = a * w_hat + b * (f_hat - keep * torch.fft.rfft2(adv))
    return torch.stack(out, 1).numpy()


ORIGINAL_SEEDS = {"train": 100, "test": 102}  # numpy seeds of the original arm's draws (sample i: [seed, i])
CHUNK = 16  # samples solved (and cached) together


def original_w0(split: str, lo: int, hi: int, n: int) -> np.ndarray:
    """w0 of the original arm's samples lo..hi-1 of ``split``: [hi - lo, n, n], each from its own generator."""
    return np.concatenate([grf_w0(np.random.default_rng([ORIGINAL_SEEDS[split], i]), 1, n) for i in range(lo, hi)])


def original_data(split: str, count: int, n: int, dt: float, cache: Path, first: int = 0) -> np.ndarray:
    """The original algorithm's trajectories t = 1..50 of ``split``'s samples first..first+count-1: float32
    [count, 50, n, n], solved CHUNK at a time, each chunk cached under ``cache`` (a rerun solves only what is
    missing)."""
    parts = []
    for lo in range(first, first + count, CHUNK):
        hi = min(lo + CHUNK, first + count)
        path = cache / f"original_{split}_n{n}_dt{dt:g}_{lo}-{hi}.npy"
        if not path.is_file():
            w = solve_cn(original_w0(split, lo, hi, n), NU, dt, range(1, FRAMES + 1), forcing(n),
                         label=f"original {split} samples {lo}..{hi - 1}, dt {dt:g}")
            tmp = path.with_suffix(".tmp.npy")
            np.save(tmp, w.astype(np.float32))
            tmp.replace(path)
        parts.append(np.load(path))
    return np.concatenate(parts)


def recipe_data(split: str, count: int, cache: Path, first: int = 0) -> np.ndarray:
    """The recipe's ``split`` samples first..first+count-1 (its split seed), frames t = 1..50: float32
    [count, 50, 64, 64]."""
    from pdestream import generator
    from pdestream.recipes import RECIPES

    seed = RECIPES["fno_ns2d_nu1e-3"].splits[split].seed
    parts = []
    for lo in range(first, first + count, CHUNK):
        hi = min(lo + CHUNK, first + count)
        path = cache / f"recipe_{split}_seed{seed}_{lo}-{hi}.npy"
        if not path.is_file():
            t0 = time.perf_counter()
            u = np.asarray(generator.sample(generator.get_pde("fno_ns2d_nu1e-3"), range(lo, hi), seed=seed).u)
            tmp = path.with_suffix(".tmp.npy")
            np.save(tmp, u[:, 1:, 0].astype(np.float32))  # drop w0: t = 1..50
            tmp.replace(path)
            print(f"  recipe {split} samples {lo}..{hi - 1}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        parts.append(np.load(path))
    return np.concatenate(parts)


def rel(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative L2 of a against b over the last two axes: [...]."""
    return np.sqrt(((a - b) ** 2).sum((-2, -1)) / (b**2).sum((-2, -1)))


def sanity(dt: float, few: int = 4) -> dict:
    """The same w0 (the original arm's first ``few`` test draws) through both solvers: rel L2 at t = 1, 10, 50,
    and the original scheme at dt against dt / 2 (its own time-step error: first order, so about half of dt's)."""
    from pdestream import generator

    w0 = original_w0("test", 0, few, 64)
    times = [1, 10, 50]
    ours = solve_cn(w0, NU, dt, times, forcing(64), label=f"sanity: {few} w0, dt {dt:g}")
    fine = solve_cn(w0, NU, dt / 2, times, forcing(64), label=f"sanity: {few} w0, dt {dt / 2:g}")
    pde = generator.get_pde("fno_ns2d_nu1e-3")
    recipe = np.asarray(generator.solve(pde, w0[:, None].astype(np.float32), {"nu": np.full(few, NU, np.float32)}).u)
    recipe = recipe[:, times, 0]
    out = {"times": times, "recipe_vs_original": rel(ours, recipe).max(0).tolist(),
           "recipe_vs_original_fine": rel(fine, recipe).max(0).tolist(),
           "original_dt_vs_dt/2": rel(ours, fine).max(0).tolist(), "samples": few, "dt": dt}
    for key in ("recipe_vs_original", "recipe_vs_original_fine", "original_dt_vs_dt/2"):
        print(f"  {key} (max of {few}) at t = {times}: " + " / ".join(f"{e:.1e}" for e in out[key]))
    return out


class Windows(torch.utils.data.Dataset):
    """The paper's training pairs of in-memory trajectories u [N, T, 1, s, s]: K_IN frames -> the next one, every
    window (``datasets.NextStep``); each example a batch-dict item with no parameters ("params": [0])."""

    def __init__(self, u: torch.Tensor):
        from pdestream.datasets.views import NextStep

        self.u, self.view = u, NextStep(K_IN, 1)
        self.per = self.view.per_trajectory(u.shape[1])
        self.t = torch.arange(u.shape[1], dtype=torch.float32)

    def __len__(self) -> int:
        return len(self.u) * self.per

    def __getitem__(self, i: int) -> dict:
        traj, start = divmod(i, self.per)
        return {**self.view.example(self.u[traj], self.t, start), "params": torch.zeros(0),
                "index": torch.tensor(traj)}

    def normalization(self):
        """Per-field mean / std over every training trajectory (the training loop's statistics)."""
        from pdestream.datasets.normalize import Normalization

        n = len(self.u)
        return Normalization.from_batch({"u": self.u, "params": torch.zeros(n, 0), "index": torch.arange(n)}, 2,
                                        fields=["w"])


def test_batches(u: torch.Tensor, batch: int = 16) -> list[dict]:
    """Whole test trajectories u [N, T, 1, s, s] as the evaluator's batches {"u", "params": [B, 0], "index"}."""
    return [{"u": u[i:i + batch], "params": torch.zeros(len(u[i:i + batch]), 0),
             "index": torch.arange(i, i + len(u[i:i + batch]))} for i in range(0, len(u), batch)]


def train_one(arm: str, seed: int, train_u: torch.Tensor, tests: dict, args, run_dir: Path) -> dict:
    """Train the project's FNO on ``train_u`` (one arm's trajectories) with the project's loop; the relative L2
    over the 40 rolled-out frames per test trajectory, mean and std over each test set's trajectories."""
    from pdestream import datasets
    from pdestream.surrogate.checkpoint import CHECKPOINT, load_train_state
    from pdestream.surrogate.data import EpochBatchSampler
    from pdestream.surrogate.evaluate import rollout_errors
    from pdestream.surrogate.models import build_model
    from pdestream.surrogate.modes import OneStep
    from pdestream.surrogate.train import train

    data = Windows(train_u)
    torch.manual_seed(seed)
    model = build_model("fno", 2, K_IN, 1, 0, bc=None, width=args.width, modes=args.modes, layers=args.layers)
    sampler = EpochBatchSampler(len(data), args.batch_size, seed, drop_last=True)
    loader = torch.utils.data.DataLoader(data, batch_sampler=sampler, collate_fn=datasets.collate,
                                         generator=torch.Generator())
    steps = args.epochs * len(sampler)
    meta = {"arm": arm, "seed": seed, "n_train": len(train_u), "s": train_u.shape[-1]}
    ckpt = run_dir / CHECKPOINT
    resume = load_train_state(ckpt) if ckpt.is_file() and not (run_dir / "metrics.json").is_file() else None
    t0 = time.perf_counter()
    summary = train(model, loader, steps, run_dir, lr=args.lr, schedule="cosine", mode=OneStep(loss="relative"),
                    label=f"{arm} seed {seed}", checkpoint_every=100, resume=resume, meta=meta)
    view = data.view
    errors = {}
    for name, batches in tests.items():
        per = rollout_errors(model, summary["normalizer"], batches, view).trajectory()  # [N]
        errors[name] = {"mean": float(per.mean()), "std": float(per.std()), "n": len(per)}
    return {**meta, "steps": summary["steps"], "final_loss": summary["final_loss"], "wall_s": summary["wall"],
            "eval_and_train_s": time.perf_counter() - t0, "test": errors}


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample std (0 for one value)."""
    return statistics.fmean(values), (statistics.stdev(values) if len(values) > 1 else 0.0)


def report(results: dict, arms, seeds, tests, tag: str = "") -> None:
    """Per arm and test set: mean +- std over seeds; whether |difference| <= std_a + std_b (compare.md's rule).
    tag: "" (the first training draw) or "drawK/"."""
    for test in tests:
        rows = {}
        for arm in arms:
            done = [results[f"{arm}/{tag}seed{s}"]["test"][test]["mean"] for s in seeds
                    if f"{arm}/{tag}seed{s}" in results]
            if done:
                rows[arm] = (*mean_std(done), len(done))
                print(f"  {test} test set, trained on {arm:8s}: rel L2 {rows[arm][0]:.4f} +- {rows[arm][1]:.4f} "
                      f"({rows[arm][2]} seeds: " + ", ".join(f"{v:.4f}" for v in done) + ")")
        if len(rows) == 2:
            (ma, sa, _), (mb, sb, _) = rows.values()
            verdict = "agree" if abs(ma - mb) <= sa + sb else "differ"
            print(f"  {test} test set: |difference| {abs(ma - mb):.4f}, std_a + std_b {sa + sb:.4f}: {verdict}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-train", type=int, default=64, help="training trajectories per arm")
    parser.add_argument("--n-test", type=int, default=32, help="test trajectories per test set")
    parser.add_argument("--epochs", type=int, default=7)
    parser.add_argument("--batch-size", type=int, default=20)
    parser.add_argument("--lr", type=float, default=4e-3)
    parser.add_argument("--width", type=int, default=20)
    parser.add_argument("--modes", type=int, default=12)
    parser.add_argument("--layers", type=int, default=4)
    parser.add_argument("--sub", type=int, default=2, help="subsample the 64^2 solutions by this (2: 32^2)")
    parser.add_argument("--dt", type=float, default=2e-3, help="the original algorithm's time step")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--draw", type=int, default=0, help="train on each arm's training samples "
                        "draw*n_train .. (draw+1)*n_train-1 (another draw of the same size: the data-draw spread)")
    parser.add_argument("--arms", default="recipe,original")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1: best on shared cores)")
    parser.add_argument("--cache-dir", default="/tmp/pdestream_fno_ns")
    parser.add_argument("--results", default=str(RESULTS))
    parser.add_argument("--sanity", action="store_true", help="only the same-w0 check of the two solvers "
                        "(written to sanity.json beside --results)")
    args = parser.parse_args(argv)
    for name in ("n_train", "n_test", "epochs", "batch_size", "width", "modes", "layers", "sub", "threads"):
        if getattr(args, name) < 1:
            parser.exit(2, f"--{name.replace('_', '-')}={getattr(args, name)} not allowed; must be >= 1\n")
    if not 0 < args.dt <= 0.01 or abs(round(1 / args.dt) * args.dt - 1) > 1e-9:
        parser.exit(2, f"--dt={args.dt} not allowed; must divide 1 and be in (0, 0.01]\n")
    if args.draw < 0:
        parser.exit(2, f"--draw={args.draw} not allowed; must be >= 0\n")
    if 64 % args.sub:
        parser.exit(2, f"--sub={args.sub} not allowed; must divide 64\n")
    arms = args.arms.split(",")
    if not set(arms) <= {"recipe", "original"}:
        parser.exit(2, f"--arms={args.arms} not allowed; allowed: recipe, original (comma-separated)\n")
    seeds = [int(s) for s in args.seeds.split(",")]
    torch.set_num_threads(args.threads)
    cache, results_path = Path(args.cache_dir), Path(args.results)
    cache.mkdir(parents=True, exist_ok=True)
    if args.sanity:
        out = results_path.with_name("sanity.json")
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(sanity(args.dt), indent=2))  # committed beside the results
        return
    setup = {"n_train": args.n_train, "n_test": args.n_test, "epochs": args.epochs, "batch_size": args.batch_size,
             "lr": args.lr, "fno": {"width": args.width, "modes": args.modes, "layers": args.layers},
             "s": 64 // args.sub, "dt_original": args.dt, "loss": "relative", "schedule": "cosine"}
    saved = json.loads(results_path.read_text()) if results_path.is_file() else {}
    if saved and saved.get("setup") != setup:
        parser.exit(2, f"{results_path} holds results of another set-up ({saved.get('setup')}); pass --results "
                       "ANOTHER.json for this one\n")
    results = saved.get("runs", {})
    print(f"fno_ns2d_nu1e-3 reproduction: {setup}")
    t0 = time.perf_counter()
    sub = slice(None, None, args.sub)

    def load(u: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(u[:, :, sub, sub]))[:, :, None]  # [N, 50, 1, s, s]

    tests = {"original": test_batches(load(original_data("test", args.n_test, 64, args.dt, cache))),
             "recipe": test_batches(load(recipe_data("test", args.n_test, cache)))}
    print(f"  test sets ready ({time.perf_counter() - t0:.0f} s)")
    train_sets = {}
    first, tag = args.draw * args.n_train, f"draw{args.draw}/" if args.draw else ""
    for seed in seeds:  # seed by seed, both arms: a budget cut short leaves them balanced
        for arm in (a for a in arms if f"{a}/{tag}seed{seed}" not in results):
            if arm not in train_sets:
                train_sets[arm] = load(original_data("train", args.n_train, 64, args.dt, cache, first)
                                       if arm == "original" else recipe_data("train", args.n_train, cache, first))
            name = f"{arm}_{tag.rstrip('/') or 'draw0'}_seed{seed}_n{args.n_train}_e{args.epochs}_s{64 // args.sub}"
            run = train_one(arm, seed, train_sets[arm], tests, args, cache / "runs" / name)
            results[f"{arm}/{tag}seed{seed}"] = {**run, "draw": args.draw, "first_sample": first}
            results_path.parent.mkdir(parents=True, exist_ok=True)
            tmp = results_path.with_suffix(".tmp")
            tmp.write_text(json.dumps({"setup": setup, "runs": results}, indent=2))
            tmp.replace(results_path)
            print(f"  {arm} {tag}seed {seed}: " + ", ".join(f"{k} test {v['mean']:.4f}" for k, v in run["test"].items())
                  + f" ({run['steps']} steps, {run['eval_and_train_s']:.0f} s)")
    report(results, arms, seeds, tests, tag)


if __name__ == "__main__":
    main()
