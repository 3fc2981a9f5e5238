"""Steady Poisson and Helmholtz problems with walls: a random source in, the field out.

    poisson:    -Laplacian(u) = f
    helmholtz:  -Laplacian(u) - k^2 u = f

on [0, length]^d (1D or 2D), each axis Dirichlet, Neumann or periodic (``bc``, as for the spectral entries).
The source f is the IC distribution (a Gaussian random field by default) drawn on the periodic box of twice the
side and folded to the walls (generator.pdes.walls.fold), so it is a sine / cosine / Fourier series like u; the
solve is direct in that basis, u_m = f_m / (|kappa_m|^2 - k^2), on cell centres (generator.bounded): exact for the
series, spectrally accurate for smooth data. Dirichlet values (bc_lo on x = 0, bc_hi on x = length of the first
Dirichlet axis, any other Dirichlet walls carrying the line between them) by the affine lifting g: -Laplacian(g) =
0, so w = u - g solves the same problem with source f + k^2 g.

Refused in one line: boundary values without a Dirichlet axis; a Poisson problem whose walls are all Neumann or
periodic (its constant mode has no equation) with a source whose mean is not zero (no solution exists); a
Helmholtz k domain that comes within RESONANCE_GAP of an eigenvalue of the walls' Laplacian (the operator is
singular there). With all-Neumann/periodic walls Poisson's constant mode is set to 0 (u has mean 0).
A sample is (f [1, *space], u [1, *space]), no time axis.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ... import boundaries
from ..chunked import chunked_map
from ..domains import Fixed, Uniform
from ..ics import FourierSeries, GaussianRandomField
from ..problem import Param, resolve_params
from ..spectral.bounded import AXES
from ..spectral.walls import LIFT_PARAMS, WallGrid, fold, parse_bc
from .base import SteadyProblem

CHUNK = 8  # samples per compiled call (generator.chunked)
RESONANCE_GAP = 0.02  # |kappa^2 - k^2| >= gap * (pi / length)^2 for every eigenvalue kappa^2 of the walls


@dataclass(frozen=True)
class Poisson(WallGrid, SteadyProblem):
    """-Laplacian(u) = f with a random source f and walls per axis (``bc``); see the module docstring."""

    EQUATION: ClassVar[str] = "-Laplacian(u) = f"
    FIELDS: ClassVar[tuple] = ("u",)
    INPUTS: ClassVar[tuple] = ("f",)
    FIELD_UNITS: ClassVar[dict] = {"f": "1/length^2", "u": "1"}  # f = -Laplacian(u) (or with + k^2 u)
    IC_KINDS: ClassVar[dict] = {"grf": GaussianRandomField, "fourier": FourierSeries}
    IC_LABEL: ClassVar[str] = "source f"
    BOUNDARIES: ClassVar[tuple] = ("dirichlet", "neumann", "periodic")
    PARAMS: ClassVar[dict] = dict(LIFT_PARAMS)
    DIMENSIONS: ClassVar[dict] = {1: {}, 2: {"n": 64}}
    MIN_NODES: ClassVar[int] = 8
    SHIFTED: ClassVar[bool] = False  # a -k^2 u term (Helmholtz): the constant mode then has an equation

    n: int = 128  # cells per axis (points at their centres)
    length: float = 1.0
    bc: str = "dirichlet"
    ic: Any = GaussianRandomField(sigma=100.0, tau=5.0, alpha=2.0)
    bc_lo: Any = Fixed(0.0)
    bc_hi: Any = Fixed(0.0)

    @property
    def BCS(self) -> tuple[str, ...]:  # noqa: N802 (the walls, as the spectral family's walled classes name them)
        return parse_bc(self, {"bc": self.bc}, current=boundaries.periodic_words(self.NDIM))

    def k2(self, p) -> jax.Array:
        """The Helmholtz shift k^2 (0 for Poisson)."""
        return jnp.float32(0.0)

    def check_settings(self) -> None:
        object.__setattr__(self, "bc", _canonical(self.BCS))
        if self.n % 2:
            raise ValueError(f"{self.NAME}: n={self.n} not allowed: cells per axis must be even")
        if not boundaries.pins_value(self.BCS):
            for name in ("bc_lo", "bc_hi"):
                if getattr(self, name).bounds != (0.0, 0.0):
                    raise ValueError(f"{self.NAME}: {name}={getattr(self, name)} not allowed: no axis is Dirichlet "
                                     f"(bc={self.bc}); wall values need bc=dirichlet on an axis")
        constant_mode = not boundaries.pins_value(self.BCS)
        mean = getattr(self.ic, "mean", 0.0) if getattr(self.ic, "zero_mean", True) else None
        mean = getattr(self.ic, "offset", mean)
        if constant_mode and not self.SHIFTED and mean != 0.0:
            raise ValueError(f"{self.NAME}: a Neumann/periodic problem whose source has a nonzero mean has no solution "
                             f"(the integral of f must equal the zero wall flux); allowed: a source of mean 0 "
                             f"(ic.mean=0 with ic.zero_mean=true, or ic.offset=0), or bc=dirichlet on an axis")

    def describe_solver(self) -> str:
        walls = ", ".join(f"{AXES[a]} {b}" for a, b in enumerate(self.BCS))
        return f"direct solve in the walls' sine/cosine/Fourier basis ({walls})"

    def failure(self) -> tuple[str, str]:
        return ("solves gave NaN/Inf", "a source of smaller magnitude or a k farther from the eigenvalues avoids this")

    def lift(self, p) -> jax.Array:
        """g [*space]: bc_lo + (bc_hi - bc_lo) x / length along the first Dirichlet axis (0 without one)."""
        if not boundaries.pins_value(self.BCS):
            return jnp.zeros(self.grid.shape, jnp.float32)
        axis = boundaries.first_pinned(self.BCS)
        shape = [1] * self.NDIM
        shape[axis] = -1
        x = jnp.asarray((self.grid.coords(axis) / self.length).reshape(shape))
        return p["bc_lo"] + (p["bc_hi"] - p["bc_lo"]) * x

    def solve_one(self, f: jax.Array, p) -> jax.Array:
        """u [*space] from the source f [*space] and the parameters p (traced scalars)."""
        grid, k2 = self.grid, self.k2(p)
        g = self.lift(p)
        rhs = grid.rfft(f + k2 * g)
        denom = -jnp.asarray(grid.laplacian()) - k2  # |kappa|^2 - k^2
        if not boundaries.pins_value(self.BCS) and not self.SHIFTED:
            denom = denom.at[(0,) * self.NDIM].set(1.0)  # the constant mode: u's mean is set to 0 below
            keep = np.ones(grid.kshape, np.float32)
            keep[(0,) * self.NDIM] = 0.0
            rhs = rhs * keep
        if jnp.iscomplexobj(rhs):  # real divisions: a complex one rounds differently vectorised and not
            w = jax.lax.complex(rhs.real / denom, rhs.imag / denom)
        else:
            w = rhs / denom
        return grid.irfft(w) + g

    def _draw(self, key, explicit, given):
        k_param, k_source = jax.random.split(key)
        p = resolve_params(self, k_param, explicit, given)
        f = fold(self.ic.sample(k_source, self.box, 1), self.BCS, self.n)[0]
        u = self.solve_one(f, p)
        return p, f, u, jnp.all(jnp.isfinite(u))

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """keys [B] -> (u [B, 1, *space], params {name: [B]}, finite [B], inputs f [B, 1, *space])."""
        p, f, u, ok = chunked_map(_compiled(self), CHUNK, keys, explicit, given, report=True)
        return u[:, None], p, ok, f[:, None]


@dataclass(frozen=True)
class Helmholtz(Poisson):
    """-Laplacian(u) - k^2 u = f with a random wavenumber k and source f; refused near a resonance."""

    EQUATION: ClassVar[str] = "-Laplacian(u) - k^2 u = f"
    SHIFTED: ClassVar[bool] = True
    PARAMS: ClassVar[dict] = {"k": Param("wavenumber", "1/length", positive=True), **LIFT_PARAMS}

    k: Any = Uniform(0.5, 2.5)

    def k2(self, p) -> jax.Array:
        return p["k"] * p["k"]

    def check_settings(self) -> None:
        super().check_settings()
        eigen = -np.asarray(self.grid.laplacian(), np.float64).ravel()
        lo, hi = (b * b for b in self.k.bounds)
        gap = RESONANCE_GAP * (math.pi / self.length) ** 2
        near = eigen[(eigen > lo - gap) & (eigen < hi + gap)]
        if near.size:
            nearest = float(near[np.argmin(np.abs(near - 0.5 * (lo + hi)))])
            raise ValueError(f"{self.NAME}: k={self.k} not allowed: k^2 comes within {gap:.3g} of the eigenvalue "
                             f"{nearest:.4g} (k = {math.sqrt(nearest):.4g}) of -Laplacian on these walls, where the "
                             "problem is singular; allowed: a k domain clear of the eigenvalues")


def _canonical(bcs: tuple[str, ...]) -> str:
    return bcs[0] if len(set(bcs)) == 1 else ",".join(f"{AXES[a]}={b}" for a, b in enumerate(bcs))


@functools.lru_cache(maxsize=32)
def _compiled(pde: Poisson):
    """jit of (keys [K], explicit [K, P], given [K, P]) -> (params, f [K, *space], u [K, *space], finite [K]), one
    key per loop iteration (a fixed program per chunk: the bits of a sample do not depend on its batch)."""
    return jax.jit(lambda keys, explicit, given: jax.lax.map(lambda a: pde._draw(*a), (keys, explicit, given)))
