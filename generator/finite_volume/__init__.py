"""Finite-volume solvers for conservation laws with shocks and fronts (JAX; float32, float64 under x64;
jit/vmap-able).

Entries: ``euler1d`` (``problem.Euler1D``), 1D compressible Euler by MUSCL (minmod or MC limiter on the primitive
variables), HLLC fluxes and SSP-RK3 (``euler``); ``shallow_water2d`` (``problem2d.ShallowWater2D``), flat-bed
shallow water with wet/dry fronts by MUSCL, HLL and SSP-RK3 (``shallow_water``); ``euler2d``
(``problem2d.Euler2D``), 2D compressible Euler by euler1d's scheme dimension by dimension; ``compressible_ns1d``
(``problem.CompressibleNS1D``), euler1d plus a viscous stress (``navier_stokes``). The parts they share (ghost
cells, limiter, faces, the 2D divergence, SSP-RK3, the guarded loop) are ``scheme``'s. Checked against exact
solutions (Riemann problems, Ritter's dam break, the isentropic vortex), conservation, positivity and batch invariance:
tests/test_finite_volume.py, tests/test_finite_volume_2d.py.
"""

from .problem import CompressibleNS1D, Euler1D, FVGrid
from .problem2d import Euler2D, ShallowWater2D

__all__ = ["CompressibleNS1D", "Euler1D", "Euler2D", "FVGrid", "ShallowWater2D"]
