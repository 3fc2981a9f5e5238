"""The pseudo-spectral family: ETDRK4 on periodic grids (walls through odd/even extensions), one file per equation.

    fourier                 grids, wavenumbers, dealiasing, ETDRK4 coefficients and steps
    base                    PDE / LinearPDE: what an equation file declares (linear and nonlinear parts, stable step)
    rollout, interactive    the compiled sampling loop; a caller's states advanced k frames and its VJP
    bounded, walls          Dirichlet / Neumann walls by extension; the walled variants of the entries
    terms, common           shared nonlinear terms and drift helpers
    advection.py ... wave.py  the equations (the catalog's named entries are generator.catalog)
"""

import importlib

__all__ = ["LinearPDE", "PDE", "Param"]


def __getattr__(name: str):
    # on first use: generator.ics imports .fourier, whose package must not import .base (which imports ics back)
    if name in __all__:
        return getattr(importlib.import_module(".base", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
