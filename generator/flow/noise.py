"""A random initial smoke field for the flows: PhiFlow's ``Noise`` measure (the one PDEArena's smoke set draws).

The law (PhiFlow 2.1.0, phi/field/_noise.py, ``Noise.grid_sample``; PDEArena pins phiflow==2.1): on a box of
nx x ny cells over lx x ly, every grid wavenumber m = (m_x, m_y) (the FFT's integer frequencies) gets an
independent complex Gaussian c_m = a_m + i b_m (a, b standard normal) times the weight
w(m) = (|k|^2)^-smoothness where |k|^2 > 0.1, else 0, with k = (m_x / lx, m_y / ly) * scale; the field is the real
part of the inverse FFT, divided by its own spatial standard deviation, then its spatial mean removed (so every
draw has spatial mean 0 and spatial std 1 exactly, up to rounding); the smoke is its absolute value (PDEArena's
abs()). The power of the signed field at mode m is therefore proportional to w(m)^2 = |k|^(-4 smoothness):
at PDEArena's scale 11, smoothness 6 on 32 x 32 every m != 0 passes the 0.1 cut and the |m| = 1 modes carry all but
~0.05% of the variance (|m|^2 = 2 has 2^-24 of their power per mode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

LOWEST = 0.1  # PhiFlow's lowest_frequency: modes with |k|^2 <= this get no weight (|k| in scale / length units)


def noise_weights(shape: tuple[int, int], lengths: tuple[float, float], scale: float, smoothness: float) -> np.ndarray:
    """The weight w(m) of each FFT mode of an (nx, ny) grid over (lx, ly): (|k|^2)^-smoothness where |k|^2 > LOWEST,
    else 0 (k = m / length * scale per axis), divided by its largest value (the draw is normalised afterwards, so
    the factor changes nothing but keeps float32 in range); float64 [nx, ny]."""
    ks = [np.fft.fftfreq(n) * n / length * scale for n, length in zip(shape, lengths)]
    k2 = sum(k**2 for k in np.meshgrid(*ks, indexing="ij"))
    with np.errstate(divide="ignore"):
        log_w = np.where(k2 > LOWEST, -smoothness * np.log(np.where(k2 > 0, k2, 1.0)), -np.inf)
    if not np.isfinite(log_w.max()):  # no mode passes the cut
        return np.zeros(k2.shape)
    return np.exp(log_w - log_w.max())


def signed_noise(key: jax.Array, shape: tuple[int, int], lengths: tuple[float, float], scale: float,
                 smoothness: float) -> jax.Array:
    """One draw of the signed field (before the absolute value), float32 [nx, ny]: spatial mean 0, std 1."""
    kr, ki = jax.random.split(key)
    w = jnp.asarray(noise_weights(shape, lengths, scale, smoothness), jnp.float32)
    c = jax.lax.complex(jax.random.normal(kr, shape, jnp.float32), jax.random.normal(ki, shape, jnp.float32))
    f = jnp.real(jnp.fft.ifft2(c * w))
    f = f / jnp.std(f)  # PhiFlow's order: divide by the std, then remove the mean
    return f - jnp.mean(f)


@dataclass(frozen=True)
class SmokeNoise:
    """The flow at rest with a random smoke field: smoke = |PhiFlow Noise(scale, smoothness)| (this module's law:
    the signed field has spatial mean 0 and std 1, power |k|^(-4 smoothness) above |k|^2 = 0.1, k = m scale /
    length), velocity zero. ``sample`` gives frame 0's fields [n_fields, nx, ny]: zeros but the last (the
    entry's ``smoke``), dimensionless."""

    scale: float = 11.0  # PhiFlow's physical size of the fluctuations (PDEArena: 11 on a 32 x 32 box)
    smoothness: float = 6.0  # how fast high wavenumbers die out (PDEArena: 6)
    kind = "noise"
    field_count = None

    def sample(self, key: jax.Array, grid, n_fields: int) -> jax.Array:
        """float32 [n_fields, *grid.shape]: velocity and pressure 0, the last field (smoke) the draw."""
        lengths = (grid.aspect * grid.length, grid.length)
        smoke = jnp.abs(signed_noise(key, grid.shape, lengths, self.scale, self.smoothness))
        return jnp.concatenate([jnp.zeros((n_fields - 1, *grid.shape), jnp.float32), smoke[None]])

    def check(self, grid) -> None:
        for name in ("scale", "smoothness"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"ic.{name}={value!r} not allowed: must be a finite number > 0")
        lengths = (grid.aspect * grid.length, grid.length)
        if not np.any(noise_weights(grid.shape, lengths, self.scale, self.smoothness) > 0):
            raise ValueError(f"ic.scale={self.scale:g} not allowed: no mode of this grid passes PhiFlow's cut |k|^2 > "
                             f"{LOWEST:g} (k = m scale / length); a scale above "
                             f"{math.sqrt(LOWEST) * max(lengths) / (max(grid.shape) // 2):.3g}")

    def bound(self, grid) -> float:
        """max smoke <= sqrt(cells): a field of spatial std 1 cannot exceed it anywhere."""
        return math.sqrt(math.prod(grid.shape))

    def __str__(self) -> str:
        return (f"fluid at rest, smoke = |PhiFlow Noise(scale={self.scale:g}, smoothness={self.smoothness:g})| "
                "(spatial mean 0, std 1 before the abs)")


__all__ = ["LOWEST", "SmokeNoise", "noise_weights", "signed_noise"]
