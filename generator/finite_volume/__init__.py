"""Finite-volume solvers for conservation laws with shocks (JAX; float32, float64 under x64; jit/vmap-able).

So far one entry: ``euler1d`` (``problem.Euler1D``), 1D compressible Euler by MUSCL (minmod or MC limiter on the
primitive variables), HLLC fluxes and SSP-RK3 (``euler``). Checked against an exact Riemann solver (Sod, Lax,
Toro's 123), conservation, positivity, a translated density wave and batch invariance: tests/test_finite_volume.py.
"""

from .problem import Euler1D, FVGrid

__all__ = ["Euler1D", "FVGrid"]
