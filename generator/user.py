"""Your own PDE: problems declared outside the package, found by name like the catalog's entries.

Three ways to make a problem class known (each a frozen dataclass implementing ``generator.problem.Problem``;
the easy one subclasses ``generator.PDE`` and supplies ``linear``, ``nonlinear`` and ``stable_dt``):

* Python: ``generator.register("mypde", MyPDE)``;
* an installed package's entry point in group ``pdestream.pdes`` (``mypde = "mypkg.module:MyPDE"``);
* an import path wherever a name goes: ``pdestream generate mypkg.module:MyPDE`` (and ``pde = "..."`` in TOML).

A user problem's ``config()`` carries its origin (module, class, ``VERSION`` and the sha256 of its module's
source), so a cache of it is never resumed, nor a run trained from it, with other code: the config hash differs,
and ``from_config`` refuses an origin whose source changed.
"""

from __future__ import annotations

import inspect
from typing import Any

from .origin import REGISTERED, load
from .problem import ProblemBase

ENTRY_POINT_GROUP = "pdestream.pdes"
# What a problem class must offer beyond being a frozen dataclass (the attributes the sampler, cache and CLI read).
REQUIRED = ("NAME", "EQUATION", "FIELDS", "NDIM", "PARAMS", "grid", "times", "run_keys", "config", "replace",
            "describe", "failure")


def check_class(cls: Any, where: str) -> None:
    """One-line ValueError unless ``cls`` is a problem class that can be built (``where``: how it was named)."""
    if not inspect.isclass(cls):
        raise ValueError(f"{where}: {cls!r} is not a class; a PDE is a class (subclass generator.PDE)")
    missing = [name for name in REQUIRED if not hasattr(cls, name)]
    if missing:
        raise ValueError(f"{where}: class {cls.__name__} lacks {', '.join(missing)}; a PDE subclasses generator.PDE "
                         "(or generator.ProblemBase) and sets NAME, EQUATION, FIELDS, NDIM, PARAMS")
    abstract = sorted(getattr(cls, "__abstractmethods__", ()))
    if abstract:
        raise ValueError(f"{where}: class {cls.__name__} lacks the required method(s) {', '.join(abstract)}")
    params = cls.__dict__.get("__dataclass_params__")  # its own: a subclass of a dataclass is not one by itself
    if not issubclass(cls, ProblemBase) or params is None or not params.frozen:
        raise ValueError(f"{where}: class {cls.__name__} must be a @dataclass(frozen=True) subclass of generator.PDE "
                         "(or generator.ProblemBase)")
    if cls.DIMENSIONS:
        raise ValueError(f"{where}: class {cls.__name__} has DIMENSIONS; a user PDE is one class per dimension "
                         "(set NDIM)")


def _named(cls: type, name: str, where: str) -> type:
    """``cls`` known as ``name``: its NAME set if empty, refused if it names another PDE."""
    check_class(cls, where)
    if not cls.NAME:
        cls.NAME = name  # the class is the user's; its name is where the user put it
    elif cls.NAME != name:
        raise ValueError(f"{where}: class {cls.__name__} has NAME {cls.NAME!r}; register it as {cls.NAME!r} "
                         "(or leave NAME empty)")
    return cls


def register(name: str, cls: type, taken: tuple[str, ...] = ()) -> type:
    """Make problem class ``cls`` known as ``name``; returns the class. ``taken``: names it may not have (the
    catalog's: ``generator.register`` passes them, this module does not import the catalog)."""
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"register: name {name!r} not allowed: a PDE name is an identifier such as 'mypde'")
    if name in taken:
        raise ValueError(f"register: name {name!r} not allowed: it is a catalog entry or a recipe; choose another name")
    REGISTERED[name] = _named(cls, name, f"register({name!r})")
    return cls


def unregister(name: str) -> None:
    """Forget a PDE registered by Python (tests; a no-op for an unknown name)."""
    REGISTERED.pop(name, None)


def _entry_points() -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def names() -> list[str]:
    """The user PDEs known by name: registered by Python, then installed entry points."""
    return [*REGISTERED, *(n for n in _entry_points() if n not in REGISTERED)]


def lookup(name: str) -> type | None:
    """The user class called ``name`` (registered, entry point, or an import path), or None."""
    if name in REGISTERED:
        return REGISTERED[name]
    eps = _entry_points()
    if name in eps:
        return _named(load(eps[name].value), name, f"entry point {name!r} ({eps[name].value})")
    if ":" in name:
        return _adopted(load(name), name)
    return None


def _adopted(cls: type, path: str) -> type:
    """A class found by import path: checked, and named by the path if it declares no NAME of its own."""
    check_class(cls, f"PDE {path!r}")
    return cls if cls.NAME else _named(cls, path, f"PDE {path!r}")
