"""Pieces shared by several PDE definitions."""

import jax.numpy as jnp

from ..spectral import cmul

# Advective CFL number for ETDRK4 with a spectral derivative: RK4's imaginary-axis limit 2.83 over the
# largest dealiased wavenumber (2 pi/L)(n/3) gives dt <= 1.35 dx / max|u|; 1.0 keeps a margin.
CFL = 1.0


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
