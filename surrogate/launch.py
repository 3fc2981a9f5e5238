"""``pdestream train`` as a library call: ``train(TrainConfig(pde="burgers1d", out="run"))``.

A new run (its checks, torch's threads, ``--overwrite`` built beside the old run and swapped in when it has
value), a resumed one, and ``ddp=N``: N spawned ranks meeting through a file. An interrupt is raised again as a
KeyboardInterrupt saying what was kept. The runs themselves are ``surrogate.runs``'.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from pathlib import Path

from pdestream.interrupts import USER_ERRORS, check_not_in_zarr, check_writable_dir, remove_created, snapshot

from .config import TRAIN_STEPS, TrainConfig, check_resumable

RUN_MARKERS = ("run.json", "checkpoint.pt", "model.pt", "metrics.json")  # any of them: the directory holds a run


def train(cfg: TrainConfig, log=print) -> dict | None:
    """Train (or resume) the run of ``cfg``; ``log`` gets the report lines. Returns the run's summary (None on a
    rank other than 0, and from the ``ddp`` launcher, whose ranks report). ValueError and friends: one line."""
    if cfg.resume is None and cfg.out is None:  # before anything heavy is imported
        raise ValueError("give --out RUN_DIR for a new run (or --resume RUN_DIR to continue one)")
    if cfg.resume is None:
        check_writable_dir(cfg.out)
        check_not_in_zarr(cfg.out)
        check_out_free(cfg.out, cfg.overwrite)
    elif Path(cfg.resume).is_dir():
        check_writable_dir(cfg.resume, "--resume")
        check_resumable(cfg.resume, cfg.steps)  # what run.json and metrics.json say, before torch
    else:  # (said by runs.read_run after torch before adv51)
        raise ValueError(f"--resume {cfg.resume}: no such run directory")
    config = source_config(cfg.source) if cfg.resume is None else None  # (one line for a cache it cannot train on)
    if config is not None and cfg.pde is None and isinstance(config.get("pde"), str):
        from dataclasses import replace

        cfg = replace(cfg, pde=config["pde"])  # `train --source PATH`: the PDE its cache (or export) holds
    if cfg.resume is None and isinstance(cfg.pde, str):
        from pdestream.settings import build_pde

        pde = build_pde(cfg.pde, cfg.settings)  # the name and --set checked before torch (and JAX) are imported
        check_new_data(pde, cfg, config)
    from pdestream.datasets.generate import configure_solvers
    from pdestream.surrogate import ddp

    configure_solvers(cfg.solver_workers, cfg.solver_timeout)  # (environment: spawned ranks inherit it)
    ranks = cfg.ranks()
    # one process trains a run at a time: two `train --resume RUN` at once both ran and both wrote the run (the ranks
    # of a ddp launch or torchrun are one training, their launcher holds it)
    with holding_run(cfg.resume if cfg.resume is not None and ddp.env_world() == 1 else None):
        if ranks > 1 and ddp.env_world() == 1:  # ddp=N: check here, then start the N ranks
            return launch_ranks(cfg, ranks)
        try:
            return _resume(cfg, ranks, log) if cfg.resume is not None else _new(cfg, ranks, log)
        finally:
            ddp.finish()


def source_config(source) -> dict | None:
    """The PDE config (``PDE.config()``) of a new run's ``--source`` cache or export, read without torch or JAX;
    None for the stream (or a source the reader opens all the same: it is left to the loader). One line, the
    reader's own, for a path that is not there, not a pdestream cache or export, damaged, or an interrupted
    generate's (each was said only once torch was imported, 2-5 s; a damaged cache with no PDE named read "no PDE
    named")."""
    if source in (None, "stream"):
        return None
    if not str(source).strip():  # (Path("") is ".": it read "cache path '.' must end in .h5 ...")
        raise ValueError("--source '' is empty; allowed: stream, or a cache's path (.h5, .hdf5, .zarr) or an export's")
    if not Path(source).exists():
        raise FileNotFoundError(f"--source {source}: no such cache (or use --source stream)")
    from pdestream.datasets.export import cache_written, cached_config

    config = cached_config(source)
    if config is None:  # the reader's words for why (xarray and h5py, no torch)
        from pdestream.datasets.cache import open_cache
        from pdestream.datasets.export import as_cache

        open_cache(as_cache(source)).close()
        return None
    if not isinstance(config.get("pde"), str) or not config["pde"]:  # (it read "no PDE named", or "holds 5 samples")
        raise ValueError(f"{source} is damaged: its stored config (pdestream_config) names no PDE "
                         f"({config.get('pde')!r})")
    from pdestream.catalog_names import check_name

    try:
        check_name(config["pde"])
    except ValueError as err:  # (it said "unknown PDE ..." without naming the cache)
        raise ValueError(f"{source} holds samples of {config['pde']!r}, a PDE not known here: {err}") from None
    written = cache_written(source)
    if written is not None:
        raise ValueError(f"{source} is incomplete ({written[0]} of {written[1]} samples written); finish it with "
                         "`pdestream generate ... --resume` (train reads complete caches)")
    return config


def check_new_data(pde, cfg: TrainConfig, config: dict | None = None) -> None:
    """What a new run's data allows, one line each before torch (each was refused only once the cache was open or
    the corrector built, after torch): a ``--source`` cache's stored ``config`` (``source_config``; None: the
    stream) against ``pde`` and the --set given; solver-in-the-loop's coarse grid and an explicit ``--restrict``
    against the fine grid (the stream's ``pde`` or the cache's); the mode's next-step window against its frames
    (the cache's was refused by the view after torch, naming k_out). A steady entry is refused for the mode itself
    (``check_new``)."""
    from .checks import check_cache_matches
    from .mode_table import check_coarse_grid, check_restrict_acts, check_window, frames_ahead, mode_settings

    check_view_options(pde, cfg)
    fine = pde
    if config is not None:
        from pdestream.datasets import pde_from_config

        check_cache_matches(cfg.source, config, pde, cfg.settings)
        try:
            fine = pde_from_config(config)
        except ValueError as err:  # (it named a setting the user never gave: "burgers1d: bad value for n")
            raise ValueError(f"{cfg.source}: its stored config does not build here: {err}") from None
    if cfg.mode == "solver-in-the-loop" and not pde.STEADY:
        check_coarse_grid(fine, mode_settings(cfg.mode, coarse_n=cfg.coarse_n)["coarse_n"])
        check_restrict_acts(fine, cfg.restrict)
    if not fine.STEADY and (cfg.view or "next_step") == "next_step":  # the mode's window against the frames
        unroll = mode_settings(cfg.mode, unroll=cfg.unroll).get("unroll", 1)  # (one-step, noise: 1)
        k_out = 1 if cfg.k_out is None else cfg.k_out
        check_window(cfg.mode, unroll, 1 if cfg.k_in is None else cfg.k_in, frames_ahead(cfg.mode, unroll, k_out),
                     fine.n_frames, "--set n_frames={n}" if config is None else "a cache of {n} frames")


@contextlib.contextmanager
def holding_run(run_dir):
    """An exclusive lock on the directory RUN_DIR (flock: the kernel drops it when the process ends, kill -9 too; no
    file is written) while a run is resumed; a second process resuming it meanwhile is refused in one line.
    None: nothing to hold."""
    import fcntl

    try:
        fd = None if run_dir is None else os.open(run_dir, os.O_RDONLY)
    except OSError:  # not there, or not a directory: the resume's own checks say so
        fd = None
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise ValueError(f"{run_dir} is being trained by another process right now (a --resume of it is "
                                 "running); wait for it to end or stop it, then resume") from None
        yield
    finally:
        if fd is not None:
            os.close(fd)


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_threads(source: str, ranks: int = 1) -> int:
    """torch CPU threads for `train` without --threads: the cores this process may use minus one (at least 1).
    On the stream the solver thread needs that core (torch's threads fighting it ran 6x slower on 2 cores). On a
    cache the loader, the OS and other programs do: torch's spinning OpenMP threads on both cores of a busy
    2-core machine trained 17-30x slower than one thread (50 FNO steps of the README's command: 72.4 s vs 4.2 s,
    41.9 s vs 1.5 s), same losses. ``source`` ("stream" or a cache path) is kept for callers; both get this.
    ranks: processes training on this machine (--ddp N), which share its cores."""
    cores = usable_cores()
    return max(1, cores // ranks - 1)


def set_threads(threads: int | None) -> None:
    """torch's CPU threads (None: left as they are); one line for a count < 1."""
    import torch

    if threads is not None:
        if threads < 1:
            raise ValueError(f"--threads={threads} not allowed; must be >= 1")
        torch.set_num_threads(threads)


def make_view(name: str, k_in: int = 1, k_out: int = 1):
    """The training view ``name``: next_step takes k_in input frames and k_out predicted ones, operator neither."""
    from pdestream import datasets

    return datasets.make_view(name, k_in=k_in, k_out=k_out) if name == "next_step" else datasets.make_view(name)


def input_frames(pde, cfg: TrainConfig, log=print) -> int:
    """next_step's input frames: ``cfg.k_in``, or for a recipe (``pde.recipe``) its published input frames when its
    trajectories hold them and a frame to predict (said in a line), else 1."""
    if cfg.k_in is not None:
        return cfg.k_in
    from pdestream.recipes import RECIPES

    recipe = RECIPES.get(getattr(pde, "recipe", ""))
    k = recipe.input_frames if recipe is not None else None
    if not k or pde.STEADY or (cfg.view or "next_step") != "next_step" or pde.n_frames < k + cfg.k_out:
        return 1
    log(f"--k-in {k}: recipe {recipe.name}'s published input frames (give --k-in to choose)")
    return k


def mode_settings(cfg: TrainConfig) -> dict:
    """The mode's settings for train_run: the mode table's defaults, one line for an option the mode does not
    take (surrogate.mode_table.mode_settings); k_out is checked with the view (surrogate.modes)."""
    from pdestream.surrogate import mode_table

    settings = mode_table.mode_settings(cfg.mode, unroll=cfg.unroll, coarse_n=cfg.coarse_n, noise=cfg.noise,
                                        corrector_start=cfg.corrector_start, clip=cfg.clip, remat=cfg.remat,
                                        restrict=cfg.restrict)
    return settings if cfg.loss == "mse" else {**settings, "loss": cfg.loss}


def check_view_options(pde, cfg: TrainConfig) -> None:
    """What the view allows, one line each (no torch: ``check_new_data`` says it before torch, ``check_new`` again
    for a PDE object): a mode other than one-step, or the next-step view, on a steady entry (the modes' own refusal
    would send the user to --view next_step); --k-in / --k-out on the operator view, which takes none (they ran,
    rc 0, unread)."""
    if pde.STEADY and cfg.mode != "one-step":
        verb = "perturbs input frames" if cfg.mode == "noise" else "unrolls over frames"
        raise ValueError(f"--mode {cfg.mode} {verb} and {pde.NAME} is steady (no frames); allowed: "
                         "--mode one-step")
    from .mode_table import check_mode_k_in

    check_mode_k_in(cfg.mode, cfg.k_in)  # (said after torch)
    if pde.STEADY and cfg.view == "next_step":  # (the view refused it after torch)
        raise ValueError(f"--view next_step needs a time axis and {pde.NAME} is steady (no frames); allowed: "
                         "--view operator")
    view = cfg.view or ("operator" if pde.STEADY else "next_step")
    given = [f"{o} {v}" for o, v, unset in (("--k-in", cfg.k_in, None), ("--k-out", cfg.k_out, 1))
             if v not in (None, unset)]
    if view != "next_step" and given:
        why = (f"{pde.NAME} is steady: its samples (input field -> solution) have no frames" if pde.STEADY else
               f"not {view} (u(t=0) -> u(t_end))")
        raise ValueError(f"{' and '.join(given)} {'goes' if len(given) == 1 else 'go'} with --view next_step"
                         f"{'; ' if pde.STEADY else ', '}{why}")


def check_out_free(out, overwrite: bool) -> list[str]:
    """The run files ``out`` holds (RUN_MARKERS); FileExistsError (one line) when it holds any and ``overwrite`` is
    not given. No torch: ``train`` checks it first (it was said after torch was imported), ``check_new`` again."""
    held = [name for name in RUN_MARKERS if (Path(out) / name).exists()]
    if held and not overwrite:
        raise FileExistsError(f"{out} already holds a run ({', '.join(held)}); pass --resume {out} to "
                              "continue it, --overwrite to replace it, or choose another --out")
    return held


def check_new(cfg: TrainConfig, ranks: int):
    """(pde, held run files) of a new run, after its checks (ValueError: one line)."""
    from pdestream.settings import build_pde

    if cfg.out is None:
        raise ValueError("give --out RUN_DIR for a new run (or --resume RUN_DIR to continue one)")
    held = check_out_free(cfg.out, cfg.overwrite)
    if cfg.source != "stream" and not Path(cfg.source).exists():
        raise FileNotFoundError(f"--source {cfg.source}: no such cache (or use --source stream)")
    pde = build_pde(cfg.pde, cfg.settings)
    check_view_options(pde, cfg)
    cfg.check()
    return pde, held


def _new(cfg: TrainConfig, ranks: int, log) -> dict | None:
    from pdestream.surrogate import ddp, runs

    pde, held = check_new(cfg, ranks)
    set_threads(default_threads(cfg.source, ranks) if cfg.threads is None else cfg.threads)
    ddp.init_from_env(cfg.device)  # several ranks: every rank has passed the checks once all have joined
    out = Path(cfg.out)
    kw = dict(model=cfg.model, model_cfg=dict(cfg.model_cfg),
              view=make_view(cfg.view or ("operator" if pde.STEADY else "next_step"), input_frames(pde, cfg, log),
                             cfg.k_out),
              steps=TRAIN_STEPS if cfg.steps is None else cfg.steps, batch_size=cfg.batch_size, lr=cfg.lr,
              schedule=cfg.schedule, seed=cfg.seed, n_test=cfg.test_samples, explicit=dict(cfg.settings),
              checkpoint_every=cfg.checkpoint_every, data_cfg=cfg.reservoir, device=cfg.device,
              mode=mode_settings(cfg))
    if ddp.world()[0] > 0:  # another rank than 0: trains, writes nothing, leaves the files and their clean-up to 0
        runs.train_run(pde, cfg.source, out, **kw)
        return None
    # overwrite over a run: the new run is built beside it and moves in only when it finishes (or is interrupted
    # with a checkpoint, which is then worth resuming); a refusal, a divergence or an early Ctrl-C leave the old one
    target = runs.staging_dir(out) if held else out
    before = snapshot(target)
    try:
        s = runs.train_run(pde, cfg.source, target, **kw)
    except KeyboardInterrupt:
        if target != out:
            raise KeyboardInterrupt(_overwrite_left(target, out)) from None
        raise KeyboardInterrupt(_train_left(out, before)) from None
    except BaseException:  # refused or failed: the old run stays as it was, and a new one without a checkpoint goes
        if target != out:
            runs.remove_staging(target)
        else:
            _train_left(out, before)
        raise
    if target != out:
        runs.replace_run(target, out)
    log(run_report(s, cfg.model, cfg.source, cfg.test_samples, cfg.out))
    return s


def _overwrite_left(staging: Path, out: Path) -> str:
    """What an interrupted `train --overwrite` leaves, in words: the new run in place of the old one if it has a
    checkpoint to resume from, else the old run untouched (and the new one's files removed)."""
    from pdestream.surrogate.runs import CHECKPOINT, remove_staging, replace_run

    if (staging / CHECKPOINT).is_file():
        replace_run(staging, out)
        return f"{out} now holds the new run's checkpoint; pdestream train --resume {out} continues from it"
    remove_staging(staging)
    return f"nothing of the new run was kept (no checkpoint yet); {out} still holds the earlier run, untouched"


def _train_left(out: Path, before) -> str:
    """What an interrupted fresh `train` leaves, in words. With a checkpoint the run stays for --resume. Without
    one nothing of the training is saved, so what the command created (run.json, the directory) is removed
    rather than kept for a resume from step 0: the same command then starts again, with no --overwrite."""
    if (out / "metrics.json").is_file():  # finished before the interrupt (or an old finished run, untouched)
        return f"{out} holds a finished run"
    if (out / "checkpoint.pt").is_file():
        return f"{out} holds a checkpoint; pdestream train --resume {out} continues from it"
    remove_created(out, before)
    return "nothing was kept (no checkpoint yet); run the command again to start over"


def check_resume(cfg: TrainConfig, ranks: int) -> tuple[dict, dict]:
    """read_run's (settings, checkpoint) of a resumed run, after its checks (ValueError: one line)."""
    from pdestream.surrogate.runs import RUN_FILE, check_ranks, read_run

    given = cfg.given_with_resume()
    if given:
        raise ValueError(f"resume takes the run's settings from {Path(cfg.resume) / RUN_FILE}; drop "
                         f"{', '.join(given)} (only threads, steps and ddp may go with it)")
    run = read_run(Path(cfg.resume), cfg.steps)  # refuse a non-run or a finished run before anything else
    check_ranks(cfg.resume, run[0], ranks)
    return run


def _resume(cfg: TrainConfig, ranks: int, log) -> dict | None:
    """A resumed run: everything from RUN_DIR/run.json; other settings are refused (one line)."""
    from pdestream.surrogate import ddp
    from pdestream.surrogate.runs import resume_run

    run = check_resume(cfg, ranks)
    settings = run[0]
    set_threads(default_threads(settings["source"], ranks) if cfg.threads is None else cfg.threads)
    steps = settings["steps"] if cfg.steps is None else cfg.steps
    ddp.init_from_env(settings.get("device", "cpu"))
    ddp.barrier()  # every rank has read run.json before rank 0 may rewrite it (an extension)
    writes = ddp.world()[0] == 0
    if steps != settings["steps"] and writes:
        log(replan_line(cfg.resume, settings["steps"], steps, run[1]["step"], settings.get("schedule", "cosine")))
    s, step = resume_run(cfg.resume, run, steps)
    if not writes:
        return None
    log(f"resumed {cfg.resume} at step {step} of {steps}")
    log(run_report(s, settings["model"], settings["source"], settings["n_test"], cfg.resume))
    return s


def replan_line(run_dir, planned: int, steps: int, at: int, schedule: str = "cosine") -> str:
    """The line a resume with a new total says: a run of ``planned`` steps, at step ``at``, now ``steps`` (fewer
    than planned: an unfinished run cut short, which it called "extending")."""
    verb = "extending" if steps > planned else "shortening"
    return (f"{verb} {run_dir} from {planned} to {steps} steps at its step {at}; the {schedule} schedule is re-planned "
            f"for {steps} steps")


def check_rank_count(ranks: int, device: str) -> None:
    """ddp=N started here: at most one rank per CPU core (64 ranks on 2 cores were started), or per GPU with a
    cuda device (refused in one line where torch sees none, before any rank starts)."""
    import torch

    if str(device).startswith("cuda"):
        gpus = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if gpus == 0:
            raise ValueError(f"--ddp {ranks} --device {device}: torch sees no GPU here (a CPU-only torch build or no "
                             "driver); use --device cpu")
        if ranks > gpus:
            raise ValueError(f"--ddp {ranks} not allowed with --device {device}: torch sees {gpus} GPU(s), one per rank")
        return
    cores = usable_cores()
    if ranks > cores:
        raise ValueError(f"--ddp {ranks} not allowed on the CPU here: {cores} core(s), at most one rank per core "
                         "(torchrun across machines for more)")


def launch_ranks(cfg: TrainConfig, ranks: int) -> None:
    """ddp=N: the checks here (one line, before anything starts), then N spawned ranks that meet through a file;
    rank 0's output is shown, and the first failure's one line is raised here after the others are stopped. A
    reservoir with producer dask and no scheduler gets one embedded cluster here that every rank submits to."""
    import contextlib
    import multiprocessing as mp
    import tempfile
    from multiprocessing.connection import wait

    held, before = [], None
    if cfg.resume is not None:
        data_cfg = check_resume(cfg, ranks)[0]["data_cfg"] or {}
    else:
        held = check_new(cfg, ranks)[1]
        before = None if held else snapshot(cfg.out)
        data_cfg = cfg.reservoir or {}
    check_rank_count(ranks, cfg.device)  # (after the run's own checks: a resume names its world size first)
    with tempfile.TemporaryDirectory(prefix="pdestream-ddp-") as tmp, contextlib.ExitStack() as stack:
        env = {}
        if data_cfg.get("producer") == "dask" and not data_cfg.get("scheduler"):
            # one pool for every rank: a cluster of `workers` processes here, which all ranks' reservoirs submit to
            from pdestream.datasets.distributed import dask_client
            from pdestream.datasets.ranks import SHARED_SCHEDULER

            env[SHARED_SCHEDULER] = stack.enter_context(dask_client(None, data_cfg.get("workers", 1))).scheduler.address
        ctx = mp.get_context("spawn")  # JAX is not fork-safe
        procs = [ctx.Process(target=train_rank, args=(r, ranks, cfg, tmp, env), daemon=False) for r in range(ranks)]
        for proc in procs:
            proc.start()
        interrupted = False
        try:
            while any(p.exitcode is None for p in procs) and all(p.exitcode in (None, 0) for p in procs):
                wait([p.sentinel for p in procs if p.exitcode is None], timeout=1.0)
        except KeyboardInterrupt:  # the terminal's Ctrl-C reached the ranks too: they leave as one process would
            interrupted = True
        for proc in procs:  # a failed rank leaves the others waiting in a collective: stop them
            proc.join(120 if interrupted else 0.5)
            if proc.exitcode is None:
                proc.terminate()
                proc.join()
        failed = [r for r, p in enumerate(procs) if p.exitcode != 0]
        if not failed and not interrupted:
            return None
        if interrupted or any(procs[r].exitcode == 130 for r in failed):
            raise KeyboardInterrupt(_ranks_left(Path(tmp), cfg, held, before))
        said = [(Path(tmp) / f"rank{r}.err") for r in range(ranks)]
        said = [f.read_text() for f in said if f.is_file()]
        if said:
            raise ValueError(said[0])
        log = Path(tmp) / f"rank{failed[0]}.log"
        tail = log.read_text().strip().splitlines()[-1:] if log.is_file() else []
        raise RuntimeError(f"rank {failed[0]} of {ranks} failed (exit code {procs[failed[0]].exitcode})"
                           + (f": {tail[0]}" if tail else ""))


def _ranks_left(tmp: Path, cfg: TrainConfig, held: list, before) -> str:
    """What interrupted ranks left, in words: rank 0's own account (it writes every file) or, where rank 0 could
    not give one (its interrupt arrived as a collective's failure, or it was stopped), the launcher's from the disk,
    with rank 0's clean-up done here: a new run without a checkpoint is removed, as one process would."""
    said = tmp / "rank0.err"
    if said.is_file() and said.read_text():
        return said.read_text()
    if cfg.resume is not None:
        return ""  # a resumed run keeps its last checkpoint, as after a one-process interrupt
    from pdestream.surrogate.runs import staging_dir

    out = Path(cfg.out)
    return _overwrite_left(staging_dir(out), out) if held else _train_left(out, before)


def train_rank(rank: int, ranks: int, cfg: TrainConfig, tmp: str, env: dict) -> None:
    """One rank of ddp=N (a spawned process): the environment torchrun would give it (and ``env``: the shared
    Dask cluster's address), then ``train``. Its user error goes to TMP/rank{rank}.err for the launcher to show
    once; ranks other than 0 print nothing."""
    from pdestream.surrogate.ddp import INIT_ENV

    os.environ.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(ranks), LOCAL_WORLD_SIZE=str(ranks),
                      **{INIT_ENV: f"file://{tmp}/rendezvous"}, **env)
    if rank > 0:  # their output would repeat rank 0's; a crash's traceback is kept for the launcher
        sys.stdout = open(os.devnull, "w")
        sys.stderr = open(Path(tmp) / f"rank{rank}.log", "w", buffering=1)
    seen = []

    def interrupt(signum, frame):
        seen.append(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    try:
        train(cfg)
    except USER_ERRORS as err:
        (Path(tmp) / f"rank{rank}.err").write_text(str(err))
        sys.exit(2)
    except KeyboardInterrupt as err:
        (Path(tmp) / f"rank{rank}.err").write_text(str(err))
        sys.exit(130)
    except Exception:
        if not seen:
            raise
        # the Ctrl-C reached a peer first, and this rank's collective failed before its own interrupt was
        # raised: an interrupt all the same (no traceback), which the launcher describes from the disk
        sys.exit(130)


def run_report(s: dict, model: str, source: str, n_test: int, out) -> str:
    """The lines that say what a run did: steps, time and its waiting share, test errors, the reservoir's counts."""
    mode = s.get("mode") or {"name": "one-step"}
    shown = {k: v for k, v in mode.items() if k not in ("name", "rule")}  # (unroll, coarse_n, noise, loss when not mse)
    how = f" ({', '.join(f'{k} {v}' for k, v in shown.items())})" if shown else ""
    if mode["name"] != "one-step":
        how = f" --mode {mode['name']}{how}"
    on = f" on {s['ranks']} ranks" if s.get("ranks") else ""  # (each rank its own data; the counts are all ranks')
    lines = [f"trained {model}{how} on {source}{on} for {s['steps']} steps in {s['wall']:.1f} s "
             f"(waiting for data {s['t_data']:.1f} s = {100 * s['data_share']:.1f}% of the loop, normalization draw "
             f"included; computing {s['t_compute']:.1f} s); "
             f"{s['trajectories_seen']} trajectories, final loss {s['final_loss']:.4g}"]
    t = s["test"]["test"]
    if mode["name"] == "solver-in-the-loop":  # the corrected coarse solver against the fine solution restricted
        lines.append(f"(errors on the coarse grid n={mode['coarse_n']}, against the fine solution "
                     f"{restriction_words(mode, s.get('pde'))})")
    lines.append(f"test ({n_test} held-out trajectories): rel L2 {t['rel_l2']:.4f}, nRMSE {t['nrmse']:.4f}"
                 + (f", rollout rel L2 at the last frame {t['rollout_final']:.4f}" if "rollout_final" in t else ""))
    reservoir = "data_stats" in s and "reuse_mean" in s["data_stats"]
    if reservoir:
        d = s["data_stats"]
        who = f"rank 0's reservoir (of {s['ranks']} ranks)" if s.get("ranks") else "reservoir"
        lines.append(f"{who}: {d['inserted']} trajectories solved, {d['evicted']} evicted, reuse mean "
                     f"{d['reuse_mean']:.2f} (max {d['reuse_max']:.2f}); waiting for solves {100 * d['wait_share']:.1f}% "
                     "of the time since the first batch (the reservoir's own clock: the loop's waiting share above "
                     "also counts the normalization draw and handing batches over)" + _pacing(d))
    extra = ", reservoir.json, reservoir.png" if reservoir else ""
    lines.append(f"run: {out}/metrics.csv, metrics.json, model.pt, checkpoint.pt{extra}")
    return "\n".join(lines)


def restriction_words(mode: dict, config: dict | None) -> str:
    """How the corrector restricted the fine solution (``surrogate.modes.subsample``), in words: by ``mode``'s
    "restrict" on periodic axes (absent: points, as make_mode reads it), by the mean of the two fine points around
    each coarse cell centre across walls, by cell / face means on a staggered grid (the run's PDE ``config``; it
    said "subsampled" on a grid with walls, whose run records no "restrict")."""
    periodic = "Fourier-truncated" if mode.get("restrict") == "fourier" else "subsampled"  # (absent: points)
    try:
        from pdestream.boundaries import kinds
        from pdestream.datasets import pde_from_config

        pde = pde_from_config(config)
        walls = [not b.periodic for b in kinds(tuple(pde.grid.bc))]
        staggered = bool(getattr(pde, "FIELD_LOCATIONS", {}))
    except Exception:  # no config (a summary of old), or one this cannot build: the setting's own words
        return periodic
    if staggered:
        return "restricted by cell / face means (a staggered grid)"
    if all(walls):
        return "averaged to the coarse cell centres"
    if any(walls):
        return f"{periodic} on its periodic axes, averaged to the coarse cell centres across its walls"
    return periodic


def _pacing(d: dict) -> str:
    """The summary's words on the reservoir's pacing (datasets/reservoir_pacer.py), "" for stats without it."""
    r = d.get("target_reuse")
    if r is None:
        return ""
    idle = d.get("producer_idle_share")
    said = "; producer paced at reuse target " + (f"{r:.2f}" if r == r else "off (flat out)")
    return said + (f", idle {100 * idle:.0f}% of its time" if idle is not None else "")
