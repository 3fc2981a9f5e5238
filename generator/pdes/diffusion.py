"""Heat equation: u_t = nu u_xx (each Fourier mode decays as exp(-nu k^2 t))."""

from dataclasses import dataclass
from typing import Any, ClassVar

from ..domains import LogUniform
from ..ics import FourierSeries
from .base import PDE, Param


@dataclass(frozen=True)
class Diffusion1D(PDE):
    """Periodic diffusion. Linear, so each step is the exact exponential: no step limit."""

    NAME: ClassVar[str] = "diffusion1d"
    EQUATION: ClassVar[str] = "u_t = nu u_xx"
    PARAMS: ClassVar[dict] = {"nu": Param("diffusivity", "length^2/time", positive=True)}

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    nu: Any = LogUniform(1e-3, 1e-2)

    def linear(self, grid, p):
        return (p["nu"] * grid.laplacian())[None]
