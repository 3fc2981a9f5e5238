"""Any Exponax stepper as a pdestream entry: ``exponax:KortewegDeVries`` (1D), ``exponax:Burgers2d`` or
``--set num_spatial_dims=2``, with random parameters and initial conditions.

The entry's settings are the stepper's grid and step (``n`` = num_points, ``length`` = domain_extent, ``dt``,
``num_spatial_dims``), the frames (``n_frames``, ``n_steps_per_frame`` stepper steps between two) and its
parameters: every float keyword of the stepper's constructor (numerical ones like ``dealiasing_fraction``
excepted), each fixed at Exponax's default until a domain is set (``--set "diffusivity=uniform(0.01, 0.1)"``).
The initial condition is pdestream's (``generator.ics``, a random truncated Fourier series by default) drawn from
the sample's key. Sample i depends on (config, seed, i) only: its key is split into a parameter key and an IC key
as the spectral family does, the stepper is built with the drawn values (a concrete Python step: samples run one
after another) and rolled out with ``exponax.rollout``. Exponax's version is a setting, so a cache is never
resumed with another version. Exponax is optional: it is imported when an ``exponax:`` name is resolved.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import re
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ..dispatch import report, sync
from ..ics import FourierSeries
from ..problem import Param, ProblemBase, resolve_params
from ..spectral.fourier import Grid

PREFIX = "exponax:"
MISSING = "exponax is not installed: pip install exponax"
# Constructor keywords that are numerics of the scheme, not coefficients of the equation: never parameters.
NUMERICS = frozenset({"dealiasing_fraction", "circle_radius", "num_circle_points", "order"})
MAX_FRAME_STEPS = 10**6  # stepper steps per trajectory, as generator.problem.MAX_STEPS


def _exponax():
    try:
        import exponax
    except ImportError:
        raise ValueError(MISSING) from None
    return exponax


def steppers() -> dict[str, type]:
    """The Exponax stepper classes by name: exponax.stepper's and exponax.stepper.reaction's."""
    ex = _exponax()
    out = {}
    for module in (ex.stepper, ex.stepper.reaction):
        for name, obj in vars(module).items():
            if inspect.isclass(obj) and issubclass(obj, ex.BaseStepper) and not name.startswith("_"):
                out.setdefault(name, obj)
    return dict(sorted(out.items()))


def float_keywords(stepper_cls: type) -> dict[str, float]:
    """The stepper's keyword arguments with a float default (its coefficients): {name: default}."""
    sig = inspect.signature(stepper_cls)
    return {name: float(p.default) for name, p in sig.parameters.items()
            if p.kind is inspect.Parameter.KEYWORD_ONLY and type(p.default) is float and name not in NUMERICS}


@dataclass(frozen=True)
class ExponaxProblem(ProblemBase):
    """An Exponax stepper's trajectories: u [T, C, *space] at t = 0, dt k, 2 dt k, ... (k = n_steps_per_frame)."""

    STEPPER: ClassVar[str] = ""
    CHANNELS: ClassVar[int] = 1

    n: int = 64  # num_points per dimension
    length: float = 1.0  # domain_extent: the periodic box [0, length)^d
    num_spatial_dims: int = 1
    dt: float = 0.01  # the stepper's time step
    n_steps_per_frame: int = 1
    n_frames: int = 21
    exponax_version: str = ""  # the Exponax that made the samples (part of their identity)
    ic: Any = FourierSeries(max_mode=4, decay=1.0, amplitude=1.0)

    @property
    def grid(self) -> Grid:
        return Grid(self.NDIM, self.n, self.length)

    def times(self) -> np.ndarray:
        return (np.arange(self.n_frames) * (self.dt * self.n_steps_per_frame)).astype(np.float32)

    def validate(self) -> None:
        where = f"{self.NAME}"
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 4:
            raise ValueError(f"{where}: n={self.n!r} not allowed: num_points must be an integer >= 4")
        self._check_length()
        if self.num_spatial_dims != self.NDIM:
            raise ValueError(f"{where}: num_spatial_dims={self.num_spatial_dims!r} not allowed here: this entry is "
                             f"{self.NDIM}D (replace(num_spatial_dims=...) gives the entry of another dimension)")
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f"{where}: dt={self.dt} not allowed: must be a finite number > 0")
        for name, low in (("n_steps_per_frame", 1), ("n_frames", 2)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{where}: {name}={value!r} not allowed: need an integer >= {low}")
        if self.n_steps_per_frame * (self.n_frames - 1) > MAX_FRAME_STEPS:
            raise ValueError(f"{where}: n_steps_per_frame * (n_frames - 1) = "
                             f"{self.n_steps_per_frame * (self.n_frames - 1)} steps not allowed: the limit is "
                             f"{MAX_FRAME_STEPS}")
        installed = _exponax().__version__
        if self.exponax_version != installed:
            raise ValueError(f"{where}: exponax_version={self.exponax_version!r} but exponax {installed} is "
                             "installed: samples of another Exponax are not these; install that version or start "
                             "a new cache")
        self._check_size()
        self._check_ic_on_grid()

    def describe_setup(self) -> str:
        return (f"  fields {', '.join(self.FIELDS)} on {self.grid.describe()} (periodic); exponax "
                f"{self.exponax_version} stepper {self.STEPPER}, dt={self.dt:g} x {self.n_steps_per_frame} per "
                f"frame, {self.n_frames} frames to t={float(self.times()[-1]):g}")

    def failure(self) -> tuple[str, str]:
        return (f"trajectories blew up (NaN/Inf) with dt={self.dt:g}",
                "a smaller dt or a narrower parameter domain avoids this")

    # --- a dimension is another class: replace(num_spatial_dims=d) moves to it ----------------------
    def replace(self, overrides: Mapping[str, Any] | None = None, **kwargs) -> ProblemBase:
        changes = {**(overrides or {}), **kwargs}
        if "num_spatial_dims" in changes:
            ndim = changes.pop("num_spatial_dims")
            try:
                ndim = int(ndim) if not isinstance(ndim, bool) and float(ndim) == int(float(ndim)) else ndim
            except (TypeError, ValueError):
                pass
            if ndim != self.NDIM:
                if ndim not in (1, 2, 3):
                    raise ValueError(f"{self.NAME}: num_spatial_dims={ndim!r} not allowed: 1, 2 or 3")
                other = exponax_class(self.STEPPER, ndim)
                mine = type(self)()
                kept = {k: getattr(self, k) for k in self.config_fields()
                        if k != "num_spatial_dims" and getattr(self, k) != getattr(mine, k)}
                if self.ic != mine.ic:
                    kept["ic"] = dataclasses.asdict(self.ic) | {"kind": self.ic.kind}
                kept = {k: (str(v) if k in self.PARAMS else v) for k, v in kept.items()}
                return other().replace({**kept, **changes})
        return super().replace(changes)

    def __reduce_ex__(self, protocol):
        """Pickles as its config (its class is made at run time, found again by name)."""
        return (_rebuild, (self.config(),))

    # --- solving ----------------------------------------------------------------------------------
    def stepper(self, params: Mapping[str, float]):
        """The Exponax stepper of this entry with parameters ``params`` (floats), other keywords at defaults."""
        cls = steppers()[self.STEPPER]
        return cls(self.NDIM, float(self.length), int(self.n), float(self.dt), **{k: float(v) for k, v in params.items()})

    @property
    def step_dt(self) -> float:
        return self.dt

    def evolve(self, u0: jax.Array, p: Mapping[str, jax.Array]):
        """A caller's initial conditions u0 [B, C, *space], params {name: [B]} -> (u [B, T, C, *space], finite [B])
        (``generator.solve``), one sample after another."""
        roll, us = _roll(self.n_frames - 1, self.n_steps_per_frame), []
        for i in range(u0.shape[0]):
            us.append(roll(self.stepper({k: float(v[i]) for k, v in p.items()}), u0[i]))
            sync([(us[-1],)])
            report(i + 1, u0.shape[0])
        u = jnp.stack(us)
        return u, jnp.all(jnp.isfinite(u.reshape(u.shape[0], -1)), axis=1)

    def run_keys(self, keys: jax.Array, explicit: np.ndarray, given: np.ndarray):
        """One sample per key [B], one after another (a host sync between two): (u [B, T, C, *space],
        params {name: [B]}, ok [B], None)."""
        setup, roll = _setup(self), _roll(self.n_frames - 1, self.n_steps_per_frame)
        explicit, given = jnp.asarray(explicit, jnp.float32), jnp.asarray(given, bool)
        us, ps = [], []
        for i in range(keys.shape[0]):
            p, u0 = setup(keys[i], explicit[i], given[i])
            u = roll(self.stepper({k: float(v) for k, v in p.items()}), u0)
            sync([(u,)])
            report(i + 1, keys.shape[0])
            us.append(u)
            ps.append(p)
        u = jnp.stack(us)
        params = {k: jnp.stack([p[k] for p in ps]) for k in self.PARAMS}
        ok = jnp.all(jnp.isfinite(u.reshape(u.shape[0], -1)), axis=1)
        return u, params, ok, None


@functools.lru_cache(maxsize=64)
def _setup(problem: ExponaxProblem):
    """jit of (key, explicit [P], given [P]) -> (params {name: scalar}, u0 [C, *space]) for one sample: the key
    split into a parameter key and an IC key, as the spectral family's set-up."""
    def one(key, explicit, given):
        k_param, k_ic = jax.random.split(key)
        p = resolve_params(problem, k_param, explicit, given)
        return p, problem.ic.sample(k_ic, problem.grid, len(problem.FIELDS)).astype(jnp.float32)
    return jax.jit(one)


@functools.lru_cache(maxsize=64)
def _roll(n_frames: int, per_frame: int):
    """jit (by equinox: the stepper is a pytree, its parameters traced) of exponax.rollout."""
    import equinox as eqx

    ex = _exponax()

    def roll(stepper, u0):
        step = stepper if per_frame == 1 else ex.repeat(stepper, per_frame)
        return ex.rollout(step, n_frames, include_init=True)(u0)
    return eqx.filter_jit(roll)


_NAME = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*?)(?:([123])[dD])?$")


def parse_name(name: str) -> tuple[str, int]:
    """"exponax:Burgers" -> ("Burgers", 1); "exponax:Burgers2d" -> ("Burgers", 2)."""
    rest = name[len(PREFIX):]
    match = _NAME.match(rest)
    if match is None:
        raise ValueError(f"PDE {name!r} not allowed: an Exponax entry is exponax:Stepper or exponax:Stepper2d")
    stepper, ndim = match.group(1), int(match.group(2) or 1)
    known = steppers()
    if stepper not in known:
        if rest in known:  # a stepper whose own name ends in a digit and d (none in exponax 0.2)
            stepper, ndim = rest, 1
        else:
            raise ValueError(f"unknown Exponax stepper {stepper!r}; allowed: {', '.join(known)} "
                             "(as exponax:Name, exponax:Name2d or exponax:Name3d)")
    return stepper, ndim


def exponax_class(stepper: str, ndim: int) -> type[ExponaxProblem]:
    """The problem class of Exponax stepper ``stepper`` in ``ndim`` dimensions (made once, then cached)."""
    return _make_class(stepper, int(ndim))


@functools.lru_cache(maxsize=None)
def _make_class(stepper: str, ndim: int) -> type[ExponaxProblem]:
    ex = _exponax()
    cls = steppers()[stepper]
    try:
        probe = cls(ndim, 1.0, 8, 0.01)
    except Exception as err:  # a stepper of other dimensions only (Navier-Stokes: 2D)
        raise ValueError(f"exponax:{stepper} in {ndim}D not allowed: Exponax refuses it "
                         f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})") from None
    channels = int(probe.num_channels)
    fields = ("u",) if channels == 1 else tuple(f"u{c}" for c in range(channels))
    coefficients = float_keywords(cls)
    params = {k: Param(f"Exponax {stepper} keyword {k} (default {v:g})") for k, v in coefficients.items()}
    name = f"Exponax{stepper}{ndim}D"
    defaults: dict[str, Any] = {"num_spatial_dims": ndim, "exponax_version": ex.__version__,
                                **{k: repr(v) for k, v in coefficients.items()}}
    annotations = {"num_spatial_dims": int, "exponax_version": str, **{k: Any for k in coefficients}}
    namespace = {"NAME": f"{PREFIX}{stepper}", "STEPPER": stepper, "NDIM": ndim, "FIELDS": fields,
                 "CHANNELS": channels, "FIELD_UNITS": {f: "1" for f in fields}, "PARAMS": params,
                 "EQUATION": f"Exponax's {stepper} stepper ({ndim}D, {channels} channel{'s' * (channels > 1)})",
                 **defaults, "__annotations__": annotations, "__module__": __name__, "__qualname__": name,
                 "__doc__": f"exponax.stepper {stepper} in {ndim}D as a pdestream entry."}
    return dataclass(frozen=True)(type(name, (ExponaxProblem,), namespace))


def exponax_pde_class(name: str) -> type[ExponaxProblem]:
    """The class of name "exponax:Stepper" (1D) or "exponax:Stepper2d"."""
    return exponax_class(*parse_name(name))


def _rebuild(config: dict) -> ExponaxProblem:
    cfg = dict(config)
    cls = exponax_pde_class(cfg.pop("pde"))
    return cls().replace(cfg)
