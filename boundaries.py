"""The boundary conditions of an axis, declared once: periodic, dirichlet, neumann, each a value with behaviour.

Below both JAX and torch (this module imports neither, nor anything of pdestream): the solvers, the caches and
the models ask a ``Boundary`` what they need of it instead of comparing its name:

    Boundary.of("dirichlet").periodic      False (True only for periodic)
    Boundary.of("dirichlet").pins_value    True: a given value on the wall (a sine basis, boundary values bc_lo /
                                           bc_hi lifted, no constant mode); False for periodic and neumann
    Boundary.of("neumann").bc_type         'open' (The Well's word: periodic / wall / open)
    Boundary.of("neumann").pad_mode        'replicate' (torch's padding mode a model uses on that axis)
    Boundary.of("dirichlet").derivative    (NEUMANN, 1): the basis of d/dx of a field on that axis and its sign
    parse("x=dirichlet,y=periodic", 2)     ('dirichlet', 'periodic')

A ``Boundary`` is a ``StrEnum``: it equals, hashes, formats and is stored as its word ('periodic', 'dirichlet',
'neumann'), so a cache written with these values reads the same as one written with the words, and a tuple of
words (grid.bc, a cache's attribute) needs no conversion. The words are stored; ``Boundary.of`` gives the value.

The flow solver's side kinds (generator.flow.grid.SIDE_KINDS: wall, inflow, outflow, periodic) are not declared
here: they are conditions of one side on velocity and pressure, of which a per-axis boundary is a consequence
(generator.flow.problem.FlowGrid.bc maps them); only their 'periodic' is this module's, asked with ``is_periodic``.
"""

from __future__ import annotations

import enum
from typing import Any, Iterable, Mapping

AXES = ("x", "y", "z")


class Boundary(enum.StrEnum):
    """One axis's boundary condition; see the module's docstring for what it answers."""

    PERIODIC = "periodic"
    DIRICHLET = "dirichlet"
    NEUMANN = "neumann"

    @classmethod
    def of(cls, word: Any) -> "Boundary":
        """The boundary named ``word`` (a Boundary or its word, any case); ValueError in one line otherwise."""
        text = str(word).strip().lower()
        try:
            return cls(text)
        except ValueError:
            raise ValueError(f"boundary {word!r} not allowed; allowed: {', '.join(BOUNDARY_TYPES)}") from None

    @property
    def periodic(self) -> bool:
        """The axis wraps around (no wall)."""
        return self is Boundary.PERIODIC

    @property
    def walled(self) -> bool:
        """The axis ends in walls (Dirichlet or Neumann): a model pads it, a spectral grid uses sines / cosines."""
        return self is not Boundary.PERIODIC

    @property
    def pins_value(self) -> bool:
        """A value is given on the walls (Dirichlet): boundary values may be set (bc_lo / bc_hi), the field has
        no constant mode, its basis is odd about the walls (sines)."""
        return self is Boundary.DIRICHLET

    @property
    def bc_type(self) -> str:
        """The Well's per-axis word: a Dirichlet (given-value) boundary is a wall, a zero-gradient one is open."""
        return BC_TYPE[self.value]

    @property
    def pad_mode(self) -> str:
        """The torch padding mode of a convolution on this axis: wrap around, zeros (the wall's value), or the
        edge value repeated (zero gradient)."""
        return _PAD_MODE[self]

    @property
    def derivative(self) -> tuple["Boundary", int]:
        """The boundary kind of d/dx of a field on this axis and the sign of the basis change: a sine series'
        derivative is a cosine one (+), a cosine series' a sine one (-); periodic stays periodic."""
        return _DERIVATIVE[self]


BOUNDARY_TYPES: tuple[str, ...] = tuple(b.value for b in Boundary)  # ('periodic', 'dirichlet', 'neumann')
# The Well's per-axis vocabulary, keyed by the word (as generator.grids has always offered it).
BC_TYPE: dict[str, str] = {"periodic": "periodic", "dirichlet": "wall", "neumann": "open"}
_PAD_MODE = {Boundary.PERIODIC: "circular", Boundary.DIRICHLET: "constant", Boundary.NEUMANN: "replicate"}
_DERIVATIVE = {Boundary.PERIODIC: (Boundary.PERIODIC, 1), Boundary.DIRICHLET: (Boundary.NEUMANN, 1),
               Boundary.NEUMANN: (Boundary.DIRICHLET, -1)}
PERIODIC, DIRICHLET, NEUMANN = Boundary.PERIODIC, Boundary.DIRICHLET, Boundary.NEUMANN


def is_periodic(word: Any) -> bool:
    """``word`` is the periodic boundary's word, as stored (any other word, a flow side kind such as 'wall'
    included: False). Exact: user text is read with ``Boundary.of`` or ``parse``."""
    return str(word) == Boundary.PERIODIC.value


def kinds(bcs: Iterable[Any]) -> tuple[Boundary, ...]:
    """The Boundary of each word in ``bcs``; ValueError in one line for a word that names none."""
    return tuple(Boundary.of(b) for b in bcs)


def _known(word: Any) -> Boundary | None:
    """The Boundary whose stored word ``word`` is exactly, else None."""
    try:
        return Boundary(str(word))
    except ValueError:
        return None


def all_periodic(bcs: Iterable[Any] | None) -> bool:
    """Every axis periodic (None, the models' 'no walls', counts as all periodic); a word that names no boundary
    is not periodic (the caller's check refuses it in its own words)."""
    return bcs is None or all(is_periodic(b) for b in bcs)


def pins_value(bcs: Iterable[Any]) -> bool:
    """Some axis has a given value on its walls (Dirichlet); unknown words count as not."""
    return any((k := _known(b)) is not None and k.pins_value for b in bcs)


def first_pinned(bcs: Iterable[Any]) -> int:
    """The index of the first axis with a given wall value (Dirichlet); ValueError when there is none."""
    bcs = tuple(bcs)
    for axis, b in enumerate(bcs):
        if (k := _known(b)) is not None and k.pins_value:
            return axis
    raise ValueError(f"no {Boundary.DIRICHLET.value} axis among {list(map(str, bcs))}")


def periodic_words(ndim: int) -> tuple[str, ...]:
    """('periodic',) * ndim: the boundaries of a grid with no walls, as stored."""
    return (Boundary.PERIODIC.value,) * ndim


def words(value: Any, ndim: int) -> tuple[str, ...]:
    """One word per axis from a stored attribute: 'dirichlet periodic' (split), or nothing (all periodic)."""
    return tuple(str(value).split()) if value else periodic_words(ndim)


def parse(spec: Any, ndim: int, *, allowed: Iterable[Any] = BOUNDARY_TYPES, current: Iterable[Any] | None = None,
          name: str = "bc") -> tuple[str, ...]:
    """The per-axis boundary words after applying ``spec`` to ``current`` (all periodic when None): a word for
    every axis ('dirichlet'), per axis text ('x=dirichlet,y=periodic'), or a mapping {"bc": ..., "bc.x": ...}
    (a TOML dotted key gives {"bc": {"x": ...}}). ValueError in one line naming the bad value and what
    is allowed; ``name`` (an entry's name) starts it, ``allowed`` (words) limits the kinds."""
    allowed = tuple(str(a) for a in allowed)
    bcs = list(current or periodic_words(ndim))
    axes = AXES[:ndim]

    def put(axis: str, value: Any, shown: str) -> None:
        if axis not in axes:
            raise ValueError(f"{name}: bc.{axis} not allowed: the axes of a {ndim}D entry are {', '.join(axes)}")
        word = str(value).strip().lower()
        if word not in allowed:
            extra = f" ({word} is not among this entry's boundaries)" if word in BOUNDARY_TYPES else ""
            raise ValueError(f"{name}: {shown}={value!r} not allowed{extra}; allowed: {', '.join(allowed)}")
        bcs[axes.index(axis)] = word

    if not isinstance(spec, Mapping):
        spec = {"bc": spec}
    for key, value in spec.items():
        if key == "bc" and isinstance(value, Mapping):  # a TOML dotted key bc.x = "neumann"
            for axis, word in value.items():
                put(axis, word, f"bc.{axis}")
        elif key == "bc":
            text = str(value)
            if "=" in text:
                named = [part.partition("=")[0].strip() for part in text.split(",")]
                twice = sorted({a for a in named if named.count(a) > 1})
                if twice:  # the last one would win, silently
                    raise ValueError(f"{name}: bc={text!r} not allowed: axis {', '.join(twice)} given twice; "
                                     "give each axis once, e.g. 'x=dirichlet,y=periodic'")
                for part in text.split(","):
                    axis, _, word = part.partition("=")
                    put(axis.strip(), word, f"bc.{axis.strip()}")
            else:
                for axis in axes:
                    put(axis, text, "bc")
        else:
            put(key[3:], value, key)  # "bc.x"
    return tuple(bcs)


def text(bcs: Iterable[Any]) -> str:
    """The canonical ``bc`` setting: one word when every axis has it, else 'x=dirichlet,y=periodic'."""
    bcs = tuple(str(b) for b in bcs)
    return bcs[0] if len(set(bcs)) == 1 else ",".join(f"{AXES[a]}={b}" for a, b in enumerate(bcs))


__all__ = ["AXES", "BC_TYPE", "BOUNDARY_TYPES", "Boundary", "DIRICHLET", "NEUMANN", "PERIODIC", "all_periodic",
           "first_pinned", "is_periodic", "kinds", "parse", "periodic_words", "pins_value", "text", "words"]
