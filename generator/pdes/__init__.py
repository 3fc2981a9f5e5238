"""The PDE catalog: one file per PDE, one line each in PDES."""

from .advection import Advection1D
from .base import PDE, Param
from .burgers import Burgers1D
from .diffusion import Diffusion1D
from .grayscott import GrayScott2D
from .kdv1d import KdV1D
from .ks import KS1D
from .ns2d import NS2D

PDES: dict[str, type[PDE]] = {
    cls.NAME: cls for cls in (Advection1D, Diffusion1D, Burgers1D, KdV1D, KS1D, NS2D, GrayScott2D)
}

__all__ = ["PDE", "PDES", "Param"]
