"""What every PDE declares, in one place: equation, fields, parameter domains, initial-condition
distribution, periodic grid, time window and stable-step rule.

A PDE is a frozen dataclass (hashable, so a compiled sampler is cached per configuration). Its fields are
the configuration; ``PARAMS`` names the fields that are random coefficients (each a Domain). A subclass
must supply ``linear`` (diagonal operator L), ``nonlinear`` (N, or None) of ``dv/dt = L v + N(v)`` in
Fourier space, and ``stable_dt`` (abstract: a class missing one cannot be built). ``LinearPDE`` supplies
the last two for PDEs whose step is the exact exponential.

One class may serve several dimensions (diffusion in 1D/2D/3D): it lists them in ``DIMENSIONS`` with
the setting defaults each one changes, and ``for_dimension`` gives the class attributes that depend on
the dimension. The catalog (generator.catalog) makes one entry per dimension, named with it.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ..domains import Domain, Fixed, parse_domain
from ..ics import IC_KINDS, check_value, coerce, make_ic
from ..spectral import Grid

# Limits that keep one configuration's frame/step arithmetic and memory sane; a setting beyond them is refused
# when the PDE is built, naming the limit, instead of overflowing, exhausting memory or running for days.
MAX_STEPS = 10**6  # internal time steps per trajectory (steps_per_frame * (n_frames - 1)); defaults take <= 2000
MAX_GRID_POINTS = 2**24  # points per field (n**ndim): 4096^2 in 2D
MAX_TRAJECTORY_BYTES = 2**30  # float32 frames of one trajectory (n_frames * fields * n**ndim * 4 B)
MAX_IC_BOUND = 1e18  # max|u0|: a quadratic nonlinearity squares it, and float32 ends at 3.4e38


@dataclass(frozen=True)
class Param:
    """A random PDE coefficient: what it means, its units, and whether it must be > 0."""

    description: str
    units: str = "1"
    positive: bool = False


@dataclass(frozen=True)
class PDE(abc.ABC):
    """Base configuration shared by every PDE (subclasses set their own defaults)."""

    NAME: ClassVar[str] = ""
    EQUATION: ClassVar[str] = ""
    FIELDS: ClassVar[tuple[str, ...]] = ("u",)
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict[str, Param]] = {}
    # A class serving several dimensions: {ndim: setting defaults that differ in that dimension}, e.g.
    # {1: {}, 2: {"n": 64}, 3: {"n": 32}}. Empty: the class is one PDE of dimension NDIM.
    DIMENSIONS: ClassVar[Mapping[int, Mapping[str, Any]]] = {}
    # Fields of a dimension-generic class that an entry of lower dimension does not use (c_z in 2D):
    # not part of its configuration (set by for_dimension).
    UNUSED: ClassVar[frozenset] = frozenset()

    n: int = 128  # grid points per dimension
    length: float = 1.0  # domain [0, length)^ndim
    t_end: float = 1.0  # final time; frames are saved at linspace(0, t_end, n_frames)
    n_frames: int = 51  # saved frames including t = 0
    dt: float | None = None  # internal step; None: the largest stable step that divides a frame interval
    ic: Any = None  # initial-condition distribution (see generator.ics)

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

    @classmethod
    def for_dimension(cls, ndim: int) -> dict[str, Any]:
        """Class attributes of this class's ``ndim``-dimensional entry that depend on the dimension
        (PARAMS, FIELDS, EQUATION, UNUSED); only for classes with DIMENSIONS."""
        return {}

    def sample_ic(self, key: jax.Array) -> jax.Array:
        """One initial condition, float32 [C, *space]."""
        return self.ic.sample(key, self.grid, len(self.FIELDS))

    # --- what the sampler, cache, stream and views use: shared with steady PDEs (darcy2d) --------------
    # A sample is u [T, C, *space] here; a STEADY PDE's is u [C, *space] (no time axis) with its random input
    # fields INPUTS [C_in, *space] (stored beside u). INPUTS is empty for time-dependent PDEs (the IC is frame 0).
    STEADY: ClassVar[bool] = False
    INPUTS: ClassVar[tuple[str, ...]] = ()
    IC_KINDS: ClassVar[Mapping[str, type]] = IC_KINDS  # the ic kinds this PDE takes (darcy2d: its own field)

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """Solve one sample per key [B] (explicit float32 [B, P] parameter values where given bool [B, P]):
        (u [B, T, C, *space], params {name: [B]}, ok bool [B] (finite), inputs None). ETDRK4 rollouts."""
        from ..sampler import _run_keys  # the sampler imports the catalog: a module-level import would cycle

        return (*_run_keys(self, keys, explicit, given), None)

    def failure(self) -> tuple[str, str]:
        """(what a failed sample did, how to avoid it), for BlowUpError's message."""
        return (f"trajectories blew up (NaN/Inf) with step {self.step_dt:.4g}",
                "a smaller dt or a narrower parameter domain avoids this")

    # --- derived -----------------------------------------------------------------------------------
    @property
    def grid(self) -> Grid:
        return Grid(self.NDIM, self.n, self.length)

    @property
    def param_domains(self) -> dict[str, Domain]:
        return {name: getattr(self, name) for name in self.PARAMS}

    def param_upper(self, name: str) -> float:
        """Largest |value| the domain of parameter ``name`` can produce (for stability rules)."""
        return max(abs(b) for b in getattr(self, name).bounds)

    @property
    def frame_dt(self) -> float:
        return self.t_end / (self.n_frames - 1)

    @property
    def steps_per_frame(self) -> int:
        target = self.dt if self.dt is not None else self.stable_dt()
        return max(1, math.ceil(self.frame_dt / target * (1 - 1e-9)))

    @property
    def step_dt(self) -> float:
        """The internal step actually taken: frame_dt / steps_per_frame (<= dt and <= stable_dt)."""
        return self.frame_dt / self.steps_per_frame

    def times(self) -> np.ndarray:
        """Frame times, float32 [n_frames]."""
        return np.linspace(0.0, self.t_end, self.n_frames).astype(np.float32)

    # --- validation and configuration --------------------------------------------------------------
    def __post_init__(self):
        if self.DIMENSIONS and not self.NAME:
            raise TypeError(f"{type(self).__name__} serves {sorted(self.DIMENSIONS)}D: build it as a catalog entry "
                            "(generator.get_pde(name), names ending in the dimension)")
        self._check_fields()
        self._parse_params()
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 8 or self.n % 2:
            raise ValueError(f"{self.NAME}: n={self.n!r} not allowed: resolution must be an even integer >= 8")
        if not (self.length > 0 and math.isfinite(self.length)):
            raise ValueError(f"{self.NAME}: length={self.length} not allowed: must be a finite number > 0")
        if not (self.t_end > 0 and math.isfinite(self.t_end)):
            raise ValueError(f"{self.NAME}: t_end={self.t_end} not allowed: must be a finite number > 0")
        if isinstance(self.n_frames, bool) or not isinstance(self.n_frames, int) or self.n_frames < 2:
            raise ValueError(f"{self.NAME}: n_frames={self.n_frames!r} not allowed: need an integer >= 2 (t=0 and t_end)")
        self._check_size()  # before anything allocates arrays of the grid's size
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
        check_operators(self)

    def _parse_params(self) -> None:
        """Each random parameter's setting -> its Domain (a string, number or Domain), positivity checked."""
        for name, spec in self.PARAMS.items():
            try:
                domain = parse_domain(getattr(self, name))
            except ValueError as err:
                raise ValueError(f"{self.NAME}: parameter {name}: {err}") from None
            object.__setattr__(self, name, domain)
            if spec.positive and not min(domain.bounds) > 0:
                raise ValueError(f"{self.NAME}: {name}={domain} not allowed: {spec.description} must be > 0")

    def check_settings(self) -> None:  # noqa: B027 (an optional hook: most PDEs have nothing more to check)
        """Subclass hook: refuse values of the PDE's own settings (types and finiteness are already checked)."""

    def _check_fields(self) -> None:
        """Every non-parameter setting and IC field has its field's kind and, if a number, is finite."""
        try:
            for name in self.config_fields():
                if name not in self.PARAMS:
                    object.__setattr__(self, name, check_value(name, getattr(self, name), self.default(name)))
            ic = make_ic(self.ic, self.IC_KINDS)
            if dataclasses.is_dataclass(ic):
                fields = {f.name: check_value(f"ic.{f.name}", getattr(ic, f.name), f.default)
                          for f in dataclasses.fields(ic)}
                changed = {k: v for k, v in fields.items() if type(v) is not type(getattr(ic, k))}
                ic = dataclasses.replace(ic, **changed) if changed else ic
        except ValueError as err:
            raise ValueError(f"{self.NAME}: {err}") from None
        object.__setattr__(self, "ic", ic)

    @classmethod
    def default(cls, name: str) -> Any:
        """The declared default of setting ``name`` (it decides the setting's kind: int, number, name, ...)."""
        return next(f.default for f in dataclasses.fields(cls) if f.name == name)

    @classmethod
    def fitting_ic_kinds(cls) -> list[str]:
        """The names in IC_KINDS whose distributions make as many fields as this PDE has (what `ic=` may name)."""
        return [k for k, c in cls.IC_KINDS.items() if getattr(c, "field_count", None) in (None, len(cls.FIELDS))]

    def _check_ic_on_grid(self) -> None:
        """The IC's own rules on this PDE's grid, the error naming the PDE."""
        try:
            self.ic.check(self.grid)
        except ValueError as err:
            raise ValueError(f"{self.NAME}: {err}") from None

    def _check_ic(self) -> None:
        """The IC fits this PDE: its kind's field count, its own rules on this grid, a float32-safe magnitude."""
        want = getattr(self.ic, "field_count", None)
        if want is not None and want != len(self.FIELDS):
            fitting = self.fitting_ic_kinds()
            raise ValueError(f"{self.NAME}: ic={self.ic.kind!r} not allowed: it makes {want} fields and {self.NAME} has "
                             f"{len(self.FIELDS)} ({', '.join(self.FIELDS)}); allowed: {', '.join(fitting)}")
        self._check_ic_on_grid()
        bound = self.ic.bound(self.grid)
        if not bound <= MAX_IC_BOUND:
            raise ValueError(f"{self.NAME}: ic {self.ic} not allowed: its values reach ~{bound:.3g}; the limit is "
                             f"max|u0| <= {MAX_IC_BOUND:g} (float32 data)")

    def _check_size(self) -> None:
        """Grid points and bytes of one trajectory within MAX_GRID_POINTS and MAX_TRAJECTORY_BYTES."""
        points = self.n**self.NDIM
        if points > MAX_GRID_POINTS:
            most = _root(MAX_GRID_POINTS, self.NDIM)
            raise ValueError(f"{self.NAME}: n={self.n} not allowed: {points} grid points per field; the limit is "
                             f"{MAX_GRID_POINTS} points (n <= {most} in {self.NDIM}D)")
        size = 4 * self.n_frames * len(self.FIELDS) * points
        if size > MAX_TRAJECTORY_BYTES:
            raise ValueError(f"{self.NAME}: n={self.n}, n_frames={self.n_frames} not allowed: one trajectory would "
                             f"take {size / 2**30:.3g} GiB; the limit is {MAX_TRAJECTORY_BYTES / 2**30:g} GiB "
                             "(fewer frames or a coarser grid)")

    def _check_steps(self) -> None:
        """The internal steps of one trajectory within MAX_STEPS (before steps_per_frame is ever computed)."""
        target = self.dt if self.dt is not None else self.stable_dt()
        steps = (self.n_frames - 1) * (self.frame_dt / target) if target > 0 else math.inf
        if not steps <= MAX_STEPS:
            raise ValueError(f"{self.NAME}: t_end={self.t_end:g}, n_frames={self.n_frames} with step {target:.3g} "
                             f"would take ~{steps:.3g} internal steps per trajectory; the limit is {MAX_STEPS} "
                             "(a shorter t_end, a larger dt, or a smaller initial condition, whose size sets the step)")

    def replace(self, overrides: Mapping[str, Any] | None = None, **kwargs) -> "PDE":
        """A copy with fields changed; values may be strings (as from ``--set key=value``).

        Keys: any configuration field, a parameter (domain string), ``ic`` (a kind: one of IC_KINDS, or a
        dict with "kind"), or ``ic.FIELD``.
        """
        changes: dict[str, Any] = {}
        ic_changes: dict[str, Any] = {}
        for key, value in {**(overrides or {}), **kwargs}.items():
            if key.startswith("ic."):
                ic_changes[key[3:]] = value
            elif key == "ic" and isinstance(value, Mapping) and "kind" not in value:
                ic_changes.update(value)  # a TOML dotted key `ic.alpha = 2.5` arrives as {"ic": {"alpha": 2.5}}
            elif key == "ic":
                try:
                    changes["ic"] = make_ic(value, self.IC_KINDS, listed=self.fitting_ic_kinds())
                except ValueError as err:
                    raise ValueError(f"{self.NAME}: {err}") from None
            elif key in self.PARAMS:
                changes[key] = value
            elif key in self.config_fields():
                try:
                    changes[key] = coerce(key, value, self.default(key))
                except ValueError as err:
                    domain = isinstance(value, str) and "(" in value  # e.g. n=uniform(8, 16): only parameters vary
                    hint = (f"; {key} takes one value for every sample, only the parameters "
                            f"({', '.join(self.PARAMS)}) take domains") if domain and self.PARAMS else ""
                    raise ValueError(f"{self.NAME}: {err}{hint}") from None
            else:
                allowed = ", ".join([*self.config_fields(), "ic", "ic.<field>"])
                raise ValueError(f"{self.NAME}: unknown setting {key!r}; allowed: {allowed}")
        ic = changes.get("ic", self.ic)
        if ic_changes:
            ic_fields = [f.name for f in dataclasses.fields(ic)]
            for key, value in ic_changes.items():
                if key not in ic_fields:
                    raise ValueError(f"{self.NAME}: unknown setting 'ic.{key}' for ic kind {ic.kind!r}; allowed: "
                                     + ", ".join(f"ic.{f}" for f in ic_fields))
                ic_changes[key] = coerce(f"ic.{key}", value, getattr(ic, key))
            changes["ic"] = dataclasses.replace(ic, **ic_changes)
        return dataclasses.replace(self, **changes)

    @classmethod
    def config_fields(cls) -> list[str]:
        """The settings of this PDE (its dataclass fields but the IC and the ones its dimension does not use)."""
        return [f.name for f in dataclasses.fields(cls) if f.name != "ic" and f.name not in cls.UNUSED]

    def config(self) -> dict[str, Any]:
        """The full resolved configuration as plain JSON-able values (domains as strings)."""
        out: dict[str, Any] = {"pde": self.NAME}
        for name in self.config_fields():
            value = getattr(self, name)
            out[name] = str(value) if name in self.PARAMS else value
        out["ic"] = {"kind": self.ic.kind, **dataclasses.asdict(self.ic)}
        return out

    def config_hash(self) -> str:
        """sha256 of the canonical JSON configuration (first 16 hex digits)."""
        text = json.dumps(self.config(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def describe(self) -> str:
        """Several lines for humans: equation, fields, grid, time window, parameters and IC."""
        g = self.grid
        lines = [
            f"{self.NAME}: {self.EQUATION}",
            f"  fields: {', '.join(self.FIELDS)}   grid: {'x'.join(map(str, g.shape))} on [0, {self.length:g})^{self.NDIM}"
            f"   t in [0, {self.t_end:g}], {self.n_frames} frames, step {self.step_dt:.4g} ({self.steps_per_frame}/frame)",
        ]
        for name, spec in self.PARAMS.items():
            domain = getattr(self, name)
            how = f"= {domain} (fixed)" if isinstance(domain, Fixed) else f"~ {domain}"
            lines.append(f"  {name} {how}   {spec.description} [{spec.units}]")
        lines.append(f"  ic: {self.ic}")
        return "\n".join(lines)


@dataclass(frozen=True)
class LinearPDE(PDE):
    """A PDE with no nonlinear part: every step is the exact exponential e^{hL}, so no step limit."""

    def nonlinear(self, grid, p):
        return None

    def stable_dt(self):
        return math.inf


@functools.lru_cache(maxsize=256)
def check_operators(pde: PDE) -> None:
    """L (and N's output, and the state basis) have the state's shape [C, *kshape]; a ValueError naming the PDE
    otherwise. Shapes only (jax.eval_shape: nothing is computed), once per configuration."""
    grid, n_fields = pde.grid, len(pde.FIELDS)
    want = (n_fields, *grid.kshape)
    p = {name: jax.ShapeDtypeStruct((), jnp.float32) for name in pde.PARAMS}
    state = jax.ShapeDtypeStruct(want, jnp.complex64)

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


def _root(limit: int, ndim: int) -> int:
    """The largest n with n**ndim <= limit."""
    n = round(limit ** (1 / ndim))
    return n if n**ndim <= limit else n - 1
