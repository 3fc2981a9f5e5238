"""Parameter domains: where a PDE coefficient is drawn from.

Four kinds, named as in Ray Tune / Optuna: ``Fixed(v)``, ``Uniform(a, b)``, ``LogUniform(a, b)``,
``Choice(v1, v2, ...)``. Each is accepted as an object or as a string such as
``"loguniform(1e-3, 1e-1)"`` (parsed with a small grammar, never ``eval``'d); a bare number means Fixed.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Union

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp


@dataclass(frozen=True)
class Fixed:
    """Always the same value."""

    value: float

    def __post_init__(self):
        object.__setattr__(self, "value", _finite("fixed", self.value))

    def sample(self, key: jax.Array) -> jax.Array:
        """One float32 scalar (the key is unused: a fixed value consumes no randomness)."""
        del key
        return jnp.float32(self.value)

    @property
    def bounds(self) -> tuple[float, float]:
        return (self.value, self.value)

    def contains(self, value: float) -> bool:
        """Whether ``value`` is one this domain can produce (float32 rounding allowed)."""
        return bool(np.float32(value) == np.float32(self.value))

    def __str__(self) -> str:
        return repr(float(self.value))


class _Interval:
    """What an interval domain [low, high] answers besides its draws (fields ``low``, ``high`` in the subclass)."""

    low: float
    high: float

    @property
    def bounds(self) -> tuple[float, float]:
        return (self.low, self.high)

    def contains(self, value: float) -> bool:
        """Whether ``value`` lies in [low, high] (float32 rounding allowed)."""
        return bool(np.float32(self.low) <= np.float32(value) <= np.float32(self.high))


@dataclass(frozen=True)
class Uniform(_Interval):
    """Uniform on [low, high)."""

    low: float
    high: float

    def __post_init__(self):
        _check_interval("uniform", self.low, self.high)

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.uniform(key, (), jnp.float32, self.low, self.high)

    def __str__(self) -> str:
        return f"uniform({self.low!r}, {self.high!r})"


@dataclass(frozen=True)
class LogUniform(_Interval):
    """log(value) uniform on [log low, log high); low > 0."""

    low: float
    high: float

    def __post_init__(self):
        _check_interval("loguniform", self.low, self.high)
        if self.low <= 0:
            raise ValueError(f"loguniform({self.low}, {self.high}): low must be > 0")

    def sample(self, key: jax.Array) -> jax.Array:
        log_v = jax.random.uniform(key, (), jnp.float32, math.log(self.low), math.log(self.high))
        # exp can round a hair past the ends in float32; the domain is a promise, so clip.
        return jnp.clip(jnp.exp(log_v), jnp.float32(self.low), jnp.float32(self.high))

    def __str__(self) -> str:
        return f"loguniform({self.low!r}, {self.high!r})"


@dataclass(frozen=True)
class Choice:
    """One of a finite set of values, each equally likely."""

    options: tuple[float, ...]

    def __post_init__(self):
        if len(self.options) == 0:
            raise ValueError("choice() needs at least one option, e.g. choice(0.5, 1.0)")
        object.__setattr__(self, "options", tuple(_finite("choice", o) for o in self.options))

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.choice(key, jnp.asarray(self.options, jnp.float32))

    @property
    def bounds(self) -> tuple[float, float]:
        return (min(self.options), max(self.options))

    def contains(self, value: float) -> bool:
        """Whether ``value`` is one of the options (compared in float32)."""
        return bool(np.float32(value) in np.asarray(self.options, np.float32))

    def __str__(self) -> str:
        return "choice(" + ", ".join(repr(o) for o in self.options) + ")"


Domain = Union[Fixed, Uniform, LogUniform, Choice]
DOMAIN_KINDS = {"fixed": Fixed, "uniform": Uniform, "loguniform": LogUniform, "choice": Choice}
_CALL = re.compile(r"^\s*([A-Za-z_]+)\s*\((.*)\)\s*$")


def _finite(kind: str, value) -> float:
    """``value`` as a float if it is a finite real number (not a bool); ValueError naming the domain otherwise."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{kind}({value!r}): values must be finite numbers")
    return float(value)


def _check_interval(kind: str, low: float, high: float) -> None:
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f"{kind}({low}, {high}): bounds must be finite numbers")
    if not low < high:
        raise ValueError(f"{kind}({low}, {high}): low must be < high")


def _number(text: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"bad domain {spec!r}: {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"bad domain {spec!r}: {text.strip()!r} is not a finite number")
    return value


def parse_domain(spec: Domain | str | float | int) -> Domain:
    """A Domain from an object, a number (-> Fixed) or a string like "uniform(0.1, 1)".

    Allowed strings: a number, "fixed(v)", "uniform(a, b)", "loguniform(a, b)", "choice(v1, v2, ...)".
    """
    if isinstance(spec, (Fixed, Uniform, LogUniform, Choice)):
        return spec
    if isinstance(spec, bool):
        raise ValueError(f"bad domain {spec!r}: expected a number or a domain string")
    if isinstance(spec, (int, float)):
        return Fixed(_number(str(spec), str(spec)))
    if not isinstance(spec, str):
        raise ValueError(f"bad domain {spec!r}: expected a number, a Domain or a string like 'uniform(0.1, 1)'")
    match = _CALL.match(spec)
    if match is None:
        try:
            float(spec)
        except ValueError:
            raise ValueError(
                f"bad domain {spec!r}: expected a number or one of "
                "fixed(v), uniform(a, b), loguniform(a, b), choice(v1, v2, ...)"
            ) from None
        return Fixed(_number(spec, spec))  # a number that float() reads but is not finite ('nan', '1e400') says so
    kind, args = match.group(1).lower(), match.group(2)
    if kind not in DOMAIN_KINDS:
        raise ValueError(f"bad domain {spec!r}: unknown kind {kind!r}; allowed: {', '.join(DOMAIN_KINDS)}")
    values = [_number(a, spec) for a in args.split(",")] if args.strip() else []
    if kind == "choice":
        return Choice(tuple(values))
    wanted = 1 if kind == "fixed" else 2
    if len(values) != wanted:
        raise ValueError(f"bad domain {spec!r}: {kind} takes {wanted} number(s), got {len(values)}")
    return DOMAIN_KINDS[kind](*values)
