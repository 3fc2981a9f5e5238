"""The `neuraloperator` library's FNO (``neuralop.models.FNO``) as a pdestream model.

    pip install neuraloperator
    PYTHONPATH=. pdestream train burgers1d --model examples.neuralop_fno:NeuralopFNO --model-set modes=16

pdestream builds ``NeuralopFNO(ndim, in_channels, out_channels, n_params, **model_set)`` and calls
``forward(x [B, in_channels, *space], params [B, n_params] or None) -> [B, out_channels, *space]``. The PDE's
parameters reach the network as constant input channels, one per parameter; neuralop adds the grid coordinates
itself (its default positional embedding). Works in 1D, 2D and 3D (modes per axis: ``modes``).
"""

import torch
from neuralop.models import FNO
from torch import nn


class NeuralopFNO(nn.Module):
    """neuralop's FNO with ``modes`` Fourier modes per axis, ``width`` hidden channels and ``layers`` blocks."""

    def __init__(self, ndim: int, in_channels: int, out_channels: int, n_params: int = 0,
                 modes: int = 16, width: int = 32, layers: int = 4):
        super().__init__()
        self.n_params = n_params
        self.fno = FNO(n_modes=(modes,) * ndim, in_channels=in_channels + n_params, out_channels=out_channels,
                       hidden_channels=width, n_layers=layers)

    def forward(self, x: torch.Tensor, params: torch.Tensor | None = None) -> torch.Tensor:
        if self.n_params:  # [B, n_params] -> [B, n_params, *space], beside the state's channels
            space = x.shape[2:]
            x = torch.cat([x, params.reshape(*params.shape, *(1,) * len(space)).expand(-1, -1, *space)], dim=1)
        return self.fno(x)

    def state_dict(self, *args, **kwargs):
        """The weights without neuralop's '_metadata' entry (its constructor's arguments, functions among them):
        pdestream's checkpoints hold tensors and plain containers only (torch.load(weights_only=True))."""
        state = super().state_dict(*args, **kwargs)
        state.pop("_metadata", None)  # neuralop's load_state_dict does without it
        return state
