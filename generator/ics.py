"""Initial-condition distributions on periodic grids, in 1D and 2D.

Every distribution is band-limited to the solver's 2/3-rule modes, so the field the solver starts from
is exactly the field it was given (frame 0 of a trajectory is the initial condition, bit for bit).
``sample(key, grid, n_fields)`` returns float32 ``[n_fields, *grid.shape]``, one independent draw per field.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .spectral import Grid


def _white_noise_hat(key: jax.Array, grid: Grid, n_fields: int) -> jax.Array:
    """rfft of unit white noise: complex [C, *kshape] with exact Hermitian symmetry and E|.|^2 = n^ndim."""
    return grid.rfft(jax.random.normal(key, (n_fields, *grid.shape), jnp.float32))


def _mode_norm(grid: Grid) -> np.ndarray:
    """Integer-wavenumber magnitude |m| on the rfft layout, float64 kshape."""
    return np.sqrt(sum(m**2 for m in np.broadcast_arrays(*grid.integer_wavenumbers())))


def _full_mode_norm(grid: Grid) -> np.ndarray:
    """|m| over the full (not half) FFT layout, for sums over all modes: float64 [n]*ndim."""
    m = np.fft.fftfreq(grid.n, 1.0 / grid.n)
    return np.sqrt(sum(x**2 for x in np.meshgrid(*([m] * grid.ndim), indexing="ij")))


@dataclass(frozen=True)
class FourierSeries:
    """Random truncated Fourier series, rescaled so that max|u0| = amplitude, plus a constant offset.

    Modes 1 <= |m|_inf <= max_mode get Gaussian coefficients scaled by |m|^-decay (m: integer wavenumber).
    """

    max_mode: int = 5
    decay: float = 1.0
    amplitude: float = 1.0
    offset: float = 0.0
    kind = "fourier"
    field_count = None  # any: one independent draw per PDE field

    def check(self, grid: Grid) -> None:
        """Raise ValueError if this distribution cannot be represented on ``grid``."""
        if not 1 <= self.max_mode <= grid.n // 3:
            raise ValueError(
                f"ic.max_mode={self.max_mode} not allowed on n={grid.n}: need 1 <= max_mode <= n//3 = {grid.n // 3}"
            )
        if not self.amplitude > 0:
            raise ValueError(f"ic.amplitude={self.amplitude} not allowed: must be > 0")

    def sample(self, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        m_inf = grid.max_abs_mode()
        keep = (m_inf >= 1) & (m_inf <= self.max_mode)
        weight = np.where(keep, np.maximum(_mode_norm(grid), 1.0) ** (-self.decay), 0.0)
        u = grid.irfft(_white_noise_hat(key, grid, n_fields) * jnp.asarray(weight, jnp.float32))
        peak = jnp.max(jnp.abs(u), axis=tuple(range(1, u.ndim)), keepdims=True)
        return self.amplitude * u / peak + self.offset

    def bound(self, grid: Grid) -> float:
        """max|u0| (exact for this distribution)."""
        del grid
        return abs(self.offset) + self.amplitude


@dataclass(frozen=True)
class GaussianRandomField:
    """Gaussian random field N(mean, sigma^2 (-Laplacian + tau^2 I)^(-alpha)) on the periodic domain.

    The covariance operator has eigenvalues lambda_k = sigma^2 (|k|^2 + tau^2)^(-alpha) for angular
    wavenumbers k = 2 pi m / length; the field is sum_k sqrt(lambda_k) xi_k e_k with e_k the
    L2-orthonormal Fourier modes, so its pointwise variance is sum_k lambda_k / length^ndim.
    The FNO paper's Burgers initial condition N(0, 625 (-Laplacian + 25 I)^-2) is sigma=25, tau=5, alpha=2.
    ``zero_mean`` drops the k = 0 mode (as the FNO generator does).
    """

    sigma: float = 25.0
    tau: float = 5.0
    alpha: float = 2.0
    mean: float = 0.0
    zero_mean: bool = True
    kind = "grf"
    field_count = None  # any: one independent draw per PDE field

    def check(self, grid: Grid) -> None:
        for name in ("sigma", "alpha"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ic.{name}={getattr(self, name)} not allowed: must be > 0")
        if self.tau < 0 or (self.tau == 0 and not self.zero_mean):
            raise ValueError(f"ic.tau={self.tau} not allowed: must be >= 0 (> 0 unless zero_mean)")

    def eigenvalues(self, grid: Grid, full: bool = False) -> np.ndarray:
        """lambda_k on the rfft layout (or the full FFT layout), zero outside the 2/3 band; float64."""
        m = _full_mode_norm(grid) if full else _mode_norm(grid)
        k2 = (2 * np.pi / grid.length) ** 2 * m**2
        with np.errstate(divide="ignore"):
            lam = self.sigma**2 * (k2 + self.tau**2) ** (-self.alpha)
        if self.zero_mean:
            lam = np.where(m == 0, 0.0, lam)
        if full:
            m_axis = np.abs(np.fft.fftfreq(grid.n, 1.0 / grid.n))
            band = np.maximum.reduce(np.meshgrid(*([m_axis] * grid.ndim), indexing="ij")) <= grid.n // 3
        else:
            band = np.asarray(grid.dealias_mask())
        return np.where(band, lam, 0.0)

    def pointwise_std(self, grid: Grid) -> float:
        """Standard deviation of u0(x) at any point: sqrt(sum_k lambda_k / length^ndim)."""
        return float(np.sqrt(self.eigenvalues(grid, full=True).sum() / grid.length**grid.ndim))

    def sample(self, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        # U_k = xi_hat_k sqrt(lambda_k N / L^d) gives coefficients c_k = U_k / N with E|c_k|^2 = lambda_k / L^d.
        n_total = grid.n**grid.ndim
        scale = np.sqrt(self.eigenvalues(grid) * n_total / grid.length**grid.ndim)
        u = grid.irfft(_white_noise_hat(key, grid, n_fields) * jnp.asarray(scale, jnp.float32))
        return u + self.mean

    def bound(self, grid: Grid) -> float:
        """A practical bound on max|u0|: |mean| + 4 pointwise standard deviations."""
        return abs(self.mean) + 4.0 * self.pointwise_std(grid)


IC_KINDS = {"fourier": FourierSeries, "grf": GaussianRandomField}
