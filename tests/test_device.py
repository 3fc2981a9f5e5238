"""--device: refused with one line where it cannot work; batches and evaluation follow the model's device."""

import pytest
import torch

from pdestream.surrogate.data import check_device, model_device, to_device


@pytest.mark.parametrize("bad", ["gpu", "cuda:x", "", "mps"])
def test_bad_device_names_are_refused_with_the_value(bad):
    with pytest.raises(ValueError, match="--device"):
        check_device(bad)


def test_cuda_is_refused_without_a_gpu():
    if torch.cuda.is_available():
        assert check_device("cuda").type == "cuda"
    else:
        with pytest.raises(ValueError, match="sees no GPU"):
            check_device("cuda")


def test_to_device_moves_tensors_and_keeps_other_entries():
    batch = {"x": torch.ones(2, 3), "index": torch.arange(2), "param_names": ["nu"]}
    out = to_device(batch, "cpu")
    assert out["param_names"] == ["nu"] and torch.equal(out["x"], batch["x"])
    assert model_device(torch.nn.Linear(2, 2)).type == "cpu"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (run on a GPU machine)")
def test_train_run_on_the_gpu(tmp_path):
    from pdestream import generator
    from pdestream.surrogate.runs import train_run

    pde = generator.get_pde("burgers1d", n=64, n_frames=5)
    s = train_run(pde, "stream", tmp_path / "run", model_cfg={"width": 8, "modes": 4, "layers": 1}, steps=4,
                  batch_size=4, n_test=2, checkpoint_every=0, device="cuda")
    assert s["test"]["test"]["rel_l2"] > 0 and s["steps"] == 4
