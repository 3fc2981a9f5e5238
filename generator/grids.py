"""What every grid of a problem states: dimension, points per axis, domain size, its points and its boundaries.

``bc`` gives each axis's boundary condition, one of ``BOUNDARY_TYPES``; a cache records it (and The Well's
``bc_type`` word for it, ``BC_TYPE``), and a model builder pads non-periodic axes accordingly. The periodic
spectral grid is ``generator.spectral.Grid``; the grids of the elliptic family are ``NodeGrid`` (boundary nodes
included) and ``GhostCellGrid`` (cell centres, the boundary value held half a cell outside) here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..boundaries import BC_TYPE, BOUNDARY_TYPES, Boundary  # noqa: F401 (BC_TYPE, BOUNDARY_TYPES: re-exported)


@dataclass(frozen=True)
class GridBase:
    """``n`` points per axis on a box of side ``length`` in ``ndim`` dimensions."""

    POINTS: ClassVar[str] = ""  # what the points are, in words (a cache's space coordinates say it)

    ndim: int
    n: int
    length: float

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n,) * self.ndim

    @property
    def bc(self) -> tuple[str, ...]:
        """Per-axis boundary condition, each one of BOUNDARY_TYPES."""
        raise NotImplementedError

    @property
    def bc_type(self) -> tuple[str, ...]:
        """Per-axis boundary type in The Well's vocabulary (periodic / wall / open)."""
        return tuple(Boundary.of(b).bc_type for b in self.bc)

    def coords(self, axis: int = 0) -> np.ndarray:
        """Point positions along ``axis``, float32 [n] (length units)."""
        raise NotImplementedError

    def describe(self) -> str:
        """The grid in words, e.g. '64x64 on [0, 1)^2'."""
        raise NotImplementedError


@dataclass(frozen=True)
class NodeGrid(GridBase):
    """n x n nodes x_i = i h, h = length / (n - 1), boundary nodes included (not periodic): u = 0 held there."""

    POINTS: ClassVar[str] = "grid nodes of [0, length], boundary included"

    @property
    def spacing(self) -> float:
        return self.length / (self.n - 1)

    @property
    def bc(self) -> tuple[str, ...]:
        return (Boundary.DIRICHLET.value,) * self.ndim

    def coords(self, axis: int = 0) -> np.ndarray:
        """Node positions along ``axis``, float32 [n] (0 and length included; the same on every axis)."""
        return np.linspace(0.0, self.length, self.n).astype(np.float32)

    def describe(self) -> str:
        return f"{'x'.join(map(str, self.shape))} nodes on [0, {self.length:g}]^{self.ndim} (boundary included)"


@dataclass(frozen=True)
class GhostCellGrid(GridBase):
    """n x n cell centres x_i = (i + 1/2) h, h = length / n, of (0, length): the boundary value is held at the ghost
    centres -h/2 and length + h/2, half a cell outside each wall (PDEBench's placement for its 2D Darcy flow: first
    order in the wall's position). A solver on nodes sees it as n + 2 nodes of spacing h, ghosts included."""

    POINTS: ClassVar[str] = "cell centres of (0, length); the boundary value held at ghost centres half a cell outside"

    @property
    def spacing(self) -> float:
        return self.length / self.n

    @property
    def bc(self) -> tuple[str, ...]:
        return (Boundary.DIRICHLET.value,) * self.ndim

    def coords(self, axis: int = 0) -> np.ndarray:
        """Cell-centre positions along ``axis``, float32 [n] (the same on every axis)."""
        return ((np.arange(self.n) + 0.5) * (self.length / self.n)).astype(np.float32)

    def describe(self) -> str:
        return (f"{'x'.join(map(str, self.shape))} cell centres of (0, {self.length:g})^{self.ndim} (u = 0 at ghost "
                "centres half a cell outside)")
