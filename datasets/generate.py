"""``pdestream generate`` as a library call: ``generate(GenerateConfig(pde="burgers1d", n=64, out="b.h5"))``.

The config's defaults are the CLI's (it reads them from here); this module imports nothing heavy until called,
so the parser can read them without JAX or torch.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path


@dataclass
class GenerateConfig:
    """Solve samples 0..n-1 of ``pde`` (a name, an import path or a PDE object; ``settings``: --config/--set
    values) under ``seed`` and write them to the cache ``out`` (.h5/.hdf5 or .zarr, format by suffix)."""

    pde: object = None
    n: int | None = None  # samples; None: the split's size (with ``split``)
    out: str = ""
    settings: dict = field(default_factory=dict)
    seed: int | None = None  # None: 0, or with ``split`` the split's seed (an explicit other seed is refused)
    resume: bool = False
    overwrite: bool = False
    block: int | None = None  # samples solved and written per block (None: ~32 MiB)
    on_blowup: str = "raise"  # raise | redraw | skip (skip is refused: a cache holds every index)
    executor: str = "local"  # local | dask (Zarr output only)
    scheduler: str | None = None  # dask: a running scheduler's address (None: an embedded LocalCluster)
    workers: int | None = None  # dask: worker processes of the embedded cluster (None: 2)
    solver_workers: int | None = None  # external solvers: worker processes per solving process
    solver_timeout: float | None = None  # external solvers: seconds per solve
    split: str | None = None  # a recipe's train / valid / test: its seed, and its size unless n is given


def resolve_split(cfg: GenerateConfig) -> tuple[int, int]:
    """(seed, n) of ``cfg``: its own, or with ``split`` the recipe's split seed and size (n, if given, takes the
    split's first n samples: a prefix of the full split). One line if the split, seed or n do not go together."""
    if cfg.split is None:
        if cfg.n is None:
            raise ValueError("give --n N (the number of samples), or --split train|valid|test with a recipe")
        return (0 if cfg.seed is None else cfg.seed), cfg.n
    from pdestream.recipes import split_of

    split = split_of(cfg.pde, cfg.split)
    if cfg.seed not in (None, split.seed):  # --seed 0 too: the train split's seed given with another split
        raise ValueError(f"--split {cfg.split} fixes the seed ({split.seed}); drop --seed {cfg.seed}")
    if cfg.n is not None and cfg.n > split.n:  # samples past the published set would be silently labelled as it
        raise ValueError(f"--n {cfg.n} is more than the {cfg.split} split's {split.n} samples; allowed: --n 1..{split.n}"
                         f" (for more of that seed's draws, drop --split and give --seed {split.seed} --n {cfg.n}: its "
                         f"first {split.n} are the split)")
    return split.seed, split.n if cfg.n is None else cfg.n


def configure_solvers(workers: int | None, timeout: float | None) -> None:
    """External solvers' worker processes and timeout for this process and the producers it starts (one line if
    bad; nothing imported when both are None)."""
    if workers is None and timeout is None:
        return
    from pdestream.generator.external import solver as external

    external.configure(workers, timeout)


def generate(cfg: GenerateConfig) -> str:
    """Write the cache of ``cfg``; returns the line saying what was written. A Ctrl-C is raised again as a
    KeyboardInterrupt saying what was left at ``cfg.out`` (the writer has cleaned up by then)."""
    from pdestream.settings import build_pde

    seed, n = resolve_split(cfg)
    configure_solvers(cfg.solver_workers, cfg.solver_timeout)
    pde = build_pde(cfg.pde, cfg.settings)
    cfg = replace(cfg, seed=seed, n=n)
    try:
        return _generate(pde, cfg) + recipe_note(pde)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(left_after_interrupt(cfg.out, cfg.resume)) from None


def recipe_note(pde) -> str:
    """A second line when ``pde`` is a recipe whose settings --set changed: its cache is labelled with the recipe
    (where it came from), and `inspect` says the same; '' otherwise."""
    recipe = getattr(pde, "recipe", "")
    if not recipe:
        return ""
    from pdestream.recipes import changed_note

    changed = changed_note(recipe, pde.config())
    return f"\nnote: recipe {recipe}{changed}; `pdestream inspect` says so too" if changed else ""


def _generate(pde, cfg: GenerateConfig) -> str:
    from pdestream import datasets

    kw = dict(seed=cfg.seed, resume=cfg.resume, overwrite=cfg.overwrite, block=cfg.block, on_blowup=cfg.on_blowup)
    if cfg.executor == "dask":
        from pdestream.datasets.distributed import write_cache_dask

        if cfg.scheduler and cfg.workers is not None:
            raise ValueError("--workers sizes the embedded cluster; with --scheduler the cluster has its own workers")
        done = write_cache_dask(pde, cfg.out, cfg.n, scheduler=cfg.scheduler,
                                workers=2 if cfg.workers is None else cfg.workers, **kw)  # 0 is refused there
    elif cfg.executor != "local":
        raise ValueError(f"executor={cfg.executor!r} not allowed; allowed: local, dask")
    elif cfg.scheduler or cfg.workers is not None:
        raise ValueError("--scheduler and --workers go with --executor dask")
    else:
        done = datasets.write_cache(pde, cfg.out, cfg.n, **kw)
    if cfg.resume and done.written == 0:
        return f"{cfg.out} is already complete: all {done.n_samples} samples were written; nothing to solve"
    return done.line()


def left_after_interrupt(out: str, resume: bool) -> str:
    """What an interrupted `generate` left at ``out``, in words (the writer has cleaned up by now)."""
    from pdestream.datasets.cache import is_complete, open_cache

    if not Path(out).exists():
        return "nothing was written"
    try:
        with open_cache(out) as ds:
            done, total, complete = int((ds["complete"].values == 1).sum()), ds.sizes["sample"], is_complete(ds)
    except (ValueError, OSError):
        return f"{out} is left as it was"
    if complete:  # --overwrite: the old cache, untouched (its replacement was removed)
        return f"{out} is unchanged"
    return f"{out} holds {done} of {total} samples; run the command with --resume{'' if resume else ' added'} to finish it"
