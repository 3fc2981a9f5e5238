"""pdestream.generator: randomized-parameter PDE sampling with JAX pseudo-spectral ETDRK4 solvers.

JAX only (never imports torch). Public API::

    PDES                              the catalog {name: problem class} (generator.catalog: entries, groups)
    Problem                           what every problem offers (generator.problem); families: PDE (spectral,
                                      time-dependent), SteadyProblem (elliptic, no time axis)
    ExternalSolver                    any solver as an entry: subclass, give solve(params, seed) -> [T, C, *space]
                                      or a COMMAND (generator.external: worker processes, timeouts, causes)
    register(name, cls)               your own PDE (generator.user; also entry points `pdestream.pdes` and
                                      import paths "package.module:Class" wherever a name goes)
    get_pde(name, **overrides)        a configured PDE (overrides may be strings, e.g. nu="loguniform(1e-3, 1e-2)";
                                      bc="dirichlet" / "x=dirichlet,y=periodic" puts walls on the spectral entries
                                      that take them: generator.pdes.walls, generator.bounded)
    sample(pde, indices, seed=0)      Trajectory with u [B, T, C, *space] float32, t [T], params {name: [B]}
    solve(pde, u0, params)            trajectory from a caller's initial condition
    interactive.advance(pde, u, params, frames) / advance_vjp(...)   a caller's states [B, C, *space] advanced k frames
    NUMERICS                          revision of the numerics behind a sample's bits (recorded in caches)
    enable_compilation_cache(path)    JAX's persistent compilation cache, so a new process skips compiling
                                      (not used, with a warning, if another user owns or may write it)
"""

import dataclasses

from pdestream.recipes import RECIPES

from . import user
from .catalog import GROUP, GROUPS, PDES, get_pde, pde_class, register
from .domains import Choice, Domain, Fixed, LogUniform, Uniform, parse_domain
from .external.solver import ExternalSolver
from .grids import BC_TYPE, BOUNDARY_TYPES, NodeGrid
from .ics import IC_KINDS, FourierSeries, GaussianRandomField, GrayScottSpots, InitialCondition, make_ic
from .origin import rebuild
from .problem import Problem, ProblemBase
from .sampler import BlowUpError, Trajectory, draw_params, sample, sample_keys, solve
from .spectral import interactive
from .spectral.base import PDE, LinearPDE, Param
from .spectral.fourier import Grid
from .steady.base import SteadyProblem
from .user import unregister

# The revision of the numerics that decide a sample's bits for a given (config, seed, index): bumped by every change
# that alters them (2: ETDRK4 coefficients with one exponential per wavenumber; 3: Gray-Scott spots kept in range;
# 4: the flows' coarse pseudo-inverse by elementwise Gauss-Jordan, not LAPACK's eigh, and their pressure solve's
# sums in a fixed order: every flow's bits; 5: karman2d's cylinder a sharp body, cut faces and ghost velocities on
# the exact circle, and its forces on it; 6: a cut face's flux the velocity at its open part's centroid, projected
# consistently: karman2d's bits; 7: the sharp body's wall pressure read from the fluid only: karman2d's drag and
# lift outputs; 8: the pressure V-cycle's Jacobi sweeps in a loop and its coarse weight on the restricted residual:
# every flow's bits, rounding-level; 9: the sharp body's cut-face centroids, centroid weights and the inflow
# parabola written with no product feeding a sum, so LLVM's multiply-add contraction cannot follow the CPU's
# vector width: karman2d's and channel2d's bits, rounding-level; 10: a rollout computes the sharp bodies' geometry
# once and fills their ghost faces from a list of them, not at every face: karman2d's and sharp channel2d's bits,
# rounding-level).
# Caches record it and --resume compares it, so a cache is never finished with samples of other bits.
NUMERICS = 10

_REFUSED_CACHE_DIRS: set[str] = set()
CACHE_MAX_BYTES = 2 * 1024**3  # the compilation cache's bound (least recently used programs go first)


def enable_compilation_cache(path, min_compile_time_s: float = 0.0) -> None:
    """Store compiled programs under ``path`` (created, private) and reuse them in later processes.

    With min_compile_time_s = 0 the small set-up programs are cached too, so a warm process compiles nothing.
    """
    import os
    import warnings

    import jax

    os.makedirs(path, mode=0o700, exist_ok=True)
    unsafe = unsafe_cache_dir(path)
    if unsafe:  # programs loaded from the cache are executed: someone else able to write there could run code
        if str(path) in _REFUSED_CACHE_DIRS:
            return  # said once per process (workers call this for every block)
        _REFUSED_CACHE_DIRS.add(str(path))
        warnings.warn(f"not using the JAX compilation cache {path}: {unsafe}; programs compiled into it would be "
                      "executed (make it yours and private: chmod 700, or set PDESTREAM_JAX_CACHE elsewhere)",
                      stacklevel=2)
        return
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_time_s)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    try:  # a size bound turns on JAX's file lock around every read and write of an entry
        import filelock  # noqa: F401 (JAX imports it itself; torch installs it)
    except ImportError:
        return
    # Without the lock JAX writes an entry in place, so a spawned worker (or a second run) could read a
    # program half written by another process.
    give_entries_access_times(path)
    jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)


def give_entries_access_times(path) -> int:
    """Write the access-time file that JAX's bounded cache keeps beside each entry (``KEY-atime``: the time in
    ns, 8 bytes little-endian; the entry's mtime here) for every entry ``KEY-cache`` in ``path`` that lacks one;
    returns how many. Entries written by an unbounded cache (pdestream before the bound) or by a process killed
    between the two writes have none, and JAX's eviction scan, which reads every entry's, then fails on each
    new program ("Error writing persistent compilation cache entry ... -atime"): nothing is cached again."""
    from pathlib import Path

    added = 0
    for entry in Path(path).glob("*-cache"):
        atime = entry.with_name(entry.name[: -len("-cache")] + "-atime")
        if not atime.exists():
            try:
                atime.write_bytes(entry.stat().st_mtime_ns.to_bytes(8, "little"))
                added += 1
            except OSError:  # gone meanwhile (evicted by another process), or read-only: JAX copes or warns
                pass
    return added


def unsafe_cache_dir(path) -> str | None:
    """Why directory ``path`` is unsafe for compiled programs (owned by another user, writable by group or
    others), or None if it is private to this user (or the platform has no POSIX owners)."""
    import os
    import stat

    if not hasattr(os, "getuid"):
        return None
    st = os.stat(path)  # follows a symlink: the directory actually used is what counts
    if st.st_uid != os.getuid():
        return f"it is owned by uid {st.st_uid}, not by this user (uid {os.getuid()})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"it is writable by {'others' if st.st_mode & stat.S_IWOTH else 'its group'} (mode {stat.S_IMODE(st.st_mode):o})"
    return None


def from_config(config: dict) -> PDE:
    """Rebuild a PDE from ``PDE.config()`` output (e.g. a cache's provenance)."""
    if "origin" in config:  # a user's PDE: its class by origin, refused if its code changed since the config
        return rebuild(config)
    cfg = dict(config)
    name, recipe = cfg.pop("pde", None), cfg.pop("recipe", "")
    if recipe and recipe not in RECIPES:  # a recipe renamed since: the stored settings are complete anyway
        return dataclasses.replace(get_pde(name, cfg), recipe=recipe)
    return get_pde(recipe or name, cfg)


__all__ = [
    "BC_TYPE", "BOUNDARY_TYPES", "BlowUpError", "Choice", "Domain", "ExternalSolver", "Fixed", "FourierSeries", "GROUP", "GROUPS",
    "GaussianRandomField", "GrayScottSpots", "Grid", "IC_KINDS", "InitialCondition", "LinearPDE", "LogUniform",
    "NodeGrid", "PDE", "PDES", "Param", "Problem", "ProblemBase", "SteadyProblem", "Trajectory", "Uniform",
    "draw_params", "enable_compilation_cache", "from_config", "get_pde", "pde_class", "register", "unregister", "user",
    "interactive", "make_ic", "parse_domain", "sample", "sample_keys", "solve",
]
