"""Initial-condition distributions on periodic grids in 1D, 2D and 3D, one protocol for all, and their parsing.

Every distribution follows ``InitialCondition``: ``kind`` (its name in IC_KINDS), ``field_count`` (the
number of PDE fields it makes, or None for any), ``sample(key, grid, n_fields)`` -> float32
``[n_fields, *grid.shape]``, ``check(grid)`` (ValueError if it cannot be represented on the grid) and
``bound(grid)`` (max|u0|, for stability rules). The smooth ones are band-limited to the solver's 2/3-rule
modes, so the field the solver starts from is the field it was given (frame 0 of a trajectory is the IC).

A distribution that also follows ``LatentIC`` exposes the coordinates a proposal may steer (``latent_size``,
``latent_from_key``, ``ic_from_latent``, ``latent_prior``): ``ic_from_latent(latent_from_key(key), key)`` is
``sample(key)`` bit for bit, so a sample given the latent its key draws is the sample drawn.

IC_KINDS is declared here, complete: no module adds to it at import time. ``make_ic`` turns a kind name or
a dict {"kind": ..., field: value} into a distribution; ``coerce`` / ``check_value`` turn a setting's
value (possibly text from ``--set``) into the kind of its default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Protocol, runtime_checkable

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ..boundaries import is_periodic
from .spectral.fourier import Grid

# The spot loop is unrolled into the compiled set-up program (written out for bit-identity), so its size
# bounds compile time and memory: 256 spots cover a 64^2 box many times over.
MAX_SPOTS = 256


@runtime_checkable
class InitialCondition(Protocol):
    """What every initial-condition distribution provides (a frozen dataclass whose fields are its settings)."""

    kind: str  # its name in IC_KINDS
    field_count: int | None  # PDE fields it makes (None: any; one independent draw per field)

    def sample(self, key: jax.Array, grid: Grid, n_fields: int) -> jax.Array:
        """One draw, float32 [n_fields, *grid.shape]."""

    def check(self, grid: Grid) -> None:
        """Raise ValueError (one line naming the setting and what is allowed) if not representable on ``grid``."""

    def bound(self, grid: Grid) -> float:
        """A bound on max|u0| (used by stability rules and the float32 limit)."""


# The most coordinates a latent exposes (per distribution, all fields together): a proposal over the latent and the
# parameters is a loss model on that many dimensions (OGAS's largest space is 308).
MAX_LATENT = 256


@runtime_checkable
class LatentIC(Protocol):
    """An IC distribution whose draw has steerable coordinates: the latent float32 [L] (L = ``latent_size``, at most
    MAX_LATENT) is part of what the key draws; the rest of the draw (modes beyond the latent, noise) still comes
    from the key. So a sample is a pure function of (key, latent), and of the key alone when the latent is the
    key's own (``latent_from_key``)."""

    def latent_size(self, grid: Grid, n_fields: int) -> int:
        """L: the number of latent coordinates on ``grid`` (0: none)."""

    def latent_from_key(self, key: jax.Array, grid: Grid, n_fields: int) -> jax.Array:
        """The latent the key draws today, float32 [L]."""

    def ic_from_latent(self, latent: jax.Array, key: jax.Array, grid: Grid, n_fields: int) -> jax.Array:
        """The IC float32 [n_fields, *grid.shape] with its latent coordinates set to ``latent`` [L] and the rest of
        the draw from ``key``; equal bit for bit to ``sample(key)`` when ``latent == latent_from_key(key)``."""

    def latent_prior(self, grid: Grid, n_fields: int) -> tuple[str, np.ndarray, np.ndarray]:
        """The law ``latent_from_key`` draws each coordinate from: ("normal", mean [L], std [L]) or
        ("uniform", low [L], high [L]), float64 (what a proposal maps its unit box onto)."""


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


def _twins(grid: Grid) -> np.ndarray:
    """For each flat rfft-layout index [prod(kshape)], the flat index of its conjugate twin -m where both live in the
    layout (the real planes: last axis 0, and n/2 for an even n; itself for a self-conjugate mode), else -1."""
    idx = np.indices(grid.kshape).reshape(grid.ndim, -1)
    last = idx[-1]
    real = (last == 0) | ((grid.n % 2 == 0) & (last == grid.n // 2))
    mirror = np.concatenate([(-idx[:-1]) % grid.n, last[None]])
    return np.where(real, np.ravel_multi_index(tuple(mirror), grid.kshape), -1)


def _pow2_scale(grid: Grid) -> float:
    """The power of two nearest the std of a real or imaginary part of an rfft coefficient of unit white noise,
    sqrt(n^ndim / 2): a latent in these units is about standard normal, and scaling by a power of two is exact."""
    return float(2.0 ** round(math.log2(math.sqrt(grid.n**grid.ndim / 2))))


class SpectralLatent:
    """The latent of an IC made from the rfft of unit white noise (``_white_noise_hat``): the real and imaginary
    parts of its leading modes (those the distribution weights, the zero mode left out, in order of |m| then layout
    position), per field, divided by ``_pow2_scale``; layout [n_fields, modes, 2] flattened, at most MAX_LATENT.
    Modes beyond it come from the key. In 2D and 3D the rfft's real planes (last axis 0, and n/2 for an even n) hold
    both m and its twin -m, complex conjugates in a key's draw: the latent holds one of each pair (the first in the
    layout; a self-conjugate mode, real in a key's draw, none) and sets its twin to the conjugate, so a latent drawn
    from ``latent_prior`` is a draw of the key's law (set apart, the two would halve those modes' energy: a 2D GRF's
    by 16%). Where a latent mode equals the key's own value its twin keeps the key's (whose rounding may differ from
    an exact conjugate), so the key's own latent gives the key's IC bit for bit."""

    def _weights(self, grid: Grid) -> np.ndarray:
        """Which rfft modes the distribution uses (nonzero), float64 kshape."""
        raise NotImplementedError

    def _modes(self, grid: Grid, n_fields: int) -> np.ndarray:
        """Flat rfft-layout indices of the latent's modes, int [modes] (one of each conjugate pair: the class doc)."""
        m = _mode_norm(grid).ravel()
        twin, flat = _twins(grid), np.arange(m.size)
        used = np.flatnonzero((self._weights(grid).ravel() != 0) & (m > 0) & ((twin < 0) | (twin > flat)))
        order = used[np.argsort(m[used], kind="stable")]
        return order[: MAX_LATENT // (2 * n_fields)]

    def latent_size(self, grid: Grid, n_fields: int) -> int:
        return 2 * n_fields * len(self._modes(grid, n_fields))

    def latent_from_key(self, key: jax.Array, grid: Grid, n_fields: int) -> jax.Array:
        hat = _white_noise_hat(key, grid, n_fields).reshape(n_fields, -1)[:, self._modes(grid, n_fields)]
        return (jnp.stack([hat.real, hat.imag], axis=-1) / _pow2_scale(grid)).reshape(-1)

    def _hat(self, latent: jax.Array, key: jax.Array, grid: Grid, n_fields: int) -> jax.Array:
        """The key's white-noise rfft with the latent's modes set from ``latent``: complex [C, *kshape]."""
        modes = self._modes(grid, n_fields)
        z = jnp.asarray(latent, jnp.float32).reshape(n_fields, len(modes), 2) * _pow2_scale(grid)
        z = jax.lax.complex(z[..., 0], z[..., 1])
        hat = _white_noise_hat(key, grid, n_fields).reshape(n_fields, -1)
        twin = _twins(grid)[modes]
        paired = twin >= 0
        if paired.any():  # a twin is the conjugate, or the key's own value where the mode is the key's (class doc)
            same = z[:, paired] == hat[:, modes[paired]]
            hat = hat.at[:, twin[paired]].set(jnp.where(same, hat[:, twin[paired]], jnp.conj(z[:, paired])))
        hat = hat.at[:, modes].set(z)
        return hat.reshape(n_fields, *grid.kshape)

    def latent_prior(self, grid: Grid, n_fields: int) -> tuple[str, np.ndarray, np.ndarray]:
        size = self.latent_size(grid, n_fields)
        std = math.sqrt(grid.n**grid.ndim / 2) / _pow2_scale(grid)
        return "normal", np.zeros(size), np.full(size, std)


@dataclass(frozen=True)
class FourierSeries(SpectralLatent):
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

    def _weights(self, grid: Grid) -> np.ndarray:
        m_inf = grid.max_abs_mode()
        keep = (m_inf >= 1) & (m_inf <= self.max_mode)
        return np.where(keep, np.maximum(_mode_norm(grid), 1.0) ** (-self.decay), 0.0)

    def sample(self, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        return self._from_hat(_white_noise_hat(key, grid, n_fields), grid)

    def ic_from_latent(self, latent: jax.Array, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        return self._from_hat(self._hat(latent, key, grid, n_fields), grid)

    def _from_hat(self, hat: jax.Array, grid: Grid) -> jax.Array:
        u = grid.irfft(hat * jnp.asarray(self._weights(grid), jnp.float32))
        peak = jnp.max(jnp.abs(u), axis=tuple(range(1, u.ndim)), keepdims=True)
        return self.amplitude * u / peak + self.offset

    def bound(self, grid: Grid) -> float:
        """max|u0| (exact for this distribution)."""
        del grid
        return abs(self.offset) + self.amplitude


@dataclass(frozen=True)
class GaussianRandomField(SpectralLatent):
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

    def _weights(self, grid: Grid) -> np.ndarray:
        # U_k = xi_hat_k sqrt(lambda_k N / L^d) gives coefficients c_k = U_k / N with E|c_k|^2 = lambda_k / L^d.
        return np.sqrt(self.eigenvalues(grid) * grid.n**grid.ndim / grid.length**grid.ndim)

    def sample(self, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        return self._from_hat(_white_noise_hat(key, grid, n_fields), grid)

    def ic_from_latent(self, latent: jax.Array, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        return self._from_hat(self._hat(latent, key, grid, n_fields), grid)

    def _from_hat(self, hat: jax.Array, grid: Grid) -> jax.Array:
        return grid.irfft(hat * jnp.asarray(self._weights(grid), jnp.float32)) + self.mean

    def bound(self, grid: Grid) -> float:
        """A practical bound on max|u0|: |mean| + 4 pointwise standard deviations."""
        return abs(self.mean) + 4.0 * self.pointwise_std(grid)


@dataclass(frozen=True)
class GrayScottSpots:
    """u = 1 - 2 s - noise * a, v = s + noise * b: s is n_spots Gaussian bumps (periodic distance, width ``radius``)
    at uniform random centres, scaled so that max s <= ``height``; a, b are non-negative noise fields in [0, 1].

    Two fields (Gray-Scott's u, v), any dimension. Both are concentrations and stay in their physical range:
    0 <= v <= height + noise and 1 - 2 height - noise <= u <= 1 (so 0 <= u, v <= 1, the declared bound; ``check``
    refuses settings that would leave it). Why scaled, not summed: overlapping bumps summed to s > 1/2 and u < 0
    (u min -0.24 in grayscott3d). Why non-negative noise: zero-mean white noise made v < 0 wherever s = 0. The noise
    is the square of white noise band-limited to |m| <= n // 6 per axis, divided by its maximum: its square stays
    inside the solver's 2/3-rule band, so frame 0 (the IC's projection) keeps the range (the bumps' tails beyond the
    band are below 1e-8 at the default radii and spacing).
    """

    n_spots: int = 6
    radius: float = 0.03
    height: float = 0.25
    noise: float = 0.01
    kind = "spots"
    field_count = 2  # (u, v) = (1 - 2 s, s): Gray-Scott's two fields

    def check(self, grid: Grid) -> None:
        if not 1 <= self.n_spots <= MAX_SPOTS:
            raise ValueError(f"ic.n_spots={self.n_spots} not allowed: need 1 <= n_spots <= {MAX_SPOTS}")
        if not self.radius > 0:
            raise ValueError(f"ic.radius={self.radius} not allowed: must be > 0")
        if not (self.height >= 0 and self.noise >= 0 and 2 * self.height + self.noise <= 1):
            raise ValueError(f"ic.height={self.height}, ic.noise={self.noise} not allowed: need height >= 0, "
                             "noise >= 0 and 2 height + noise <= 1 (u = 1 - 2 s - noise stays >= 0)")

    def _noise(self, key: jax.Array, grid: Grid) -> jax.Array:
        """Two non-negative fields in [0, 1] with max 1, float32 [2, *shape], band-limited to |m| <= 2 (n // 6)."""
        keep = jnp.asarray(grid.max_abs_mode() <= grid.n // 6)
        g = grid.irfft(_white_noise_hat(key, grid, 2) * keep)
        g2 = g * g
        # max is exact in any order (unlike a sum), so the scale does not depend on the batch
        peak = jnp.max(g2.reshape(2, -1), axis=1).reshape((2,) + (1,) * grid.ndim)
        return g2 / jnp.maximum(peak, jnp.finfo(jnp.float32).tiny)

    # The latent: the spot centres [n_spots, ndim] (flattened), uniform over the box; the noise comes from the key.
    def latent_size(self, grid: Grid, n_fields: int = 2) -> int:
        return self.n_spots * grid.ndim if self.n_spots * grid.ndim <= MAX_LATENT else 0

    def latent_from_key(self, key: jax.Array, grid: Grid, n_fields: int = 2) -> jax.Array:
        return self._centres(key, grid).reshape(-1)

    def latent_prior(self, grid: Grid, n_fields: int = 2) -> tuple[str, np.ndarray, np.ndarray]:
        size = self.latent_size(grid)
        return "uniform", np.zeros(size), np.full(size, float(grid.length))

    def _centres(self, key: jax.Array, grid: Grid) -> jax.Array:
        k_centre, _ = jax.random.split(key)
        return jax.random.uniform(k_centre, (self.n_spots, grid.ndim), jnp.float32, 0.0, grid.length)

    def sample(self, key: jax.Array, grid: Grid, n_fields: int = 2) -> jax.Array:
        return self._from_centres(self._centres(key, grid), key, grid)

    def ic_from_latent(self, latent: jax.Array, key: jax.Array, grid: Grid, n_fields: int = 2) -> jax.Array:
        return self._from_centres(jnp.asarray(latent, jnp.float32).reshape(self.n_spots, grid.ndim), key, grid)

    def _from_centres(self, centres: jax.Array, key: jax.Array, grid: Grid) -> jax.Array:
        """The spots at ``centres`` float32 [n_spots, ndim] plus the key's noise: float32 [2, *grid.shape]."""
        _, k_noise = jax.random.split(key)
        x = jnp.asarray(grid.coords())
        mesh = jnp.meshgrid(*([x] * grid.ndim), indexing="ij")
        # Sums are written out term by term: XLA may reassociate a reduce differently per batch size,
        # which would break bit-identity of a sample across batches.
        s = jnp.zeros(grid.shape, jnp.float32)
        for i in range(self.n_spots):
            d2 = jnp.zeros(grid.shape, jnp.float32)
            for axis in range(grid.ndim):
                # chord distance on the circle: smooth and periodic, ~ |x - c| for nearby points
                d2 = d2 + (grid.length / jnp.pi * jnp.sin(jnp.pi * (mesh[axis] - centres[i, axis]) / grid.length)) ** 2
            s = s + jnp.exp(-d2 / (2 * self.radius**2))
        # one scale for the whole field (keeps it smooth and band-limited, unlike clipping): peak height at most
        s = (self.height / jnp.maximum(1.0, jnp.max(s))) * s
        a, b = self._noise(k_noise, grid)
        return jnp.stack([1.0 - 2.0 * s - self.noise * a, s + self.noise * b])

    def bound(self, grid: Grid) -> float:
        return 1.0  # 0 <= u, v <= 1 (check)


@dataclass(frozen=True)
class RandomSines:
    """A random superposition of sines on a periodic 1D domain, PDEBench's 1D measure (its ``init_multi``).

    Draw ``n_modes`` integers uniformly from 1..max_mode; mode k (k = 1..max_mode, drawn c_k times) gives the
    term A_k sin(2 pi k c_k x / L + phi_k) with A_k ~ U(0, 1), phi_k ~ U(0, 2 pi): as in PDEBench, a mode drawn
    twice has twice the wavenumber and a mode not drawn adds the constant A_k sin(phi_k). Then u0 -> |u0| with
    probability ``abs_prob``, a random sign, and with probability ``window_prob`` the window
    0.5 (tanh((x - x_l) / w) - tanh((x - x_r) / w)), x_l ~ U(0.1, 0.45) L, x_r ~ U(0.55, 0.9) L,
    w = window_width L. ``normalise``: rescaled to min 0, max 1 (PDEBench's reaction-diffusion IC).
    """

    max_mode: int = 4
    n_modes: int = 2
    abs_prob: float = 0.1
    window_prob: float = 0.1
    window_width: float = 0.01
    normalise: bool = False
    kind = "sines"
    field_count = None  # any: one independent draw per PDE field
    ndims = (1,)  # the dimensions it serves (other kinds: any)

    def check(self, grid: Grid) -> None:
        if grid.ndim != 1:
            raise ValueError(f"ic kind 'sines' is one-dimensional; this grid is {grid.ndim}D (allowed: fourier, grf)")
        if not all(is_periodic(bc) for bc in getattr(grid, "bc", ("periodic",))):
            raise ValueError("ic kind 'sines' is periodic; this grid has walls (allowed there: fourier, grf)")
        if not (self.max_mode >= 1 and self.n_modes >= 1 and self.max_mode * self.n_modes <= grid.n // 3):
            raise ValueError(f"ic.max_mode={self.max_mode}, ic.n_modes={self.n_modes} not allowed on n={grid.n}: "
                             f"need both >= 1 and max_mode * n_modes <= n//3 = {grid.n // 3} (the highest wavenumber)")
        for name in ("abs_prob", "window_prob"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"ic.{name}={getattr(self, name)} not allowed: a probability in [0, 1]")
        if not self.window_width > 0:
            raise ValueError(f"ic.window_width={self.window_width} not allowed: must be > 0")

    # The latent: each field's amplitudes A_k and phases phi_k, [n_fields, max_mode, 2] flattened, uniform on
    # [0, 1] x [0, 2 pi]; which modes are picked, |u|, the sign and the window still come from the key.
    def latent_size(self, grid: Grid, n_fields: int = 1) -> int:
        return 2 * self.max_mode * n_fields if 2 * self.max_mode * n_fields <= MAX_LATENT else 0

    def _amp_phase(self, key: jax.Array) -> jax.Array:
        """One field's (A_k, phi_k) as the key draws them: float32 [max_mode, 2]."""
        _, k_amp, k_phase, *_ = jax.random.split(key, 8)
        amp = jax.random.uniform(k_amp, (self.max_mode,), jnp.float32)
        phase = jax.random.uniform(k_phase, (self.max_mode,), jnp.float32, 0.0, 2 * jnp.pi)
        return jnp.stack([amp, phase], axis=-1)

    def latent_from_key(self, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        return jnp.stack([self._amp_phase(jax.random.fold_in(key, f)) for f in range(n_fields)]).reshape(-1)

    def latent_prior(self, grid: Grid, n_fields: int = 1) -> tuple[str, np.ndarray, np.ndarray]:
        high = np.tile([1.0, 2 * np.pi], self.max_mode * n_fields)
        return "uniform", np.zeros(high.size), high

    def ic_from_latent(self, latent: jax.Array, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        x = jnp.asarray(grid.coords(), jnp.float32)
        latent = jnp.asarray(latent, jnp.float32).reshape(n_fields, self.max_mode, 2)
        return jnp.stack([self._one(jax.random.fold_in(key, f), x, grid.length, latent[f]) for f in range(n_fields)])

    def _one(self, key: jax.Array, x: jax.Array, length: float, amp_phase: jax.Array | None = None) -> jax.Array:
        k_pick, _, _, k_abs, k_sign, k_left, k_right, k_win = jax.random.split(key, 8)
        picks = jax.random.randint(k_pick, (self.n_modes,), 0, self.max_mode)
        amp, phase = (self._amp_phase(key) if amp_phase is None else amp_phase).T
        u = jnp.zeros_like(x)
        for k in range(self.max_mode):  # written out term by term: a reduce may reassociate per batch size
            count = jnp.zeros((), jnp.float32)
            for j in range(self.n_modes):
                count = count + (picks[j] == k).astype(jnp.float32)
            u = u + amp[k] * jnp.sin(2 * jnp.pi * (k + 1) * count * x / length + phase[k])
        u = jnp.where(jax.random.uniform(k_abs) < self.abs_prob, jnp.abs(u), u)
        u = jnp.where(jax.random.uniform(k_sign) < 0.5, u, -u)
        x_l = length * jax.random.uniform(k_left, (), jnp.float32, 0.1, 0.45)
        x_r = length * jax.random.uniform(k_right, (), jnp.float32, 0.55, 0.9)
        w = self.window_width * length
        window = 0.5 * (jnp.tanh((x - x_l) / w) - jnp.tanh((x - x_r) / w))
        u = jnp.where(jax.random.uniform(k_win) < self.window_prob, u * window, u)
        if self.normalise:
            u = u - jnp.min(u)
            u = u / jnp.maximum(jnp.max(u), jnp.finfo(jnp.float32).tiny)
        return u

    def sample(self, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        x = jnp.asarray(grid.coords(), jnp.float32)
        return jnp.stack([self._one(jax.random.fold_in(key, f), x, grid.length) for f in range(n_fields)])

    def bound(self, grid: Grid) -> float:
        return 1.0 if self.normalise else float(self.max_mode)  # |u0| <= sum_k A_k <= max_mode


@dataclass(frozen=True)
class WhiteNoise:
    """Independent N(mean, std^2) values at every grid point of every field (PDEBench's 2D diffusion-reaction IC:
    a standard normal per cell). Not band-limited: a spectral solver starts from its 2/3-rule projection (frame 0),
    which keeps about (2/3)^d of its variance ((floor(2n/3) + 1)^d / n^d on walls: std 0.672 at n = 128, 2D).
    ``pointwise``: on a grid with
    walls it is drawn at the grid's own points, not folded from the doubled box (a fold averages 2^d independent
    draws and would shrink its variance). Not in IC_KINDS: only an entry that lists it (diffusion_reaction2d)
    takes it; on most equations a grid-scale field is not a meaningful start.
    """

    std: float = 1.0
    mean: float = 0.0
    kind = "white"
    field_count = None  # any: one independent draw per PDE field
    pointwise = True

    def check(self, grid: Grid) -> None:
        if not (self.std > 0 and math.isfinite(self.std)):
            raise ValueError(f"ic.std={self.std} not allowed: must be a finite number > 0")
        if not math.isfinite(self.mean):
            raise ValueError(f"ic.mean={self.mean} not allowed: must be a finite number")

    def sample(self, key: jax.Array, grid: Grid, n_fields: int = 1) -> jax.Array:
        return self.mean + self.std * jax.random.normal(key, (n_fields, *grid.shape), jnp.float32)

    def bound(self, grid: Grid) -> float:
        """A practical bound on max|u0|: |mean| + 5 std (exceeded at one of 2^15 points with probability ~2%)."""
        del grid
        return abs(self.mean) + 5.0 * self.std


IC_KINDS: Mapping[str, type] = {"fourier": FourierSeries, "grf": GaussianRandomField, "spots": GrayScottSpots,
                                "sines": RandomSines}


# --- parsing: kind names, dicts and setting values ---------------------------------------------------------
def make_ic(value: Any, kinds: Mapping[str, type] | None = None, listed: list[str] | None = None) -> InitialCondition:
    """An IC distribution from an object, a kind name (defaults) or a dict {"kind": ..., field: ...}; ``kinds``:
    the vocabulary of kind names (default IC_KINDS; a PDE whose input is another kind of field has its own);
    ``listed``: the names a refusal offers (default all of ``kinds``; a PDE offers those that fit its fields)."""
    kinds = IC_KINDS if kinds is None else kinds
    listed = list(kinds) if listed is None else listed
    if isinstance(value, str):
        value = {"kind": value}
    if isinstance(value, Mapping):
        fields = dict(value)
        kind = fields.pop("kind", None)
        if not isinstance(kind, str) or kind not in kinds:
            raise ValueError(f"unknown ic kind {show(kind)}; allowed: {', '.join(listed)}")
        cls = kinds[kind]
        defaults = cls()
        try:
            return cls(**{k: coerce(f"ic.{k}", v, getattr(defaults, k)) for k, v in fields.items()})
        except AttributeError as err:
            raise ValueError(f"ic kind {kind!r}: {err}") from None
    if isinstance(value, InitialCondition):
        return value
    raise ValueError(f"bad ic {show(value)}: expected a kind name ({', '.join(listed)}) or a dict with 'kind'")


def coerce(name: str, value: Any, current: Any) -> Any:
    """Convert a (possibly string) override to the kind of the field's current value, then check it."""
    if isinstance(value, str):
        value = _parse_text(name, value, current)
    return check_value(name, value, current)


def _parse_text(name: str, value: str, current: Any) -> Any:
    """A setting's text (as from ``--set``) as the kind of ``current``: true/false, an integer, a number or None."""
    text = value.strip()
    try:
        if isinstance(current, bool):
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError
            return text.lower() in ("true", "1", "yes")
        if isinstance(current, int):
            return int(text)
        if isinstance(current, float) or current is None:
            return None if text.lower() == "none" else float(text)
    except ValueError:
        raise ValueError(f"bad value for {name}: {value!r} is not {_kind(current)}") from None
    return text


def _kind(default: Any) -> str:
    """What a setting whose default is ``default`` must be, in words."""
    if isinstance(default, bool):
        return "true or false"
    if isinstance(default, int):
        return "an integer"
    if isinstance(default, str):
        return "a name (a string)"
    return "a number" if default is not None else "a number or none"


def check_value(name: str, value: Any, default: Any) -> Any:
    """``value`` as a plain Python scalar of the kind of the field's ``default`` (bool, int, number, name; None
    where the default is None), finite if a number; ValueError naming the setting otherwise."""
    if isinstance(value, np.generic):
        value = value.item()  # numpy scalars become plain values: clean JSON configs and messages
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if number and isinstance(default, str) and math.isfinite(value):
        value, number = str(value), False  # a domain text ("uniform(1, 2)") given from Python as a fixed number
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = number or (value is None and default is None)
    if not ok:
        raise ValueError(f"bad value for {name}: {show(value)} is not {_kind(default)}")
    if number and not math.isfinite(value):
        raise ValueError(f"{name}={value} not allowed: must be a finite number")
    return value


def show(value: Any) -> str:
    """repr for messages, without numpy's wrappers (np.float64(0.1) -> 0.1)."""
    return repr(value.item() if isinstance(value, np.generic) else value)
