"""Where a user's problem class came from, and the class again from that record (no other part of the package).

A user problem's ``config()`` carries its origin: {module, class, version, source_sha256}. ``rebuild`` turns such
a config back into the problem in any process (a worker, a resumed run) and refuses it in one line when the code
that made it changed. Kept apart from ``generator.user`` (registration, entry points) and ``generator.problem``
(which records the origin) so that neither imports the other back: this module imports nothing of the package.
"""

from __future__ import annotations

import hashlib
import inspect
import sys
from typing import Any

from pdestream import load_object  # the package's root: no JAX, no torch

# Problem classes made known by ``generator.register`` in this process, by name (a class defined inside a
# function cannot be found again by its import path, so rebuild looks here first).
REGISTERED: dict[str, type] = {}


def load(spec: str) -> Any:
    """The object at import path ``spec`` = "package.module:Class" (one-line ValueError if it cannot be had)."""
    return load_object(spec, "PDE")


def user_class(cls: type) -> type | None:
    """The first class in ``cls``'s MRO from outside the package (a walled variant's user class), or None."""
    return next((c for c in cls.__mro__ if c.__module__.partition(".")[0] not in ("pdestream", "builtins", "abc")), None)


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


def class_of(name: str, stored: dict) -> type:
    """The class of a stored config's origin (registered here under ``name``, else imported by its path and named
    ``name`` if it has no NAME), refused in one line if its code is no longer what made the config."""
    if not isinstance(stored, dict) or not {"module", "class"} <= set(stored):
        raise ValueError(f"PDE {name!r}: origin {stored!r} not allowed: needs module and class")
    cls = REGISTERED.get(name)
    if cls is None:  # another process (a worker), an entry point or an import path: the class by its origin
        cls = load(f"{stored['module']}:{stored['class']}")
        if not inspect.isclass(cls) or not hasattr(cls, "NAME"):
            raise ValueError(f"PDE {name!r}: {stored['module']}:{stored['class']} is no longer a problem class")
        if not cls.NAME:
            cls.NAME = name  # named as it was when the config was made
    now = origin(cls) or {}
    for key in ("module", "class", "version", "source_sha256"):
        if stored.get(key) != now.get(key):
            raise ValueError(f"PDE {name!r}: its code changed since this config was made ({key}: was "
                             f"{stored.get(key)!r}, now {now.get(key)!r} in {now.get('module')}:{now.get('class')}); "
                             "use the code that made it, or start a new cache / run")
    return cls


def rebuild(config: dict):
    """The problem of a user problem's ``config()`` (what it pickles as: see ProblemBase.__reduce_ex__)."""
    cfg = dict(config)
    name = cfg.pop("pde", None)
    cls = class_of(name, cfg.pop("origin", None))
    return cls().replace(cfg) if cfg else cls()
