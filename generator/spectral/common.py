"""Pieces shared by several PDE definitions."""

from __future__ import annotations

from pdestream.generator.lazy_jax import jnp

from .base import Param
from .fourier import cmul

# Advective CFL number for ETDRK4 with a spectral derivative: RK4's imaginary-axis limit 2.83 over the
# largest dealiased wavenumber (2 pi/L)(n/3) gives dt <= 1.35 dx / max|u|; 1.0 keeps a margin.
CFL = 1.0

AXES = ("x", "y", "z")


def velocity_params(ndim: int, what: str, equation: str, extra: dict | None = None) -> dict:
    """Class attributes of a PDE with a random constant velocity: ``c`` in 1D, ``c_x, c_y(, c_z)`` in 2D/3D.

    Returns {"PARAMS", "UNUSED", "EQUATION"} for ``PDE.for_dimension``; ``extra`` params follow the velocity.
    (1D keeps the name ``c`` of the original advection1d, so its configurations and samples are unchanged.)
    """
    names = ["c"] if ndim == 1 else [f"c_{a}" for a in AXES[:ndim]]
    params = {n: Param(f"{what} speed" if ndim == 1 else f"{what} velocity along {n[-1]}", "length/time") for n in names}
    unused = {"c", "c_x", "c_y", "c_z"} - set(names)
    return {"PARAMS": {**params, **(extra or {})}, "UNUSED": frozenset(unused), "EQUATION": equation}


def drift(grid, p, ndim: int):
    """Symbol of -c . grad, -i (c . k): complex64, broadcastable to kshape (c from ``velocity_params`` names)."""
    ks = grid.wavenumbers()
    if ndim == 1:
        return (-1j * p["c"] * ks[0]).astype(jnp.complex64)
    dot = sum(p[f"c_{a}"] * k for a, k in zip(AXES, ks))  # written out: a per-axis sum, no reduction
    return (-1j * dot).astype(jnp.complex64)


def conservative_quadratic(grid, coefficient: float | jnp.ndarray):
    """N(v) = coefficient * d/dx (u^2) in Fourier space, 1D: v [C, kshape] -> [C, kshape].

    One irfft and one rfft per call; the product is dealiased by the solver's 2/3 mask on the output.
    """
    (k,) = grid.wavenumbers()
    factor = (1j * k * coefficient).astype(jnp.complex64)

    def nonlinear(v):
        u = grid.irfft(v)
        return cmul(factor, grid.rfft(u * u))

    return nonlinear
