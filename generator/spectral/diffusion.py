"""Heat equation in 1D/2D/3D: u_t = nu Laplacian(u) (each Fourier mode decays as exp(-nu |k|^2 t))."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ...boundaries import BOUNDARY_TYPES
from ..domains import LogUniform
from ..ics import FourierSeries
from .base import LinearPDE, Param


@dataclass(frozen=True)
class Diffusion(LinearPDE):
    """Periodic diffusion on the unit box. Linear, so each step is the exact exponential: no step limit.

    nu ~ loguniform(1e-3, 1e-2) length^2/time: by t = 1 the slowest IC mode (|k| = 2 pi) keeps 67%..96% of its
    amplitude and the fastest (|m| = 5) 0.005%..37%, so trajectories neither freeze nor vanish.
    """

    EQUATION: ClassVar[str] = "u_t = nu u_xx"
    PARAMS: ClassVar[dict] = {"nu": Param("diffusivity", "length^2/time", positive=True)}
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64}, 3: {"n": 32, "n_frames": 26}}
    BOUNDARIES: ClassVar[tuple] = BOUNDARY_TYPES  # `--set bc=...` (generator.pdes.walls)

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    nu: Any = LogUniform(1e-3, 1e-2)

    @classmethod
    def for_dimension(cls, ndim):
        return {"EQUATION": "u_t = nu u_xx" if ndim == 1 else "u_t = nu Laplacian(u)"}

    def linear(self, grid, p):
        return (p["nu"] * grid.laplacian())[None]
