"""Solvers that are not ours, as catalog entries behind the same Problem protocol.

    solver.ExternalSolver   any ``solve(params, seed)`` or command line, run in worker processes
    worker                  the worker process's entry point (``python -m pdestream.generator.external.worker``)
    exponax                 Exponax's steppers as entries (``exponax:NAME``), when exponax is installed
"""

from .solver import ExternalSolver

__all__ = ["ExternalSolver"]
