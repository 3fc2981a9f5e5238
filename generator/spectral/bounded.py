"""Grids with walls: sine (Dirichlet) and cosine (Neumann) bases on cell centres, mixed with periodic axes.

On a non-periodic axis the points are cell centres x_j = (j + 1/2) L / n, j = 0..n-1. A Dirichlet axis
(u = 0 on both walls) expands u in sin(pi m x / L), m = 1..n; a Neumann axis (u_x = 0 on both walls) in
cos(pi k x / L), k = 0..n-1. Both are eigenfunctions of d^2/dx^2 with eigenvalue -(pi m / L)^2, so the
Laplacian (and any polynomial in it) is diagonal and ETDRK4 stays exact for the linear part, as on a periodic
grid. The transforms are DCT-II / DCT-III (and DST through them: DST-II(x)_k = DCT-II((-1)^j x_j)_{n-1-k})
written on JAX's real FFT with real arithmetic only, so a sample's bits do not depend on its batch (XLA's CPU
complex multiply rounds differently vectorised and not; see spectral.cmul). A transform costs about one real
FFT of length n plus O(n) twiddles.

Coefficients are the synthesis amplitudes: u(x_j) = sum_k a_k cos(pi k x_j / L) on a Neumann axis and
u(x_j) = sum_m b_m sin(pi m x_j / L) on a Dirichlet axis (stored b_1..b_n at indices 0..n-1). Periodic axes
use the real FFT as ``spectral.Grid`` does (rfft on the last periodic axis). A derivative swaps the bases (d/dx
of a sine series is a cosine series): ``gradient`` returns it in physical space, where nonlinear terms are
formed, and the forward transform projects their products back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ...boundaries import DIRICHLET, NEUMANN, Boundary, kinds
from ..grids import GridBase

AXES = "xyz"


def _along(x: jax.Array, axis: int, fn) -> jax.Array:
    """fn applied along ``axis`` of x (fn works on the last axis)."""
    return jnp.moveaxis(fn(jnp.moveaxis(x, axis, -1)), -1, axis)


# The twiddle arithmetic runs on rows padded to a multiple of LANES values: XLA's CPU loops round a multiply-add
# differently in their vector body and their scalar remainder, so with rows of n/2 + 1 values a sample's bits
# depended on its batch (which elements fall in the remainder); whole vectors only, they do not (tested).
LANES = 16


def _padded(x: jax.Array) -> jax.Array:
    pad = (-x.shape[-1]) % LANES
    return jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, pad)]) if pad else x


def _twiddles(n: int, dtype, scale: float = 1.0) -> tuple[jax.Array, jax.Array]:
    """scale * cos, scale * sin of pi k / 2n for k = 0..n/2, zero-padded to whole LANES: [ceil((n/2+1)/LANES) LANES]."""
    theta = np.pi * np.arange(n // 2 + 1) / (2 * n)
    return _padded(jnp.asarray(scale * np.cos(theta), dtype)), _padded(jnp.asarray(scale * np.sin(theta), dtype))


def cos_analysis(u: jax.Array) -> jax.Array:
    """Cosine amplitudes a [..., n] of cell-centred values u [..., n] (last axis): u_j = sum_k a_k cos(pi k (j+1/2)/n).
    (Makhoul's DCT-II: even samples, then odd ones reversed, one real FFT, a real twiddle.)"""
    n = u.shape[-1]
    v = jnp.concatenate([u[..., ::2], u[..., 1::2][..., ::-1]], axis=-1)
    spec = jnp.fft.rfft(v, axis=-1)  # V_k, k = 0..n/2
    c, s = _twiddles(n, u.dtype)
    re, im = _padded(spec.real), _padded(spec.imag)
    half = (c * re + s * im)[..., : n // 2 + 1]  # Re(e^{-i pi k / 2n} V_k), k = 0..n/2
    # k > n/2: Re(e^{-i pi k/2n} V_k) with V_k = conj(V_{n-k}): -(sin(pi (n-k)/2n) Re V_{n-k} - cos(.) Im V_{n-k})
    upper = (s * re - c * im)[..., 1 : (n + 1) // 2][..., ::-1]
    dct = jnp.concatenate([half, upper], axis=-1)[..., :n]  # sum_j u_j cos(pi k (2j+1) / 2n)
    scale = np.full(n, 2.0 / n)
    scale[0] = 1.0 / n
    return dct * jnp.asarray(scale, u.dtype)


def cos_synthesis(a: jax.Array) -> jax.Array:
    """Cell-centred values u [..., n] of cosine amplitudes a [..., n] (last axis); inverse of ``cos_analysis``."""
    n = a.shape[-1]
    # Makhoul's inverse: V_k = e^{i pi k/2n} (X_k - i X_{n-k}) / 2 with X the DCT-II (X_n = 0), k = 0..n/2
    x = a * jnp.asarray(np.where(np.arange(n) == 0, 1.0, 0.5) * n, a.dtype)  # X_k: the DCT-II of the values
    head = _padded(x[..., : n // 2 + 1])
    tail = _padded(jnp.concatenate([jnp.zeros_like(x[..., :1]), x[..., ::-1][..., : n // 2]], axis=-1))  # X_{n-k}
    c, s = _twiddles(n, a.dtype, scale=1.0)
    re = (c * head + s * tail)[..., : n // 2 + 1]
    im = (s * head - c * tail)[..., : n // 2 + 1]
    v = jnp.fft.irfft(jax.lax.complex(re, im), n=n, axis=-1)  # v = IFFT(2 V): the DCT-III's reordered values
    even, odd = v[..., : (n + 1) // 2], v[..., (n + 1) // 2 :][..., ::-1]  # u_2j = v_j, u_2j+1 = v_{n-1-j}
    if n % 2:  # interleave by stacking (a strided scatter took 17x the time of the FFT on a CPU)
        odd = jnp.concatenate([odd, jnp.zeros_like(even[..., :1])], axis=-1)
    return jnp.stack([even, odd], axis=-1).reshape(*v.shape[:-1], -1)[..., :n]


def _alternating(n: int, dtype) -> jax.Array:
    return jnp.asarray((-1.0) ** np.arange(n), dtype)


def sin_analysis(u: jax.Array) -> jax.Array:
    """Sine amplitudes b [..., n] (b_m, m = 1..n at 0..n-1) of cell-centred u [..., n]: u_j = sum b_m sin(pi m (j+1/2)/n)."""
    return cos_analysis(u * _alternating(u.shape[-1], u.dtype))[..., ::-1]


def sin_synthesis(b: jax.Array) -> jax.Array:
    """Cell-centred values u [..., n] of sine amplitudes b [..., n]; inverse of ``sin_analysis``."""
    return cos_synthesis(b[..., ::-1]) * _alternating(b.shape[-1], b.dtype)


def _mode_up(y: jax.Array) -> jax.Array:
    """Amplitudes moved one index up the last axis (index k -> k + 1, a zero first): sine m -> cosine k = m, where
    the cosine of index 0 gets none and the last sine mode drops (it vanishes at the cell centres)."""
    return jnp.concatenate([jnp.zeros_like(y[..., :1]), y[..., :-1]], -1)


def _mode_down(y: jax.Array) -> jax.Array:
    """Amplitudes moved one index down the last axis (k -> k - 1, a zero last): cosine k -> sine m = k."""
    return jnp.concatenate([y[..., 1:], jnp.zeros_like(y[..., :1])], -1)


ANALYSIS = {DIRICHLET: sin_analysis, NEUMANN: cos_analysis}  # keyed by Boundary (a StrEnum: its word works too)
SYNTHESIS = {DIRICHLET: sin_synthesis, NEUMANN: cos_synthesis}
DERIVATIVE = {b: b.derivative for b in (DIRICHLET, NEUMANN)}  # d/dx: the other basis, and the sign


@dataclass(frozen=True)
class BoundedGrid(GridBase):
    """n points per axis on [0, length]^ndim with a boundary condition per axis (``bcs``): sine / cosine bases on
    Dirichlet / Neumann axes (cell centres), Fourier on periodic ones (cell-left points). The same interface
    as ``spectral.Grid`` (rfft = forward transform, irfft = inverse, kshape, laplacian, wavenumbers,
    dealias_mask), so the spectral family's rollouts run on it unchanged; states are real when no axis is
    periodic, complex otherwise."""

    POINTS: ClassVar[str] = "cell centres of [0, length] on wall axes, cell-left points on periodic axes"

    bcs: tuple[str, ...] = ()

    @property
    def bc(self) -> tuple[str, ...]:
        return self.bcs

    @property
    def periodic_axes(self) -> tuple[int, ...]:
        return tuple(a for a, b in enumerate(kinds(self.bcs)) if b.periodic)

    @property
    def wall_axes(self) -> tuple[int, ...]:
        return tuple(a for a, b in enumerate(kinds(self.bcs)) if b.walled)

    @property
    def kshape(self) -> tuple[int, ...]:
        shape = [self.n] * self.ndim
        if self.periodic_axes:
            shape[self.periodic_axes[-1]] = self.n // 2 + 1
        return tuple(shape)

    @property
    def dx(self) -> float:
        return self.length / self.n

    def coords(self, axis: int = 0) -> np.ndarray:
        """Point positions along ``axis``, float32 [n]: cell centres on a wall axis, cell-left on a periodic one."""
        shift = 0.0 if Boundary.of(self.bcs[axis]).periodic else 0.5
        return ((np.arange(self.n) + shift) * self.dx).astype(np.float32)

    def describe(self) -> str:
        walls = ", ".join(f"{AXES[a]} {b}" for a, b in enumerate(self.bcs))
        return f"{'x'.join(map(str, self.shape))} on [0, {self.length:g}]^{self.ndim} ({walls})"

    # --- modes -------------------------------------------------------------------------------------------
    def integer_wavenumbers(self) -> tuple[np.ndarray, ...]:
        """Mode numbers per axis, float64, broadcastable to kshape: m (sine, 1..n), k (cosine, 0..n-1), or the
        FFT's signed m on periodic axes (rfft layout on the last periodic one)."""
        out = []
        for axis, bc in enumerate(kinds(self.bcs)):
            if bc.pins_value:
                m = np.arange(1, self.n + 1, dtype=np.float64)
            elif bc.walled:
                m = np.arange(self.n, dtype=np.float64)
            elif axis == self.periodic_axes[-1]:
                m = np.fft.rfftfreq(self.n, 1.0 / self.n)
            else:
                m = np.fft.fftfreq(self.n, 1.0 / self.n)
            shape = [1] * self.ndim
            shape[axis] = -1
            out.append(m.reshape(shape))
        return tuple(out)

    def wavenumbers(self) -> tuple[np.ndarray, ...]:
        """Angular wavenumbers per axis, float32 broadcastable to kshape: pi m / length on wall axes (the half
        wave fits the box), 2 pi m / length on periodic ones."""
        return tuple((np.pi * (1 if bc.walled else 2) / self.length * m).astype(np.float32)
                     for bc, m in zip(kinds(self.bcs), self.integer_wavenumbers()))

    def laplacian(self) -> np.ndarray:
        """Symbol of the Laplacian, -|k|^2, float32 broadcastable to kshape (exact eigenvalues of the bases)."""
        return -sum(k**2 for k in self.wavenumbers())

    def dealias_mask(self) -> np.ndarray:
        """The 2/3 rule per axis: |m| <= n/3 on periodic axes, m <= 2n/3 on wall axes (the same fraction of the
        highest mode: a wall axis is the half of a periodic box of 2n points), bool kshape."""
        keep = np.ones(self.kshape, bool)
        for bc, m in zip(kinds(self.bcs), self.integer_wavenumbers()):
            keep = keep & (np.abs(m) <= (self.n // 3 if bc.periodic else (2 * self.n) // 3))
        return keep

    # --- transforms --------------------------------------------------------------------------------------
    def _walls(self, x: jax.Array, table, skip: int | None = None) -> jax.Array:
        for axis in self.wall_axes:
            if axis != skip:
                x = _along(x, axis - self.ndim, table[self.bcs[axis]])
        return x

    def rfft(self, u: jax.Array) -> jax.Array:
        """Physical [..., *shape] -> coefficients [..., *kshape] (complex when an axis is periodic)."""
        v = self._walls(u, ANALYSIS)
        axes = tuple(a - self.ndim for a in self.periodic_axes)
        return jnp.fft.rfftn(v, axes=axes) if axes else v

    def _unperiodic(self, v: jax.Array) -> jax.Array:
        axes = tuple(a - self.ndim for a in self.periodic_axes)
        return jnp.fft.irfftn(v, s=(self.n,) * len(axes), axes=axes) if axes else v

    def irfft(self, v: jax.Array) -> jax.Array:
        """Coefficients [..., *kshape] -> physical [..., *shape] (last ndim axes)."""
        return self._walls(self._unperiodic(v), SYNTHESIS)

    def derivative_of(self, w: jax.Array, axis: int) -> jax.Array:
        """Coefficients [..., *kshape] (the state's bases) of d w / d x_axis for a physical field w [..., *shape]
        that is even where the state is odd about the walls of ``axis`` (a flux such as u^2 / 2 on Dirichlet walls):
        w is expanded in the other basis along ``axis`` and differentiated in coefficient space, one transform
        instead of the two of ``rfft(gradient(...))``. On a periodic axis: i k times the Fourier coefficients."""
        k = self.wavenumbers()[axis]
        bc = Boundary.of(self.bcs[axis])
        if bc.periodic:
            v = self.rfft(w)
            return jax.lax.complex(-k * v.imag, k * v.real)
        other, _ = DERIVATIVE[bc]
        x = _along(w, axis - self.ndim, ANALYSIS[other])
        if bc.pins_value:  # cosine amplitudes a_k -> sine b_m = -a_m pi m / L at m = k (m = n: none)
            x = _along(x, axis - self.ndim, _mode_down)
        else:  # sine amplitudes b_m (m = 1..n) -> cosine a_k = b_k pi k / L at k = m (k = 0: none; m = n vanishes)
            x = _along(x, axis - self.ndim, _mode_up)
        x = (-k if bc.pins_value else k) * x
        x = self._walls(x, ANALYSIS, skip=axis)
        axes = tuple(a - self.ndim for a in self.periodic_axes)
        return jnp.fft.rfftn(x, axes=axes) if axes else x

    def gradient(self, v: jax.Array, axis: int) -> jax.Array:
        """d u / d x_axis in physical space [..., *shape] from the coefficients v [..., *kshape] of u (exact for
        the series: a sine series' derivative is a cosine series and vice versa; the periodic ones as ``ddx``)."""
        k = self.wavenumbers()[axis]
        if Boundary.of(self.bcs[axis]).periodic:
            return self.irfft(jax.lax.complex(-k * v.imag, k * v.real))
        x = self._unperiodic(v)
        other, sign = DERIVATIVE[self.bcs[axis]]
        x = sign * k * x  # b_m (pi m / L) cos(.) for a sine series; -a_k (pi k / L) sin(.) for a cosine one
        # re-index to the other basis: sine m = 1..n <-> cosine k = m; cosine k = 0..n-1 <-> sine m = k
        if not other.pins_value:  # sine amplitudes at m = 1..n -> cosine at k = 0..n-1 (k = m; m = n vanishes)
            x = _along(x, axis - self.ndim, _mode_up)
        else:  # cosine at k = 0..n-1 -> sine at m = 1..n (m = k; k = 0 has no derivative)
            x = _along(x, axis - self.ndim, _mode_down)
        x = _along(x, axis - self.ndim, SYNTHESIS[other])
        return self._walls(x, SYNTHESIS, skip=axis)
