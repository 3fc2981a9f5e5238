"""Does a proposal over (parameters, IC latent) find where the model's loss is high? Measured on fresh solves.

``python -m benchmarks.latent_bench [--pde burgers1d] [--steps 800] [--sim-budget 256] [--draws 256]
[--proposals active,generative] [--spaces params+ic,params]`` trains the compare arms' small FNO (operator view, one
seed) through a deterministic reservoir with each proposal over each space, as ``compare --sim-budget`` does, then
asks the proposal it ended with for ``draws`` high-difficulty draws (``ParamProposal.steered``: its steered part
alone, no uniform floor) and compares them with uniform draws (the prior: what the key would draw), all solved afresh
on a held-out seed with the same sample indices (so the IC's coordinates beyond the latent are the same in every set).
Two uniform sets are solved once and scored by every model: one with explicit prior latents (the joint space's
uniform draw) and one whose IC comes from the key (the parameters space's); a model's ratio is against the set of its
own space. Prints each set's mean, median and p95 per-trajectory relative L2 error, the ratio of means with a 95%
bootstrap interval, and the proposal's skill and steered share.
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
from pdestream.datasets.proposal_fit import correlation
from pdestream.surrogate.evaluate import rollout_errors
from pdestream.surrogate.fno import COMPARE_FNO
from pdestream.surrogate.models import build_model
from pdestream.surrogate.modes import make_mode
from pdestream.surrogate.train import Stop, source_normalization, train

HELD_OUT_SEED = 1_000_003  # the fresh solves' seed: never a training sample


def train_arm(pde, space: str, steps: int, sim_budget: int, batch: int, seed: int, out: Path, floor: float = 0.25,
              proposal: str = "active"):
    """The compare arm reservoir_active's data path over ``space`` with ``proposal``: (model, normalization, view, the
    final proposal, the training summary)."""
    view = datasets.make_view("operator")
    reuse = max(1.0, 1.05 * steps * batch / sim_budget)
    stream = datasets.ReservoirStream(pde, seed=seed, view=view, batch_size=batch, capacity=sim_budget, max_reuse=reuse,
                                      solve_batch=16, sim_budget=sim_budget, mode="deterministic", target_reuse=reuse,
                                      warmup=sim_budget // 4, proposal=proposal,
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
    """n unit points: the proposal's steered part alone (``ParamProposal.steered``) or uniform, as {param: [n],
    LATENT?: [n, L]}; uniform where the proposal has nothing to steer by (a warning line says so)."""
    z = proposal.steered(n, rng) if steered else None
    if steered and z is None:
        print(f"{proposal.mode}: no fit to steer by: its high-difficulty draws are uniform")
    return proposal.from_unit(rng.random((n, proposal.dims)) if z is None else z)


def solve_set(pde, values: dict, chunk: int = 32) -> list[dict]:
    """Fresh solves of ``values`` (sample indices 0..n-1, seed HELD_OUT_SEED) as rollout_errors' test batches."""
    n = len(next(iter(values.values())))
    out = []
    for lo in range(0, n, chunk):
        idx = np.arange(lo, min(lo + chunk, n))
        params = {k: v[idx] for k, v in values.items() if k != LATENT}
        latent = values[LATENT][idx] if LATENT in values else None
        traj = generator.sample(pde, idx, HELD_OUT_SEED, params=params or None, latent=latent)
        u = torch.from_numpy(np.asarray(traj.u))
        p = torch.from_numpy(np.stack([np.asarray(traj.params[k]) for k in pde.PARAMS], 1))
        out.append({"u": u, "params": p, "index": torch.from_numpy(idx)})
    return out


def errors(model, norm, view, batches: list[dict]) -> np.ndarray:
    """Per-trajectory relative L2 of the model on solved batches [n]."""
    return rollout_errors(model, norm, batches, view).trajectory()


def ratio_interval(a: np.ndarray, b: np.ndarray, rng: np.random.Generator, n: int = 1000) -> tuple[float, float]:
    """95% percentile bootstrap interval of mean(a) / mean(b), the two resampled independently."""
    r = [rng.choice(a, len(a)).mean() / rng.choice(b, len(b)).mean() for _ in range(n)]
    return float(np.percentile(r, 2.5)), float(np.percentile(r, 97.5))


def describe(e: np.ndarray) -> str:
    return f"mean {e.mean():.4f} median {np.median(e):.4f} p95 {np.percentile(e, 95):.4f}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pde", default="burgers1d")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--steps", type=int, default=800)
    ap.add_argument("--sim-budget", type=int, default=256)
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--draws", type=int, default=256)
    ap.add_argument("--proposals", default="active", help="comma-separated steered proposals (datasets.proposal.MODES)")
    ap.add_argument("--spaces", default="params+ic,params")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--floor", type=float, default=0.25, help="the proposal's uniform share (1: never steered, a control)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    pde = generator.get_pde(args.pde).replace(dict(s.split("=", 1) for s in args.set))
    print(f"{pde.NAME} (n={pde.n}, ic {pde.ic}, latent L={pde.latent_size()}), {args.sim_budget} solves, "
          f"{args.steps} steps, FNO {COMPARE_FNO}, {args.draws} fresh draws per set, seed {args.seed}, floor {args.floor}")
    arms = [(p, s) for s in args.spaces.split(",") for p in args.proposals.split(",")]
    uniform, models = {}, []
    for proposal, space in arms:
        t0 = time.perf_counter()
        with TemporaryDirectory() as tmp:
            model, norm, view, prop, summary = train_arm(pde, space, args.steps, args.sim_budget, args.batch_size,
                                                         args.seed, Path(tmp), args.floor, proposal)
        hard = errors(model, norm, view, solve_set(pde, draws(prop, args.draws, True, np.random.default_rng([args.seed, 5]))))
        if space not in uniform:  # the space's uniform set, solved once and scored by every model
            values = draws(prop, args.draws, False, np.random.default_rng([args.seed, 6, len(uniform)]))
            unit = prop.to_unit(np.stack([values.get(k, np.ones(args.draws)) for k in pde.PARAMS], 1), values.get(LATENT))
            uniform[space] = (solve_set(pde, values), unit)
        own = errors(model, norm, view, uniform[space][0])
        # the skill gate's predictor, offline: its correlation with the log error of the uniform draws' fresh solves
        pred = prop.predict(uniform[space][1])
        offline = "none" if pred is None else f"{correlation(pred, np.log(own)):.3f}"
        lo, hi = ratio_interval(hard, own, np.random.default_rng([args.seed, 7]))
        moved = ""
        if getattr(prop, "_gen", None) is not None:  # the generative model: its hard solves' effective count
            v = np.exp(prop._gen[1])
            moved = f" (its model: {len(v)} hard solves, effective {1 / (v @ v):.0f})"
        print(f"{proposal} over {space}: {summary['steps']} steps; skill {prop.skill:.3f}{moved}, steered share "
              f"{prop.steer:.2f}, predictor's correlation on the uniform draws {offline}; fresh high-difficulty draws {describe(hard)}; uniform draws {describe(own)}; "
              f"ratio of means {hard.mean() / own.mean():.2f} [{lo:.2f}, {hi:.2f}] (95% bootstrap); "
              f"{time.perf_counter() - t0:.0f} s to train and score", flush=True)
        models.append((f"{proposal} over {space}", model, norm, view))
    if len(uniform) > 1:  # every model on every space's uniform set: a model gap or a test-set gap?
        for name, model, norm, view in models:
            print(f"{name} on " + "; ".join(f"the uniform draws of {s}: {describe(errors(model, norm, view, u[0]))}"
                                            for s, u in uniform.items()))

if __name__ == "__main__":
    main()
