"""House rules of issue 21: one atomic write, one name per class, a public engine API, no benchmarks in the wheel."""

import os
import stat

import pytest

from datasets import schema


def test_there_is_one_atomic_write_and_it_syncs_the_directory(tmp_path, monkeypatch):
    import surrogate.checkpoint
    import surrogate.runs
    import surrogate.train

    assert surrogate.train.atomic_write is schema.atomic_write is surrogate.runs.atomic_write is surrogate.checkpoint.atomic_write
    synced = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(stat.S_ISDIR(os.fstat(fd).st_mode)) or real(fd))
    target = tmp_path / "meta.json"
    target.write_bytes(b"old")
    schema.atomic_write(target, b"new")
    assert target.read_bytes() == b"new" and synced == [False, True]  # the file, then its directory
    assert [p.name for p in tmp_path.iterdir()] == ["meta.json"]  # no temp file left


def test_a_failed_atomic_write_leaves_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "meta.json"
    target.write_bytes(b"old")
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError):
        schema.atomic_write(target, b"new")
    assert target.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["meta.json"]


def test_one_class_named_progress():
    import ast
    from pathlib import Path

    root = Path(__file__).parent.parent
    seen = {}
    for package in ("generator", "datasets", "surrogate"):
        for path in sorted((root / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef):
                    seen.setdefault(node.name, []).append(str(path.relative_to(root)))
    assert seen["StreamPosition"] == ["datasets/progress.py"]  # was a second `Progress` beside surrogate.train's
    assert len(seen.get("Progress", [])) <= 1


def test_only_the_datasets_package_imports_its_private_bridge():
    import ast
    from pathlib import Path

    import datasets

    root = Path(__file__).parent.parent
    outside = [root / "cli.py", *(root / "surrogate").rglob("*.py"), *(root / "generator").rglob("*.py")]
    for path in outside:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert "_bridge" not in (node.module or ""), f"{path.name} imports datasets._bridge"
                assert all(a.name != "_bridge" for a in node.names), f"{path.name} imports datasets._bridge"
    assert datasets.max_index() > 0 and callable(datasets.pde_from_config)  # the public door instead


def test_the_wheel_leaves_the_benchmarks_out():
    import tomllib
    from pathlib import Path

    from setuptools import find_packages

    root = Path(__file__).parent.parent
    found = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    shipped = find_packages(where=str(root), include=found["include"], exclude=found.get("exclude", ()))
    assert "generator" in shipped and "surrogate" in shipped
    assert not [p for p in shipped if p.split(".")[0] in ("benchmarks", "tests")]


def test_bench_json_into_a_missing_directory_is_refused_before_the_benchmark(tmp_path, capsys, monkeypatch):
    import cli

    monkeypatch.setattr(cli, "import_benchmarks", lambda: pytest.fail("the benchmark ran"))
    code = cli.main(["bench", "generator", "--quick", "--json", str(tmp_path / "no" / "b.json")])
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and "does not exist" in err and "Traceback" not in err
