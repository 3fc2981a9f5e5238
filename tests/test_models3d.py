"""3D surrogates: the 3D spectral convolution against a direct sum over Fourier modes (numpy, not the layer's own
output), the 3D U-Net's shapes and periodic padding, and `pdestream train diffusion3d` / `burgers3d` from the
stream and from a cache on a small grid."""

import itertools

import numpy as np
import pytest
import torch

from pdestream import cli
from pdestream.surrogate.fno import FNO, SpectralConv
from pdestream.surrogate.models import build_model, model_spec
from pdestream.surrogate.unet import UNet


def test_spectral_conv_3d_matches_a_direct_sum_over_the_kept_modes():
    torch.manual_seed(0)
    n, m, c_in, c_out = 6, 2, 2, 3
    layer = SpectralConv(3, c_in, c_out, m)
    x = torch.randn(1, c_in, n, n, n, dtype=torch.float64)
    got = layer.double()(x).detach().numpy()[0]

    w = layer.weight.detach().numpy()
    w = w[..., 0] + 1j * w[..., 1]  # [4, C_in, C_out, m, m, m]
    x_hat = np.fft.rfftn(x.numpy()[0], axes=(1, 2, 3))  # [C_in, n, n, n//2+1]: k3 >= 0 only
    out_hat = np.zeros((c_out, *x_hat.shape[1:]), complex)
    # kept: -m <= k1, k2 < m on the two full axes (the m lowest of each sign), 0 <= k3 < m on the half one;
    # a corner's weights are indexed like its slice of the spectrum (k for k >= 0, k + m for the negative corner)
    for k1, k2, k3 in itertools.product(range(-m, m), range(-m, m), range(m)):
        block = 2 * (k1 < 0) + (k2 < 0)  # which corner's weights: the signs of (k1, k2)
        out_hat[:, k1, k2, k3] = x_hat[:, k1, k2, k3] @ w[block, :, :, k1 % m, k2 % m, k3]
    want = np.fft.irfftn(out_hat, s=(n, n, n), axes=(1, 2, 3))
    assert np.allclose(got, want, atol=1e-12), np.abs(got - want).max()


def test_spectral_conv_3d_is_a_low_pass_with_unit_weights():
    layer = SpectralConv(3, 1, 1, 4)
    with torch.no_grad():
        layer.weight.zero_()
        layer.weight[..., 0] = 1.0
    x = torch.randn(2, 1, 8, 8, 8, dtype=torch.float64)
    got = layer.double()(x).detach().numpy()
    x_hat = np.fft.rfftn(x.numpy(), axes=(2, 3, 4))
    x_hat[..., 4] = 0  # the last axis keeps modes 0..3 of 0..4; the full axes all 8 (0..3 and -4..-1)
    assert np.allclose(got, np.fft.irfftn(x_hat, s=(8, 8, 8), axes=(2, 3, 4)), atol=1e-12)


@pytest.mark.parametrize("name", ["fno", "unet", "fno3d", "unet3d"])
def test_3d_models_build_run_and_rebuild_from_their_spec(name):
    model = build_model(name, 3, 2, 3, n_params=1, **({"modes": 3} if "fno" in name else {"depth": 2}))
    x, p = torch.randn(2, 2, 8, 8, 8), torch.randn(2, 1)
    assert model(x, p).shape == (2, 3, 8, 8, 8)
    again = build_model(**{**model_spec(model), "name": name})
    again.load_state_dict(model.state_dict())
    assert torch.equal(again(x, p), model(x, p))
    assert isinstance(model, FNO if "fno" in name else UNet)


def test_unet_3d_is_periodic_equivariant():
    """Circular padding, pooling and upsampling commute with a shift by 2**depth points along any axis."""
    torch.manual_seed(0)
    model = UNet(3, 1, 1).eval()
    x = torch.randn(1, 1, 16, 16, 16)
    for axis in (2, 3, 4):
        assert torch.allclose(model(x.roll(8, axis)), model(x).roll(8, axis), atol=1e-5)


def test_a_2d_model_pinned_refuses_3d_data():
    with pytest.raises(ValueError, match="model 'fno2d' is 2D but the PDE is 3D"):
        build_model("fno2d", 3, 1, 1)


@pytest.mark.parametrize("pde, model", [("diffusion3d", "fno"), ("burgers3d", "unet")])
def test_train_3d_from_the_stream_and_from_a_cache(pde, model, tmp_path, capsys):
    small = ["--set", "n=8", "--set", "n_frames=4", "--set", "ic.max_mode=2" if pde == "diffusion3d" else "ic.tau=3"]
    sets = ["--model", model, "--model-set", "modes=3" if model == "fno" else "depth=2"]
    cache = tmp_path / "c.zarr"
    assert cli.main(["generate", pde, "--n", "4", "--out", str(cache), *small]) == 0
    for source in ("stream", str(cache)):
        out = tmp_path / f"run_{len(source)}"
        code = cli.main(["train", pde, *small, *sets, "--source", source, "--steps", "3", "--test-samples", "2",
                         "--out", str(out)])
        text, err = capsys.readouterr()
        assert code == 0 and f"trained {model} on" in text and "rel L2" in text, err
        assert (out / "model.pt").exists()
