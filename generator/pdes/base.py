"""What every PDE declares, in one place: equation, fields, parameter domains, initial-condition
distribution, periodic grid, time window and stable-step rule.

A PDE is a frozen dataclass (hashable, so a compiled sampler is cached per configuration). Its fields are
the configuration; ``PARAMS`` names the fields that are random coefficients (each a Domain). A subclass
supplies ``linear`` (diagonal operator L) and optionally ``nonlinear`` (N) of ``dv/dt = L v + N(v)`` in
Fourier space, and ``stable_dt``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping

import jax
import numpy as np

from ..domains import Domain, parse_domain
from ..ics import IC_KINDS
from ..spectral import Grid


@dataclass(frozen=True)
class Param:
    """A random PDE coefficient: what it means, its units, and whether it must be > 0."""

    description: str
    units: str = "1"
    positive: bool = False


@dataclass(frozen=True)
class PDE:
    """Base configuration shared by every PDE (subclasses set their own defaults)."""

    NAME: ClassVar[str] = ""
    EQUATION: ClassVar[str] = ""
    FIELDS: ClassVar[tuple[str, ...]] = ("u",)
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict[str, Param]] = {}

    n: int = 128  # grid points per dimension
    length: float = 1.0  # domain [0, length)^ndim
    t_end: float = 1.0  # final time; frames are saved at linspace(0, t_end, n_frames)
    n_frames: int = 51  # saved frames including t = 0
    dt: float | None = None  # internal step; None: the largest stable step that divides a frame interval
    ic: Any = None  # initial-condition distribution (see generator.ics)

    # --- what subclasses provide -------------------------------------------------------------------
    def linear(self, grid: Grid, p: Mapping[str, jax.Array]) -> jax.Array:
        """Diagonal operator L, [C, *kshape] (real or complex); p holds one traced scalar per parameter."""
        raise NotImplementedError

    def nonlinear(self, grid: Grid, p: Mapping[str, jax.Array]) -> Callable[[jax.Array], jax.Array] | None:
        """N(v_hat) as a function of the Fourier state [C, *kshape], or None for a linear PDE."""
        return None

    def stable_dt(self) -> float:
        """Largest internal step (time units) that is stable for every parameter in the domain."""
        return math.inf

    def sample_ic(self, key: jax.Array) -> jax.Array:
        """One initial condition, float32 [C, *space]."""
        return self.ic.sample(key, self.grid, len(self.FIELDS))

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
        for name, spec in self.PARAMS.items():
            try:
                domain = parse_domain(getattr(self, name))
            except ValueError as err:
                raise ValueError(f"{self.NAME}: parameter {name}: {err}") from None
            object.__setattr__(self, name, domain)
            low = min(domain.bounds)
            if spec.positive and not low > 0:
                raise ValueError(f"{self.NAME}: {name}={domain} not allowed: {spec.description} must be > 0")
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 8 or self.n % 2:
            raise ValueError(f"{self.NAME}: n={self.n!r} not allowed: resolution must be an even integer >= 8")
        if not (self.length > 0 and math.isfinite(self.length)):
            raise ValueError(f"{self.NAME}: length={self.length} not allowed: must be a finite number > 0")
        if not (self.t_end > 0 and math.isfinite(self.t_end)):
            raise ValueError(f"{self.NAME}: t_end={self.t_end} not allowed: must be a finite number > 0")
        if isinstance(self.n_frames, bool) or not isinstance(self.n_frames, int) or self.n_frames < 2:
            raise ValueError(f"{self.NAME}: n_frames={self.n_frames!r} not allowed: need an integer >= 2 (t=0 and t_end)")
        if self.dt is not None:
            stable = self.stable_dt()
            if not self.dt > 0:
                raise ValueError(f"{self.NAME}: dt={self.dt} not allowed: must be > 0")
            if self.dt > stable:
                raise ValueError(
                    f"{self.NAME}: dt={self.dt} is unstable for this grid and parameter domain: "
                    f"allowed dt <= {stable:.4g} (or leave dt unset to derive it)"
                )
        self.ic.check(self.grid)

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
            elif key == "ic":
                changes["ic"] = make_ic(value)
            elif key in self.config_fields():
                changes[key] = value if key in self.PARAMS else _coerce(key, value, getattr(self, key))
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
                ic_changes[key] = _coerce(f"ic.{key}", value, getattr(ic, key))
            changes["ic"] = dataclasses.replace(ic, **ic_changes)
        return dataclasses.replace(self, **changes)

    @classmethod
    def config_fields(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls) if f.name != "ic"]

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
            lines.append(f"  {name} ~ {getattr(self, name)}   {spec.description} [{spec.units}]")
        lines.append(f"  ic: {self.ic}")
        return "\n".join(lines)


def make_ic(value: Any):
    """An IC distribution from an object, a kind name (defaults) or a dict {"kind": ..., field: ...}."""
    if isinstance(value, str):
        value = {"kind": value}
    if isinstance(value, Mapping):
        fields = dict(value)
        kind = fields.pop("kind", None)
        if kind not in IC_KINDS:
            raise ValueError(f"unknown ic kind {kind!r}; allowed: {', '.join(IC_KINDS)}")
        cls = IC_KINDS[kind]
        defaults = cls()
        try:
            return cls(**{k: _coerce(f"ic.{k}", v, getattr(defaults, k)) for k, v in fields.items()})
        except AttributeError as err:
            raise ValueError(f"ic kind {kind!r}: {err}") from None
    if hasattr(value, "sample") and hasattr(value, "kind"):
        return value
    raise ValueError(f"bad ic {value!r}: expected a kind name ({', '.join(IC_KINDS)}) or a dict with 'kind'")


def _coerce(name: str, value: Any, current: Any) -> Any:
    """Convert a (possibly string) override to the type of the field's current value."""
    if not isinstance(value, str):
        if value is None or isinstance(value, (bool, int, float)):
            return value
        raise ValueError(f"bad value for {name}: {value!r} is not a {type(current or 0.0).__name__}")
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
        kind = "true/false" if isinstance(current, bool) else type(current or 0.0).__name__
        raise ValueError(f"bad value for {name}: {value!r} is not a {kind}") from None
    return text
