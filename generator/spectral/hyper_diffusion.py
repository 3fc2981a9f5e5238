"""Hyper-diffusion in 1D/2D: u_t = -nu Laplacian^2(u) (each Fourier mode decays as exp(-nu |k|^4 t))."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ..domains import LogUniform
from ..ics import FourierSeries
from .base import LinearPDE, Param


@dataclass(frozen=True)
class HyperDiffusion(LinearPDE):
    """Periodic hyper-diffusion on the unit box: a scale-selective damping (u_t = -nu u_xxxx in 1D).

    nu ~ loguniform(1e-6, 1e-5) length^4/time: by t = 1 the lowest IC mode (|k| = 2 pi) keeps 98.5%..99.8% of
    its amplitude and the top one (|m| = 5) 0.006%..38%: the small scales go, the large stay. Linear, so each
    step is the exact exponential (no step limit); the 5-mode Fourier-series IC is resolved on the default
    grids (128, 64^2).
    """

    EQUATION: ClassVar[str] = "u_t = -nu u_xxxx"
    PARAMS: ClassVar[dict] = {"nu": Param("hyper-diffusivity", "length^4/time", positive=True)}
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64}}

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    nu: Any = LogUniform(1e-6, 1e-5)

    @classmethod
    def for_dimension(cls, ndim):
        return {"EQUATION": "u_t = -nu u_xxxx" if ndim == 1 else "u_t = -nu Laplacian(Laplacian(u))"}

    def linear(self, grid, p):
        lap = grid.laplacian()
        return (-p["nu"] * (lap * lap))[None]
