"""MkDocs hook: a tree of links that mkdocstrings (griffe) reads the package from.

The package is the repository root (pyproject maps `pdestream` to it), which griffe cannot find by name, and
datasets/ has no __init__.py (so a checkout never shadows HuggingFace's `datasets`), which griffe does not load
inside a regular package. On import (mkdocs imports its hooks before mkdocstrings reads its paths) this hook
makes .docs-api/ (git-ignored; mkdocs.yml gives it as mkdocstrings' path) with

    pdestream/            __init__.py, cli.py, generator/, surrogate/, experiments/: links to the repository's
    pdestream_datasets/   a link to datasets/; docs/api/datasets.md documents pdestream_datasets.<module>
                          under the heading pdestream.datasets.<module>
"""

from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]
_TREE = _ROOT / ".docs-api"


def _link(path: Path, target: Path) -> None:
    if not path.is_symlink():
        path.symlink_to(target, target_is_directory=target.is_dir())


(_TREE / "pdestream").mkdir(parents=True, exist_ok=True)
for name in ("__init__.py", "cli.py", "generator", "surrogate", "experiments"):
    _link(_TREE / "pdestream" / name, _ROOT / name)
_link(_TREE / "pdestream_datasets", _ROOT / "datasets")
