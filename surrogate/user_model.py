"""Your own model: ``--model package.module:MyNet`` wherever a model name goes (train, compare, checkpoints).

The class is a torch ``nn.Module`` built as ``MyNet(ndim=..., in_channels=..., out_channels=..., n_params=...,
**model_set)`` (``--model-set key=value``: ints, floats or strings) whose ``forward(x, params)`` maps x
[B, in_channels, *space] and params [B, n_params] (None when n_params = 0) to [B, out_channels, *space].
``UserModel`` wraps it so the training loop, checkpoints and resume see what they see of the built-in models;
its spec records the import path and the sha256 of the module's source, so a checkpoint is resumed or loaded
only by the same code. A module that does not import, a name that is not an nn.Module class, a constructor that
refuses the settings and an output of the wrong shape are one line each.
"""

from __future__ import annotations

import hashlib
import inspect
import sys

import torch
from torch import nn

from pdestream import load_object


def load_class(path: str) -> type:
    """The nn.Module class at ``path`` = "package.module:Class" (one-line ValueError otherwise)."""
    obj = load_object(path, "model")
    if not (inspect.isclass(obj) and issubclass(obj, nn.Module)):
        raise ValueError(f"model {path!r}: {obj!r} is not a torch nn.Module class")
    return obj


def source_hash(cls: type) -> str | None:
    """sha256 (16 hex digits) of the source of ``cls``'s module, or None when it has none (defined interactively)."""
    try:
        source = inspect.getsource(sys.modules[cls.__module__])
    except (OSError, TypeError, KeyError):
        return None
    return hashlib.sha256(source.encode()).hexdigest()[:16]


def setting(value):
    """A --model-set value as given on the command line -> int, float, or the string itself."""
    if not isinstance(value, str):
        return value
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


class UserModel(nn.Module):
    """A user's model as a pdestream surrogate: name (its import path), ndim, channels, n_params, config (the
    --model-set dict) and the source hash of its module; forward checks the output's shape."""

    def __init__(self, path: str, ndim: int, in_channels: int, out_channels: int, n_params: int = 0,
                 source_sha256: str | None = None, **cfg):
        super().__init__()
        cls = load_class(path)
        now = source_hash(cls)
        if source_sha256 is not None and source_sha256 != now:  # a checkpoint's model: only the code that made it
            raise ValueError(f"model {path!r}: its code changed since the checkpoint was made (source sha256 was "
                             f"{source_sha256}, now {now}); use the code that made it, or train again")
        self.name, self.ndim, self.in_channels, self.out_channels = path, ndim, in_channels, out_channels
        self.n_params, self.source_sha256 = n_params, now
        self.config = {k: setting(v) for k, v in cfg.items()}
        try:
            self.net = cls(ndim=ndim, in_channels=in_channels, out_channels=out_channels, n_params=n_params,
                           **self.config)
        except TypeError as err:  # a setting the class does not take, or a constructor of another signature
            raise ValueError(f"model {path!r} cannot be built as {cls.__name__}(ndim, in_channels, out_channels, "
                             f"n_params, {', '.join(self.config) or 'no --model-set keys'}): {err}") from None

    def forward(self, x: torch.Tensor, params: torch.Tensor | None = None) -> torch.Tensor:
        try:
            out = self.net(x, params)  # [B, out_channels, *space]
        except Exception as err:  # the user's code: one line naming the model and the error (chained for Python)
            first = str(err).strip().splitlines()[0] if str(err).strip() else ""
            raise ValueError(f"model {self.name!r}: forward(x {tuple(x.shape)}, params) raised "
                             f"{type(err).__name__}{': ' + first if first else ''}") from err
        want = (x.shape[0], self.out_channels, *x.shape[2:])
        if not isinstance(out, torch.Tensor) or tuple(out.shape) != want:
            got = tuple(out.shape) if isinstance(out, torch.Tensor) else type(out).__name__
            raise ValueError(f"model {self.name!r}: output shape {got} does not match [B, out_channels, *space] = "
                             f"{want} for input {tuple(x.shape)}")
        return out

    def user_spec(self) -> dict:
        """What ``build_model(**spec)`` rebuilds this model from (checkpoints; compared on resume)."""
        return {"name": self.name, "ndim": self.ndim, "in_channels": self.in_channels,
                "out_channels": self.out_channels, "n_params": self.n_params, "source_sha256": self.source_sha256,
                **self.config}


def check_output(model: nn.Module, space: tuple[int, ...]) -> None:
    """For a user's model: one forward pass on zeros [1, in_channels, *space] before a run writes anything, so a
    wrong output shape is refused with nothing left behind (the built-in models are right by construction)."""
    if not hasattr(model, "user_spec"):  # a built-in model
        return
    device = next(model.parameters(), torch.zeros(())).device
    params = torch.zeros(1, model.n_params, device=device) if model.n_params else None
    with torch.no_grad():
        model(torch.zeros(1, model.in_channels, *space, device=device), params)
    check_state_dict(model)


def check_state_dict(model: nn.Module) -> None:
    """Checkpoints load with ``torch.load(weights_only=True)`` (tensors and plain containers only), so a user's
    model whose state_dict holds other objects (a library's metadata with functions in it) is refused here, in
    one line, instead of after training when its checkpoint is read back."""
    import io

    buffer = io.BytesIO()
    torch.save(model.state_dict(), buffer)
    buffer.seek(0)
    try:
        torch.load(buffer, map_location="cpu", weights_only=True)
    except Exception as err:  # torch's UnpicklingError explains itself over many lines: keep the reason
        import re

        found = re.search(r"GLOBAL (\S+)", str(err))
        what = found.group(1) if found else type(err).__name__
        raise ValueError(f"model {model.name!r}: its state_dict holds {what}, not only tensors and plain "
                         "containers, so its checkpoints would not load with torch.load(weights_only=True); "
                         "drop such entries in the model's state_dict()") from None
