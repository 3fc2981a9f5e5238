"""The steady (elliptic) family: one solve per sample, no time axis (Poisson / Helmholtz with walls, Darcy flow).

    base.SteadyProblem      what a steady entry offers beside the Problem protocol
    elliptic                the iterative solvers (CG / multigrid on a node grid)
    poisson, darcy2d        the entries
"""

from .base import SteadyProblem

__all__ = ["SteadyProblem"]
