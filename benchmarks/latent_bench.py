"""Does a proposal over (parameters, IC latent) find where the model's loss is high? Measured on fresh solves.

``python -m benchmarks.latent_bench [--pde burgers1d] [--steps 800] [--sim-budget 256] [--draws 256]
[--spaces params+ic,params]`` trains the compare arms' small FNO (operator view, one seed) through a deterministic
reservoir with the active proposal over each space, as ``compare --sim-budget`` does, then asks the proposal it ended
with for ``draws`` high-difficulty draws (its fit's acquisition: the steered draws, no uniform floor) and the same
number of uniform draws (the prior: what the key would draw), solves both afresh on a held-out seed with the same
sample indices (so the IC's coordinates beyond the latent are the same in both sets) and prints each set's mean and
median per-trajectory relative L2 error, their ratio with a 95% bootstrap interval, and the proposal's skill.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np
import torch
from torch.utils.data import DataLoader

from pdestream import datasets, generator
from pdestream.datasets.proposal import LATENT
from pdestream.surrogate.evaluate import rollout_errors
from pdestream.surrogate.fno import COMPARE_FNO
from pdestream.surrogate.models import build_model
from pdestream.surrogate.modes import make_mode
from pdestream.surrogate.train import Stop, source_normalization, train

HELD_OUT_SEED = 1_000_003  # the fresh solves' seed: never a training sample


def train_arm(pde, space: str, steps: int, sim_budget: int, batch: int, seed: int, out: Path, floor: float = 0.25):
    """The compare arm reservoir_active's data path over ``space``: (model, normalization, the final proposal)."""
    view = datasets.make_view("operator")
    reuse = max(1.0, 1.05 * steps * batch / sim_budget)
    stream = datasets.ReservoirStream(pde, seed=seed, view=view, batch_size=batch, capacity=sim_budget, max_reuse=reuse,
                                      solve_batch=16, sim_budget=sim_budget, mode="deterministic", target_reuse=reuse,
                                      warmup=sim_budget // 4, proposal="active",
                                      proposal_kwargs={"floor": floor, "space": space})
    loader = DataLoader(stream, batch_size=None)
    norm = source_normalization(loader)
    torch.manual_seed(seed)
    mode = make_mode(None).bind(pde, seed)
    model = build_model("fno", pde.NDIM, *mode.channels(pde, view), len(pde.PARAMS), bc=pde.grid.bc, **COMPARE_FNO)
    try:
        summary = train(model, loader, Stop(steps=steps, once=True), out, lr=3e-3, normalizer=norm, label=space,
                        mode=mode)
    finally:
        stream.close()
    return model, norm, view, stream.proposal, summary


def draws(proposal, n: int, steered: bool, rng: np.random.Generator) -> dict:
    """n unit points: the fit's acquisition resampled (steered) or uniform, as {param: [n], LATENT?: [n, L]}."""
    d = proposal.dims
    if steered:
        cand, prob = proposal._fit[:2]  # the fit the proposal steers by at the end of training
        width = 0.5 * len(prob) ** (-1.0 / min(d, 4))  # as ParamProposal.propose jitters it
        moved = np.abs(cand[rng.choice(len(prob), size=n, p=prob)] + width * rng.standard_normal((n, d)))
        z = np.clip(1.0 - np.abs(1.0 - moved), 0.0, 1.0)
    else:
        z = rng.random((n, d))
    return proposal.from_unit(z)


def fresh_errors(pde, model, norm, view, values: dict, chunk: int = 32) -> np.ndarray:
    """Per-trajectory relative L2 of the model on fresh solves of ``values`` (indices 0..n-1, seed HELD_OUT_SEED)."""
    n = len(next(iter(values.values())))
    errs = []
    for lo in range(0, n, chunk):
        idx = np.arange(lo, min(lo + chunk, n))
        params = {k: v[idx] for k, v in values.items() if k != LATENT}
        latent = values[LATENT][idx] if LATENT in values else None
        traj = generator.sample(pde, idx, HELD_OUT_SEED, params=params or None, latent=latent)
        u = torch.from_numpy(np.asarray(traj.u))
        p = torch.from_numpy(np.stack([np.asarray(traj.params[k]) for k in pde.PARAMS], 1))
        errs.append(rollout_errors(model, norm, [{"u": u, "params": p, "index": torch.from_numpy(idx)}], view).trajectory())
    return np.concatenate(errs)


def ratio_interval(a: np.ndarray, b: np.ndarray, rng: np.random.Generator, n: int = 1000) -> tuple[float, float]:
    """95% percentile bootstrap interval of mean(a) / mean(b), the two resampled independently."""
    r = [rng.choice(a, len(a)).mean() / rng.choice(b, len(b)).mean() for _ in range(n)]
    return float(np.percentile(r, 2.5)), float(np.percentile(r, 97.5))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pde", default="burgers1d")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--steps", type=int, default=800)
    ap.add_argument("--sim-budget", type=int, default=256)
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--draws", type=int, default=256)
    ap.add_argument("--spaces", default="params+ic,params")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--floor", type=float, default=0.25, help="the proposal's uniform share (1: never steered, a control)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    pde = generator.get_pde(args.pde).replace(dict(s.split("=", 1) for s in args.set))
    print(f"{pde.NAME} (n={pde.n}, ic {pde.ic}, latent L={pde.latent_size()}), {args.sim_budget} solves, "
          f"{args.steps} steps, FNO {COMPARE_FNO}, {args.draws} fresh draws per set, seed {args.seed}, floor {args.floor}")
    for space in args.spaces.split(","):
        t0 = time.perf_counter()
        with TemporaryDirectory() as tmp:
            model, norm, view, prop, summary = train_arm(pde, space, args.steps, args.sim_budget, args.batch_size,
                                                         args.seed, Path(tmp), args.floor)
        rng = np.random.default_rng([args.seed, 5])
        hard = fresh_errors(pde, model, norm, view, draws(prop, args.draws, True, rng))
        uniform = fresh_errors(pde, model, norm, view, draws(prop, args.draws, False, rng))
        lo, hi = ratio_interval(hard, uniform, rng)
        print(f"{space}: {summary['steps']} steps; skill {prop.skill:.3f}, steered share {prop.steer:.2f}; fresh "
              f"high-difficulty draws mean {hard.mean():.4f} median {np.median(hard):.4f} p95 "
              f"{np.percentile(hard, 95):.4f}; uniform draws mean {uniform.mean():.4f} median {np.median(uniform):.4f} "
              f"p95 {np.percentile(uniform, 95):.4f}; ratio of means {hard.mean() / uniform.mean():.2f} "
              f"[{lo:.2f}, {hi:.2f}] (95% bootstrap); {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
