"""JAX imported on first use: ``jax``, ``jnp`` and ``jit`` for the generator's modules.

Why: reading a problem's definition (its settings, checks, parameter domains) needs no JAX, and importing JAX
costs 1-2 s (more on a loaded machine). With these stand-ins, ``import pdestream.generator`` and
``get_pde(name, settings)`` run without JAX, so a bad ``--set`` is answered before JAX is imported; JAX is
imported the first time a module reads an attribute of ``jax`` / ``jnp`` or calls a ``jit`` function.
Everything after that is JAX itself: the stand-ins forward every attribute to the imported module.
"""

from __future__ import annotations

import functools
import importlib
from types import ModuleType
from typing import Any, Callable


class LazyModule:
    """Stands for the module ``name``: its first attribute read imports the module, every read forwards to it."""

    def __init__(self, name: str):
        self.__dict__["_name"] = name

    def _module(self) -> ModuleType:
        return importlib.import_module(self._name)  # sys.modules after the first call: a dict lookup

    def __getattr__(self, attr: str) -> Any:
        return getattr(self._module(), attr)

    def __setattr__(self, attr: str, value: Any) -> None:  # (tests' monkeypatch reaches the module itself)
        setattr(self._module(), attr, value)

    def __delattr__(self, attr: str) -> None:
        delattr(self._module(), attr)

    def __repr__(self) -> str:
        return f"<lazily imported module {self._name!r}>"


jax = LazyModule("jax")
jnp = LazyModule("jax.numpy")


def jit(fun: Callable | None = None, /, **options) -> Callable:
    """``jax.jit(fun, **options)``, made on the first call, as a decorator (``@jit`` or ``@jit(static_argnums=0)``)
    for module-level functions, whose definition then does not import JAX."""
    if fun is None:
        return functools.partial(jit, **options)
    made: list[Callable] = []

    @functools.wraps(fun)
    def call(*args, **kwargs):
        if not made:
            made.append(jax.jit(fun, **options))
        return made[0](*args, **kwargs)

    return call
