"""The spectral time-dependent family: a PDE ``v_t = L v + N(v)`` on a periodic grid, solved by ETDRK4.

A PDE is a frozen dataclass (a ``generator.problem.ProblemBase``: settings, parameter domains, IC, config).
A subclass must supply ``linear`` (diagonal operator L), ``nonlinear`` (N, or None) in Fourier space, and
``stable_dt`` (abstract: a class missing one cannot be built). ``LinearPDE`` supplies the last two for PDEs
whose step is the exact exponential. The rollouts themselves are ``generator.rollout``'s.

One class may serve several dimensions (diffusion in 1D/2D/3D): it lists them in ``DIMENSIONS`` with
the setting defaults each one changes, and ``for_dimension`` gives the class attributes that depend on
the dimension. The catalog (generator.catalog) makes one entry per dimension, named with it.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import numpy as np

from pdestream.catalog_names import NAMES
from pdestream.generator.lazy_jax import jax, jnp

from ..ics import LatentIC
from ..problem import MAX_IC_BOUND, MAX_STEPS, Param, ProblemBase, check_refine, check_solve_grid
from . import rollout
from .fourier import Grid
from .walls import with_bc

__all__ = ["LinearPDE", "PDE", "Param", "check_operators"]


@dataclass(frozen=True)
class PDE(ProblemBase):
    """Base configuration shared by every spectral PDE (subclasses set their own defaults)."""

    n: int = 128  # grid points per dimension
    length: float = 1.0  # domain [0, length)^ndim
    t_end: float = 1.0  # final time; frames are saved at linspace(t_start, t_end, n_frames)
    n_frames: int = 51  # saved frames including the first, at t = t_start
    dt: float | None = None  # internal step; None: the largest stable step that divides a frame interval
    t_start: float = 0.0  # a burn-in from the IC at t = 0, not recorded (chaotic entries: frames on the attractor)
    refine: int = 1  # solve on n * refine points per axis and keep every refine-th (a set published that way)

    # --- what subclasses provide -------------------------------------------------------------------
    @abc.abstractmethod
    def linear(self, grid: Grid, p: Mapping[str, jax.Array]) -> jax.Array:
        """Diagonal operator L, [C, *kshape] (real or complex); p holds one traced scalar per parameter."""

    @abc.abstractmethod
    def nonlinear(self, grid: Grid, p: Mapping[str, jax.Array]) -> Callable[[jax.Array], jax.Array] | None:
        """N(v_hat) as a function of the Fourier state [C, *kshape], or None for a linear PDE."""

    @abc.abstractmethod
    def stable_dt(self) -> float:
        """Largest internal step (time units) that is stable for every parameter in the domain."""

    def state_basis(self, grid: Grid, p: Mapping[str, jax.Array]):
        """(to_state, from_state): maps between the Fourier transforms of the fields [C, *kshape] and the
        variables in which ``linear`` is diagonal, or None when those are the fields themselves (all PDEs but
        a few linear systems such as the wave equation)."""
        return None

    def sample_ic(self, key: jax.Array, p: Mapping[str, jax.Array] | None = None, latent: jax.Array | None = None
                  ) -> jax.Array:
        """One initial condition, float32 [C, *space] (p: the sample's parameters, for ICs that depend on them;
        latent: float32 [L], the IC's latent coordinates (``latent_size``), None: the key's own). With ``refine``:
        the solve grid's draw, every refine-th point kept."""
        if self.refine > 1:
            return self.keep_points(self.solved.sample_ic(key, p, latent))
        return self._draw_ic(key, self.grid, latent)

    def _draw_ic(self, key: jax.Array, grid, latent: jax.Array | None) -> jax.Array:
        """The IC distribution's draw on ``grid`` from ``key``, its latent set to ``latent`` where given."""
        if latent is None:
            return self.ic.sample(key, grid, len(self.FIELDS))
        return self.ic.ic_from_latent(latent, key, grid, len(self.FIELDS))

    @property
    def ic_grid(self) -> Grid:
        """The grid the IC is drawn on (the periodic box of a walled entry; the solve grid with ``refine``)."""
        return self.solved.grid if self.refine > 1 else self.grid

    @functools.cached_property
    def solved(self) -> "PDE":
        """The problem the solver runs: this one on n * refine points per axis (``refine`` 1: itself). Its samples,
        every refine-th point kept, are this problem's."""
        if self.refine == 1:
            return self
        return dataclasses.replace(self, n=self.n * self.refine, refine=1)

    def latent_size(self) -> int:
        """L: the steerable coordinates of this entry's IC (``generator.ics.LatentIC``), 0 if it has none."""
        return self.ic.latent_size(self.ic_grid, len(self.FIELDS)) if isinstance(self.ic, LatentIC) else 0

    def latent_from_key(self, key: jax.Array) -> jax.Array:
        """The IC latent float32 [L] that an IC key draws."""
        return self.ic.latent_from_key(key, self.ic_grid, len(self.FIELDS))

    def latent_prior(self) -> tuple[str, np.ndarray, np.ndarray]:
        """The law of each latent coordinate (``LatentIC.latent_prior``)."""
        return self.ic.latent_prior(self.ic_grid, len(self.FIELDS))

    # --- walls (generator.pdes.walls): what a class that takes `bc` beyond periodic declares ---------------
    BOUNDARIES: ClassVar[tuple[str, ...]] = ("periodic",)  # the bc values this class supports

    def wall_linear(self, grid, p):
        """The diagonal operator on a grid with walls, or None when ``linear`` already is (a Laplacian polynomial)."""
        return None

    def wall_terms(self, grid, p):
        """The non-diagonal part on walls as f(u, grad) -> [C, *space] in physical space (u [C, *space] and
        grad(axis) -> du/dx_axis), or None when there is none."""
        return None

    def wall_flux(self, grid, p):
        """A conservative part of the explicit term on walls, -div F(u): F as u [C, *space] -> one flux [C, *space]
        per axis (each differentiated in coefficient space: one transform fewer than forming grad u), or None."""
        return None

    def lift_rate(self, p) -> float:
        """The constant part of the linear operator (L applied to an affine lifting g is lift_rate * g)."""
        return 0.0

    def damping_rate(self) -> float:
        """Rate of the Hermitian-part damping a growing linear part needs on a grid with a periodic axis (0: none)."""
        return 0.0

    def wall_drops_mean(self, grid) -> bool:
        """Whether the explicit part's constant mode is dropped on walls (where the basis has one: no Dirichlet axis)."""
        return False

    def wall_stable_dt(self):
        """The stable step on walls, or None when ``stable_dt`` holds there too."""
        return None

    def replace(self, overrides: Mapping[str, Any] | None = None, **kwargs) -> "PDE":
        """``ProblemBase.replace``, plus ``bc`` (all axes, or 'x=dirichlet,y=periodic') and ``bc.x`` (one axis):
        those make the entry's class for the walls asked (generator.pdes.walls), then the rest is applied."""
        changes = {**(overrides or {}), **kwargs}
        walls = {k: v for k, v in changes.items() if k == "bc" or k.startswith("bc.")}
        if not walls:
            return super().replace(changes)
        rest = {k: v for k, v in changes.items() if k not in walls}
        walled = with_bc(self, walls)
        return walled.replace(rest) if rest else walled

    # --- the problem protocol ----------------------------------------------------------------------
    @property
    def grid(self) -> Grid:
        return Grid(self.NDIM, self.n, self.length)

    def times(self) -> np.ndarray:
        """Frame times, float32 [n_frames]: linspace(t_start, t_end, n_frames)."""
        return np.linspace(self.t_start, self.t_end, self.n_frames).astype(np.float32)

    def config(self) -> dict:
        """``ProblemBase.config``; ``t_start`` only when there is a burn-in and ``refine`` only above 1, so the
        configs and hashes of every cache and run written before those settings existed are unchanged."""
        out = super().config()
        if not self.t_start:
            out.pop("t_start", None)
        if self.refine == 1:
            out.pop("refine", None)
        return out

    def keep_points(self, u: jax.Array) -> jax.Array:
        """Fields [..., *solve shape] of ``solved`` -> every refine-th point per axis, [..., *shape]."""
        r = self.refine
        return u[(Ellipsis, *(slice(None, None, r),) * self.NDIM)] if r > 1 else u

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray, latent=None):
        """Solve one sample per key [B] (explicit float32 [B, P] parameter values where given bool [B, P]; latent:
        None, or (float32 [B, L] IC latents, bool [B] where given)): (u [B, T, C, *space], params {name: [B]},
        ok bool [B] (finite), inputs None). ETDRK4 rollouts (with ``refine``: on the finer grid, points kept)."""
        if self.refine > 1:
            u, params, ok = rollout.run_keys(self.solved, keys, explicit, given, latent)
            return self.keep_points(u), params, ok, None
        return (*rollout.run_keys(self, keys, explicit, given, latent), None)

    def evolve(self, u0: jax.Array, p: Mapping[str, jax.Array]):
        """A caller's initial conditions u0 [B, C, *space], params {name: [B]} -> (u [B, T, C, *space], finite [B]).
        With ``refine``, u0 is interpolated (trigonometrically, every mode kept) onto the solve grid first."""
        if self.refine > 1:
            u, finite = rollout.evolve_from(self.solved, self.grid.interpolate(u0, self.refine), p)
            return self.keep_points(u), finite
        return rollout.evolve_from(self, u0, p)

    def failure(self) -> tuple[str, str]:
        """(what a failed sample did, how to avoid it), for BlowUpError's message."""
        return (f"trajectories blew up (NaN/Inf) with step {self.step_dt:.4g}",
                "a smaller dt or a narrower parameter domain avoids this")

    # --- the time window ---------------------------------------------------------------------------
    @property
    def frame_dt(self) -> float:
        return (self.t_end - self.t_start) / (self.n_frames - 1)

    @property
    def burn_in_steps(self) -> int:
        """ETDRK4 steps of the burn-in (0 without one): the fewest whose step is <= dt (or stable_dt)."""
        if not self.t_start:
            return 0
        if self.refine > 1:  # the solve grid's, whose rollout makes the samples
            return self.solved.burn_in_steps
        target = self.dt if self.dt is not None else self.stable_dt()
        return max(1, math.ceil(self.t_start / target * (1 - 1e-9)))

    @property
    def burn_in_dt(self) -> float:
        """The burn-in's own step, t_start / burn_in_steps (time units; 0 without a burn-in)."""
        return self.t_start / self.burn_in_steps if self.t_start else 0.0

    @property
    def steps_per_frame(self) -> int:
        if self.refine > 1:  # the solve grid's, whose rollout makes the samples (a blow-up names its step)
            return self.solved.steps_per_frame
        target = self.dt if self.dt is not None else self.stable_dt()
        return max(1, math.ceil(self.frame_dt / target * (1 - 1e-9)))

    @property
    def step_dt(self) -> float:
        """The internal step actually taken: frame_dt / steps_per_frame (<= dt and <= stable_dt)."""
        return self.frame_dt / self.steps_per_frame

    # --- validation --------------------------------------------------------------------------------
    def validate(self) -> None:
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 8 or self.n % 2:
            raise ValueError(f"{self.NAME}: n={self.n!r} not allowed: resolution must be an even integer >= 8")
        self._check_length()
        if not (self.t_end > 0 and math.isfinite(self.t_end)):
            raise ValueError(f"{self.NAME}: t_end={self.t_end} not allowed: must be a finite number > 0")
        if isinstance(self.t_start, bool) or not (0 <= self.t_start < self.t_end):
            raise ValueError(f"{self.NAME}: t_start={self.t_start!r} not allowed: need 0 <= t_start < t_end "
                             f"(t_end={self.t_end:g}; t_start is a burn-in from the IC, not recorded)")
        if isinstance(self.n_frames, bool) or not isinstance(self.n_frames, int) or self.n_frames < 2:
            raise ValueError(f"{self.NAME}: n_frames={self.n_frames!r} not allowed: need an integer >= 2 (t=0 and t_end)")
        self._check_size()  # before anything allocates arrays of the grid's size
        self._check_refine()
        self._check_ic()
        self.check_settings()
        if self.dt is not None:
            stable = self.stable_dt()
            if not self.dt > 0:
                raise ValueError(f"{self.NAME}: dt={self.dt} not allowed: must be > 0")
            if self.dt > stable:
                raise ValueError(
                    f"{self.NAME}: dt={self.dt} is unstable for this grid and parameter domain: "
                    f"allowed dt <= {stable:.4g} (or leave dt unset to derive it)"
                )
        self._check_steps()
        if not is_catalog_class(type(self)):  # a user's class: its operators' shapes, here (JAX: jax.eval_shape)
            check_operators(self)  # (the catalog's own: tests/test_catalog.py, every entry, so a bad --set is
            # refused and a good one built without importing JAX)

    def _check_refine(self) -> None:
        """refine is an integer >= 1; above 1 only on a periodic grid, and the solve grid's problem must hold."""
        check_refine(self, "1: solve on the n points kept; k: solve on n * k points per axis and keep every k-th")
        r = self.refine
        if r == 1:
            return
        if self.grid.bc != Grid(self.NDIM, self.n, self.length).bc:
            raise ValueError(f"{self.NAME}: refine={r} not allowed with walls ({', '.join(self.grid.bc)}): a finer "
                             "grid's points do not include a walled grid's (cell centres); allowed: refine=1")
        check_solve_grid(self, "points per axis")

    def _check_ic(self) -> None:
        """The IC fits this PDE: its kind's field count, its own rules on this grid, a float32-safe magnitude."""
        want = getattr(self.ic, "field_count", None)
        if want is not None and want != len(self.FIELDS):
            fitting = self.fitting_ic_kinds()
            raise ValueError(f"{self.NAME}: ic={self.ic.kind!r} not allowed: it makes {want} fields and {self.NAME} has "
                             f"{len(self.FIELDS)} ({', '.join(self.FIELDS)}); allowed: {', '.join(fitting)}")
        dims = getattr(self.ic, "ndims", None)
        if dims is not None and self.NDIM not in dims:
            raise ValueError(f"{self.NAME}: ic={self.ic.kind!r} not allowed: it serves {'/'.join(map(str, dims))}D "
                             f"and {self.NAME} is {self.NDIM}D; allowed: {', '.join(self.fitting_ic_kinds())}")
        self._check_ic_on_grid()
        bound = self.ic.bound(self.grid)
        if not bound <= MAX_IC_BOUND:
            raise ValueError(f"{self.NAME}: ic {self.ic} not allowed: its values reach ~{bound:.3g}; the limit is "
                             f"max|u0| <= {MAX_IC_BOUND:g} (float32 data)")

    def _check_steps(self) -> None:
        """The internal steps of one trajectory within MAX_STEPS (before steps_per_frame is ever computed)."""
        target = self.dt if self.dt is not None else self.stable_dt()
        steps = self.t_end / target if target > 0 else math.inf  # the burn-in's and the frames' steps
        if not steps <= MAX_STEPS:
            raise ValueError(f"{self.NAME}: t_end={self.t_end:g}, n_frames={self.n_frames} with step {target:.3g} "
                             f"would take ~{steps:.3g} internal steps per trajectory; the limit is {MAX_STEPS} "
                             "(a shorter t_end, a larger dt, or a smaller initial condition, whose size sets the step)")

    def describe_setup(self) -> str:
        run = self.solved
        solved = (f" (solved on {run.grid.describe()}, 1 point in {self.refine} kept per axis)" if self.refine > 1 else "")
        return (f"  fields: {', '.join(self.FIELDS)}   grid: {self.grid.describe()}{solved}"
                f"   t in [{self.t_start:g}, {self.t_end:g}], {self.n_frames} frames, step {run.step_dt:.4g} "
                f"({run.steps_per_frame}/frame)" + (f"; after a burn-in of {run.burn_in_steps} steps from the IC at t = 0"
                                                    if self.t_start else ""))


@dataclass(frozen=True)
class LinearPDE(PDE):
    """A PDE with no nonlinear part: every step is the exact exponential e^{hL}, so no step limit."""

    def nonlinear(self, grid, p):
        return None

    def stable_dt(self):
        return math.inf


def is_catalog_class(cls: type) -> bool:
    """Whether ``cls`` is one of the catalog's entries (or its walled variants), not a user's PDE class."""
    return cls.__module__.startswith("pdestream.generator.") and cls.NAME in NAMES


@functools.lru_cache(maxsize=256)
def check_operators(pde: PDE) -> None:
    """L (and N's output, and the state basis) have the state's shape [C, *kshape]; a ValueError naming the PDE
    otherwise. Shapes only (jax.eval_shape: nothing is computed), once per configuration."""
    grid, n_fields = pde.grid, len(pde.FIELDS)
    want = (n_fields, *grid.kshape)
    p = {name: jax.ShapeDtypeStruct((), jnp.float32) for name in pde.PARAMS}
    real = not getattr(grid, "periodic_axes", True)  # a grid with walls only has real coefficients
    state = jax.ShapeDtypeStruct(want, jnp.float32 if real else jnp.complex64)

    def shape_of(what, fn, *args):
        try:
            got = tuple(jax.eval_shape(fn, *args).shape)
        except Exception as err:  # a bug in the PDE class: say which PDE and which part
            raise ValueError(f"{pde.NAME}: {what} cannot be evaluated on a {want} state: {err}") from None
        if got != want:
            raise ValueError(f"{pde.NAME}: {what} has shape {got}; the state is [C, *kshape] = {want} "
                             f"({n_fields} field(s) {', '.join(pde.FIELDS)} on a {'x'.join(map(str, grid.shape))} grid)")

    shape_of("linear(grid, p)", lambda p: jnp.asarray(pde.linear(grid, p)), p)
    shape_of("nonlinear(grid, p)(v)", lambda p, v: _call_nonlinear(pde, grid, p, v), p, state)
    basis = pde.state_basis(grid, {name: jnp.float32(1.0) for name in pde.PARAMS})
    if basis is not None:
        shape_of("state_basis(grid, p)[0](v)", lambda v: basis[0](v), state)
        shape_of("state_basis(grid, p)[1](v)", lambda v: basis[1](v), state)


def _call_nonlinear(pde: PDE, grid: Grid, p, v):
    nonlinear = pde.nonlinear(grid, p)
    return v if nonlinear is None else nonlinear(v)
