"""PDE definitions: one file per equation (serving every dimension it is defined in). The catalog of named
entries (diffusion2d, ...) is generator.catalog."""

from .base import PDE, LinearPDE, Param

__all__ = ["LinearPDE", "PDE", "Param"]
