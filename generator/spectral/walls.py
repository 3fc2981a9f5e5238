"""Boundary conditions for the spectral family: the ``bc`` setting, and the entry classes it makes.

``get_pde("burgers1d", bc="dirichlet")`` (or ``--set bc=dirichlet``, ``--set bc.x=neumann``) returns an instance
of the entry's class specialised to those walls: its grid is a ``generator.bounded.BoundedGrid`` (sine bases on
Dirichlet axes, cosine on Neumann ones, Fourier on periodic ones); its configuration gains ``bc`` and, for a
one-field PDE with a Dirichlet axis, the boundary values ``bc_lo`` / ``bc_hi`` as random parameters like any
other (u = bc_lo on the wall x = 0 of the first Dirichlet axis, bc_hi on x = length; any other Dirichlet walls
carry the straight line between them). With every axis periodic (the default) the entry is its periodic class,
unchanged: same configuration, hash and samples.

How the equation is solved on walls: the class supplies ``wall_terms`` (its non-diagonal part in physical space,
written once on the grid's ``gradient``; None for a PDE with no such part) and ``lift_rate`` (the constant part
of its linear operator); the linear part is its usual diagonal operator (``wall_linear``), now in the sine /
cosine eigenvalues. Non-zero boundary values use a lifting u = w + g with g the affine profile above: Laplacian(g)
= 0, so w has homogeneous walls and obeys the same equation with L g = lift_rate * g and the nonlinear term
evaluated at w + g. The initial condition is the entry's distribution drawn on the periodic box of twice the
side and folded: its odd part about the walls on a Dirichlet axis, its even part on a Neumann axis, the sum of
its two halves on a periodic axis; so it satisfies the walls exactly and keeps the distribution's band limit.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Mapping

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ... import boundaries
from ..domains import Fixed
from ..problem import Param
from .bounded import AXES, BoundedGrid
from .fourier import Grid

LIFT_PARAMS = {
    "bc_lo": Param("value of u on the wall x = 0 of the first Dirichlet axis", "field units"),
    "bc_hi": Param("value of u on the wall x = length of the first Dirichlet axis", "field units"),
}


def parse_bc(pde, spec: Mapping[str, Any], current: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """The per-axis boundary conditions after applying ``spec`` ({"bc": "dirichlet" | "x=dirichlet,y=periodic" |
    {"x": ...}, "bc.x": "neumann", ...}) to those of ``pde``; ValueError naming a bad value and what is allowed."""
    now = current or getattr(pde, "BCS", None)
    return boundaries.parse(spec, pde.NDIM, allowed=pde.BOUNDARIES, current=now, name=pde.NAME)


def bc_text(bcs: tuple[str, ...]) -> str:
    """The canonical ``bc`` setting: one word when every axis has it, else 'x=dirichlet,y=periodic'."""
    return boundaries.text(bcs)


def with_bc(pde, spec: Mapping[str, Any]):
    """``pde`` with its boundary conditions changed by ``spec`` (see parse_bc): an instance of the entry's
    periodic class, or of its class for those walls (``wall_class``); other settings are kept."""
    bcs = parse_bc(pde, spec)
    base = getattr(type(pde), "PERIODIC", type(pde))
    fields = {f.name: getattr(pde, f.name) for f in dataclasses.fields(base)}
    if boundaries.all_periodic(bcs):
        return base(**fields)
    cls = wall_class(base, bcs)
    lifted = {k: getattr(pde, k) for k in LIFT_PARAMS if k in cls.PARAMS and hasattr(pde, k)}
    return cls(**fields, **lifted)


@functools.lru_cache(maxsize=None)
def wall_class(base: type, bcs: tuple[str, ...]) -> type:
    """The entry class ``base`` specialised to boundary conditions ``bcs`` (created once per pair)."""
    lifts = boundaries.pins_value(bcs) and len(base.FIELDS) == 1
    params = {**base.PARAMS, **(LIFT_PARAMS if lifts else {})}
    annotations = {"bc": str, **({k: Any for k in LIFT_PARAMS} if lifts else {})}
    name = f"{base.__name__}_{'_'.join(b[0] for b in bcs)}"  # e.g. Burgers1D_d, Diffusion2D_n_p
    namespace = {"BCS": bcs, "PERIODIC": base, "PARAMS": params, "__annotations__": annotations,
                 "bc": bc_text(bcs), **({k: Fixed(0.0) for k in LIFT_PARAMS} if lifts else {}),
                 "__module__": __name__, "__qualname__": name, "__doc__": base.__doc__}
    return dataclasses.dataclass(frozen=True)(type(name, (Walls, base), namespace))


def rebuild(base: type, bcs: tuple[str, ...], fields: dict):
    """Unpickling a walled entry: its class made again from (periodic class, bcs), then the instance."""
    return wall_class(base, bcs)(**fields)


def fold(u: jax.Array, bcs: tuple[str, ...], n: int) -> jax.Array:
    """A field drawn on the periodic box of twice the side, [C, *(2n,)], folded to [C, *(n,)] on walls ``bcs``: its
    odd part about the walls on a Dirichlet axis (a sine series), its even part on a Neumann axis (a cosine
    series), the mean of its two halves on a periodic axis (L-periodic). Band limits and means carry over."""
    for axis, bc in enumerate(boundaries.kinds(bcs)):
        a = axis + 1  # the field axis comes first
        first = jax.lax.slice_in_dim(u, 0, n, axis=a)
        if bc.periodic:  # the two halves of a 2L-periodic field sum to an L-periodic one
            u = 0.5 * (first + jax.lax.slice_in_dim(u, n, 2 * n, axis=a))
        else:  # the mirror image about x = 0 of point j is point 2n-1-j (points at cell centres)
            mirror = jax.lax.slice_in_dim(jnp.flip(u, a), 0, n, axis=a)
            u = 0.5 * (first - mirror) if bc.pins_value else 0.5 * (first + mirror)
    return u


class WallGrid:
    """What every problem on walls shares (the walled spectral entries, poisson, helmholtz): its grid from its
    per-axis ``BCS``, the doubled periodic box its random fields are drawn on (then ``fold``-ed), and the check
    of that distribution."""

    BCS: tuple[str, ...]

    @property
    def grid(self) -> BoundedGrid:
        return BoundedGrid(self.NDIM, self.n, self.length, self.BCS)

    @property
    def box(self) -> Grid:
        """The periodic box of twice the side and points on which the initial condition is drawn."""
        return Grid(self.NDIM, 2 * self.n, 2 * self.length)

    def _check_ic_on_grid(self) -> None:
        """The IC's rules on the doubled box it is drawn on; on Dirichlet walls its constant part is refused (the
        folded draw is odd about the walls, so an offset or mean would be silently dropped: bc_lo/bc_hi set values)."""
        try:
            self.ic.check(self.box)
        except ValueError as err:
            raise ValueError(f"{self.NAME}: {err}") from None
        if boundaries.pins_value(self.BCS):
            for name in ("offset", "mean"):
                value = getattr(self.ic, name, 0.0)
                if value:
                    values = " (set the wall values with bc_lo, bc_hi)" if "bc_lo" in self.PARAMS else ""
                    raise ValueError(f"{self.NAME}: ic.{name}={value:g} not allowed on Dirichlet walls: the field is "
                                     f"drawn odd about them (0 there); allowed: ic.{name}=0{values}")


class Walls(WallGrid):
    """The methods of a walled entry class (first in its bases: they take over from the periodic class's)."""

    PERIODIC: type

    def __reduce__(self):
        return rebuild, (self.PERIODIC, self.BCS, {f.name: getattr(self, f.name) for f in dataclasses.fields(self)})

    def sample_ic(self, key: jax.Array, p=None, latent=None) -> jax.Array:
        """One initial condition float32 [C, *space] satisfying the walls (the folded draw, its latent set to
        ``latent`` [L] where given), plus the lifting."""
        if getattr(self.ic, "pointwise", False):  # i.i.d. per point (white noise): drawn where it lives, unfolded
            u = self._draw_ic(key, self.grid, latent)
        else:
            u = fold(self._draw_ic(key, self.box, latent), self.BCS, self.n)
        return u if p is None or "bc_lo" not in self.PARAMS else u + self.lift(p)[None]

    @property
    def ic_grid(self):
        return self.box  # the IC is drawn on the periodic box, then folded

    # --- the lifting of Dirichlet values ----------------------------------------------------------------
    def _lift_axis(self) -> int:
        return boundaries.first_pinned(self.BCS)

    def lift(self, p) -> jax.Array:
        """g [*space]: bc_lo + (bc_hi - bc_lo) x / length along the first Dirichlet axis (0 without values)."""
        if "bc_lo" not in self.PARAMS:
            return jnp.zeros(self.grid.shape, jnp.float32)
        axis = self._lift_axis()
        x = self.grid.coords(axis) / self.length
        shape = [1] * self.NDIM
        shape[axis] = -1
        return p["bc_lo"] + (p["bc_hi"] - p["bc_lo"]) * jnp.asarray(x.reshape(shape))

    def lift_slope(self, p, axis: int):
        """d g / d x_axis (a scalar)."""
        if "bc_lo" not in self.PARAMS or axis != self._lift_axis():
            return 0.0
        return (p["bc_hi"] - p["bc_lo"]) / self.length

    def state_basis(self, grid, p):
        """With boundary values: the state is w = u - g, band-limited (to_state masks it), and a frame is w + g."""
        if "bc_lo" not in self.PARAMS:
            return None
        g_hat = grid.rfft(self.lift(p)[None])
        mask = grid.dealias_mask()
        return (lambda v: mask * (v - g_hat)), (lambda v: v + g_hat)

    # --- the equation on walls --------------------------------------------------------------------------
    def linear(self, grid, p):
        own = self.wall_linear(grid, p)
        return super().linear(grid, p) if own is None else own

    def stable_dt(self):
        own = self.wall_stable_dt()
        return super().stable_dt() if own is None else own

    def nonlinear(self, grid, p):
        terms = self.wall_terms(grid, p)
        rate = self.lift_rate(p) if "bc_lo" in self.PARAMS else 0.0
        rate_h = self.damping_rate()
        damping = wall_hermitian_damping(grid, rate_h) if rate_h else None
        flux = self.wall_flux(grid, p)  # a conservative part, -div F(u), differentiated in coefficient space
        physical = terms is not None or not (isinstance(rate, float) and rate == 0.0)
        if not physical and flux is None and damping is None:
            return None  # no explicit part (diffusion: L g = 0 for the affine lifting g)
        g = self.lift(p)[None]
        keep = None
        if self.wall_drops_mean(grid) and not boundaries.pins_value(grid.bc):  # a constant mode exists: index 0 on all axes
            keep = np.ones(grid.kshape, np.float32)
            keep[(0,) * grid.ndim] = 0.0

        def nonlinear(v):
            u = grid.irfft(v) + g

            def grad(axis):
                return grid.gradient(v, axis) + self.lift_slope(p, axis)

            out = None
            if physical:  # the part formed in physical space (skipped when a flux is all there is: no wasted transform)
                out = (0.0 if terms is None else terms(u, grad)) + rate * g
                out = grid.rfft(jnp.broadcast_to(out, u.shape).astype(u.dtype))
            if flux is not None:
                div = sum(grid.derivative_of(f, axis) for axis, f in enumerate(flux(u)))
                out = -div if out is None else out - div
            out = out if keep is None else keep * out
            return out if damping is None else out + damping(v)

        return nonlinear

    def describe_setup(self) -> str:
        text = super().describe_setup()
        if "bc_lo" in self.PARAMS:
            axis = AXES[self._lift_axis()]
            text += f"\n  walls: u = bc_lo on {axis} = 0, bc_hi on {axis} = {self.length:g} (lifted: affine in {axis})"
        return text


def wall_hermitian_damping(grid: BoundedGrid, rate):
    """``terms.hermitian_damping`` on a grid with walls: the anti-Hermitian part of the plane where the last
    periodic axis has mode 0, mirrored over the other periodic axes only (a wall axis has real coefficients).
    None when no axis is periodic (the state is real: nothing to damp)."""
    periodic = grid.periodic_axes
    if not periodic:
        return None
    last = periodic[-1] - grid.ndim  # the rfft axis

    def term(v):
        plane = jax.lax.index_in_dim(v, 0, axis=v.ndim + last, keepdims=True)
        mirror = plane
        for axis in periodic[:-1]:
            a = axis - grid.ndim
            mirror = jnp.roll(jnp.flip(mirror, a), 1, a)
        anti = (plane - jnp.conj(mirror)) * (-0.5 * rate)
        rest = jax.lax.slice_in_dim(v, 1, v.shape[last], axis=v.ndim + last)
        return jnp.concatenate([anti, jnp.zeros_like(rest)], axis=last)

    return term
