"""Your own PDE (generator.user): the docs' example (docs/guides/own-pde.md), installed as a package with an entry point in tmp_path,
goes through list / generate / resume / stream / oracle / cache through the CLI; a changed source refuses the
old cache; bad modules and classes are one line each; register() by Python."""

import importlib
import json
import pickle
import re
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

from pdestream import cli, datasets, generator

PAGE = Path(__file__).resolve().parents[1] / "docs" / "guides" / "own-pde.md"
SMALL = ["--set", "n=32", "--set", "n_frames=4", "--set", "t_end=0.3"]


def readme_example() -> str:
    """The first python block of the docs' "Your own PDE" page (so page and test cannot drift)."""
    text = PAGE.read_text()
    section = text[text.index("# Your own PDE"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def make_package(root: Path, source: str, entry: str = "DampedBurgers") -> str:
    """A package with module ``damped`` holding ``source`` and a .dist-info declaring the entry point
    damped_burgers1d in group pdestream.pdes; returns the (unique) package name."""
    pkg = f"userpde_{uuid.uuid4().hex[:8]}"
    (root / pkg).mkdir()
    (root / pkg / "__init__.py").write_text("")
    (root / pkg / "damped.py").write_text(source)
    info = root / f"{pkg}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {pkg}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[pdestream.pdes]\ndamped_burgers1d = {pkg}.damped:{entry}\n")
    return pkg


@pytest.fixture
def package(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    pkg = make_package(tmp_path, readme_example())
    yield pkg
    for name in [m for m in sys.modules if m.startswith(pkg)]:
        del sys.modules[name]


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_readme_pde_matches_an_independent_solution():
    """The docs' PDE with mu > 0, nu fixed and a tiny amplitude is linear to first order: each Fourier mode
    decays as exp(-(nu k^2 + mu) t) (closed form, not the solver's own output)."""
    namespace: dict = {}
    exec(compile(readme_example(), str(PAGE), "exec"), namespace)
    pde = namespace["DampedBurgers"](n=32, t_end=0.5, n_frames=3, nu="0.02", mu="0.5", ic="fourier")
    pde = pde.replace({"ic.amplitude": 1e-4})
    traj = generator.sample(pde, [0])
    u = np.asarray(traj.u[0, :, 0], np.float64)
    k = 2 * np.pi * np.fft.rfftfreq(32, 1 / 32)
    exact = np.fft.irfft(np.fft.rfft(u[0]) * np.exp(-(0.02 * k**2 + 0.5) * 0.5), 32)
    assert np.linalg.norm(u[-1] - exact) / np.linalg.norm(exact) < 1e-3


def test_entry_point_pde_through_the_cli(package, tmp_path, capsys):
    code, out, err = run(capsys, "list")
    assert code == 0 and "== user (1) ==" in out and "damped_burgers1d: u_t + u u_x = nu u_xx - mu u" in out
    assert f"from {package}.damped:DampedBurgers" in out
    code, out, _ = run(capsys, "list", "damped_burgers1d")
    assert code == 0 and "mu = uniform(0.1, 1.0)" in out and "version '1'" in out

    cache = tmp_path / "d.zarr"
    code, out, err = run(capsys, "generate", "damped_burgers1d", "--n", "6", "--out", str(cache), *SMALL)
    assert code == 0 and err == "" and "wrote 6 samples" in out
    code, out, err = run(capsys, "generate", "damped_burgers1d", "--n", "6", "--out", str(cache), "--resume", *SMALL)
    assert code == 0 and "already complete" in out
    # the import path names the same class: the same config, the same cache
    code, out, err = run(capsys, "generate", f"{package}.damped:DampedBurgers", "--n", "6", "--out", str(cache),
                         "--resume", *SMALL)
    assert code == 0 and "already complete" in out, err

    reservoir = ["--source", "stream", "--reservoir", "--capacity", "8", "--solve-batch", "4", "--warmup", "4",
                 "--producer", "process", "--batch-size", "4"]  # the producer process finds the class by its origin
    for extra in (["--source", "stream"], ["--source", str(cache)], ["--source", "stream", "--mode", "oracle"],
                  reservoir):
        out_dir = tmp_path / f"run{len(extra)}{extra[-1][-4:]}"
        code, out, err = run(capsys, "train", "damped_burgers1d", *SMALL, *extra, "--steps", "3", "--test-samples",
                             "4", "--out", str(out_dir))
        assert code == 0 and "trained fno" in out, err

    # the module's source changes: resuming its cache, or training from it, is refused in one line
    module = tmp_path / package / "damped.py"
    module.write_text(module.read_text() + "\n# a change\n")
    del sys.modules[f"{package}.damped"]
    importlib.invalidate_caches()
    code, out, err = run(capsys, "generate", "damped_burgers1d", "--n", "6", "--out", str(cache), "--resume", *SMALL)
    assert code == 2 and err.count("\n") == 1 and "origin.source_sha256" in err and "Traceback" not in err
    code, out, err = run(capsys, "train", "damped_burgers1d", *SMALL, "--source", str(cache), "--steps", "3",
                         "--out", str(tmp_path / "r2"))
    assert code == 2 and err.count("\n") == 1 and "its code changed since this config was made" in err


BROKEN = {
    "raise RuntimeError('no licence')\n": "does not import: RuntimeError: no licence",
}


@pytest.mark.parametrize("source, needle", [
    *BROKEN.items(),
    (None, "lacks the required method(s) stable_dt"),
    ("no dataclass", "must be a @dataclass(frozen=True)"),
    ("x = 1\n", "has no 'DampedBurgers'"),
])
def test_bad_user_modules_are_one_line(tmp_path, monkeypatch, capsys, source, needle):
    if source is None:  # the docs' class without its stable step
        source = readme_example()
        source = source[:source.index("    def stable_dt")]
    elif source == "no dataclass":
        source = readme_example().replace("@dataclass(frozen=True)\n", "")
    monkeypatch.syspath_prepend(str(tmp_path))
    pkg = make_package(tmp_path, source)
    code, out, err = run(capsys, "generate", f"{pkg}.damped:DampedBurgers", "--n", "2", "--out",
                         str(tmp_path / "x.zarr"))
    assert code == 2 and err.count("\n") == 1 and needle in err and "Traceback" not in err, err
    code, out, err = run(capsys, "list")  # a broken entry point names itself in list, the rest is listed
    assert code == 0 and needle in out and "burgers1d" in out


def test_register_by_python_and_from_config():
    namespace: dict = {"__name__": "readme_example"}
    exec(compile(readme_example(), str(PAGE), "exec"), namespace)
    cls = namespace["DampedBurgers"]
    with pytest.raises(ValueError, match="it is a catalog entry"):
        generator.register("burgers1d", cls)
    with pytest.raises(ValueError, match="has NAME 'damped_burgers1d'; register it as"):
        generator.register("other", cls)
    with pytest.raises(ValueError, match="is not a class"):
        generator.register("damped_burgers1d", object())
    generator.register("damped_burgers1d", cls)
    try:
        pde = generator.get_pde("damped_burgers1d", n=16, n_frames=3)
        assert pde.config()["origin"]["class"] == "DampedBurgers"
        assert generator.from_config(pde.config()) == pde
        with pytest.raises(ValueError, match="its code changed"):
            generator.from_config({**pde.config(), "origin": {**pde.config()["origin"], "version": "0"}})
        a = generator.sample(pde, [3], seed=1).u
        b = generator.sample(pde, [1, 2, 3], seed=1).u[2:]
        assert np.array_equal(np.asarray(a), np.asarray(b))
    finally:
        generator.unregister("damped_burgers1d")
    with pytest.raises(ValueError, match="unknown PDE 'damped_burgers1d'"):
        generator.get_pde("damped_burgers1d")


def test_import_path_by_option_and_in_a_toml_config(package, tmp_path, capsys):
    path = f"{package}.damped:DampedBurgers"
    code, out, err = run(capsys, "generate", "--pde", path, "--n", "2", "--out", str(tmp_path / "a.zarr"), *SMALL)
    assert code == 0 and "wrote 2 samples" in out, err
    config = tmp_path / "mine.toml"
    config.write_text(f'pde = "{path}"\nn = 32\nn_frames = 4\nt_end = 0.3\n')
    code, out, err = run(capsys, "generate", "--config", str(config), "--n", "2", "--out", str(tmp_path / "b.zarr"))
    assert code == 0 and "wrote 2 samples" in out, err
    a, b = (generator.from_config(json.loads(datasets.open_cache(tmp_path / f).attrs["pdestream_config"]))
            for f in ("a.zarr", "b.zarr"))
    assert a == b and a.NAME == "damped_burgers1d"
    code, out, err = run(capsys, "generate", "burgers1d", "--pde", path, "--n", "2", "--out", str(tmp_path / "c"))
    assert code == 2 and "give one" in err


@pytest.mark.slow
def test_compare_on_an_entry_point_pde(package, tmp_path, capsys):
    code, out, err = run(capsys, "compare", "damped_burgers1d", "--steps", "2", "--seeds", "1", "--set", "n=32",
                         "--shift-set", "mu=uniform(1.0, 1.5)",
                         "--out", str(tmp_path / "cmp"))
    assert code == 0 and "| cache |" in out and "| stream |" in out, err


def test_a_user_pde_pickles_by_its_config(package):
    pde = generator.get_pde(f"{package}.damped:DampedBurgers", n=16)  # NAME given in the class
    assert pickle.loads(pickle.dumps(pde)) == pde
    builtin = generator.get_pde("burgers1d", n=16)
    assert pickle.loads(pickle.dumps(builtin)) == builtin
