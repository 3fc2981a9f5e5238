"""Korteweg-de Vries: u_t + alpha u u_x + beta u_xxx = 0."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from pdestream.generator.lazy_jax import jnp

from ..domains import LogUniform, Uniform
from ..ics import FourierSeries
from .base import PDE, Param
from .common import CFL, conservative_quadratic


@dataclass(frozen=True)
class KdV1D(PDE):
    """Periodic KdV with a named nonlinear coefficient alpha and dispersion coefficient beta.

    With alpha = 6, beta = 1 the soliton is u = (c/2) sech^2(sqrt(c)/2 (x - c t)); in general
    u = (3c/alpha) sech^2(sqrt(c/beta)/2 (x - c t)). Dispersion (i beta k^3) is integrated exactly;
    the step is limited by the nonlinear CFL, dt <= CFL dx / (alpha_max * bound(u0)).
    Amplitudes of a KdV solution can exceed max|u0| (solitons grow out of smooth data), hence a factor 2.
    """

    NAME: ClassVar[str] = "kdv1d"
    EQUATION: ClassVar[str] = "u_t + alpha u u_x + beta u_xxx = 0"
    PARAMS: ClassVar[dict] = {
        "alpha": Param("nonlinear (steepening) coefficient", "length/time/u"),
        "beta": Param("dispersion coefficient", "length^3/time", positive=True),
    }

    n: int = 128
    length: float = 20.0
    t_end: float = 5.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=3, decay=1.0, amplitude=1.0)
    alpha: Any = Uniform(1.0, 3.0)
    beta: Any = LogUniform(0.5, 2.0)

    def linear(self, grid, p):
        (k,) = grid.wavenumbers()
        return (1j * p["beta"] * k**3)[None].astype(jnp.complex64)

    def nonlinear(self, grid, p):
        return conservative_quadratic(grid, -0.5 * p["alpha"])

    def stable_dt(self):
        speed = 2.0 * self.param_upper("alpha") * self.ic.bound(self.grid)
        return CFL * self.grid.dx / max(speed, 1e-12)
