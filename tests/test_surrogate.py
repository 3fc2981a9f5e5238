"""Surrogate models, the training loop, metrics, and the train / compare commands (small and fast)."""

import json

import pytest
import torch

from pdestream import cli
from pdestream.datasets.normalize import Normalization
from pdestream.surrogate import MODELS, build_model
from pdestream.surrogate.checkpoint import load_checkpoint
from pdestream.surrogate.metrics import nrmse, rel_l2
from pdestream.surrogate.train import train

torch.set_num_threads(1)


@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("ndim", [1, 2])
@pytest.mark.parametrize("n_params", [0, 2])
def test_model_output_shapes(name, ndim, n_params):
    model = build_model(name, ndim, 3, 2, n_params)
    x = torch.randn(4, 3, *([16] * ndim))
    params = torch.randn(4, n_params) if n_params else None
    assert model(x, params).shape == (4, 2, *([16] * ndim))


def test_conditioning_changes_the_output():
    model = build_model("fno", 1, 1, 1, 1)
    x = torch.randn(2, 1, 32)
    assert not torch.allclose(model(x, torch.zeros(2, 1)), model(x, torch.ones(2, 1)))


def test_fno_spectral_layer_is_translation_equivariant():
    # A spectral convolution commutes with periodic shifts; a check the layer cannot pass by accident.
    from pdestream.surrogate.fno import SpectralConv

    layer = SpectralConv(1, 2, 3, modes=8)
    x = torch.randn(1, 2, 32)
    assert torch.allclose(layer(torch.roll(x, 5, -1)), torch.roll(layer(x), 5, -1), atol=1e-5)


def test_bad_models_are_refused():
    with pytest.raises(ValueError, match="unknown model 'transformer'.*allowed: fno, unet"):
        build_model("transformer", 1, 1, 1)
    with pytest.raises(ValueError, match="'fno2d' is 2D but the PDE is 1D"):
        build_model("fno2d", 1, 1, 1)
    with pytest.raises(ValueError, match="unknown setting.*depth.*allowed: width, modes, layers"):
        build_model("fno", 1, 1, 1, depth=3)
    with pytest.raises(ValueError, match="expects input"):
        build_model("fno2d", 2, 1, 1)(torch.randn(2, 1, 32))  # 1D data into a 2D model
    with pytest.raises(ValueError, match="divisible by 8"):
        build_model("unet", 1, 1, 1)(torch.randn(2, 1, 36))


def test_metrics_against_hand_computed_values():
    y = torch.tensor([[[3.0, 4.0]], [[1.0, 0.0]]])  # [B=2, C=1, n=2]
    pred = torch.tensor([[[3.0, 0.0]], [[1.0, 1.0]]])
    assert torch.allclose(rel_l2(pred, y), torch.tensor([4 / 5, 1.0]))
    # nRMSE: RMSE / RMS(target) per sample and field; sample 0: sqrt(16/2) / sqrt(25/2) = 4/5
    assert torch.allclose(nrmse(pred, y, ndim=1), torch.tensor([0.8, 1.0]))
    # two fields: the per-field values are averaged, not pooled
    y2, p2 = torch.ones(1, 2, 4), torch.ones(1, 2, 4)
    p2[0, 1] = 3.0
    assert torch.allclose(nrmse(p2, y2, ndim=1), torch.tensor([1.0]))


def _smooth_batch(n_batch=8, n=32, k_in=1):
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(n_batch, k_in, 1, n, generator=gen)
    x = torch.fft.irfft(torch.fft.rfft(x)[..., :6], n=n)  # keep 6 low modes
    return {"x": x, "y": torch.roll(x[:, -1:], 3, -1) + 0.5, "params": torch.rand(n_batch, 1, generator=gen),
            "index": torch.arange(n_batch)}


@pytest.mark.parametrize("name,cfg", [("fno", {"width": 16, "modes": 8, "layers": 2}), ("unet", {"channels": 8, "depth": 2})])
def test_overfit_one_batch(tmp_path, name, cfg):
    torch.manual_seed(0)
    batch = _smooth_batch()
    model = build_model(name, 1, 1, 1, 1, **cfg)
    summary = train(model, [batch], 120, tmp_path, lr=3e-3, log_every=10)
    first, last = summary["curve"][0]["loss"], summary["final_loss"]
    assert last < 0.02 and last < first / 10, (first, last)


def test_checkpoint_round_trip(tmp_path):
    torch.manual_seed(0)
    batch = _smooth_batch(k_in=2)
    model = build_model("fno", 1, 2, 1, 1, width=8, modes=4, layers=2)
    summary = train(model, [batch], 3, tmp_path, meta={"pde": {"pde": "burgers1d", "n": 32}})
    raw = torch.load(tmp_path / "model.pt", weights_only=True)  # plain containers and tensors only
    assert raw["spec"]["name"] == "fno" and raw["meta"]["pde"]["n"] == 32 and raw["step"] == 3
    loaded, norm, _ = load_checkpoint(tmp_path / "model.pt")
    assert isinstance(norm, Normalization) and raw["normalization"]["samples"] == 8  # the first batch's 8 samples
    x = norm.normalize(batch["x"]).flatten(1, 2)
    p = norm.normalize_params(batch["params"])
    model.eval()
    assert torch.equal(loaded(x, p), model(x, p))
    assert torch.equal(norm.mean, summary["normalizer"].mean)
    rows = (tmp_path / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("step,loss,lr") and len(rows) == 2  # header + the final step
    assert json.loads((tmp_path / "metrics.json").read_text())["steps"] == 3


def test_normalization_from_batch_matches_torch_statistics():
    batch = {"x": torch.randn(4, 2, 3, 8) * 5 + 2, "y": torch.randn(4, 1, 3, 8), "params": torch.rand(4, 2)}
    norm = Normalization.from_batch(batch, ndim=1)
    fields = torch.cat([batch["x"].transpose(1, 2).reshape(4, 3, -1).transpose(0, 1).reshape(3, -1),
                        batch["y"].transpose(1, 2).reshape(4, 3, -1).transpose(0, 1).reshape(3, -1)], dim=1)
    assert torch.allclose(norm.mean, fields.mean(1), atol=1e-5)
    assert torch.allclose(norm.std, fields.std(1, correction=0), atol=1e-5)  # population std, as every source
    assert torch.allclose(norm.params_std, batch["params"].std(0, correction=0), atol=1e-6)
    assert norm.fields == ("field0", "field1", "field2") and norm.samples == 4
    assert torch.allclose(norm.denormalize(norm.normalize(batch["x"])), batch["x"], atol=1e-5)
    # a constant field and a fixed parameter stay unscaled (values chosen so E[u^2] - E[u]^2 leaves ~1e-17, not 0)
    const = Normalization.from_batch({"u": torch.full((100, 3, 1, 8), 0.7), "params": torch.full((1000, 1), 0.1)}, ndim=1)
    assert const.std.tolist() == [1.0] and const.params_std.tolist() == [1.0]


def test_cache_normalization_is_the_stream_draw_over_the_same_samples(tmp_path):
    import numpy as np

    from pdestream import datasets, generator

    pde = _tiny_pde()
    datasets.write_cache(pde, tmp_path / "c.h5", 6, seed=3, progress=False)
    cached = datasets.CachedTrajectories(tmp_path / "c.h5", view="operator").normalization(chunk=4)
    u = np.asarray(generator.sample(pde, range(6), 3).u, np.float64)  # [B, T, C, n], computed apart
    np.testing.assert_allclose(cached.mean.numpy(), u.mean(axis=(0, 1, 3)), atol=1e-6)
    np.testing.assert_allclose(cached.std.numpy(), u.std(axis=(0, 1, 3)), rtol=1e-5)
    drawn = datasets.TrajectoryStream(pde, 3, solve_batch=4).normalization(n=6)
    assert cached.samples == drawn.samples == 6 and cached.fields == drawn.fields == ("u",)
    for name in ("mean", "std", "params_mean", "params_std"):
        torch.testing.assert_close(getattr(cached, name), getattr(drawn, name), rtol=1e-6, atol=1e-9)


class Recording:
    """A loader wrapper that records each batch's sample indices (and still exposes ``.dataset``)."""

    def __init__(self, loader):
        self.loader, self.dataset, self.seen = loader, loader.dataset, []

    def __iter__(self):
        for batch in self.loader:
            self.seen.append(batch["index"].tolist())
            yield batch


def _tiny_pde():
    from pdestream import generator

    return generator.get_pde("burgers1d", {"n": "32", "n_frames": "6", "t_end": "0.2"})


def test_training_on_a_finite_stream_skips_no_epoch(tmp_path):
    # n_samples=2, one batch per epoch: epoch e must give samples 2e, 2e+1 (the loader owns the epochs)
    from pdestream import datasets

    stream = datasets.TrajectoryStream(_tiny_pde(), seed=0, view="operator", batch_size=2, n_samples=2,
                                       solve_batch=2, shuffle=False)
    loader = Recording(datasets.stream_loader(stream))
    model = build_model("fno", 1, 1, 1, 1, width=8, modes=4, layers=2)
    train(model, loader, 4, tmp_path, log_every=1)
    assert loader.seen == [[0, 1], [2, 3], [4, 5], [6, 7]]


def test_training_on_a_cache_reshuffles_each_epoch(tmp_path):
    from pdestream import datasets
    from pdestream.surrogate.data import train_loader

    pde = _tiny_pde()
    datasets.write_cache(pde, tmp_path / "c.h5", 4, seed=0, progress=False)
    loader, _ = train_loader(pde, str(tmp_path / "c.h5"), datasets.make_view("operator"), batch_size=4, seed=0)
    loader = Recording(loader)
    model = build_model("fno", 1, 1, 1, 1, width=8, modes=4, layers=2)
    train(model, loader, 4, tmp_path / "run", log_every=1)
    assert all(sorted(epoch) == [0, 1, 2, 3] for epoch in loader.seen)  # one epoch per batch, every sample
    assert len({tuple(epoch) for epoch in loader.seen}) > 1  # a new order each epoch


TINY = ["--set", "n=32", "--set", "n_frames=6", "--set", "t_end=0.2"]
TINY_MODEL = ["--model-set", "width=8", "--model-set", "modes=4", "--model-set", "layers=2"]


def test_train_end_to_end_stream_and_cache(tmp_path, capsys):
    from pdestream import datasets, generator

    out = tmp_path / "run"
    assert cli.main(["train", "burgers1d", *TINY, *TINY_MODEL, "--steps", "4", "--batch-size", "8",
                     "--test-samples", "4", "--out", str(out)]) == 0
    summary = json.loads((out / "metrics.json").read_text())
    assert summary["steps"] == 4 and summary["examples_seen"] == 32 and summary["source"] == "stream"
    assert json.loads((out / "run.json").read_text())["steps"] == 4  # settings for --resume
    assert torch.load(out / "checkpoint.pt", weights_only=True)["step"] == 4  # at the end (default every 100)
    assert 0 < summary["test"]["test"]["rel_l2"] and len(summary["test"]["test"]["rollout"]) == 5
    assert "rel L2" in capsys.readouterr().out
    # the same command again refuses to overwrite the run
    assert cli.main(["train", "burgers1d", *TINY, "--steps", "2", "--out", str(out)]) == 2
    assert "already holds a run" in capsys.readouterr().err

    pde = generator.get_pde("burgers1d", {"n": "32", "n_frames": "6", "t_end": "0.2"})
    cache = tmp_path / "c.h5"
    datasets.write_cache(pde, cache, 8, seed=0, progress=False)
    assert cli.main(["train", "burgers1d", "--source", str(cache), "--view", "operator", *TINY_MODEL,
                     "--steps", "3", "--batch-size", "4", "--test-samples", "4", "--out", str(tmp_path / "r2")]) == 0
    summary = json.loads((tmp_path / "r2" / "metrics.json").read_text())
    assert summary["trajectories_seen"] <= 8 and summary["pde"]["n"] == 32  # the cache's settings

    # a cache of another PDE than asked, or of other explicit settings, is refused with one line
    assert cli.main(["train", "kdv1d", "--source", str(cache), "--steps", "2", "--out", str(tmp_path / "r3")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pdestream: error:") and "holds 'burgers1d' samples, not 'kdv1d'" in err
    assert cli.main(["train", "burgers1d", "--source", str(cache), "--set", "n=64", "--steps", "2",
                     "--out", str(tmp_path / "r4")]) == 2
    assert "n: cache 32 vs asked 64" in capsys.readouterr().err


def test_train_cli_bad_input(tmp_path, capsys):
    for argv, needle in [
        (["--model", "transformer"], "unknown model 'transformer'"),
        (["--model", "unet2d"], "'unet2d' is 2D but the PDE is 1D"),
        (["--source", str(tmp_path / "missing.h5")], "no such cache"),
        (["--model-set", "depth=2"], "unknown setting(s) depth"),
    ]:
        assert cli.main(["train", "burgers1d", *TINY, "--steps", "1", "--out", str(tmp_path / "x"), *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("pdestream: error:") and needle in err and "Traceback" not in err, err


def test_compare_end_to_end(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert cli.main(["compare", "burgers1d", *TINY, *TINY_MODEL, "--steps", "4", "--batch-size", "4",
                     "--cache-samples", "4", "--seeds", "2", "--test-samples", "4", "--out", str(out)]) == 0
    for name in ("compare.md", "compare.csv", "compare.json", "compare.png", "cache.h5"):
        assert (out / name).exists(), name
    result = json.loads((out / "compare.json").read_text())
    cache, stream = result["rows"]
    assert cache["source"] == "cache" and stream["source"] == "stream" and cache["seeds"] == 2
    assert cache["samples_seen"] == 4 and stream["samples_seen"] == 16  # 4 steps x 4 fresh trajectories
    # each arm normalized from its own source: the cache's 4 stored samples, the stream's 64-sample draw
    assert cache["norm_samples"] == 4 and stream["norm_samples"] == 64
    assert "samples 0..63 of the training seed, of which 48 beyond those it trains on" in (out / "compare.md").read_text()
    assert cache["bytes_on_disk"] > 0 and stream["bytes_on_disk"] == 0
    assert "shifted_rel_l2" in cache and result["shifted_pde"]["nu"].startswith("loguniform(")
    assert "| cache |" in capsys.readouterr().out


def test_shifted_pde_lies_outside_the_training_domain():
    from pdestream import generator
    from pdestream.experiments.compare import shifted_pde

    pde = generator.get_pde("kdv1d")  # alpha uniform(1, 3), beta loguniform(0.5, 2)
    above, below = shifted_pde(pde, 0.25), shifted_pde(pde, -0.25)
    assert above.param_domains["alpha"].bounds == (3.0, 3.5)
    assert below.param_domains["alpha"].bounds == (0.5, 1.0)
    assert below.param_domains["beta"].bounds[1] == 0.5 and above.param_domains["beta"].bounds[0] == 2.0


@pytest.mark.parametrize("name", ["helmholtz1d", "karman2d", "smoke2d", "swift_hohenberg2d"])
def test_the_default_shift_gives_every_entry_a_domain_it_accepts(name):
    """The default shift (25% below) of a positive wavenumber reached 0, of a blend in [0, 1] went below 0 and of
    a source radius fell under the grid: compare refused these entries at its defaults. Now a positive parameter
    is shifted geometrically, and one refused below is shifted above; every shifted domain lies outside the
    training one and the problem accepts it."""
    from pdestream import generator
    from pdestream.experiments.compare import shifted_pde

    pde = generator.get_pde(name)
    shifted = shifted_pde(pde, -0.25)
    for param, domain in pde.param_domains.items():
        lo, hi = domain.bounds
        a, b = shifted.param_domains[param].bounds
        assert b <= lo or a >= hi, (param, domain, shifted.param_domains[param])
    if name == "helmholtz1d":  # k uniform(0.5, 2.5): 0.5 (0.5 / 2.5)^0.25 below it, not 0
        assert shifted.param_domains["k"].bounds == pytest.approx((0.5 * 0.2 ** 0.25, 0.5), rel=1e-5)
    if name == "karman2d":  # the plug blend uniform(0, 0.3) cannot go below 0: above it
        assert shifted.param_domains["plug"].bounds == (0.3, 0.375)
