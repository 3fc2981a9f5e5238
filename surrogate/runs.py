"""One training run end to end: data source -> model -> train -> held-out test errors (used by the CLI).

A run directory holds ``run.json`` (written first: every setting ``resume_run`` needs to rebuild the run; then
"normalization" is added: the statistics, from the training data only, that training, the test errors and a
resumed run all use),
``checkpoint.pt`` (the training state, every ``checkpoint_every`` steps and at the end), and when finished
``metrics.csv``, ``model.pt`` and ``metrics.json`` (written last: its presence marks a finished run).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from pdestream import datasets

from . import ddp
from .budget_plot import plot_reservoir_run
from .checkpoint import CHECKPOINT, atomic_write, load_train_state
from .data import check_device, test_set, train_loader
from .evaluate import test_errors
from .models import build_model
from .modes import check_fits, make_mode, training_view
from .phases import phase
from .train import Stop, check_train_settings, train
from .user_model import check_output

RUN_FILE = "run.json"
RUN_FORMAT = 1
# files of a run; a fresh run in a directory first removes these, so no stale checkpoint can be resumed
# the settings every run.json holds (later additions, device and mode, default when absent)
RUN_KEYS = ("pde", "source", "model", "model_cfg", "view", "view_args", "steps", "batch_size", "lr", "schedule",
            "seed", "data_seed", "n_test", "checkpoint_every", "data_cfg", "label")
RUN_FILES = (RUN_FILE, CHECKPOINT, "model.pt", "metrics.json", "metrics.csv")
# every file a run may write (a reservoir run adds its report): what replacing a run may remove, nothing else
RUN_OUTPUTS = (*RUN_FILES, "reservoir.json", "reservoir.png")
STAGING = ".{name}.new.{pid}"  # where `train --overwrite` builds the new run, beside the old one


def staging_dir(out: Path) -> Path:
    """The hidden directory beside ``out`` in which a run that replaces ``out``'s is built (this process's), after
    removing those of dead processes (a kill -9 left them; a live process's is kept)."""
    out = Path(out)
    for stale in out.parent.glob(STAGING.format(name=out.name, pid="*")):
        pid = stale.name.rsplit(".", 1)[-1]
        if pid.isdigit() and not _alive(int(pid)) and stale.is_dir():
            remove_staging(stale)
    return out.parent / STAGING.format(name=out.name, pid=os.getpid())


def replace_run(staging: Path, out: Path) -> None:
    """Move the run built in ``staging`` into ``out`` in place of the run there: the old finished-marker
    (metrics.json) goes first and the new one comes last, so a crash in between never reads as a finished run;
    the old run's other files are replaced or removed; files in ``out`` that are not run files stay."""
    old_marker = out / "metrics.json"
    old_marker.unlink(missing_ok=True)
    names = [n for n in RUN_OUTPUTS if n != "metrics.json"] + ["metrics.json"]
    for name in names:
        if (staging / name).is_file():
            os.replace(staging / name, out / name)
        else:
            (out / name).unlink(missing_ok=True)
    remove_staging(staging)


def remove_staging(d: Path) -> None:
    """Remove a staging directory: its run files (and their temp files), then the directory if that left it empty."""
    for name in RUN_OUTPUTS:
        (d / name).unlink(missing_ok=True)
        for stray in d.glob(f".{name}.*.tmp"):
            stray.unlink(missing_ok=True)
    try:
        d.rmdir()
    except OSError:
        pass  # something else is in it: not ours to delete


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def train_run(pde, source: str, out_dir, *, model: str = "fno", model_cfg: dict | None = None, view="next_step",
              steps: int = 1000, batch_size: int = 32, lr: float = 1e-3, schedule: str = "cosine", seed: int = 0,
              data_seed: int | None = None, tests: dict[str, list[dict]] | None = None, n_test: int = 32,
              explicit: dict | None = None, label: str = "train", checkpoint_every: int = 100,
              data_cfg: dict | None = None, device: str = "cpu", mode: dict | None = None,
              seconds: float | None = None) -> dict:
    """Train ``model`` on ``source`` ("stream" or a cache path) for ``steps`` optimizer steps; evaluate.

    seed: model initialization and cache shuffling; data_seed: the stream's sample seed (default: seed).
    tests: named held-out sets (whole trajectories); default {"test": n_test trajectories of a held-out seed}
    (a resumed run rebuilds only the default). checkpoint_every: steps between checkpoints (0: only at the end).
    data_cfg: settings of the data source (a JSON-able dict), passed to ``surrogate.data.train_loader``.
    device: where the model trains ("cpu", "cuda", "cuda:1"); a stream's JAX solver runs on the GPU when JAX
    sees one, and hands its batches to torch there without a host copy.
    mode: the training mode's settings ({"name", "unroll", "coarse_n"}, see ``surrogate.modes``; None:
    one-step); a mode that unrolls trains on the view with k_out = the frames it needs. seconds: train this many
    seconds of wall clock instead of ``steps`` steps (the cosine schedule over the time; run.json records it).
    Writes run.json, checkpoint.pt, metrics.csv, model.pt and metrics.json (with the test errors) to out_dir;
    returns the summary. Under several torch.distributed ranks (``surrogate.ddp``) every rank calls this; rank 0
    writes the files, run.json records "world_size", and the run resumes only with that many ranks.
    """
    mode = make_mode(mode).settings()  # checked and normalized before anything is built
    view = training_view(make_mode(mode), datasets.make_view(view))
    settings = {"format": RUN_FORMAT, "pde": None, "source": str(source), "model": model,
                "model_cfg": dict(model_cfg or {}), "view": view.name, "view_args": dict(vars(view)),
                "steps": steps, "batch_size": batch_size, "lr": lr, "schedule": schedule, "seed": seed,
                "data_seed": seed if data_seed is None else data_seed, "n_test": n_test,
                "checkpoint_every": checkpoint_every, "data_cfg": data_cfg, "label": label, "device": device,
                "mode": mode}
    if ddp.world()[1] > 1:  # (absent: one process)
        settings["world_size"] = ddp.world()[1]
    if seconds is not None:  # (absent: a run of steps, as every run before)
        settings["seconds"] = seconds
    return _run(pde, settings, Path(out_dir), tests=tests, explicit=explicit)


def resume_run(run_dir, run: tuple[dict, dict] | None = None, steps: int | None = None,
               tests: dict[str, list[dict]] | None = None) -> tuple[dict, int]:
    """Continue the run in ``run_dir`` from its checkpoint.pt to its total steps: (summary, step resumed at).

    Everything is rebuilt from run.json; the finished run equals the uninterrupted one (bit for bit on the
    CPU) apart from timings. steps: a new total (>= the steps done) that extends the run, finished or not:
    run.json records it (and "extended": each earlier total with the step it was extended at), the schedule is
    re-planned for the new total (``checkpoint.replan_schedule``: equal to a run of that length from the start
    with the "constant" schedule), and model.pt / metrics.json are replaced when the longer run finishes.
    run: ``read_run(run_dir, steps)``'s result when the caller has it already. tests: the named held-out sets the
    run was started with (None: the default set, rebuilt from run.json). ValueError when the directory is not a
    run or the run is already complete.
    """
    run_dir = Path(run_dir)
    settings, ckpt = read_run(run_dir, steps) if run is None else run
    check_ranks(run_dir, settings, ddp.world()[1])
    from pdestream.datasets import pde_from_config  # the one door to the generator (surrogate never imports it)

    writes = ddp.world()[0] == 0
    for name in RUN_FILES:  # temp files of atomic writes cut short by the kill
        for stray in run_dir.glob(f".{name}.*.tmp") if writes else ():
            stray.unlink(missing_ok=True)
    if steps is not None and steps != settings["steps"]:
        extended = [*settings.get("extended", []), {"steps": settings["steps"], "at_step": int(ckpt["step"])}]
        settings = {**settings, "steps": steps, "extended": extended}
        if writes:
            atomic_write(run_dir / RUN_FILE, json.dumps(settings, indent=2).encode())
    return _run(pde_from_config(settings["pde"]), settings, run_dir, tests=tests, resume=ckpt), int(ckpt["step"])


def check_ranks(run_dir, settings: dict, ranks: int) -> None:
    """ValueError (one line) when the run in ``run_dir`` (its run.json ``settings``) trained on another number of
    ranks than ``ranks``: each rank's data state is its own, so a run resumes only with the same world size."""
    saved = settings.get("world_size", 1)
    if saved != ranks:
        raise ValueError(f"--resume {run_dir}: the run trained on {saved} rank(s) and this one has {ranks}; resume it "
                         f"with the same world size ({'--ddp ' + str(saved) if saved > 1 else 'without --ddp'})")


def read_run(run_dir: Path, steps: int | None = None) -> tuple[dict, dict]:
    """(run.json settings, checkpoint.pt dict) of a run to continue: an unfinished one, or any one that ``steps``
    (a new total, >= the steps it did) extends; ValueError naming what is wrong."""
    if not run_dir.is_dir():
        raise ValueError(f"--resume {run_dir}: no such run directory")
    missing = [name for name in (RUN_FILE, CHECKPOINT) if not (run_dir / name).is_file()]
    if missing:
        hint = " (killed before its first checkpoint? start it again with --overwrite)" if missing == [CHECKPOINT] else ""
        raise ValueError(f"--resume {run_dir}: not a resumable training run, no {' or '.join(missing)}{hint}")
    try:
        settings = json.loads((run_dir / RUN_FILE).read_text())
    except (OSError, ValueError) as err:
        raise ValueError(f"--resume {run_dir}: cannot read {RUN_FILE} ({err})") from None
    if not isinstance(settings, dict) or settings.get("format") != RUN_FORMAT:
        raise ValueError(f"--resume {run_dir}: {RUN_FILE} is not a pdestream run file of format {RUN_FORMAT}")
    ckpt = load_train_state(run_dir / CHECKPOINT)
    missing = [key for key in RUN_KEYS if key not in settings]
    if missing:
        raise ValueError(f"--resume {run_dir}: {RUN_FILE} is damaged: it lacks {', '.join(missing)}")
    done = ckpt.get("step")
    if steps is not None:
        if isinstance(steps, bool) or not isinstance(steps, int) or not isinstance(done, int) or steps < done:
            raise ValueError(f"--steps {steps!r} not allowed with --resume {run_dir}: the run already did {done} "
                             f"steps; allowed: an integer >= {done} (the new total)")
        if steps != settings["steps"]:
            return settings, ckpt
    if done == settings["steps"] and (run_dir / "metrics.json").is_file():
        raise ValueError(f"--resume {run_dir}: the run is already complete ({settings['steps']} of "
                         f"{settings['steps']} steps; see metrics.json); --steps N extends it to N steps")
    return settings, ckpt


def _run(pde, settings: dict, out: Path, tests: dict | None = None, explicit: dict | None = None,
         resume: dict | None = None) -> dict:
    """Build the data source and model from ``settings`` (run.json's layout), then train and evaluate. A fresh
    run (resume=None) writes run.json once everything has been checked, so a refused run leaves nothing."""
    s = settings
    check_train_settings(s["steps"], s["lr"], s["schedule"], s["checkpoint_every"])
    view = datasets.make_view(s["view"], **s["view_args"])
    mode = make_mode(s.get("mode"))  # run.json of runs before modes existed: one-step
    if s["source"] == "stream":
        check_fits(mode, view, pde)  # the mode's own words, before the stream checks the window
    device = check_device(ddp.rank_device(s.get("device", "cpu")))  # runs from before --device: the CPU;
    # several ranks on "cuda": this rank's GPU, where its reservoir lives too
    loader, data_pde = train_loader(pde, s["source"], view, s["batch_size"], seed=s["seed"], data_seed=s["data_seed"],
                                    explicit=explicit, data_cfg=s["data_cfg"], device=device)
    check_fits(mode, view, data_pde)
    view_args = dict(vars(view))  # as asked (run.json, model.pt); the view fitted to the samples is used below
    view = datasets.for_sample(view, data_pde.n_frames, len(data_pde.INPUTS))
    mode.bind(data_pde, s["seed"])
    c_in, c_out = mode.channels(data_pde, view)
    torch.manual_seed(s["seed"])  # same initial weights for every source with the same seed
    net = build_model(s["model"], data_pde.NDIM, c_in, c_out, len(data_pde.PARAMS), bc=data_pde.grid.bc,
                      **s["model_cfg"])  # the walls of the data (a cache's own, or the stream's PDE)
    if hasattr(mode, "init_model"):  # solver-in-the-loop: the correction's start (--corrector-start)
        mode.init_model(net)
    net.to(device)
    coarse = getattr(mode, "coarse_n", None)  # solver-in-the-loop: the model works on the coarse grid
    space = (coarse,) * data_pde.NDIM if coarse else tuple(data_pde.grid.shape)
    check_output(net, space)  # your own model: its output shape, before run.json is written
    writes = ddp.world()[0] == 0  # several ranks: rank 0 writes the run's files
    if resume is None:  # the data's PDE: a cache's own settings; the mode's as bound to its grid (what applies)
        s = {**s, "pde": data_pde.config(), "mode": mode.settings()}
        try:
            text = json.dumps(s, indent=2)
        except TypeError as err:
            raise ValueError(f"run settings must be JSON values (data_cfg, model_cfg): {err}") from None
    if resume is None and writes:
        out.mkdir(parents=True, exist_ok=True)
        for name in RUN_OUTPUTS:  # a fresh run in a directory (a staging one for --overwrite) leaves no stale file
            (out / name).unlink(missing_ok=True)
        atomic_write(out / RUN_FILE, text.encode())
    if resume is not None and s.get("normalization") not in (None, json.loads(json.dumps(resume["normalization"]))):
        raise ValueError(f"--resume {out}: run.json's normalization statistics differ from checkpoint.pt's; the run "
                         "would go on with other statistics than it started with")

    def record(normalizer) -> None:  # the statistics the run trains with (train, test and rollouts alike)
        if writes:
            atomic_write(out / RUN_FILE, json.dumps({**s, "normalization": normalizer.to_dict()}, indent=2).encode())

    meta = {"pde": data_pde.config(), "source": s["source"], "view": view.name, "view_args": view_args,
            "seed": s["seed"], "data_seed": s["data_seed"], "batch_size": s["batch_size"], "mode": mode.settings()}

    def finish(model, normalizer) -> dict:
        sets = tests
        if sets is None:
            with phase(f"{s['label']}: building the test set ({s['n_test']} trajectories)", total=s["n_test"],
                       solves=-(-s["n_test"] // 32)):  # test_set's batches of up to 32
                sets = {"test": test_set(data_pde, s["data_seed"], s["n_test"])}
        with phase(f"{s['label']}: test errors" + (" and rollouts" if view.rollout_k_in else "")):
            return {"test": {name: test_errors(model, normalizer, view, t, mode) for name, t in sets.items()}}

    dataset = loader.dataset
    try:
        stop = s["steps"] if s.get("seconds") is None else Stop(seconds=s["seconds"])
        summary = train(net, loader, stop, out, lr=s["lr"], schedule=s["schedule"], meta=meta,
                        label=s["label"], checkpoint_every=s["checkpoint_every"], resume=resume, finish=finish,
                        mode=mode, on_normalization=record)
        if hasattr(dataset, "report") and writes:  # a reservoir: its reuse and where it simulated (rank 0's)
            report = dataset.report()
            atomic_write(out / "reservoir.json", json.dumps(report, indent=2).encode())
            plot_reservoir_run(out / "reservoir.png", report)
        ddp.barrier()  # several ranks: all return once rank 0 has written the run (a resume may follow at once)
    finally:
        if hasattr(dataset, "close"):  # producers stop now, not at interpreter exit
            dataset.close()
    return summary
