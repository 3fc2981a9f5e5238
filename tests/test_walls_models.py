"""Models on walled data: the FNO pads a wall axis (domain padding) and the U-Net pads it without wrapping,
while a periodic axis still wraps; a periodic model is exactly what it was; the boundary conditions reach the
model from the data source, its spec and checkpoint (so --resume rebuilds the same padding)."""

import pytest
import torch
from torch import nn

from pdestream.surrogate.models import build_model, model_spec
from pdestream.surrogate.modes import subsample
from pdestream.surrogate.unet import WallConv

torch.set_num_threads(1)


def reach(model, ndim: int, axis: int) -> float:
    """How much the output at the far end of ``axis`` moves when the input at its near end is perturbed (at init
    weights): > 0 means information crossed the wall, i.e. the axis wraps around."""
    torch.manual_seed(0)
    x = torch.randn(2, 1, *([16] * ndim))
    bumped = x.clone()
    index = [slice(None), slice(None)] + [slice(None)] * ndim
    index[2 + axis] = 0
    bumped[tuple(index)] += 10.0
    with torch.no_grad():
        a, b = model(x), model(bumped)
    far = [slice(None), slice(None)] + [slice(None)] * ndim
    far[2 + axis] = slice(-1, None)
    return float((a[tuple(far)] - b[tuple(far)]).abs().max())


@pytest.mark.parametrize("bc", ["dirichlet", "neumann"])
def test_a_unet_convolution_does_not_wrap_a_wall_axis_and_wraps_a_periodic_one(bc):
    torch.manual_seed(0)
    conv = WallConv(2, 1, 2, (bc, "periodic"))
    assert reach(conv, 2, 0) == 0.0  # the stencil of the far wall's points never sees the near wall
    assert reach(conv, 2, 1) > 1e-3  # the periodic axis wraps, as nn.Conv2d(padding_mode="circular") does
    periodic = nn.Conv2d(1, 2, 3, padding=1, padding_mode="circular")
    periodic.load_state_dict(conv.conv.state_dict())
    x = torch.randn(2, 1, 16, 16)
    both = WallConv(2, 1, 2, ("periodic", "periodic"))
    both.conv.load_state_dict(conv.conv.state_dict())
    torch.testing.assert_close(both(x), periodic(x), rtol=1e-6, atol=1e-6)


def test_the_fno_pads_only_its_wall_axes():
    torch.manual_seed(0)
    model = build_model("fno", 2, 1, 1, 0, bc=("dirichlet", "periodic"), width=8, modes=4, layers=2)
    seen = []
    model.spectral[0].register_forward_hook(lambda mod, args, out: seen.append(tuple(args[0].shape)))
    assert model(torch.randn(2, 1, 32, 16)).shape == (2, 1, 32, 16)
    assert seen == [(2, 8, 32 + 4, 16)]  # max(MIN_PAD, 32 / 8) zeros after x's far wall; y (periodic) unpadded
    assert reach(model, 2, 0) < reach(build_model("fno", 2, 1, 1, 0, width=8, modes=4, layers=2), 2, 0)


@pytest.mark.parametrize("name, cfg", [("unet", {"channels": 4, "depth": 2}), ("fno", {"width": 8, "modes": 4, "layers": 2})])
@pytest.mark.parametrize("ndim, bc", [(1, ("neumann",)), (2, ("dirichlet", "neumann")), (2, ("periodic", "dirichlet"))])
def test_walled_models_keep_shapes_and_rebuild_from_their_spec(name, cfg, ndim, bc):
    torch.manual_seed(0)
    model = build_model(name, ndim, 2, 3, 1, bc=bc, **cfg)
    x, p = torch.randn(2, 2, *([16] * ndim)), torch.randn(2, 1)
    assert model(x, p).shape == (2, 3, *([16] * ndim))
    spec = model_spec(model)
    assert spec["bc"] == list(bc)
    again = build_model(spec.pop("name"), spec.pop("ndim"), spec.pop("in_channels"), spec.pop("out_channels"),
                        spec.pop("n_params"), **spec)
    again.load_state_dict(model.state_dict())
    assert torch.equal(again(x, p), model(x, p))


@pytest.mark.parametrize("name", ["unet", "fno"])
def test_an_all_periodic_model_is_unchanged(name):
    torch.manual_seed(0)
    old = build_model(name, 2, 1, 1, 1)
    torch.manual_seed(0)
    new = build_model(name, 2, 1, 1, 1, bc=("periodic", "periodic"))
    assert "bc" not in model_spec(new) and model_spec(new) == model_spec(old)
    assert list(new.state_dict()) == list(old.state_dict())  # checkpoints from before walls still load
    x, p = torch.randn(2, 1, 16, 16), torch.randn(2, 1)
    assert torch.equal(new(x, p), old(x, p))


def test_bad_bc_is_one_line():
    with pytest.raises(ValueError, match=r"fno: bc=\['wall'\] not allowed: need 1 of periodic, dirichlet, neumann"):
        build_model("fno", 1, 1, 1, bc=("wall",))


def test_coarse_points_of_a_walled_axis_are_its_cell_centres():
    fine = (torch.arange(16.0) + 0.5) / 16  # cell centres of [0, 1], 16 cells
    for factor in (2, 4):
        coarse = (torch.arange(16 // factor) + 0.5) / (16 // factor)
        assert torch.allclose(subsample(fine[None], factor, 1, ("dirichlet",))[0], coarse)
    u = torch.randn(3, 2, 16, 16)
    assert torch.equal(subsample(u, 4, 2), u[..., ::4, ::4])  # periodic: every factor-th point, exactly
