"""pdestream.generator: randomized-parameter PDE sampling with JAX pseudo-spectral ETDRK4 solvers.

JAX only (never imports torch). Public API::

    PDES                              registry {name: PDE class}
    get_pde(name, **overrides)        a configured PDE (overrides may be strings, e.g. nu="loguniform(1e-3, 1e-2)")
    sample(pde, indices, seed=0)      Trajectory with u [B, T, C, *space] float32, t [T], params {name: [B]}
    solve(pde, u0, params)            trajectory from a caller's initial condition
    enable_compilation_cache(path)    JAX's persistent compilation cache, so a new process skips compiling
"""

from .domains import Choice, Domain, Fixed, LogUniform, Uniform, parse_domain
from .ics import IC_KINDS, FourierSeries, GaussianRandomField
from .pdes import PDE, PDES, Param
from .pdes.base import make_ic
from .sampler import BlowUpError, Trajectory, draw_params, get_pde, sample, sample_keys, solve
from .spectral import Grid


def enable_compilation_cache(path, min_compile_time_s: float = 0.0) -> None:
    """Store compiled programs under ``path`` (created, private) and reuse them in later processes.

    With min_compile_time_s = 0 the small set-up programs are cached too, so a warm process compiles nothing.
    """
    import os

    import jax

    os.makedirs(path, mode=0o700, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_time_s)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def from_config(config: dict) -> PDE:
    """Rebuild a PDE from ``PDE.config()`` output (e.g. a cache's provenance)."""
    cfg = dict(config)
    name = cfg.pop("pde", None)
    return get_pde(name, cfg)


__all__ = [
    "BlowUpError", "Choice", "Domain", "Fixed", "FourierSeries", "GaussianRandomField", "Grid", "IC_KINDS",
    "LogUniform", "PDE", "PDES", "Param", "Trajectory", "Uniform", "draw_params", "enable_compilation_cache", "from_config", "get_pde",
    "make_ic", "parse_domain", "sample", "sample_keys", "solve",
]
