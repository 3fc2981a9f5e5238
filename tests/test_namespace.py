"""One package, pdestream, installable beside HuggingFace's ``datasets`` (also imported from the repository root,
where the current directory is on sys.path), every module importable under its pdestream name, and module
paths written before the namespace still resolving."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import pdestream

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("generator", "datasets", "surrogate", "experiments")


@pytest.mark.parametrize("pythonpath", [None, "root"])
def test_huggingface_datasets_and_pdestream_import_side_by_side_from_the_repository_root(pythonpath):
    pytest.importorskip("datasets.load", reason="HuggingFace's datasets is in the test extra")
    code = ("import datasets, pdestream.datasets as ours\n"
            "assert callable(datasets.load_dataset), datasets.__file__\n"
            "assert ours.TrajectoryStream.__module__ == 'pdestream.datasets.stream'\n"
            "from pdestream.datasets import write_cache\n"
            "print(datasets.__file__)\n")
    env = None
    if pythonpath:
        import os
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    got = Path(out.stdout.strip()).resolve()  # HuggingFace's (a venv may live in the checkout), not our folder
    assert not got.is_relative_to(ROOT / "datasets") and "site-packages" in got.parts, got


def test_no_folder_of_the_package_shadows_a_top_level_name_it_shares_with_hugging_face():
    assert not (ROOT / "datasets" / "__init__.py").exists()  # a regular package would win over site-packages


def test_every_module_imports_under_its_pdestream_name():
    names = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            if parts[-1] == "worker":  # the external solvers' worker process: importing it starts nothing, but
                continue               # it is run as a script (python -m)
            names.append("pdestream." + ".".join(parts))
    for name in names:
        importlib.import_module(name)
    assert "pdestream.generator.spectral.burgers" in names and "pdestream.experiments.budget" in names


def test_module_paths_written_before_the_namespace_still_resolve():
    from pdestream.generator.spectral.burgers import Burgers
    from pdestream.surrogate.fno import FNO

    assert pdestream.load_object("generator.pdes.burgers:Burgers") is Burgers
    assert pdestream.load_object("surrogate.fno:FNO") is FNO
    assert pdestream.current_module("generator.pdes.flows") == "pdestream.generator.flow.entries"
    assert pdestream.current_module("mypdes.damped") == "mypdes.damped"  # a user's module is left alone
    for old, new in pdestream.LEGACY_MODULES.items():
        importlib.import_module(new)  # every old path points at a module that exists
        assert pdestream.current_module(old) == new
    with pytest.raises(ValueError, match=r"^PDE 'generator.pdes.nosuch:X': module 'generator.pdes.nosuch' does not"):
        pdestream.load_object("generator.pdes.nosuch:X", "PDE")


def test_a_catalog_entry_is_stored_by_name_not_by_module_path():
    from pdestream import generator

    pde = generator.get_pde("burgers1d", n=32)
    assert generator.from_config(pde.config()) == pde  # catalog entries are stored by name, not by path
