"""TrainConfig: everything ``pdestream train`` takes, with its defaults (the CLI reads them from here).

No torch here (the parser reads these defaults before anything heavy is imported); the work is
``surrogate.launch.train(cfg)``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields

TRAIN_STEPS = 1000  # optimizer steps of a new run when ``steps`` is None (None lets --resume tell if it was given)
# What may go with resume: how the run goes on (threads, ranks, external solver workers), and a new total of steps.
RESUME_ALLOWED = ("resume", "threads", "steps", "ddp", "solver_workers", "solver_timeout")


@dataclass
class TrainConfig:
    """A new run (``out``) or a resumed one (``resume``: a run directory, whose run.json gives the rest).

    pde: a catalog name, a user PDE's name or import path, or a PDE object; settings: its --config/--set values.
    source: "stream" (solved on the fly), a cache path, or a file written by `pdestream export`.
    model_cfg: the model's settings (e.g. {"width": 64}); view: "next_step" or "operator" (None: next_step, operator
    on a steady PDE); steps: optimizer steps (None: TRAIN_STEPS, or a resumed run's own); threads: torch CPU
    threads (None: all cores but one, shared by the ranks); ddp: ranks started here (None: 1, or torchrun's).
    mode / loss / unroll / coarse_n / noise / corrector_start / clip / remat / restrict: the interactive training mode
    (surrogate/mode_table.py; None: its default).
    reservoir: the training reservoir's settings (train_run's data_cfg, kind "reservoir"; None: no reservoir).
    solver_workers / solver_timeout: external solvers' worker processes and seconds per solve.
    """

    pde: object = None
    settings: dict = field(default_factory=dict)
    source: str = "stream"
    out: str | None = None
    resume: str | None = None
    overwrite: bool = False
    seed: int = 0
    test_samples: int = 32
    checkpoint_every: int = 100
    ddp: int | None = None
    model: str = "fno"
    model_cfg: dict = field(default_factory=dict)
    view: str | None = None
    k_in: int | None = None  # None: a recipe's published input frames (recipes.Recipe.input_frames), else 1
    k_out: int = 1
    steps: int | None = None
    batch_size: int = 32
    lr: float = 1e-3
    schedule: str = "cosine"
    threads: int | None = None
    device: str = "cpu"
    mode: str = "one-step"
    loss: str = "mse"
    unroll: int | None = None
    coarse_n: int | None = None
    noise: float | str | None = None
    corrector_start: str | None = None
    clip: float | str | None = None
    remat: bool = False
    restrict: str | None = None
    reservoir: dict | None = None
    solver_workers: int | None = None
    solver_timeout: float | None = None

    def ranks(self) -> int:
        """The ranks this run trains on: ``ddp``, or torchrun's WORLD_SIZE (they must agree when both are set)."""
        env = env_world()
        if self.ddp is not None:
            if isinstance(self.ddp, bool) or not isinstance(self.ddp, int) or self.ddp < 1:
                raise ValueError(f"--ddp={self.ddp} not allowed; must be an integer >= 1 (ranks)")
            if env > 1 and self.ddp != env:
                raise ValueError(f"--ddp {self.ddp} but torchrun started {env} ranks (WORLD_SIZE={env}); drop --ddp or "
                                 "make them agree")
        return env if env > 1 else (self.ddp or 1)

    def check(self) -> None:
        """The checks of a new run's own values (one line each), before any file, PDE or rank."""
        from pdestream.surrogate.checks import check_count, check_number  # (no torch)

        if self.test_samples < 1:
            raise ValueError(f"--test-samples={self.test_samples} not allowed; must be >= 1")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**31:
            raise ValueError(f"--seed={self.seed!r} not allowed; must be an integer in [0, 2**31)")  # (the sampler's)
        for name, value in (("--k-in", self.k_in), ("--k-out", self.k_out)):
            if value is not None:
                check_count(name, value)
        check_solver_options(self.solver_workers, self.solver_timeout)
        if self.threads is not None and self.threads < 1:  # (as set_threads says it, which imports torch)
            raise ValueError(f"--threads={self.threads} not allowed; must be >= 1")
        if self.steps is not None:  # (None: TRAIN_STEPS)
            check_count("steps", self.steps)
        check_count("batch_size", self.batch_size)
        check_number("lr", self.lr, 0)
        if self.checkpoint_every < 0:
            raise ValueError(f"--checkpoint-every={self.checkpoint_every} not allowed; must be >= 0 (0: only at the "
                             "end)")
        if self.ranks() > 1 and self.source != "stream":
            raise ValueError(f"--ddp goes with --source stream (with or without --reservoir); a cache ({self.source}) "
                             "is not sharded across ranks")
        if self.reservoir is not None and self.source != "stream":
            raise ValueError(f"--reservoir goes with --source stream (got --source {self.source})")
        from pdestream.surrogate.mode_table import mode_settings  # (no torch)

        mode_settings(self.mode, unroll=self.unroll, coarse_n=self.coarse_n, noise=self.noise,
                      corrector_start=self.corrector_start, clip=self.clip, remat=self.remat, restrict=self.restrict)

    def check_resume(self) -> None:
        """The checks of what may go with --resume (--threads, --ddp, --solver-*), one line each before torch (a bad
        --threads or --ddp was refused after it, 7-10 s at load 8)."""
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"--threads={self.threads} not allowed; must be >= 1")
        self.ranks()
        check_solver_options(self.solver_workers, self.solver_timeout)

    def given_with_resume(self) -> list[str]:
        """The fields set besides those RESUME_ALLOWED (a resumed run takes its settings from its run.json)."""
        default = TrainConfig()
        return [f.name for f in fields(self) if f.name not in RESUME_ALLOWED
                and getattr(self, f.name) != getattr(default, f.name)]


def check_solver_options(workers, timeout) -> None:
    """--solver-workers (an integer in [0, 256]) and --solver-timeout (seconds > 0, finite), None: not given; one
    line each, as ``generator.external.solver.configure`` says them (which train reached after torch)."""
    import math

    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or not 0 <= workers <= 256):
        raise ValueError(f"--solver-workers={workers!r} not allowed; must be an integer in [0, 256]")
    if timeout is not None and (isinstance(timeout, bool) or not isinstance(timeout, (int, float))
                                or not 0 < timeout < math.inf):
        raise ValueError(f"--solver-timeout={timeout!r} not allowed; must be a number of seconds > 0")


def env_world() -> int:
    """The world size torchrun (or surrogate.launch) gave this process through WORLD_SIZE; 1 when not set."""
    value = os.environ.get("WORLD_SIZE", "1")
    try:
        return max(1, int(value))
    except ValueError:
        raise ValueError(f"WORLD_SIZE={value!r} not allowed; must be an integer >= 1 (set by torchrun)") from None


def checkpoint_step(path) -> int | None:
    """The optimizer step a checkpoint.pt (``torch.save``'s zip of a ``train_state`` dict) was saved at, read
    without torch: its pickle unpickled with every class and tensor storage stubbed out (only the plain "step" is
    kept). None when the file is not such a zip or holds no int step (``runs.read_run`` then says why)."""
    import pickle
    import zipfile

    class _Stub(dict):  # a dict: an OrderedDict of weights is filled item by item
        def __init__(self, *args, **kwargs):
            super().__init__()

        def __call__(self, *args, **kwargs):
            return self

        def __setstate__(self, state):
            pass

    class _Plain(pickle.Unpickler):  # safe on any file: no real callable is ever resolved, so nothing in it runs
        def find_class(self, module, name):  # tensors, dtypes, OrderedDicts of weights: not needed here
            return _Stub

        def persistent_load(self, pid):  # the tensors' storages
            return None

    try:
        with zipfile.ZipFile(path) as archive:
            name = next(n for n in archive.namelist() if n.endswith("/data.pkl"))
            with archive.open(name) as f:
                state = _Plain(f).load()
    except Exception:  # not a zip of this layout, or a pickle this cannot read: read_run's own words
        return None
    step = state.get("step") if isinstance(state, dict) else None
    return step if isinstance(step, int) and not isinstance(step, bool) else None


RESUME_ADVICE = "the run cannot go on from it: start it again with --overwrite (a copy of the file from before the " \
                "damage resumes)"


def damaged_checkpoint(path, why: str, advice: str = RESUME_ADVICE) -> str:
    """The one line for a checkpoint.pt or model.pt that cannot be read (``why``: "empty", "not a torch.save file
    ...") and what to do (``advice``)."""
    return f"{path} is damaged ({why}); {advice}"


def check_checkpoint_file(path, advice: str = RESUME_ADVICE) -> None:
    """ValueError (one line, ``damaged_checkpoint``) for a checkpoint.pt or model.pt that is empty or not a zip at
    all (torch.save writes a zip; a truncated one has lost its closing directory), without torch."""
    import os
    import zipfile

    if os.path.getsize(path) == 0:
        raise ValueError(damaged_checkpoint(path, "empty", advice))
    if not zipfile.is_zipfile(path):
        raise ValueError(damaged_checkpoint(path, "not a torch.save file: truncated or overwritten", advice))


def check_resumable(run_dir, steps: int | None) -> None:
    """What run.json and metrics.json tell of ``train --resume RUN_DIR [--steps N]`` without torch, one line each
    (``runs.read_run`` says the rest once torch has read checkpoint.pt): RUN_DIR is an arm of a comparison (run.json's
    label is not "train", the label every run of ``train`` has): resumed or extended here, that comparison would
    then refuse the arm; a finished run (metrics.json's steps = run.json's: its checkpoint is at that step) given a
    smaller N, or no larger one."""
    import json
    from pathlib import Path

    run_dir = Path(run_dir)
    try:
        settings = json.loads((run_dir / "run.json").read_text())
        done = json.loads((run_dir / "metrics.json").read_text()).get("steps") \
            if (run_dir / "metrics.json").is_file() else None
    except (OSError, ValueError, AttributeError):
        return  # not a run, or a damaged one: read_run's own words
    if not isinstance(settings, dict) or not (run_dir / "checkpoint.pt").is_file():
        return
    if "format" in settings:  # (a run.json that is no run file: read_run names it first)
        check_checkpoint_file(run_dir / "checkpoint.pt")
    label = settings.get("label", "train")
    if label != "train":
        raise ValueError(f"{run_dir} is the {label} arm of the comparison in {run_dir.parent}; that comparison would "
                         "refuse the arm once resumed here: rerun its `pdestream compare` command instead (an "
                         "interrupted one goes on; longer runs: the new --steps with --overwrite, or another --out)")
    if settings.get("steps") != done or isinstance(done, bool) or not isinstance(done, int):
        # unfinished, or extended since it finished: the checkpoint holds the step (read_run judged it after torch)
        at = checkpoint_step(run_dir / "checkpoint.pt")
        if steps is not None and at is not None and steps < at:
            raise ValueError(f"--steps {steps!r} not allowed with --resume {run_dir}: the run already did {at} "
                             f"steps; allowed: an integer >= {at} (the new total)")
        check_source_unchanged(run_dir, settings)
        return
    if steps is not None and steps < done:
        raise ValueError(f"--steps {steps!r} not allowed with --resume {run_dir}: the run already did {done} steps; "
                         f"allowed: an integer >= {done} (the new total)")
    if steps is None or steps == done:
        raise ValueError(f"--resume {run_dir}: the run is already complete ({done} of {done} steps; see "
                         "metrics.json); --steps N extends it to N steps")
    check_source_unchanged(run_dir, settings)


def check_source_unchanged(run_dir, settings: dict) -> None:
    """ValueError (one line) when the cache a run trained on (run.json's "source", a path) is gone, or now holds data
    of another PDE config than the run's (run.json's "pde"; both read through the current PDE classes, so a cache
    written by an older version compares by its meaning): replaced since. It was refused after torch as "the
    checkpoint belongs to another run". Anything unreadable is left to the resume's own checks."""
    source = settings.get("source")
    if not isinstance(source, str) or source == "stream":
        return
    from pathlib import Path

    if not Path(source).exists():  # (said after torch: "no cache at ...")
        raise ValueError(f"--resume {run_dir}: its cache {source} is not there (moved or deleted, or a path relative "
                         "to the directory the run was started in); put it back, or resume from that directory")
    try:
        from pdestream.datasets import pde_from_config
        from pdestream.datasets.export import cached_config

        found = cached_config(source)
        have, now = pde_from_config(settings["pde"]).config(), pde_from_config(found).config()
    except Exception:  # no cache there, unreadable, or a config these classes cannot build: read_run's words
        return
    if have == now:
        return
    keys = [k for k in (*have, *(k for k in now if k not in have)) if have.get(k) != now.get(k)]
    said = "; ".join(f"{k}: the run's {_shown(have, k)}, the cache's {_shown(now, k)}" for k in keys[:3])
    raise ValueError(f"--resume {run_dir}: its cache {source} now holds other data ({said}"
                     f"{'; ...' if len(keys) > 3 else ''}); put back the cache it trained on to go on (or train "
                     "afresh on this one: --overwrite)")


def _shown(config: dict, key: str) -> str:
    return repr(config[key]) if key in config else "unset"
