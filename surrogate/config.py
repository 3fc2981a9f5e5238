"""TrainConfig: everything ``pdestream train`` takes, with its defaults (the CLI reads them from here).

No torch here (the parser reads these defaults before anything heavy is imported); the work is
``surrogate.launch.train(cfg)``.
"""

from __future__ import annotations

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
    mode / loss / unroll / coarse_n: the interactive training mode (surrogate/mode_table.py; None: its default).
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
    k_in: int = 1
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
    reservoir: dict | None = None
    solver_workers: int | None = None
    solver_timeout: float | None = None

    def given_with_resume(self) -> list[str]:
        """The fields set besides those RESUME_ALLOWED (a resumed run takes its settings from its run.json)."""
        default = TrainConfig()
        return [f.name for f in fields(self) if f.name not in RESUME_ALLOWED
                and getattr(self, f.name) != getattr(default, f.name)]
