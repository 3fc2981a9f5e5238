"""Models and views describe themselves: a checkpoint names the model class that wrote it (not "fno, else
unet"), and build_model rebuilds it from the name -> class table."""

from dataclasses import dataclass

import pytest
import torch
from torch import nn

from pdestream.datasets.normalize import Normalization
from pdestream.surrogate import models
from pdestream.surrogate.checkpoint import load_checkpoint, save_checkpoint
from pdestream.surrogate.models import MODELS, build_model, model_spec


def _norm(c: int, p: int) -> Normalization:
    return Normalization(("u",) * c, torch.zeros(c), torch.ones(c), ("nu",) * p, torch.zeros(p), torch.ones(p), 1)


@pytest.mark.parametrize("name, cfg", [("fno", {"width": 8, "modes": 4, "layers": 2}), ("unet", {"channels": 4, "depth": 2})])
def test_models_round_trip_through_save_and_load_with_their_own_names(tmp_path, name, cfg):
    torch.manual_seed(0)
    model = build_model(name, 1, 2, 3, 1, **cfg)
    spec = model_spec(model)
    assert spec == {"name": name, "ndim": 1, "in_channels": 2, "out_channels": 3, "n_params": 1, **cfg}
    save_checkpoint(tmp_path / "m.pt", model, _norm(1, 1), step=5)
    loaded, _, ckpt = load_checkpoint(tmp_path / "m.pt")
    assert type(loaded) is type(model) and ckpt["spec"]["name"] == name and model_spec(loaded) == spec
    x, p = torch.randn(2, 2, 16), torch.randn(2, 1)
    assert torch.equal(loaded(x, p), model.train(False)(x, p))


@dataclass(frozen=True)
class TinyConfig:
    scale: int = 1


class Tiny(nn.Module):
    """A third model, registered like the others: its checkpoints must say "tiny"."""

    name = "tiny"
    Config = TinyConfig

    def __init__(self, ndim, in_channels, out_channels, n_params=0, config=TinyConfig()):
        super().__init__()
        self.ndim, self.in_channels, self.out_channels, self.n_params, self.config = (
            ndim, in_channels, out_channels, n_params, config)
        self.mix = nn.Linear(in_channels, out_channels)

    def forward(self, x, params=None):
        return self.config.scale * self.mix(x.movedim(1, -1)).movedim(-1, 1)


def test_a_newly_registered_model_keeps_its_name(tmp_path, monkeypatch):
    monkeypatch.setitem(MODELS, "tiny", Tiny)
    model = build_model("tiny", 1, 2, 2, scale=3)
    save_checkpoint(tmp_path / "m.pt", model, _norm(1, 1), step=1)
    loaded, _, ckpt = load_checkpoint(tmp_path / "m.pt")
    assert ckpt["spec"] == {"name": "tiny", "ndim": 1, "in_channels": 2, "out_channels": 2, "n_params": 0, "scale": 3}
    assert isinstance(loaded, Tiny) and loaded.config.scale == 3
    assert "isinstance" not in open(models.__file__).read()  # the registry switches on nothing


def test_train_reads_its_config_file_once(tmp_path, monkeypatch):
    from pdestream import cli, settings
    from pdestream.surrogate import launch
    from pdestream.surrogate import runs as run_module

    reads, runs = [], []
    real = settings.read_config
    monkeypatch.setattr(settings, "read_config", lambda path: reads.append(path) or real(path))
    monkeypatch.setattr(run_module, "train_run", lambda pde, source, out, **kw: runs.append((pde, kw)) or {})
    monkeypatch.setattr(launch, "run_report", lambda *a: "")
    config = tmp_path / "b.toml"
    config.write_text('pde = "burgers1d"\nn = 32\nn_frames = 5\n')
    assert cli.main(["train", "--config", str(config), "--out", str(tmp_path / "run")]) == 0
    assert reads == [str(config)] and runs[0][0].n == 32 and runs[0][1]["explicit"] == {"n": 32, "n_frames": 5}


def test_views_describe_their_models_and_evaluation():
    """Channels, the evaluation view and the rollout come from the view itself: a new view class needs no
    isinstance branch elsewhere."""
    from dataclasses import dataclass as dc

    from pdestream import datasets
    from pdestream.surrogate.predict import model_channels, pairs

    class Pde:
        FIELDS = ("u", "v")

    nxt, op = datasets.make_view("next_step", k_in=2, k_out=3, windows=1), datasets.make_view("operator")
    assert model_channels(Pde, nxt) == (4, 6) and model_channels(Pde, op) == (2, 2)
    assert nxt.evaluation() == datasets.NextStep(2, 3, "all") and op.evaluation() is op
    assert (nxt.rollout_k_in, op.rollout_k_in) == (2, None)
    for call in (lambda: model_channels(Pde, datasets.make_view("whole")), lambda: datasets.Whole().evaluation()):
        with pytest.raises(ValueError, match="'whole' view"):
            call()

    @dc(frozen=True)
    class LastFrame(datasets.Operator):  # a view of its own: first frame -> last frame, both fields
        name = "last_frame"

        def channels(self, c):
            return c, 1

    batch = {"u": torch.randn(2, 5, 2, 8), "params": torch.randn(2, 1), "index": torch.arange(2)}
    assert datasets.make_view(LastFrame()) == LastFrame() and model_channels(Pde, LastFrame()) == (2, 1)
    assert pairs(LastFrame(), batch)["x"].shape == (2, 2, 8)
