"""The docs' "Your own solver" examples (docs/guides/own-solver.md) (examples/nagumo_scipy.py, examples/burgers_phiflow.py): each against
an independent solution, and each streamed into training through the reservoir from the command line at small
size. The page shows the files' code verbatim (checked here, so they cannot drift)."""

import re
from pathlib import Path

import numpy as np
import pytest

from pdestream import cli, generator

ROOT = Path(__file__).resolve().parents[1]


pytestmark = pytest.mark.usefixtures("solver_settings")  # (tests/conftest.py)


def docs_solver_blocks() -> list[str]:
    text = (ROOT / "docs" / "guides" / "own-solver.md").read_text()
    section = text[text.index("# Your own solver"):]
    return re.findall(r"```python\n(.*?)```", section, re.S)


@pytest.mark.parametrize("name", ["nagumo_scipy.py", "burgers_phiflow.py"])
def test_the_docs_show_the_example_files(name):
    source = (ROOT / "examples" / name).read_text()
    body = source[source.index("from dataclasses"):]  # the file less its docstring
    assert any(body.strip() in block for block in docs_solver_blocks()), name


def test_nagumo_front_moves_at_the_travelling_wave_speed(monkeypatch):
    """u_t = D u_xx + r u (1 - u)(u - a) has fronts travelling at c = sqrt(2 D r) (1/2 - a) (closed form)."""
    from examples.nagumo_scipy import Nagumo

    pde = Nagumo(n=256, t_end=1.5, n_frames=4, D="0.005", a="0.2")
    u = np.asarray(generator.sample(pde, [0]).u[0, :, 0], np.float64)
    x = pde.grid.coords()
    assert np.all(u[:, 0] == 1.0) and np.all(u[:, -1] == 0.0)  # the walls hold

    def position(v):  # where the front crosses 1/2, linearly interpolated
        i = np.flatnonzero(v < 0.5)[0]
        return x[i - 1] + (v[i - 1] - 0.5) / (v[i - 1] - v[i]) * (x[i] - x[i - 1])

    speed = position(u[3]) - position(u[1])  # over t in [0.5, 1.5], after the front has formed
    assert speed == pytest.approx(np.sqrt(2 * 0.005 * 20.0) * (0.5 - 0.2), rel=0.02)


def test_phiflow_burgers_at_small_amplitude_decays_as_the_heat_equation():
    """At amplitude 1e-4 advection is negligible: each Fourier mode decays as exp(-nu |k|^2 t) (exact)."""
    pytest.importorskip("phi")
    from examples.burgers_phiflow import PhiBurgers

    pde = PhiBurgers(amplitude=1e-4, nu="0.01")
    u = np.asarray(generator.sample(pde, [0]).u[0], np.float64)
    k = 2 * np.pi * np.fft.fftfreq(pde.n, pde.length / pde.n)
    k2 = k[:, None] ** 2 + k[None, :] ** 2
    exact = np.real(np.fft.ifft2(np.fft.fft2(u[0]) * np.exp(-0.01 * k2 * pde.times()[-1])))
    assert np.linalg.norm(u[-1] - u[0]) > 0.3 * np.linalg.norm(u[0])  # it did decay, by ~40%
    assert np.linalg.norm(u[-1] - exact) < 0.005 * np.linalg.norm(exact)
    assert np.array_equal(np.asarray(generator.sample(pde, [0]).u[0]), u.astype(np.float32))  # replay


def train_through_the_reservoir(tmp_path, capsys, monkeypatch, path, *settings):
    monkeypatch.syspath_prepend(str(ROOT))  # as `PYTHONPATH=.` does for the docs' commands
    code = cli.main(["train", "--pde", path, *settings, "--reservoir", "--capacity", "8", "--solve-batch", "4",
                     "--warmup", "4", "--batch-size", "4", "--view", "next_step", "--steps", "3",
                     "--test-samples", "2", "--proposal", "loss", "--solver-workers", "2", "--out", str(tmp_path / "r")])
    out, err = capsys.readouterr()
    assert code == 0 and "trained fno" in out, err
    assert (tmp_path / "r" / "reservoir.json").exists()


def test_nagumo_streams_into_training_through_the_reservoir(tmp_path, capsys, monkeypatch):
    train_through_the_reservoir(tmp_path, capsys, monkeypatch, "examples.nagumo_scipy:Nagumo", "--set", "n=32",
                                "--set", "n_frames=5", "--set", "t_end=0.5")


@pytest.mark.slow
def test_phiflow_burgers_streams_into_training_through_the_reservoir(tmp_path, capsys, monkeypatch):
    pytest.importorskip("phi")
    train_through_the_reservoir(tmp_path, capsys, monkeypatch, "examples.burgers_phiflow:PhiBurgers", "--set",
                                "n=16", "--set", "n_frames=4", "--set", "t_end=0.1")
