"""House rules of issue 21: one atomic write, one name per class, a public engine API, no benchmarks in the wheel."""

import os
import stat

import pytest

from pdestream.datasets import schema


def test_there_is_one_atomic_write_and_it_syncs_the_directory(tmp_path, monkeypatch):
    from pdestream.surrogate import checkpoint, runs, train

    assert train.atomic_write is schema.atomic_write is runs.atomic_write is checkpoint.atomic_write
    synced = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(stat.S_ISDIR(os.fstat(fd).st_mode)) or real(fd))
    target = tmp_path / "meta.json"
    target.write_bytes(b"old")
    schema.atomic_write(target, b"new")
    assert target.read_bytes() == b"new" and synced == [False, True]  # the file, then its directory
    assert [p.name for p in tmp_path.iterdir()] == ["meta.json"]  # no temp file left
    old = os.umask(0o022)
    try:  # metadata files were created readable by their owner only (mkstemp's 0600)
        schema.atomic_write(tmp_path / "run.json", b"{}")
        assert stat.S_IMODE(os.stat(tmp_path / "run.json").st_mode) == 0o644
    finally:
        os.umask(old)


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

    from pdestream import datasets

    root = Path(__file__).parent.parent
    outside = [root / "cli.py", *(root / "surrogate").rglob("*.py"), *(root / "generator").rglob("*.py")]
    for path in outside:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert "_bridge" not in (node.module or ""), f"{path.name} imports datasets._bridge"
                assert all(a.name != "_bridge" for a in node.names), f"{path.name} imports datasets._bridge"
    assert datasets.max_index() > 0 and callable(datasets.pde_from_config)  # the public door instead


def test_the_wheel_ships_pdestream_alone():
    import tomllib
    from pathlib import Path

    root = Path(__file__).parent.parent
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    shipped = setup["packages"]
    assert setup["package-dir"] == {"pdestream": "."} and all(p.split(".")[0] == "pdestream" for p in shipped)
    # every folder of the package with Python files is shipped; benchmarks, tests, examples and docs are not
    folders = {"pdestream." + ".".join(p.parent.relative_to(root).parts) for p in root.glob("*/**/*.py")
               if p.parent.relative_to(root).parts[0] in ("generator", "datasets", "surrogate", "experiments")}
    assert folders == set(shipped) - {"pdestream"}


def test_the_library_never_imports_the_benchmarks():
    import ast
    from pathlib import Path

    root = Path(__file__).parent.parent
    files = [root / "cli.py", root / "__init__.py"]
    files += [p for d in ("generator", "datasets", "surrogate", "experiments") for p in (root / d).rglob("*.py")]
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not any(n.split(".")[0] == "benchmarks" for n in names), f"{path} imports the benchmarks"
            if isinstance(node, ast.Attribute) and node.attr in ("insert", "append", "extend"):
                target = node.value
                edits = isinstance(target, ast.Attribute) and target.attr == "path" and getattr(target.value, "id", "") == "sys"
                edits_ok = path.name == "cli.py" and node.attr == "append"  # importable_here: the current directory
                assert not edits or edits_ok, f"{path} edits sys.path"


def test_bench_json_into_a_missing_directory_is_refused_before_the_benchmark(tmp_path, capsys, monkeypatch):
    import benchmarks.__main__ as bench

    monkeypatch.setattr(bench, "run", lambda *a: pytest.fail("the benchmark ran"))
    code = bench.main(["--only", "generator", "--quick", "--json", str(tmp_path / "no" / "b.json")])
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and "does not exist" in err and "Traceback" not in err


@pytest.mark.xdist_group("house")
def test_xdist_keeps_the_groups_it_was_given(request):
    """Under `--dist loadgroup` (CI), an entry's tests share one worker, which compiles its programs once: xdist
    marks a grouped test by suffixing its id with "@GROUP". pytest 9.2 with pytest-xdist 3.8 silently drops the
    suffix (pytest-xdist #1386; pyproject pins pytest < 9.2), and CI then compiles every entry in both workers."""
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("runs under pytest -n N --dist loadgroup (the default addopts with -n)")
    assert request.node.nodeid.endswith("@house"), request.node.nodeid


def test_tests_patch_the_cache_formats_on_their_classes():
    """monkeypatch.setattr on an instance (store.ZARR / HDF5) leaves the original bound method on it when undone,
    which hides every later patch of the class in that process: a test's outcome then depends on which tests
    its xdist worker ran before it (CI: test_write_limits' import succeeded where it must fail)."""
    import re
    from pathlib import Path

    pattern = re.compile(r"monkeypatch\.setattr\((store\.)?(ZARR|HDF5)\s*,")
    offenders = [f"{p.name}:{i}" for p in Path(__file__).parent.glob("test_*.py")
                 for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert offenders == [], offenders


def test_ci_runs_the_readmes_test_command_and_full_runs_every_test():
    """The README's test command is what the gate (.ci/run) runs, with the docs' code blocks; .ci/full adds the slow
    set to the same command."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    readme = (root / "README.md").read_text()
    command = next(line for line in readme.splitlines() if line.startswith("python3 -m venv") and "pytest" in line)
    tests = command[command.index("ruff check ."):]  # after the installs, which CI runs quietly (pip -q)
    gate, full = (root / ".ci" / "run").read_text(), (root / ".ci" / "full").read_text()
    assert tests + " && " in gate, f".ci/run no longer runs the README's {tests!r}"
    assert "-m slow tests/test_docs.py" in gate, ".ci/run no longer runs the docs' code blocks (the slow set's)"
    assert tests + ' -m "slow or not slow"' in full, f".ci/full no longer runs {tests!r} over every test"
    assert "-m" not in tests.split("pytest", 1)[1], "the README's test command selects the default (quick) set"
