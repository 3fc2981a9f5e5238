"""Model registry: ``MODELS`` (name -> class) and ``build_model``, with clear errors for unknown names and
settings; ``model_spec`` describes a built model so that ``build_model(**spec)`` rebuilds it.

Every model class declares what the registry and checkpoints need (the ``Surrogate`` interface): its ``name``,
its config dataclass ``Config``, and on each instance ndim, in_channels, out_channels, n_params and config.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Protocol

import torch
from torch import nn

from ..boundaries import all_periodic
from .fno import FNO
from .unet import UNet
from .user_model import UserModel


class Surrogate(Protocol):
    """What a model class declares: ``forward(x [B, in_channels, *space], params [B, n_params]) -> [B,
    out_channels, *space]``, built as ``cls(ndim, in_channels, out_channels, n_params, cls.Config(...), bc=...)``
    (bc: per-axis boundary conditions, None when every axis is periodic; kept as ``model.bc``). Optional:
    ``output_layer()``, the last nn.Linear, which ``zero_output`` sets to zero (``--corrector-start zero``)."""

    name: str
    Config: type
    ndim: int
    in_channels: int
    out_channels: int
    n_params: int
    config: object
    bc: tuple[str, ...] | None


MODELS: dict[str, type[Surrogate]] = {cls.name: cls for cls in (FNO, UNet)}
DIMENSIONS = (1, 2, 3)  # the spatial dimensions the built-in models take


def parse_model_name(name: str) -> tuple[str, int | None]:
    """"fno" -> ("fno", None); "fno2d" -> ("fno", 2): a suffix pins the spatial dimension."""
    base, ndim = name, None
    if name[-2:] in ("1d", "2d", "3d"):
        base, ndim = name[:-2], int(name[-2])
    if base not in MODELS:
        allowed = ", ".join([*MODELS, *(f"{m}{d}d" for m in MODELS for d in DIMENSIONS), "package.module:Class"])
        raise ValueError(f"unknown model {name!r}; allowed: {allowed}")
    return base, ndim


def build_model(name: str, ndim: int, in_channels: int, out_channels: int, n_params: int = 0,
                bc: tuple[str, ...] | None = None, **cfg) -> nn.Module:
    """A model for inputs [B, in_channels, *space] with ndim space dims, params [B, n_params] -> [B, out_channels, *space].

    bc: the data's per-axis boundary conditions (``pde.grid.bc``: periodic / dirichlet / neumann), from the data
    source; the model pads each axis accordingly (None or all periodic: the periodic model, as it always was).
    ``cfg`` sets the model's config dataclass (FNOConfig: width, modes, layers; UNetConfig: channels, depth);
    string values (from ``--model-set``) are converted to int. A name "package.module:Class" builds your own
    model (surrogate.user_model.UserModel: the class gets ndim, channels, n_params and ``cfg``; no wall padding).
    """
    if ":" in str(name):  # your own model, by import path (surrogate.user_model)
        return UserModel(name, ndim, in_channels, out_channels, n_params, **cfg)
    base, pinned = parse_model_name(name)
    if ndim not in DIMENSIONS:
        raise ValueError(f"model {name!r}: ndim={ndim} not supported; allowed: {', '.join(map(str, DIMENSIONS))}")
    if pinned is not None and pinned != ndim:
        raise ValueError(f"model {name!r} is {pinned}D but the PDE is {ndim}D; use {base!r} or {base}{ndim}d")
    cls = MODELS[base]
    config_cls = cls.Config
    fields = [f.name for f in dataclasses.fields(config_cls)]
    unknown = sorted(set(cfg) - set(fields))
    if unknown:
        raise ValueError(f"model {base!r}: unknown setting(s) {', '.join(unknown)}; allowed: {', '.join(fields)}")
    values = {}
    for key, value in cfg.items():
        try:
            values[key] = int(value)
        except (TypeError, ValueError):
            raise ValueError(f"model {base!r}: {key}={value!r} is not an integer") from None
    walls = not all_periodic(bc)  # a periodic model is built as it always was
    if walls and "bc" not in inspect.signature(cls).parameters:
        raise ValueError(f"model {base!r} has no padding for walls (its class takes no bc); the data's boundaries are "
                         f"{', '.join(bc)}; allowed: {', '.join(n for n, c in MODELS.items() if 'bc' in inspect.signature(c).parameters)}")
    return cls(ndim, in_channels, out_channels, n_params, config_cls(**values), **({"bc": tuple(bc)} if walls else {}))


def model_spec(model: Surrogate) -> dict:
    """Plain dict that ``build_model(**spec)`` turns back into the same architecture (for checkpoints): the
    model's own name, its shape (ndim, channels, n_params) and its config's fields."""
    if hasattr(model, "user_spec"):  # your own model (surrogate.user_model.UserModel)
        return model.user_spec()
    bc = getattr(model, "bc", None)
    walls = {} if bc is None else {"bc": list(bc)}  # a periodic model's spec is what it always was
    return {"name": model.name, "ndim": model.ndim, "in_channels": model.in_channels,
            "out_channels": model.out_channels, "n_params": model.n_params, **walls, **dataclasses.asdict(model.config)}


def zero_output(model: nn.Module) -> None:
    """Set a model's output layer (``model.output_layer()``: the FNO's last projection, the U-Net's head, each a
    pointwise linear map) to weight 0 and bias 0, so that model(x, p) is exactly 0 for every input; the layers
    before it keep their initialisation, and the first optimizer step moves the output layer off zero. ValueError
    (one line) for a model without ``output_layer`` (your own model: zero its output in its constructor)."""
    if not hasattr(model, "output_layer"):
        raise ValueError(f"--corrector-start zero not allowed with the model {type(model).__name__}: it has no "
                         f"output_layer(); allowed with {', '.join(MODELS)} (or use --corrector-start random)")
    layer = model.output_layer()
    with torch.no_grad():
        layer.weight.zero_()
        layer.bias.zero_()
