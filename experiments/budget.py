"""Budget-matched comparison: which data route trains the better surrogate for the same cost?

Arms (each trains the same model from the same initial weights; the clock of an arm covers everything it
does: compiling, solving, writing and reading a cache, computing normalization statistics, training):

- ``precomputed``: solve N trajectories into a cache (HDF5), read it back, train epochs over it;
- ``fifo``: the plain stream, every solve used once;
- ``reservoir``: the stream through a training reservoir (reuse under a bound, uniform parameters);
- ``reservoir_loss``: the reservoir with loss-driven parameter sampling;
- ``reservoir_active``: the reservoir with active sampling (loss model + ensemble disagreement, a proposal that
  can hold a sharp mode, a uniform floor: ``datasets.proposal``, mode "active");
- ``reservoir_generative``: the reservoir with the generative proposal (draws near the hardest fresh solves,
  ``datasets.proposal`` mode "generative", behind its lift gate), uniform replay;
- ``reservoir_priority``: the reservoir with uniform parameters and prioritized replay (draw "priority": each
  trajectory drawn in proportion to its last per-example relative L2 error in training, over a uniform floor), the lever that reaches the
  initial conditions, which no proposal over parameters steers. At a simulation budget its reuse bound is
  ``priority_cap`` times the mean reuse (the solves paced at the mean), so hard trajectories can be drawn more.

Two budgets:

- ``budget_s`` (wall-clock seconds per arm): every arm trains until its clock reaches the budget, with a
  cosine learning rate over the elapsed fraction. The precomputed arm sizes its dataset as a careful user
  would (``precompute_size``): it measures the solver's rate and the training step's, then solves as many
  trajectories as it can train over ``max_reuse`` epochs in the rest of the budget (each trajectory used as
  often as the reservoir arms may use one); ``precompute_share`` fixes the share of the budget spent solving
  instead. The budget is a deadline, whatever the rates said: the arm solves in chunks of ``solve_batch``,
  re-measuring the rate after each, and stops solving by ``MAX_SOLVE_SHARE`` (half) of the budget (or the
  share given), so the rest is left to train; every arm's training loop stops at the budget (the last step or
  chunk started before it may end after it).
- ``sim_budget`` (solved trajectories per arm): every arm gets the same N trajectories and ``steps`` optimizer
  steps (the FIFO stream runs out after N trajectories' examples: it trains fewer steps, as it would). The
  reservoir arms run in deterministic mode there: ``sim_warmup_share`` of the solves (uniform) before the first
  step, the rest paced over the training run, so the loss-driven proposals follow the model as it learns.

The precomputed arm stores only the frames its view uses (the operator view: the first and the last, solved
with the same internal step, so they are the stream's frames bit for bit), as a user who precomputes would.

Test sets are stratified over the parameter box (a Latin hypercube in the unit box: linear for uniform, log for
loguniform), with ICs from a held-out seed, plus the shifted domain. Errors are per trajectory (relative L2 of
the operator's output, or of the whole autoregressive rollout for next-step models) and reported as mean,
p95, p99, CVaR_0.95 and max, with bootstrap intervals (``experiments.budget_report``, ``surrogate.tails``). The models are snapshotted along the run and evaluated afterwards, so evaluation never eats an
arm's budget or competes with its solver. Outputs: compare.md/csv/json and compare.png.
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from pdestream import datasets
from pdestream.datasets.cache import solve_block, write_solved
from pdestream.datasets.proposal import ParamProposal
from pdestream.datasets.reservoir_config import DEFAULTS as RESERVOIR
from pdestream.surrogate.checks import check_count, check_number
from pdestream.surrogate.data import TEST_SEED_OFFSET, EpochBatchSampler, check_device
from pdestream.surrogate.evaluate import error_stats, rollout_errors
from pdestream.surrogate.fno import COMPARE_FNO
from pdestream.surrogate.models import build_model
from pdestream.surrogate.modes import check_fits, make_mode, training_view
from pdestream.surrogate.phases import phase
from pdestream.surrogate.train import Stop, source_normalization, train

# the report's names, re-exported where they have always been (``X as X``: an explicit re-export)
from .budget_report import COLUMNS as COLUMNS
from .budget_report import MIN_STEPS as MIN_STEPS
from .budget_report import combine_seeds, verdicts, write_tables
from .budget_report import precompute_line as precompute_line
from .budget_report import too_few_steps_note as too_few_steps_note
from .shift import shifted_pde

ARMS = ("precomputed", "fifo", "reservoir", "reservoir_loss", "reservoir_active", "reservoir_priority",
        "reservoir_generative")
DEFAULT_ARMS = ARMS[:4]  # the steered arms after them are named to be run (one more arm x seeds each)
PROPOSALS = {"reservoir_loss": "loss", "reservoir_active": "active", "reservoir_generative": "generative"}  # the steered arms' proposal modes
DRAWS = {"reservoir_priority": "priority", "reservoir_active": "priority"}  # the arms that draw by priority (the rest: uniform)


@dataclass
class BudgetConfig:
    """What every arm shares. Exactly one of budget_s / sim_budget is set. The reservoir arms' settings default
    to ``ReservoirConfig``'s (capacity, max_reuse, target_reuse, reservoir_mode = its mode, priority_power,
    priority_floor, solve_batch)."""

    budget_s: float | None = None
    sim_budget: int | None = None
    arms: tuple = DEFAULT_ARMS
    model: str = "fno"
    model_cfg: dict = field(default_factory=lambda: dict(COMPARE_FNO))
    view: object = "operator"
    batch_size: int = 32
    lr: float = 3e-3
    steps: int = 1000  # sim_budget: optimizer steps per arm
    precompute_share: float | None = None  # budget_s: share of the budget spent solving (None: precompute_size)
    capacity: int = RESERVOIR.capacity
    max_reuse: float = RESERVOIR.max_reuse
    target_reuse: float | str | None = RESERVOIR.target_reuse  # time budget: the reservoirs' solver pace ("auto": by
    # measured rates, datasets/reservoir_pacer.py; a number: fixed; None / "off": flat out)
    sim_warmup_share: float = 0.5  # sim budget: share of the solves a reservoir arm makes before training starts
    reservoir_mode: str = RESERVOIR.mode
    proposal_floor: float = 0.25
    proposal_kwargs: dict | None = None  # more ParamProposal settings for the steered arms (e.g. ensemble, kappa)
    priority_power: float = RESERVOIR.priority_power  # prioritized replay: draw probability ~ last loss ** power ...
    priority_floor: float = RESERVOIR.priority_floor  # ... over this uniform share
    priority_cap: float = 4.0  # sim budget: the priority arms' reuse bound, in multiples of the mean reuse
    solve_batch: int = RESERVOIR.solve_batch
    seeds: int = 3  # repetitions per arm: model and data seeds 0..seeds-1 (mean, spread and verdicts)
    n_test: int = 128
    shift: float = -0.25
    device: str = "cpu"  # where the models train ("cuda": JAX solves on the GPU too when it sees one)
    snapshots: int = 8
    mode: dict | None = None  # the training mode's settings (surrogate.modes; None: one-step)

    def check(self) -> None:
        if (self.budget_s is None) == (self.sim_budget is None):
            raise ValueError("give exactly one budget: --budget SECONDS or --sim-budget N")
        if self.budget_s is not None:
            check_number("--budget", self.budget_s, 0, unit="seconds")
        if self.sim_budget is not None:
            check_count("--sim-budget", self.sim_budget, note=" (trajectories)")
        unknown = [a for a in self.arms if a not in ARMS]
        if unknown or not self.arms:
            raise ValueError(f"arms {list(self.arms)} not allowed; choose from {', '.join(ARMS)}")
        check_number("sim warm-up share", self.sim_warmup_share, 0, 1, closed="both")
        check_number("--priority-cap", self.priority_cap, 1, closed="low")
        if self.precompute_share is not None:
            check_number("precompute share", self.precompute_share, 0, 1)
        check_device(self.device)
        for name, value in (("--steps", self.steps), ("--seeds", self.seeds), ("--test-samples", self.n_test),
                            ("snapshots", self.snapshots), ("--batch-size", self.batch_size)):
            check_count(name, value)
        check_number("--lr", self.lr, 0)
        make_mode(self.mode)


# --- test sets ------------------------------------------------------------------------------------------
def stratified_test_set(pde, n: int, seed: int, chunk: int = 32) -> list[dict]:
    """n whole trajectories {"u": [b, T, C, *space], "params": [b, P], "index": [b]} whose parameters form a
    Latin hypercube over the PDE's parameter box (every stratum of every parameter once); ICs from
    seed TEST_SEED_OFFSET + seed."""
    prop = ParamProposal(datasets.param_domains(pde), mode="uniform")
    rng = np.random.default_rng([TEST_SEED_OFFSET, seed])
    z = np.stack([(rng.permutation(n) + rng.random(n)) / n for _ in prop.random], 1) if prop.random else np.zeros((n, 0))
    values = prop.from_unit(z)
    out = []
    for lo in range(0, n, chunk):
        idx = np.arange(lo, min(lo + chunk, n))
        pad = np.resize(idx, chunk)  # one compiled shape for every chunk
        data = datasets.sample_tensors(pde, pad, TEST_SEED_OFFSET + seed, params={k: v[pad] for k, v in values.items()})
        out.append({"u": data["u"][: len(idx)].clone(), "params": data["params"][: len(idx)].clone(),
                    "index": data["index"][: len(idx)].clone()})
    return out


def per_trajectory_errors(model, norm, view, test: list[dict], mode=None) -> np.ndarray:
    """Relative L2 per test trajectory [N]: the operator's output, or the whole rollout of a next-step model."""
    return rollout_errors(model, norm, test, view, mode).trajectory()


# --- one arm ----------------------------------------------------------------------------------------------
def stored_pde(pde, view):
    """The PDE whose samples the precomputed arm stores: for the operator view, frames 0 and n_frames - 1 only,
    solved with the same internal step (``dt`` pinned to the full trajectory's, so the frames are the stream's
    bit for bit); otherwise ``pde`` itself (next-step windows use every frame; a problem without a ``dt``
    setting, e.g. the flows, is stored whole)."""
    step = getattr(pde, "step_dt", None)
    if view.name != "operator" or pde.STEADY or pde.n_frames <= 2 or step is None or "dt" not in pde.config():
        return pde
    # a hair above the step, so that ceil(t_end / dt) gives back the same number of steps in all
    return pde.replace({"n_frames": 2, "dt": step * (1 + 1e-9)})


def precompute_size(cfg: BudgetConfig, rate: float, step_s: float, left_s: float, per: int) -> int:
    """Trajectories for the precomputed arm at a time budget, the way a careful user sizes a dataset: as many
    as it can both solve (``rate`` trajectories/s) and train over ``cfg.max_reuse`` epochs (``step_s`` seconds
    per optimizer step of ``cfg.batch_size`` examples, ``per`` examples per trajectory) in the ``left_s``
    seconds left. N solves take N / rate s and N max_reuse per / batch steps the rest:
    N = left / (1 / rate + max_reuse per step_s / batch). ``cfg.precompute_share`` instead fixes the solving
    share. At least one batch."""
    if cfg.precompute_share is not None:
        return max(cfg.batch_size, int(rate * (cfg.precompute_share * cfg.budget_s - (cfg.budget_s - left_s))))
    return max(cfg.batch_size, int(left_s / (1 / rate + cfg.max_reuse * per * step_s / cfg.batch_size)))


MAX_SOLVE_SHARE = 0.5  # budget_s: the precomputed arm solves until at most this share of its budget, then trains


def _solve_in_time(stored, cfg: BudgetConfig, seed: int, clock_start: float, step_s: float, per: int):
    """The precomputed arm's solve phase at a time budget: ``cfg.solve_batch`` trajectories per chunk, the clock
    read after each. The deadline is hard: no chunk starts once ``MAX_SOLVE_SHARE`` of the budget (or
    ``cfg.precompute_share``) has passed since ``clock_start``, nor one the last chunk's time says would end past
    it, so at least 1 - that share is left to train (less at most one chunk, should the solver slow down). Within
    it, ``precompute_size`` at the rate just measured (re-measured every chunk; the first, compiling chunk is not
    used to stop) says how many trajectories to solve. The first chunk is always solved. Returns (blocks for
    ``datasets.cache.write_solved``, the plan's figures)."""
    share = cfg.precompute_share if cfg.precompute_share is not None else MAX_SOLVE_SHARE
    stop_at = clock_start + share * cfg.budget_s
    blocks, n, rate, last, target = [], 0, None, 0.0, cfg.solve_batch
    while True:
        now = time.perf_counter()
        if blocks and now >= stop_at:
            break
        if len(blocks) >= 2:  # measured on warm chunks: the rule and the deadline as they predict
            target = precompute_size(cfg, rate, step_s, cfg.budget_s - (now - clock_start) + n / rate, per)
            if n >= target or now + last > stop_at:
                break
        hi = n + max(1, min(cfg.solve_batch, target - n)) if len(blocks) >= 2 else n + cfg.solve_batch
        t0 = time.perf_counter()
        blocks.append((n, hi, *solve_block(stored, seed, n, hi, cfg.solve_batch, "raise")))
        last = time.perf_counter() - t0  # a chunk is padded to solve_batch: one compile, the same cost
        rate, n = cfg.solve_batch / max(last, 1e-9), hi
    end = time.perf_counter() - clock_start
    return blocks, {"solve_per_s": rate, "step_s": step_s, "solve_share": end / cfg.budget_s, "solve_cap": share,
                    "epochs_planned": (cfg.budget_s - end) / step_s * cfg.batch_size / (n * per)}


def _step_seconds(pde, view, cfg: BudgetConfig, mode) -> float:
    """Seconds per optimizer step of the arms' model at ``cfg.batch_size`` (random inputs; 2 warm-up steps,
    then the median of 5): the training rate the precomputed arm plans its dataset with."""
    c_in, c_out = mode.channels(pde, view)
    model = build_model(cfg.model, pde.NDIM, c_in, c_out, len(pde.PARAMS), bc=pde.grid.bc, **cfg.model_cfg).to(cfg.device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    x = torch.randn(cfg.batch_size, c_in, *pde.grid.shape, device=cfg.device)
    y = torch.randn(cfg.batch_size, c_out, *pde.grid.shape, device=cfg.device)
    p = torch.randn(cfg.batch_size, len(pde.PARAMS), device=cfg.device) if pde.PARAMS else None
    times = []
    for i in range(7):
        t0 = time.perf_counter()
        opt.zero_grad()
        torch.nn.functional.mse_loss(model(x, p), y).backward()
        opt.step()
        float(y.sum())  # the step is done (a GPU runs asynchronously)
        if i >= 2:
            times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _loader(arm: str, pde, view, cfg: BudgetConfig, seed: int, out: Path, clock_start: float, log):
    """(DataLoader, what the arm did to get it: {"trajectories_solved"?, "cache_bytes"?, "precompute"?})."""
    if arm == "precomputed":
        stored = stored_pde(pde, view)
        plan = {"frames_stored": stored.n_frames, "frames": pde.n_frames}
        if cfg.sim_budget is not None:
            n = cfg.sim_budget
            plan["rule"] = "the simulation budget"
        else:  # measure the training step, then solve in chunks against the clock (_solve_in_time)
            step_s = _step_seconds(pde, view, cfg, make_mode(cfg.mode).bind(pde, seed))
            blocks, plan_more = _solve_in_time(stored, cfg, seed, clock_start, step_s, view.per_trajectory(pde.n_frames))
            n = blocks[-1][1]
            plan.update(rule=f"share {cfg.precompute_share:g}" if cfg.precompute_share is not None else
                        f"each trajectory trained on {cfg.max_reuse:g} times", **plan_more)
        path = out / "cache.h5"
        if cfg.sim_budget is not None:
            written = datasets.write_cache(stored, path, n, seed=seed, overwrite=path.exists(), progress=False)
        else:
            written = write_solved(stored, path, seed, blocks, cfg.solve_batch, overwrite=path.exists())
        log(f"  precomputed: {written.line()}")
        cached = datasets.CachedTrajectories(path, view=view)
        sampler = EpochBatchSampler(len(cached), cfg.batch_size, seed, drop_last=len(cached) >= cfg.batch_size)
        loader = DataLoader(cached, batch_sampler=sampler, collate_fn=datasets.collate, generator=torch.Generator())
        return loader, {"trajectories_solved": n, "cache_bytes": written.bytes, "precompute": plan}
    if arm == "fifo":
        stream = datasets.TrajectoryStream(pde, seed=seed, view=view, batch_size=cfg.batch_size,
                                           solve_batch=cfg.solve_batch, n_samples=cfg.sim_budget)
        return datasets.stream_loader(stream), {}
    per = len(view.starts(pde.n_frames, torch.Generator().manual_seed(0)))
    draw = DRAWS.get(arm, "uniform")
    reuse, target = cfg.max_reuse, cfg.target_reuse
    if cfg.sim_budget is not None:  # enough reuse for the steps, the bound still holding
        reuse = target = max(1.0, 1.05 * cfg.steps * cfg.batch_size / (cfg.sim_budget * per))
        if draw == "priority":  # room for the hard trajectories to be drawn more than the mean
            reuse = cfg.priority_cap * target
    stream = datasets.ReservoirStream(
        pde, seed=seed, view=view, batch_size=cfg.batch_size, capacity=cfg.capacity,
        # at a simulation budget the solves are paced by training (deterministic schedule: one solve batch per
        # solve_batch x the mean reuse drawn), so loss-driven proposals see the model's current losses rather
        # than an untrained model's, and the run is reproducible
        max_reuse=reuse, solve_batch=cfg.solve_batch, sim_budget=cfg.sim_budget,
        mode="deterministic" if cfg.sim_budget is not None else cfg.reservoir_mode,
        target_reuse=target,  # (at a sim budget = the bound unless it draws by priority: the same schedule)
        warmup=min(_warmup(cfg), cfg.capacity), draw=draw, priority_power=cfg.priority_power,
        priority_floor=cfg.priority_floor,
        proposal=PROPOSALS.get(arm, "uniform"), proposal_kwargs=_proposal_kwargs(cfg, arm))
    return DataLoader(stream, batch_size=None), {}


def _paced(stats: dict) -> str:
    """The arm's log words on its producer's pacing (datasets/reservoir_pacer.py): "" without a reuse target."""
    r = (stats or {}).get("target_reuse")
    if r is None or r != r:
        return ""
    return (f", reuse target {r:.2f} (mean reuse {stats['reuse_mean']:.2f}), producer idle "
            f"{100 * stats['producer_idle_share']:.0f}%")


def _proposal_kwargs(cfg: BudgetConfig, arm: str) -> dict:
    """ParamProposal settings of ``arm``: the floor, plus ``cfg.proposal_kwargs`` those of its mode accepts
    (the "active" mode's ensemble, kappa, refit and candidates go to reservoir_active only; none to an unsteered arm)."""
    if arm not in PROPOSALS:  # an arm with the key's own draws steers nothing: no setting of a proposal applies
        return {}
    active_only = ("ensemble", "kappa", "refit", "candidates")
    extra = {k: v for k, v in (cfg.proposal_kwargs or {}).items() if arm == "reservoir_active" or k not in active_only}
    return {"floor": cfg.proposal_floor, **extra}


def _warmup(cfg: BudgetConfig) -> int:
    """Trajectories a reservoir arm holds before its first batch: at a simulation budget, ``sim_warmup_share`` of
    it, solved up front (uniformly), the rest paced over the run; at a time budget, one batch's worth."""
    first = max(cfg.solve_batch, cfg.batch_size)
    if cfg.sim_budget is None:
        return first
    return max(first, int(cfg.sim_warmup_share * cfg.sim_budget))


def run_arm(arm: str, pde, view, cfg: BudgetConfig, out: Path, tests: dict, log=print, seed: int = 0) -> dict:
    """Train one arm (model and data seed ``seed``) within the budget through ``train.train`` (its clock started
    before the data source was built: a cache's solves count); evaluate its snapshots afterwards. ``view``: the
    arm's training view (``training_view`` of the mode). Returns the arm's record."""
    out.mkdir(parents=True, exist_ok=True)
    clock_start = time.perf_counter()
    mode = make_mode(cfg.mode).bind(pde, seed)
    loader, extra = _loader(arm, pde, view, cfg, seed, out, clock_start, log)
    dataset = loader.dataset
    norm = source_normalization(loader)  # before training: not counted as the loop's data wait
    torch.manual_seed(seed)  # the same initial weights in every arm
    model = build_model(cfg.model, pde.NDIM, *mode.channels(pde, view), len(pde.PARAMS), bc=pde.grid.bc,
                        **cfg.model_cfg).to(cfg.device)
    snapshots, loop_end = [], [0.0]

    def snapshot(step: int, fraction: float, elapsed: float) -> None:
        loop_end[0] = elapsed
        if len(snapshots) < cfg.snapshots and fraction >= (len(snapshots) + 1) / cfg.snapshots - 1e-9:
            snapshots.append((elapsed, step, copy.deepcopy(model.state_dict())))

    # a cache is trained over in epochs; a stream's simulation budget, once spent, ends the arm
    stop = Stop(steps=cfg.steps if cfg.sim_budget is not None else None,
                seconds=cfg.budget_s if cfg.sim_budget is None else None, once=arm != "precomputed")
    try:
        summary = train(model, loader, stop, out, lr=cfg.lr, normalizer=norm, label=arm, mode=mode,
                        started=clock_start, after_step=snapshot, meta={"arm": arm, "seed": seed, "mode": mode.settings()})
    finally:
        stats = dataset.stats() if hasattr(dataset, "stats") else {}
        report = dataset.report() if hasattr(dataset, "report") else {}  # a reservoir's reuse and where it solved
        if hasattr(dataset, "close"):
            dataset.close()
    if summary["stop"] == "data" or not snapshots:  # the data ran out before the budget: the model as it ended
        snapshots.append((summary["wall"], summary["steps"], copy.deepcopy(model.state_dict())))
    steps, examples, t_data, t_compute = summary["steps"], summary["examples_seen"], summary["t_data"], summary["t_compute"]
    wall = loop_end[0] if steps else summary["wall"]
    # a cache knows its size; a reservoir counts its insertions; the FIFO stream uses each solve once
    solved = extra.get("trajectories_solved", stats.get("inserted", summary["trajectories_seen"]))
    with phase(f"{arm}: evaluating {len(snapshots)} snapshots on the test sets"):
        curve = _snapshot_curve(model, norm, view, mode, snapshots, tests)  # leaves the model at the last one
        final = {k: per_trajectory_errors(model, norm, view, ts, mode) for k, ts in tests.items()}
    reuse, density = report.get("reuse", []), report.get("density")
    record = {"arm": arm, "seed": seed, "wall_s": wall, "steps": steps, "examples": examples, "trajectories_solved": solved,
              "data_wait_s": t_data, "compute_s": t_compute, "startup_s": wall - t_data - t_compute,
              "wait_share": t_data / max(t_data + t_compute, 1e-9),  # of the training loop's time
              "cache_bytes": extra.get("cache_bytes", 0), "precompute": extra.get("precompute"), "stats": stats, "reuse": reuse, "density": density,
              "curve": curve, "errors": {k: v.tolist() for k, v in final.items()},
              **{f"{k}_{m}": v for k, e in final.items() for m, v in error_stats(e).items()}}
    (out / "arm.json").write_text(json.dumps(record, indent=2))
    return record


# --- the comparison ----------------------------------------------------------------------------------------
def _snapshot_curve(model, norm, view, mode, snapshots: list, tests: dict) -> list[dict]:
    """Each snapshot (elapsed, step, state dict) loaded into ``model`` and evaluated: mean, p95, p99, CVaR_0.95 and
    max of the per-trajectory errors on every test set."""
    curve = []
    for t, s, state in snapshots:
        model.load_state_dict(state)
        errors = {k: per_trajectory_errors(model, norm, view, ts, mode) for k, ts in tests.items()}
        curve.append({"elapsed": t, "step": s, **{f"{k}_{m}": v for k, e in errors.items()
                                                   for m, v in error_stats(e).items()}})
    return curve


def budget_compare(pde, out_dir, cfg: BudgetConfig, shift_overrides: dict | None = None, log=print) -> dict:
    """Run every arm at the budget; write compare.md/csv/json and compare.png; return the result dict."""
    cfg.check()
    # fitted to the samples (a steady entry's operator view has no frames to check) and the model built once, so
    # a 3D entry or a bad --model-set is refused before any solve (it was refused after the test sets and a cache)
    mode = make_mode(cfg.mode)
    view = training_view(mode, datasets.for_sample(datasets.make_view(cfg.view), pde.n_frames, len(pde.INPUTS)))
    check_fits(mode, view, pde)
    build_model(cfg.model, pde.NDIM, *mode.channels(pde, view), len(pde.PARAMS), bc=pde.grid.bc, **cfg.model_cfg)
    steered = next((a for a in ("reservoir_active", "reservoir_generative", "reservoir_loss") if a in cfg.arms),
                   "reservoir_active")
    datasets.ReservoirStream(pde, view=view, batch_size=cfg.batch_size, capacity=cfg.capacity,
                             solve_batch=cfg.solve_batch, mode=cfg.reservoir_mode,
                             proposal=PROPOSALS[steered] if steered in cfg.arms else "uniform",
                             proposal_kwargs=_proposal_kwargs(cfg, steered) if steered in cfg.arms else {}, draw="priority",
                             priority_power=cfg.priority_power, priority_floor=cfg.priority_floor)  # settings checked before any work
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    shifted = shifted_pde(pde, cfg.shift, shift_overrides)
    sets = 1 if shifted is None else 2  # each in chunks of 32 (stratified_test_set)
    with phase(f"building the test sets ({cfg.n_test} stratified trajectories each)", total=sets * cfg.n_test,
               solves=sets * -(-cfg.n_test // 32)):
        tests = {"test": stratified_test_set(pde, cfg.n_test, 0)}
        if shifted is not None:
            tests["shifted"] = stratified_test_set(shifted, cfg.n_test, 0)
    log(f"test sets: {cfg.n_test} stratified trajectories" + (" in-domain and shifted" if shifted else "")
        + f" in {time.perf_counter() - t0:.1f} s")
    records = []
    for arm in cfg.arms:
        runs = []
        for seed in range(cfg.seeds):
            rec = run_arm(arm, pde, view, cfg, out / (arm if cfg.seeds == 1 else f"{arm}_seed{seed}"), tests, log, seed)
            runs.append(rec)
            log(f"{arm:15s} seed {seed}: test mean {rec['test_mean']:.4f} p95 {rec['test_p95']:.4f} p99 {rec['test_p99']:.4f} "
                f"cvar95 {rec['test_cvar95']:.4f} max "
                f"{rec['test_max']:.4f}; {rec['steps']} steps, {rec['trajectories_solved']} trajectories, "
                f"{rec['wall_s']:.0f} s, loop waiting for data {100 * rec['wait_share']:.0f}%" + _paced(rec["stats"]))
        records.append(combine_seeds(runs))
    if len(records) > 1:
        for line in verdicts(records, cfg.seeds):
            log(line)
    test_params = {k: torch.cat([b["params"] for b in ts]).tolist() for k, ts in tests.items()}
    result = {"pde": pde.config(), "shifted_pde": shifted.config() if shifted else None,
              "config": {k: v if not hasattr(v, "name") else v.name for k, v in asdict(cfg).items()},
              "param_names": list(pde.PARAMS), "test_params": test_params, "arms": records}
    (out / "compare.json").write_text(json.dumps(result, indent=2, default=str))
    write_tables(out, result, pde, cfg)
    from pdestream.surrogate.budget_plot import plot_budget

    plot_budget(out / "compare.png", result, datasets.param_domains(pde))
    return result
