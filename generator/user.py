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

import hashlib
import importlib
import inspect
import sys
from typing import Any

ENTRY_POINT_GROUP = "pdestream.pdes"
_REGISTERED: dict[str, type] = {}
# What a problem class must offer beyond being a frozen dataclass (the attributes the sampler, cache and CLI read).
REQUIRED = ("NAME", "EQUATION", "FIELDS", "NDIM", "PARAMS", "grid", "times", "run_keys", "config", "replace",
            "describe", "failure")


def check_class(cls: Any, where: str) -> None:
    """One-line ValueError unless ``cls`` is a problem class that can be built (``where``: how it was named)."""
    from .problem import ProblemBase

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


def register(name: str, cls: type) -> type:
    """Make problem class ``cls`` known as ``name`` (get_pde, the CLI, ``pdestream list``); returns the class."""
    from .catalog import PDES

    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"register: name {name!r} not allowed: a PDE name is an identifier such as 'mypde'")
    if name in PDES:
        raise ValueError(f"register: name {name!r} not allowed: it is a catalog entry; choose another name")
    _REGISTERED[name] = _named(cls, name, f"register({name!r})")
    return cls


def unregister(name: str) -> None:
    """Forget a PDE registered by Python (tests; a no-op for an unknown name)."""
    _REGISTERED.pop(name, None)


def _entry_points() -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def names() -> list[str]:
    """The user PDEs known by name: registered by Python, then installed entry points."""
    return [*_REGISTERED, *(n for n in _entry_points() if n not in _REGISTERED)]


def load(spec: str) -> type:
    """The class at import path ``spec`` = "package.module:Class" (one-line ValueError if it cannot be had)."""
    module_name, _, qualname = spec.partition(":")
    if not module_name or not qualname:
        raise ValueError(f"PDE {spec!r} not allowed: an import path is 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except Exception as err:  # any error of the user's module: say which module and why, no traceback
        raise ValueError(f"PDE {spec!r}: module {module_name!r} does not import: {type(err).__name__}: {err}") from None
    obj: Any = module
    for part in qualname.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"PDE {spec!r}: module {module_name!r} has no {qualname!r}")
        obj = getattr(obj, part)
    return obj


def lookup(name: str) -> type | None:
    """The user class called ``name`` (registered, entry point, or an import path), or None."""
    if name in _REGISTERED:
        return _REGISTERED[name]
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


def user_class(cls: type) -> type | None:
    """The first class in ``cls``'s MRO from outside the package (a walled variant's user class), or None."""
    return next((c for c in cls.__mro__ if c.__module__.split(".")[0] not in ("generator", "builtins", "abc")), None)


def origin(cls: type) -> dict[str, Any] | None:
    """Where a user problem class came from: {module, class, version, source_sha256}; None for the package's own."""
    cls = user_class(cls)
    if cls is None:
        return None
    module = sys.modules.get(cls.__module__)
    try:
        source = inspect.getsource(module) if module is not None else inspect.getsource(cls)
    except (OSError, TypeError):  # defined interactively: the class's own source if any, else nothing to hash
        source = None
    return {"module": cls.__module__, "class": cls.__qualname__, "version": str(getattr(cls, "VERSION", "")),
            "source_sha256": hashlib.sha256(source.encode()).hexdigest()[:16] if source is not None else None}


def from_origin(name: str, stored: dict) -> type:
    """The class of a stored config's origin, refused in one line if its code is no longer what made the config."""
    if not isinstance(stored, dict) or not {"module", "class"} <= set(stored):
        raise ValueError(f"PDE {name!r}: origin {stored!r} not allowed: needs module and class")
    cls = lookup(name) if name in names() else None
    if cls is None:  # another process (a worker): the class by its origin, named as it was
        path = f"{stored['module']}:{stored['class']}"
        cls = load(path)
        check_class(cls, f"PDE {path!r}")
        cls = cls if cls.NAME else _named(cls, name, f"PDE {path!r}")
    now = origin(cls) or {}
    for key in ("module", "class", "version", "source_sha256"):
        if stored.get(key) != now.get(key):
            raise ValueError(f"PDE {name!r}: its code changed since this config was made ({key}: was "
                             f"{stored.get(key)!r}, now {now.get(key)!r} in {now.get('module')}:{now.get('class')}); "
                             "use the code that made it, or start a new cache / run")
    return cls


def rebuild(config: dict):
    """The problem of a pickled user problem's ``config()`` (see ProblemBase.__reduce_ex__)."""
    from . import from_config

    return from_config(config)
