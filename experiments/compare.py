"""On-the-fly stream vs fixed precomputed cache: the same model, the same number of optimizer steps.

Arm "cache": M samples (seed 0) written once with datasets.write_cache, read back from disk, reshuffled
each epoch. Arm "stream": samples 0, 1, 2, ... of the same seed, solved on demand (its first M samples are
the cache's). Each arm is normalized from its own source the same way (datasets.normalize.Moments): the cache
from its M stored samples, the stream from its calibration draw, samples 0..63 of the training seed (the first
samples it trains on; the draw's solve time counts as data wait). Both are evaluated on the same held-out test set (another seed) and on a shifted test set
whose parameters lie just outside the training domain. Several model seeds give mean and spread.
Outputs in out_dir: compare.md, compare.csv, compare.json, compare.png and each run's directory.
"""

from __future__ import annotations

import csv
import json
import statistics
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from pdestream import datasets
from pdestream.surrogate.checks import check_count, check_number
from pdestream.surrogate.data import test_set
from pdestream.surrogate.fno import COMPARE_FNO
from pdestream.surrogate.models import build_model
from pdestream.surrogate.phases import phase
from pdestream.surrogate.predict import model_channels
from pdestream.surrogate.runs import train_run

from .shift import shifted_pde


@dataclass
class CompareConfig:
    """What both arms share; ``cache_samples`` is M, the size of the fixed training set."""

    model: str = "fno"
    model_cfg: dict = field(default_factory=lambda: dict(COMPARE_FNO))
    view: object = "operator"  # a view name or object (datasets.make_view)
    steps: int = 1000
    batch_size: int = 32
    lr: float = 3e-3
    cache_samples: int = 32
    seeds: tuple = (0, 1, 2)
    n_test: int = 128
    shift: float = -0.25  # shifted domain: 25% of the width (in log for loguniform) below the lower bound
    cache_format: str = "h5"
    device: str = "cpu"  # where the models train (surrogate.runs.train_run)


def _stats(values: list[float]) -> tuple[float, float]:
    return statistics.fmean(values), (statistics.stdev(values) if len(values) > 1 else 0.0)


def compare(pde, out_dir, cfg: CompareConfig = CompareConfig(), shift_overrides: dict | None = None,
            log=print) -> dict:
    """Run both arms for every seed; write the table and the figure; return {"rows": [...], ...}."""
    out = Path(out_dir)
    for name, value in (("--cache-samples", cfg.cache_samples), ("--seeds", len(cfg.seeds)),
                        ("--test-samples", cfg.n_test), ("--steps", cfg.steps), ("--batch-size", cfg.batch_size)):
        check_count(name, value)
    check_number("--lr", cfg.lr, 0)
    # fail before any work: the view fitted to the samples (a steady entry has no frames), the model buildable
    view = datasets.make_view(cfg.view)
    fitted = datasets.for_sample(view, pde.n_frames, len(pde.INPUTS))
    build_model(cfg.model, pde.NDIM, *model_channels(pde, fitted), len(pde.PARAMS), bc=pde.grid.bc, **cfg.model_cfg)
    out.mkdir(parents=True, exist_ok=True)
    cache = out / f"cache.{cfg.cache_format}"
    written = datasets.write_cache(pde, cache, cfg.cache_samples, seed=0, overwrite=True)
    log(written.line())
    t0 = time.perf_counter()
    shifted = shifted_pde(pde, cfg.shift, shift_overrides)
    sets = 1 if shifted is None else 2  # each in batches of up to 32 (test_set)
    with phase(f"building the test sets ({cfg.n_test} trajectories each)", total=sets * cfg.n_test,
               solves=sets * -(-cfg.n_test // 32)):
        tests = {"test": test_set(pde, 0, cfg.n_test)}
        if shifted is not None:
            tests["shifted"] = test_set(shifted, 0, cfg.n_test)
    log(f"test sets: {cfg.n_test} trajectories in-domain" + (f", {cfg.n_test} shifted ({_domains(shifted)})" if shifted else "")
        + f" in {time.perf_counter() - t0:.1f} s")
    runs = {"cache": [], "stream": []}
    for seed in cfg.seeds:
        for arm, source in (("cache", str(cache)), ("stream", "stream")):
            summary = train_run(pde, source, out / f"{arm}_seed{seed}", model=cfg.model, model_cfg=cfg.model_cfg,
                                view=view, steps=cfg.steps, batch_size=cfg.batch_size, lr=cfg.lr, seed=seed,
                                data_seed=0, tests=tests, label=f"{arm} seed {seed}", device=cfg.device)
            runs[arm].append(summary)
            log(f"{arm:6s} seed {seed}: test rel L2 {summary['test']['test']['rel_l2']:.4f}"
                + (f", shifted {summary['test']['shifted']['rel_l2']:.4f}" if shifted else "")
                + f", train loss {summary['final_loss']:.3g}, {summary['wall']:.1f} s")
    rows = [_row(arm, runs[arm], written if arm == "cache" else None, tests) for arm in runs]
    result = {"pde": pde.config(), "shifted_pde": shifted.config() if shifted else None, "config": asdict(cfg),
              "rows": rows, "curves": {arm: [s["curve"] for s in runs[arm]] for arm in runs}}
    (out / "compare.json").write_text(json.dumps(result, indent=2))
    _write_table(out, rows, pde, shifted, cfg)
    _plot(out / "compare.png", result, tests)
    return result


def _domains(pde) -> str:
    return ", ".join(f"{k} ~ {v}" for k, v in pde.param_domains.items())


def _row(arm: str, runs: list[dict], written, tests: dict) -> dict:
    row = {"source": arm, "seeds": len(runs)}
    for name in tests:
        for metric in ("rel_l2", "nrmse", "rollout_final"):
            if metric in runs[0]["test"][name]:
                row[f"{name}_{metric}"], row[f"{name}_{metric}_std"] = _stats([r["test"][name][metric] for r in runs])
    row["final_train_loss"] = _stats([r["final_loss"] for r in runs])[0]
    row["wall_s"] = _stats([r["wall"] + (written.seconds if written else 0.0) for r in runs])[0]
    row["samples_seen"] = runs[0]["trajectories_seen"]
    row["norm_samples"] = runs[0]["normalization_samples"]  # cache: its M samples; stream: samples 0..n-1
    row["examples_seen"] = runs[0]["examples_seen"]
    row["bytes_on_disk"] = written.bytes if written else 0
    row["cache_write_s"] = written.seconds if written else 0.0
    row["data_wait_s"] = _stats([r["t_data"] for r in runs])[0]
    row["train_s"] = _stats([r["t_compute"] for r in runs])[0]
    return row


def _write_table(out: Path, rows: list[dict], pde, shifted, cfg: CompareConfig) -> None:
    with open(out / "compare.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    errs = [k for k in rows[0] if k.endswith(("rel_l2", "nrmse", "rollout_final")) and not k.endswith("_std")]
    stream = next(r for r in rows if r["source"] == "stream")
    head = ["source", *errs, "wall s", "samples seen", "norm samples", "bytes on disk", "cache write s", "data wait s", "compute s"]
    lines = [f"{pde.NAME} ({_domains(pde)}, n={pde.n}, {pde.n_frames} frames), {cfg.model} {cfg.model_cfg}, "
             f"view {datasets.make_view(cfg.view)}, {cfg.steps} steps x batch {cfg.batch_size}, M={cfg.cache_samples} cached, "
             f"seeds {list(cfg.seeds)}; errors: mean ± std over seeds on {cfg.n_test} held-out trajectories; "
             "wall s: training run (+ cache write), per seed; data wait: the loop waiting for batches (the "
             "stream solves in a background thread); compute: forward + backward + Adam; samples seen: distinct "
             "training trajectories; norm samples: the trajectories each arm's normalization statistics came from "
             f"(cache: its {cfg.cache_samples} stored samples, i.e. its training set; stream: its calibration draw, "
             f"samples 0..{stream['norm_samples'] - 1} of the training seed, "
             + ("among the first it trains on, so no extra samples" if stream["samples_seen"] >= stream["norm_samples"]
                else f"of which {stream['norm_samples'] - stream['samples_seen']} beyond those it trains on")
             + "; its solve time is part of data wait)"
             + (f"; shifted: {_domains(shifted)}" if shifted else ""), "",
             "| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in rows:
        cells = [r["source"], *(f"{r[k]:.4f} ± {r[k + '_std']:.4f}" for k in errs), f"{r['wall_s']:.1f}",
                 str(r["samples_seen"]), str(r["norm_samples"]), f"{r['bytes_on_disk']:,}", f"{r['cache_write_s']:.1f}", f"{r['data_wait_s']:.1f}", f"{r['train_s']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    (out / "compare.md").write_text("\n".join(lines) + "\n")


def _plot(path: Path, result: dict, tests: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    colors = {"cache": "tab:red", "stream": "tab:blue"}
    for arm, curves in result["curves"].items():
        for i, curve in enumerate(curves):
            ax1.plot([r["step"] for r in curve], [r["loss"] for r in curve], color=colors[arm], alpha=0.7,
                     label=arm if i == 0 else None)
    ax1.set(yscale="log", xlabel="optimizer step", ylabel="training loss (normalized MSE)", title="training loss")
    ax1.legend()
    names, width = list(tests), 0.38
    for j, row in enumerate(result["rows"]):
        means = [row[f"{n}_rel_l2"] for n in names]
        stds = [row[f"{n}_rel_l2_std"] for n in names]
        ax2.bar([i + (j - 0.5) * width for i in range(len(names))], means, width, yerr=stds, capsize=4,
                color=colors[row["source"]], label=row["source"])
    ax2.set_xticks(range(len(names)), [f"{n} set" for n in names])
    ax2.set(ylabel="relative L2 error", title="held-out test error (mean ± std over seeds)")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
