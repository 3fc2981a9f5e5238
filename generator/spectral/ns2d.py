"""Incompressible Navier-Stokes in vorticity form on the periodic square, decaying or Kolmogorov-forced."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream.generator.lazy_jax import jnp

from ..domains import LogUniform
from ..ics import GaussianRandomField
from .base import PDE, Param
from .common import CFL
from .fourier import cmul

FORCINGS = ("none", "kolmogorov", "diagonal")


@dataclass(frozen=True)
class NS2D(PDE):
    """2D Navier-Stokes, vorticity w = v_x - u_y, velocity (u, v) = (psi_y, -psi_x) with -Laplacian psi = w.

        w_t + u w_x + v w_y = nu Laplacian(w) - drag w + f

    forcing="kolmogorov": f = -A k_f cos(k_f y), the curl of the body force (A sin(k_f y), 0), with
    k_f = 2 pi forcing_wavenumber / length. forcing="diagonal": the vorticity forcing
    f = A (sin(k_f (x + y)) + cos(k_f (x + y))) (the FNO paper's, A = 0.1, k_f = 2 pi on the unit torus). forcing="none": decaying turbulence (with drag = 0, the
    Taylor-Green vortex w = 2 sin x sin y decays as exp(-2 nu t) on [0, 2 pi)^2).
    The advective CFL uses ``velocity_bound`` (max |velocity| assumed). Unset, it is derived: the larger
    of 4 standard deviations of the initial velocity and the laminar Kolmogorov amplitude
    A / (nu_min k_f^2 + drag) (measured peaks stay below it). A run that exceeds it and blows up is caught
    by the sampler's NaN/Inf check.
    """

    NAME: ClassVar[str] = "ns2d"
    EQUATION: ClassVar[str] = "w_t + (u . grad) w = nu Laplacian(w) - drag w + f,  u = curl^-1 w"
    FIELDS: ClassVar[tuple] = ("vorticity",)
    FIELD_UNITS: ClassVar[dict] = {"vorticity": "1/time"}
    NDIM: ClassVar[int] = 2
    PARAMS: ClassVar[dict] = {"nu": Param("kinematic viscosity", "length^2/time", positive=True)}

    n: int = 64
    length: float = 2 * math.pi
    t_end: float = 10.0
    n_frames: int = 51
    ic: Any = GaussianRandomField(sigma=12.0, tau=3.0, alpha=2.5)
    nu: Any = LogUniform(1e-2, 5e-2)
    forcing: str = "kolmogorov"
    forcing_amplitude: float = 1.0
    forcing_wavenumber: int = 4
    drag: float = 0.1
    velocity_bound: float | None = None

    def check_settings(self):
        if self.forcing not in FORCINGS:
            raise ValueError(f"ns2d: forcing={self.forcing!r} not allowed; allowed: {', '.join(FORCINGS)}")
        if self.drag < 0:
            raise ValueError(f"ns2d: drag={self.drag} not allowed: must be >= 0")
        if self.velocity_bound is not None and not self.velocity_bound > 0:
            raise ValueError(f"ns2d: velocity_bound={self.velocity_bound} not allowed: must be > 0 (or none: derived)")
        if self.forcing != "none" and not 1 <= self.forcing_wavenumber <= self.n // 3:
            raise ValueError(f"ns2d: forcing_wavenumber={self.forcing_wavenumber} not allowed on n={self.n}: need "
                             f"1 <= forcing_wavenumber <= n//3 = {self.n // 3} (the grid must resolve the forcing)")

    def linear(self, grid, p):
        return (p["nu"] * grid.laplacian() - self.drag)[None]

    def forcing_hat(self, grid) -> np.ndarray:
        """Fourier transform of the vorticity forcing, complex [1, *kshape] (zero when unforced)."""
        if self.forcing == "none":
            return np.zeros((1, *grid.kshape), np.complex64)
        k_f = 2 * np.pi * self.forcing_wavenumber / grid.length
        x, y = grid.coords()[:, None], grid.coords()[None, :]
        if self.forcing == "diagonal":
            f = self.forcing_amplitude * (np.sin(k_f * (x + y)) + np.cos(k_f * (x + y)))
        else:
            f = -self.forcing_amplitude * k_f * np.cos(k_f * y) * np.ones((grid.n, 1))
        return np.fft.rfft2(f)[None].astype(np.complex64)

    def nonlinear(self, grid, p):
        kx, ky = grid.wavenumbers()
        k2 = kx**2 + ky**2
        inv_k2 = jnp.where(k2 > 0, 1.0 / jnp.where(k2 > 0, k2, 1.0), 0.0)
        # Spectral multipliers taking w_hat to the velocity (u, v) = (psi_y, -psi_x), psi_hat = w_hat / |k|^2.
        to_velocity = jnp.stack([1j * ky * inv_k2, -1j * kx * inv_k2]).astype(jnp.complex64)
        # Basdevant et al. (1981): for divergence-free (u, v), u w_x + v w_y = d_xy (v^2 - u^2) + (d_xx - d_yy)(u v),
        # so a stage needs 2 inverse and 2 forward transforms (not 4 + 1); real symbols of -d_xy and -(d_xx - d_yy):
        sym_a, sym_b = jnp.asarray(kx * ky, jnp.float32), jnp.asarray(kx**2 - ky**2, jnp.float32)
        f_hat = jnp.asarray(self.forcing_hat(grid))

        def nonlinear(v):
            u, vel_v = grid.irfft(cmul(to_velocity, v[0]))
            a, b = grid.rfft(jnp.stack([vel_v * vel_v - u * u, u * vel_v]))
            return (f_hat[0] + sym_a * a + sym_b * b)[None]

        return nonlinear

    def derived_velocity_bound(self) -> float:
        """max |velocity| assumed by the CFL rule when velocity_bound is unset (length/time)."""
        grid = self.grid
        if hasattr(self.ic, "eigenvalues"):  # a GRF vorticity: velocity variance is sum lambda_k / |k|^2 / L^2
            lam = self.ic.eigenvalues(grid, full=True)
            m = np.fft.fftfreq(grid.n, 1.0 / grid.n)
            k2 = (2 * np.pi / grid.length) ** 2 * sum(x**2 for x in np.meshgrid(m, m, indexing="ij"))
            ic_velocity = 4.0 * float(np.sqrt((lam / np.where(k2 > 0, k2, np.inf)).sum() / grid.length**2))
        else:
            ic_velocity = self.ic.bound(grid)
        if self.forcing == "none":
            return ic_velocity
        k_f = 2 * np.pi * self.forcing_wavenumber / grid.length
        if self.forcing == "diagonal":  # steady vorticity amplitude sqrt2 A / (2 nu k_f^2 + drag), over |k| = sqrt2 k_f
            laminar = self.forcing_amplitude / (k_f * (2 * min(self.nu.bounds) * k_f**2 + self.drag))
        else:
            laminar = self.forcing_amplitude / (min(self.nu.bounds) * k_f**2 + self.drag)
        # The laminar amplitude grows as 1 / nu and is not reached within a short window from rest: advection and
        # viscosity never raise the velocity's L2 norm, so its rms grows at most by the forcing's rms per unit time;
        # 4 rms of that bound (the IC's rule) caps the assumed peak (FNO's nu = 1e-5 set: 1.0 instead of 20).
        growth = ic_velocity + 4.0 * self.forcing_velocity_rms(grid) * self.t_end
        return max(ic_velocity, min(laminar, growth))

    def forcing_velocity_rms(self, grid) -> float:
        """The rms over the domain of the body force (length/time^2) whose curl is the vorticity forcing f."""
        f_hat = np.fft.fft2(np.fft.irfft2(self.forcing_hat(grid)[0].astype(np.complex128), s=grid.shape))
        m = np.fft.fftfreq(grid.n, 1.0 / grid.n)
        k2 = (2 * np.pi / grid.length) ** 2 * sum(x**2 for x in np.meshgrid(m, m, indexing="ij"))
        return float(np.sqrt((np.abs(f_hat) ** 2 / np.where(k2 > 0, k2, np.inf)).sum()) / grid.n**2)

    def stable_dt(self):
        bound = self.velocity_bound if self.velocity_bound is not None else self.derived_velocity_bound()
        return CFL * self.grid.dx / bound
