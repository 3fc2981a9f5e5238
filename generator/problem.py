"""The problem protocol: what the sampler, stream, cache, oracle and CLI read of a problem, and the
configuration machinery every problem shares.

A problem is one frozen dataclass (hashable: compiled programs are cached per configuration) whose fields are
its settings; ``PARAMS`` names the fields that are random coefficients (each a Domain, drawn per sample).
Two families implement it: the spectral time-dependent PDEs (``generator.pdes.base.PDE``: ETDRK4 rollouts of
``v_t = L v + N(v)``) and the steady elliptic problems (``generator.pdes.steady.SteadyProblem``: one solve per
sample, no time axis). Neither the protocol nor the families import the sampler: the sampler imports them.
"""

from __future__ import annotations

import abc
import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Protocol

import numpy as np

from pdestream.generator.lazy_jax import jax

from .domains import Domain, Fixed, parse_domain
from .grids import GridBase
from .ics import IC_KINDS, check_value, coerce, make_ic
from .origin import origin, rebuild

# Limits that keep one configuration's frame/step arithmetic and memory sane; a setting beyond them is refused
# when the problem is built, naming the limit, instead of overflowing, exhausting memory or running for days.
MAX_STEPS = 10**6  # internal time steps per trajectory (steps_per_frame * (n_frames - 1)); defaults take <= 2000
MAX_GRID_POINTS = 2**24  # points per field (n**ndim): 4096^2 in 2D
MAX_TRAJECTORY_BYTES = 2**30  # float32 frames of one trajectory (n_frames * fields * n**ndim * 4 B)
MAX_IC_BOUND = 1e18  # max|u0|: a quadratic nonlinearity squares it, and float32 ends at 3.4e38


@dataclass(frozen=True)
class Param:
    """A random coefficient: what it means, its units, and whether it must be > 0."""

    description: str
    units: str = "1"
    positive: bool = False


# Where an Output's values lie (its dims after the sample's): one per sample, one per frame, one per grid point.
OUTPUT_DIMS = ("", "time", "space")


@dataclass(frozen=True)
class Output:
    """A per-sample variable a problem computes beside its fields (``Problem.OUTPUTS``, ``Problem.outputs``): what
    it means, its units, ``dims`` (one of OUTPUT_DIMS: "" one value per sample, "time" one per frame [T],
    "space" one per grid point [*space], constant in time) and ``dtype`` ("float32", or "int8" for a 0/1 flag).
    Stored as a cache variable of that name, handed out as a stream key, listed by ``pdestream inspect``."""

    description: str
    units: str = "1"
    dims: str = ""
    dtype: str = "float32"

    def __post_init__(self):
        if self.dims not in OUTPUT_DIMS or self.dtype not in ("float32", "int8"):
            raise ValueError(f"Output dims={self.dims!r}, dtype={self.dtype!r}: allowed dims {OUTPUT_DIMS}, "
                             "dtypes float32 / int8")


class Problem(Protocol):
    """What every problem offers its users (sampler, stream, cache, oracle, CLI).

    A sample of a time-dependent problem is u [T, C, *space] over FIELDS at ``times()``; a STEADY problem's is
    u [C, *space] (no time axis) with its random input fields INPUTS [C_in, *space] stored beside it.
    ``n_frames`` is the frames per sample (1 for a steady problem). ``run_keys`` solves one sample per key in
    bounded calls (a Ctrl-C or ``sampler.cancel_on`` stops it between two), each sample's bits independent of
    its batch (``generator.chunked``).
    """

    NAME: str
    EQUATION: str
    FIELDS: tuple[str, ...]
    INPUTS: tuple[str, ...]
    STEADY: bool
    NDIM: int
    PARAMS: Mapping[str, Param]
    n: int
    n_frames: int

    @property
    def grid(self) -> GridBase: ...  # shape, coords(), bc (per-axis boundary types), describe()

    @property
    def param_domains(self) -> dict[str, Domain]: ...

    def times(self) -> np.ndarray: ...  # float32 [T] frame times (empty for a steady problem: no time axis)

    def config(self) -> dict[str, Any]: ...  # every setting, JSON-able; ``generator.from_config`` rebuilds it

    def config_hash(self) -> str: ...

    def describe(self) -> str: ...

    def replace(self, overrides: Mapping[str, Any] | None = None, **kwargs) -> "Problem": ...

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray): ...
    # keys [B], explicit float32 [B, P], given bool [B, P] -> (u, params {name: [B]}, ok bool [B], inputs or None);
    # a problem whose latent_size() > 0 also takes latent=(float32 [B, L] IC latents, bool [B] where given)

    def latent_size(self) -> int: ...  # L: its IC's steerable coordinates (generator.ics.LatentIC), 0: none

    def failure(self) -> tuple[str, str]: ...  # (what a failed sample did, how to avoid it), for BlowUpError

    def failure_causes(self) -> list[str]: ...  # why each sample of this thread's last run_keys failed ('' if not)

    # OUTPUTS {name: Output}: per-sample variables beside the fields (forces, distances, flags); ``outputs``
    # computes them from the final samples u [B, ...], params {name: [B]} and the samples' keys [B] (their random
    # geometry, where it is not in u): {name: [B, *dims]} ({} if none)
    OUTPUTS: Mapping[str, Output]

    def outputs(self, u: jax.Array, params: Mapping[str, jax.Array], keys: jax.Array | None = None
                ) -> dict[str, jax.Array]: ...


def draw_params(problem, key: jax.Array) -> dict[str, jax.Array]:
    """One draw of every parameter from its domain: {name: float32 scalar}."""
    return {name: dom.sample(jax.random.fold_in(key, j)) for j, (name, dom) in enumerate(problem.param_domains.items())}


def resolve_params(problem, key: jax.Array, explicit: jax.Array, given: jax.Array) -> dict[str, jax.Array]:
    """The parameters of one sample: the caller's ``explicit`` [P] values where ``given`` [P] (bool), drawn from
    ``key`` elsewhere (all draws are made either way, so a sample given its drawn values is bit-identical)."""
    drawn = draw_params(problem, key)
    return {name: jax.numpy.where(given[j], explicit[j], drawn[name]) for j, name in enumerate(problem.PARAMS)}


@dataclass(frozen=True)
class ProblemBase(abc.ABC):
    """The settings machinery shared by every problem: parsing and checking settings, parameter domains and the
    IC distribution, ``replace``, ``config``, its hash, and ``describe``. A family supplies ``grid``, ``times``,
    ``n_frames``, ``run_keys``, ``failure``, ``validate`` (its own checks, in order) and ``describe_setup``."""

    NAME: ClassVar[str] = ""
    EQUATION: ClassVar[str] = ""
    FIELDS: ClassVar[tuple[str, ...]] = ("u",)
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict[str, Param]] = {}
    STEADY: ClassVar[bool] = False
    INPUTS: ClassVar[tuple[str, ...]] = ()
    # Per-sample variables computed beside the fields ({name: Output}; see ``outputs``). Empty: none.
    OUTPUTS: ClassVar[Mapping[str, Output]] = {}
    IC_KINDS: ClassVar[Mapping[str, type]] = IC_KINDS  # the ic kinds this problem takes
    # Where each field lives when not at the grid's points (a staggered grid): {field: location}, locations
    # "face_x" / "face_y" (on the cell's lower face along that axis), "centre" (cell average), "mask" (a cell set,
    # 0/1, the solver's geometry: restricted by "any", never changed by a model). Empty: every field at the points.
    FIELD_LOCATIONS: ClassVar[Mapping[str, str]] = {}
    # The units of every field and input field, in the words of Param.units ("1": dimensionless, "length/time"):
    # shown by `pdestream list NAME`, in pictures, and stored as each cache variable's CF `units` attribute.
    FIELD_UNITS: ClassVar[Mapping[str, str]] = {"u": "1"}
    # A class serving several dimensions: {ndim: setting defaults that differ in that dimension}, e.g.
    # {1: {}, 2: {"n": 64}, 3: {"n": 32}}. Empty: the class is one problem of dimension NDIM.
    DIMENSIONS: ClassVar[Mapping[int, Mapping[str, Any]]] = {}
    # Fields of a dimension-generic class that an entry of lower dimension does not use (c_z in 2D):
    # not part of its configuration (set by for_dimension).
    UNUSED: ClassVar[frozenset] = frozenset()
    # What a run at the defaults took on 2 CPU cores, {"startup_s": s to the first sample (mostly the compile),
    # "unit_s": s per sample after it}: a progress line's estimate on a machine that has no record of its own yet.
    TYPICAL_TIMES: ClassVar[Mapping[str, float] | None] = None

    n: int = 128  # grid points per dimension
    length: float = 1.0  # domain side
    ic: Any = None  # initial-condition (or input-field) distribution (see generator.ics)
    # The recipe (pdestream.recipes) this problem was made from: a label in its config, not a setting ("": none)
    recipe: str = dataclasses.field(default="", kw_only=True)

    # --- what a family provides ------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def grid(self) -> GridBase:
        """The problem's grid (with its per-axis boundary types)."""

    @abc.abstractmethod
    def validate(self) -> None:
        """The family's checks of the settings, after types, finiteness and parameter domains (ValueError)."""

    @abc.abstractmethod
    def describe_setup(self) -> str:
        """describe()'s second line: fields, grid, time window or solver."""

    @classmethod
    def for_dimension(cls, ndim: int) -> dict[str, Any]:
        """Class attributes of this class's ``ndim``-dimensional entry that depend on the dimension
        (PARAMS, FIELDS, EQUATION, UNUSED); only for classes with DIMENSIONS."""
        return {}

    def failure_causes(self) -> list[str]:
        """Why each sample of this thread's last ``run_keys`` failed, one line each ('' where it did not); empty:
        the family has no per-sample cause (a NaN/Inf is its only failure, said by ``failure``)."""
        return []

    def outputs(self, u: jax.Array, params: Mapping[str, jax.Array], keys: jax.Array | None = None
                ) -> dict[str, jax.Array]:
        """The OUTPUTS of samples u [B, ...] with parameters params {name: [B]} and keys [B] (the keys run_keys
        solved them with; used where the outputs need geometry drawn from them): {name: [B, *dims]} in OUTPUTS
        order, a pure function of each sample (its bits do not depend on its batch). None declared: {}."""
        return {}

    def latent_size(self) -> int:
        """L: the steerable coordinates of this problem's IC (``generator.ics.LatentIC``); 0: none (a family that
        does not take an explicit latent in ``run_keys``)."""
        return 0

    def check_settings(self) -> None:  # noqa: B027 (an optional hook: most problems have nothing more to check)
        """Subclass hook: refuse values of the problem's own settings (types and finiteness are already checked)."""

    # --- derived -----------------------------------------------------------------------------------
    @property
    def param_domains(self) -> dict[str, Domain]:
        return {name: getattr(self, name) for name in self.PARAMS}

    def param_upper(self, name: str) -> float:
        """Largest |value| the domain of parameter ``name`` can produce (for stability rules)."""
        return max(abs(b) for b in getattr(self, name).bounds)

    # --- validation --------------------------------------------------------------------------------
    def __post_init__(self):
        if self.DIMENSIONS and not self.NAME:
            raise TypeError(f"{type(self).__name__} serves {sorted(self.DIMENSIONS)}D: build it as a catalog entry "
                            "(generator.get_pde(name), names ending in the dimension)")
        self._check_fields()
        self._parse_params()
        self.validate()

    def _check_length(self) -> None:
        if not (self.length > 0 and math.isfinite(self.length)):
            raise ValueError(f"{self.NAME}: length={self.length} not allowed: must be a finite number > 0")

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
        """The names in IC_KINDS whose distributions make as many fields as this problem has, in its dimension
        (``ndims``: the dimensions a kind serves, None: any), i.e. what `ic=` may name."""
        return [k for k, c in cls.IC_KINDS.items() if getattr(c, "field_count", None) in (None, len(cls.FIELDS))
                and cls.NDIM in (getattr(c, "ndims", None) or (cls.NDIM,))]

    def _check_ic_on_grid(self) -> None:
        """The IC's own rules on this problem's grid, the error naming the problem."""
        try:
            self.ic.check(self.grid)
        except ValueError as err:
            raise ValueError(f"{self.NAME}: {err}") from None

    def _check_size(self) -> None:
        """Grid points and bytes of one sample within MAX_GRID_POINTS and MAX_TRAJECTORY_BYTES."""
        points = math.prod(self.grid.shape)
        if points > MAX_GRID_POINTS:
            most = _root(MAX_GRID_POINTS, self.NDIM)
            raise ValueError(f"{self.NAME}: n={self.n} not allowed: {points} grid points per field; the limit is "
                             f"{MAX_GRID_POINTS} points (n <= {most} in {self.NDIM}D)")
        size = 4 * self.n_frames * len(self.FIELDS) * points
        if size > MAX_TRAJECTORY_BYTES:
            raise ValueError(f"{self.NAME}: n={self.n}, n_frames={self.n_frames} not allowed: one trajectory would "
                             f"take {size / 2**30:.3g} GiB; the limit is {MAX_TRAJECTORY_BYTES / 2**30:g} GiB "
                             "(fewer frames or a coarser grid)")

    # --- configuration -----------------------------------------------------------------------------
    def replace(self, overrides: Mapping[str, Any] | None = None, **kwargs) -> "ProblemBase":
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
        """The settings of this problem (its dataclass fields but the IC and the ones its dimension does not use)."""
        return [f.name for f in dataclasses.fields(cls) if f.name not in ("ic", "recipe") and f.name not in cls.UNUSED]

    def config(self) -> dict[str, Any]:
        """The full resolved configuration as plain JSON-able values (domains as strings)."""
        out: dict[str, Any] = {"pde": self.NAME}
        for name in self.config_fields():
            value = getattr(self, name)
            out[name] = str(value) if name in self.PARAMS else value
        out["ic"] = {"kind": self.ic.kind, **dataclasses.asdict(self.ic)}
        if self.recipe:  # only when made from a recipe: the configs (and hashes) of plain entries are unchanged
            out["recipe"] = self.recipe
        where = origin(type(self))  # a user's PDE: where its code came from is part of its identity
        if where is not None:
            out["origin"] = where
        return out

    def __reduce_ex__(self, protocol):
        """A user's problem pickles as its config (rebuilt by ``generator.from_config``, which finds its class by
        origin and refuses changed code): its NAME may have been given at registration, which a class pickled by
        reference would lose in a worker process. The package's own problems pickle as usual."""
        if origin(type(self)) is None:
            return super().__reduce_ex__(protocol)
        return (rebuild, (self.config(),))

    def config_hash(self) -> str:
        """sha256 of the canonical JSON configuration (first 16 hex digits)."""
        text = json.dumps(self.config(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def describe(self) -> str:
        """Several lines for humans: equation, fields, grid and time window (or solver), parameters and IC."""
        lines = [f"{self.NAME}: {self.EQUATION}", self.describe_setup()]
        for name, spec in self.PARAMS.items():
            domain = getattr(self, name)
            how = f"= {domain} (fixed)" if isinstance(domain, Fixed) else f"~ {domain}"
            lines.append(f"  {name} {how}   {spec.description} [{spec.units}]")
        lines.append(f"  {self.IC_LABEL}: {self.ic}")
        return "\n".join(lines)

    IC_LABEL: ClassVar[str] = "ic"  # how describe() names the IC distribution (darcy2d: its random field g)


def check_refine(problem, meaning: str) -> None:
    """Refuses, in one line, a ``refine`` that is not an integer >= 1 (``meaning``: what 1 and k do, for the message)."""
    r = problem.refine
    if isinstance(r, bool) or not isinstance(r, int) or r < 1:
        raise ValueError(f"{problem.NAME}: refine={r!r} not allowed: need an integer >= 1 ({meaning})")


def check_solve_grid(problem, unit: str) -> None:
    """Builds (and so validates) ``problem.solved``, the problem on n * refine ``unit`` per axis; its refusal is
    restated as refine's, in one line."""
    points, r = math.prod(problem.grid.shape), problem.refine
    if points * r**problem.NDIM > MAX_GRID_POINTS:  # named as refine's largest (the solve grid's n meant little)
        most = next(k for k in range(_root(MAX_GRID_POINTS // points, problem.NDIM) + 1, 0, -1)
                    if points * k**problem.NDIM <= MAX_GRID_POINTS)
        raise ValueError(f"{problem.NAME}: refine={r} not allowed with n={problem.n}: the solve grid would hold "
                         f"{points} * {r}^{problem.NDIM} points per field; the limit is {MAX_GRID_POINTS}; allowed: "
                         f"refine <= {most} with n={problem.n}")
    try:
        problem.solved  # noqa: B018
    except ValueError as err:
        if _fails_alike(problem, err):  # a setting bad on any grid (n_frames=1): its own line, not refine's
            raise ValueError(str(err)) from None
        why = str(err).removeprefix(f"{problem.NAME}: ")
        raise ValueError(f"{problem.NAME}: refine={problem.refine} not allowed with n={problem.n}: the solve grid "
                         f"(n * refine = {problem.n * problem.refine} {unit}) fails: {why}") from None


def _fails_alike(problem, err: ValueError) -> bool:
    """Whether ``problem`` at refine 1 (its own grid) is refused with the very words the solve grid was."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (its grid's own warnings, e.g. under-resolved, are not this refusal's)
        try:
            dataclasses.replace(problem, refine=1)
        except ValueError as plain:
            return str(plain) == str(err)
    return False


def _root(limit: int, ndim: int) -> int:
    """The largest n with n**ndim <= limit."""
    n = round(limit ** (1 / ndim))
    return n if n**ndim <= limit else n - 1
