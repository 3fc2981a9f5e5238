"""The steady (elliptic) family: one solve per sample, no time axis, a random input field in and a field out.

A sample is (inputs [C_in, *space], u [C, *space]) on a ``NodeGrid`` (boundary nodes included). A steady
problem has no time settings (t_end, n_frames, dt are not its settings); as a ``generator.problem.Problem``
it has one frame per sample (``n_frames`` = 1) and no frame times. A subclass supplies ``run_keys`` (its
solves, through ``generator.chunked`` so that a sample's bits do not depend on its batch), ``failure``,
``describe_solver`` and, as a hook, ``check_settings`` for its solver settings.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..grids import NodeGrid
from ..problem import ProblemBase


@dataclass(frozen=True)
class SteadyProblem(ProblemBase):
    """Base of the steady problems: n nodes per side on [0, length]^NDIM, boundary included."""

    STEADY: ClassVar[bool] = True
    MIN_NODES: ClassVar[int] = 5  # an interior of at least 3 x 3 nodes

    n: int = 64
    length: float = 1.0

    @property
    def grid(self) -> NodeGrid:
        return NodeGrid(self.NDIM, self.n, self.length)

    @property
    def n_frames(self) -> int:
        """Frames per sample: one, the solution (no time axis)."""
        return 1

    def times(self) -> np.ndarray:
        return np.zeros(0, np.float32)  # steady: no time axis

    def validate(self) -> None:
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < self.MIN_NODES:
            raise ValueError(f"{self.NAME}: n={self.n!r} not allowed: nodes per side (boundary included) must be an "
                             f"integer >= {self.MIN_NODES}")
        self._check_length()
        self.check_settings()
        self._check_size()
        self._check_ic_on_grid()

    @abc.abstractmethod
    def describe_solver(self) -> str:
        """How a sample is solved, in words (describe()'s 'steady:' part)."""

    def describe_setup(self) -> str:
        return (f"  fields: {', '.join(self.INPUTS)} (input) -> {', '.join(self.FIELDS)}   grid: {self.grid.describe()}"
                f"   steady: {self.describe_solver()}")
