"""The wave equation in 1D/2D, u_tt = c^2 Laplacian(u), as the first-order system (u, v = u_t) solved in
spectral form: per Fourier mode, exactly, in the variables that diagonalise it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ..domains import Uniform
from ..ics import FourierSeries
from .base import LinearPDE, Param


def _times_i(v: jax.Array) -> jax.Array:
    """i v, exactly, in real arithmetic (no complex multiply: batch-invariant bits)."""
    return jax.lax.complex(-v.imag, v.real)


@dataclass(frozen=True)
class Wave(LinearPDE):
    """Periodic wave equation on the unit box; fields u (displacement) and v = u_t (velocity).

    As a system, u_t = v, v_t = c^2 Laplacian(u). Per mode k with omega = c |k|, the variables
    s+ = v_hat + i omega u_hat and s- = v_hat - i omega u_hat evolve as exp(+-i omega t): ``state_basis`` maps
    (u_hat, v_hat) to (s+, s-) and back, and ``linear`` is diag(i omega, -i omega), so each step is the exact
    exponential (no step limit) and the energy (1/2) integral of v^2 + c^2 |grad u|^2 is conserved.
    The k = 0 mode: mean(u) is carried unchanged and mean(v) must be zero (a net velocity would make mean(u)
    grow without bound), so initial conditions with a mean (ic.offset, ic.mean, ic.zero_mean=false) are refused
    and v's mean mode is dropped from a caller's u0 in ``solve``.
    c ~ uniform(0.25, 1) length/time: a wave crosses the unit box 0.25..1 times by t = 1. Both fields start from
    independent 5-mode Fourier series of peak 1, resolved on the default grids (128, 64^2).
    """

    EQUATION: ClassVar[str] = "u_t = v;  v_t = c^2 u_xx"
    FIELDS: ClassVar[tuple] = ("u", "v")
    FIELD_UNITS: ClassVar[dict] = {"u": "1", "v": "1/time"}  # v = u_t
    PARAMS: ClassVar[dict] = {"c": Param("wave speed", "length/time", positive=True)}
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64}}

    n: int = 128
    length: float = 1.0
    t_end: float = 1.0
    n_frames: int = 51
    ic: Any = FourierSeries(max_mode=5, decay=1.0, amplitude=1.0)
    c: Any = Uniform(0.25, 1.0)

    @classmethod
    def for_dimension(cls, ndim):
        return {"EQUATION": "u_t = v;  v_t = c^2 u_xx" if ndim == 1 else "u_t = v;  v_t = c^2 Laplacian(u)"}

    def check_settings(self):
        for name, zero in (("offset", 0.0), ("mean", 0.0), ("zero_mean", True)):
            value = getattr(self.ic, name, zero)
            if value != zero:
                raise ValueError(f"{self.NAME}: ic.{name}={value} not allowed: the wave's fields start with zero mean "
                                 f"(a mean velocity makes mean(u) grow without bound); allowed: {zero}")

    def _omega(self, grid, p):
        """c |k|, float32 broadcastable to kshape (traced through c)."""
        return p["c"] * np.sqrt(-grid.laplacian()).astype(np.float32)

    def linear(self, grid, p):
        i_omega = _times_i(jnp.asarray(self._omega(grid, p), jnp.complex64))
        return jnp.stack([i_omega, -i_omega])

    def state_basis(self, grid, p):
        omega = self._omega(grid, p)
        mean = np.zeros(grid.kshape, bool)
        mean[(0,) * grid.ndim] = True
        inv_omega = jnp.where(mean, 0.0, 1.0 / jnp.where(mean, 1.0, omega))

        def to_state(w):  # (u_hat, v_hat) -> (s+, s-); at k = 0: (mean u, 0)
            u_hat, v_hat = w[0], jnp.where(mean, 0, w[1])
            i_omega_u = _times_i(omega * u_hat)
            return jnp.stack([jnp.where(mean, u_hat, v_hat + i_omega_u), v_hat - i_omega_u])

        def from_state(s):  # (s+, s-) -> (u_hat, v_hat)
            plus, minus = s[0], s[1]
            u_hat = jnp.where(mean, plus, -_times_i(0.5 * inv_omega * (plus - minus)))
            v_hat = jnp.where(mean, 0, 0.5 * (plus + minus))
            return jnp.stack([u_hat, v_hat])

        return to_state, from_state
