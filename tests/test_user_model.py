"""Your own model (surrogate.user_model): --model package.module:Class trains, checkpoints and resumes like the
built-in ones; resume refuses another class or changed code; bad modules and wrong output shapes are one line."""

import importlib
import sys
import uuid

import pytest
import torch

from pdestream import cli
from pdestream.surrogate import load_checkpoint
from pdestream.surrogate import train as T

NET = '''
import torch
from torch import nn


class TinyNet(nn.Module):
    """A circular convolution net of any dimension; SHAPE_BUG drops an output channel."""

    def __init__(self, ndim, in_channels, out_channels, n_params=0, hidden=8):
        super().__init__()
        conv = {1: nn.Conv1d, 2: nn.Conv2d, 3: nn.Conv3d}[ndim]
        self.a = conv(in_channels + n_params, hidden, 3, padding=1, padding_mode="circular")
        self.b = conv(hidden, out_channels + SHAPE_BUG, 3, padding=1, padding_mode="circular")

    def forward(self, x, params=None):
        if params is not None:
            x = torch.cat([x, params[(..., *([None] * (x.ndim - 2)))].expand(-1, -1, *x.shape[2:])], 1)
        return self.b(torch.nn.functional.gelu(self.a(x)))


class OtherNet(TinyNet):
    pass


class BrokenNet(TinyNet):
    def forward(self, x, params=None):
        raise RuntimeError("mat1 and mat2 shapes cannot be multiplied (4x8 and 6x6)\\nmore detail")


class MetaNet(TinyNet):
    """Keeps a function in its state_dict, as some libraries' models do (neuralop's '_metadata')."""

    def get_extra_state(self):
        return {"activation": torch.nn.functional.gelu}

    def set_extra_state(self, state):
        pass

SHAPE_BUG = 0
'''
PDE = ["burgers1d", "--set", "n=32", "--set", "n_frames=4"]


@pytest.fixture
def netpkg(tmp_path, monkeypatch):
    pkg = f"usernet_{uuid.uuid4().hex[:8]}"
    (tmp_path / pkg).mkdir()
    (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / pkg / "nets.py").write_text(NET)
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    yield pkg
    for name in [m for m in sys.modules if m.startswith(pkg)]:
        del sys.modules[name]


def train(out, model, *extra):
    return ["train", *PDE, "--model", model, "--model-set", "hidden=6", "--steps", "4", "--batch-size", "4",
            "--test-samples", "2", "--checkpoint-every", "2", "--out", str(out), *extra]


def one_line(capsys, argv, needle):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err, err


def test_user_model_trains_checkpoints_and_resumes(netpkg, tmp_path, capsys, monkeypatch):
    model = f"{netpkg}.nets:TinyNet"
    real = T.forever

    def dying(loader):  # the run dies at batch 3, after its checkpoint at step 2
        for n, batch in enumerate(real(loader), 1):
            if n == 3:
                raise RuntimeError("killed")
            yield batch

    monkeypatch.setattr(T, "forever", dying)
    with pytest.raises(RuntimeError, match="killed"):
        cli.main(train(tmp_path / "run", model))
    monkeypatch.setattr(T, "forever", real)
    capsys.readouterr()
    ckpt = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == 2 and ckpt["spec"]["name"] == model and ckpt["spec"]["hidden"] == 6

    # another class under the same run: refused
    run_json = tmp_path / "run" / "run.json"
    text = run_json.read_text()
    run_json.write_text(text.replace(":TinyNet", ":OtherNet"))
    one_line(capsys, ["train", "--resume", str(tmp_path / "run")], "differs from this run's")
    run_json.write_text(text)
    # the module's code changed: refused
    source = tmp_path / netpkg / "nets.py"
    source.write_text(NET + "# a change\n")
    del sys.modules[f"{netpkg}.nets"]
    one_line(capsys, ["train", "--resume", str(tmp_path / "run")], "source_sha256")
    source.write_text(NET)
    del sys.modules[f"{netpkg}.nets"]
    # the same code: the run finishes, and its model.pt loads back into the same class
    assert cli.main(["train", "--resume", str(tmp_path / "run")]) == 0
    assert f"trained {model}" in capsys.readouterr().out
    net, _, saved = load_checkpoint(tmp_path / "run" / "model.pt")
    assert type(net.net).__name__ == "TinyNet" and saved["spec"]["source_sha256"] == net.source_sha256
    x = torch.randn(2, 1, 32)
    assert net(x, torch.zeros(2, 1)).shape == (2, 1, 32)


def test_bad_user_models_are_one_line(netpkg, tmp_path, capsys):
    one_line(capsys, train(tmp_path / "a", f"{netpkg}.missing:Net"), f"module '{netpkg}.missing' does not import")
    one_line(capsys, train(tmp_path / "b", f"{netpkg}.nets:Nope"), "has no 'Nope'")
    one_line(capsys, train(tmp_path / "c", f"{netpkg}.nets:torch"), "is not a torch nn.Module class")
    one_line(capsys, train(tmp_path / "d", f"{netpkg}.nets:TinyNet", "--model-set", "depth=3"),
             "cannot be built as TinyNet(ndim, in_channels, out_channels, n_params, hidden, depth)")
    (tmp_path / netpkg / "nets.py").write_text(NET.replace("SHAPE_BUG = 0", "SHAPE_BUG = 1"))
    sys.modules.pop(f"{netpkg}.nets", None)
    one_line(capsys, train(tmp_path / "e", f"{netpkg}.nets:TinyNet"),
             "output shape (1, 2, 32) does not match [B, out_channels, *space] = (1, 1, 32)")
    assert not (tmp_path / "e").exists()  # refused before the run wrote anything
    (tmp_path / netpkg / "nets.py").write_text(NET)
    sys.modules.pop(f"{netpkg}.nets", None)
    one_line(capsys, train(tmp_path / "g", f"{netpkg}.nets:BrokenNet"),  # was a 39-line traceback
             "forward(x (1, 1, 32), params) raised RuntimeError: mat1 and mat2 shapes cannot be multiplied")
    assert not (tmp_path / "g").exists()
    one_line(capsys, train(tmp_path / "f", f"{netpkg}.nets:MetaNet"),
             "its state_dict holds torch._C._nn.gelu, not only tensors")
    assert not (tmp_path / "f").exists()


@pytest.mark.parametrize("pde", [PDE, ["ns2d", "--set", "n=16", "--set", "n_frames=3"]])
def test_the_neuraloperator_example_trains_and_loads_back(pde, tmp_path, capsys):
    """examples/neuralop_fno.py (the README's): neuralop's FNO trains on the stream in 1D and 2D, where it installs."""
    pytest.importorskip("neuralop")
    model = "examples.neuralop_fno:NeuralopFNO"
    argv = ["train", *pde, "--model", model, "--model-set", "modes=4", "--model-set", "width=8", "--steps", "3",
            "--batch-size", "2", "--test-samples", "2", "--out", str(tmp_path / "run")]
    assert cli.main(argv) == 0, capsys.readouterr().err
    net, _, saved = load_checkpoint(tmp_path / "run" / "model.pt")
    assert type(net.net).__name__ == "NeuralopFNO" and type(net.net.fno).__module__.startswith("neuralop")
    assert saved["spec"]["modes"] == 4 and saved["spec"]["width"] == 8
