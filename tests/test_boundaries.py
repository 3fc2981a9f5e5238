"""pdestream.boundaries: the boundary kinds declared once (below JAX and torch), and nothing else comparing their
names as strings."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from pdestream import boundaries
from pdestream.boundaries import BC_TYPE, BOUNDARY_TYPES, DIRICHLET, NEUMANN, PERIODIC, Boundary

ROOT = Path(__file__).resolve().parents[1]
NAMES = set(BOUNDARY_TYPES)
PACKAGE_DIRS = ("generator", "datasets", "surrogate", "experiments")


def package_files():
    yield from sorted(ROOT.glob("*.py"))
    for d in PACKAGE_DIRS:
        yield from sorted((ROOT / d).rglob("*.py"))


def string_compares(path: Path) -> list[str]:
    """'file:line' of each comparison (==, !=, in, not in, is) with a boundary name as a string constant, or with
    a tuple / list / set of constants holding one."""
    def names_one(node) -> bool:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return node.value.strip().lower() in NAMES
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            return any(names_one(e) for e in node.elts)
        return False

    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Compare) and any(names_one(n) for n in (node.left, *node.comparators)):
            found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return found


def test_no_boundary_name_compared_as_a_string_outside_the_module():
    found = [hit for path in package_files() if path.name != "boundaries.py" for hit in string_compares(path)]
    assert not found, f"boundary names compared as strings (ask pdestream.boundaries instead): {found}"


def test_the_scan_finds_a_comparison(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text('def f(b, bcs):\n    return b == "periodic" or "Dirichlet" in bcs or b in ("neumann", "x")\n')
    assert len(string_compares_at(bad)) == 3  # one Compare node per operand of the `or`

def string_compares_at(path):
    global ROOT
    old, ROOT = ROOT, path.parent
    try:
        return string_compares(path)
    finally:
        ROOT = old


def test_importable_without_jax_or_torch():
    code = ("import sys; import pdestream.boundaries; "
            "assert not {'jax', 'torch', 'pdestream.generator'} & set(sys.modules), sorted(sys.modules)")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_kinds_and_their_behaviour():
    assert BOUNDARY_TYPES == ("periodic", "dirichlet", "neumann")
    assert BC_TYPE == {"periodic": "periodic", "dirichlet": "wall", "neumann": "open"}
    assert [b.periodic for b in Boundary] == [True, False, False]
    assert [b.walled for b in Boundary] == [False, True, True]
    assert [b.pins_value for b in Boundary] == [False, True, False]
    assert [b.bc_type for b in Boundary] == ["periodic", "wall", "open"]
    assert [b.pad_mode for b in Boundary] == ["circular", "constant", "replicate"]
    assert DIRICHLET.derivative == (NEUMANN, 1) and NEUMANN.derivative == (DIRICHLET, -1)
    assert Boundary.of(" Dirichlet ") is DIRICHLET and Boundary.of(NEUMANN) is NEUMANN
    # stored and shown as its word: caches written with the values read as those written with the words
    assert str(PERIODIC) == f"{PERIODIC}" == "periodic" and {"periodic": 1}[PERIODIC] == 1
    assert " ".join(boundaries.kinds(["dirichlet", "periodic"])) == "dirichlet periodic"


def test_refusals_in_one_line():
    with pytest.raises(ValueError, match=r"^boundary 'wall' not allowed; allowed: periodic, dirichlet, neumann$"):
        Boundary.of("wall")
    with pytest.raises(ValueError, match=r"^ks2d: bc='dirichlet' not allowed \(dirichlet is not among this "
                                         r"entry's boundaries\); allowed: periodic, neumann$"):
        boundaries.parse("dirichlet", 2, allowed=("periodic", "neumann"), name="ks2d")
    with pytest.raises(ValueError, match=r"bc.z not allowed: the axes of a 2D entry are x, y"):
        boundaries.parse("z=dirichlet", 2)
    with pytest.raises(ValueError, match="axis x given twice"):
        boundaries.parse("x=dirichlet,x=neumann", 2)


def test_parse_and_text():
    assert boundaries.parse("x=dirichlet,y=periodic", 2) == ("dirichlet", "periodic")
    assert boundaries.parse("Neumann", 2) == ("neumann", "neumann")
    assert boundaries.parse({"bc": {"y": "dirichlet"}}, 2) == ("periodic", "dirichlet")
    assert boundaries.parse({"bc.x": "neumann"}, 2, current=("dirichlet", "dirichlet")) == ("neumann", "dirichlet")
    assert boundaries.text(("dirichlet", "periodic")) == "x=dirichlet,y=periodic"
    assert boundaries.text(("neumann",) * 3) == "neumann"
    assert boundaries.words("dirichlet periodic", 2) == ("dirichlet", "periodic")
    assert boundaries.words(None, 2) == ("periodic", "periodic")


def test_the_helpers_on_words():
    assert boundaries.all_periodic(None) and boundaries.all_periodic(("periodic", "periodic"))
    assert not boundaries.all_periodic(("periodic", "wall"))  # a word that names no boundary is not periodic
    assert boundaries.pins_value(("neumann", "dirichlet")) and not boundaries.pins_value(("neumann", "foo"))
    assert boundaries.first_pinned(("neumann", "dirichlet")) == 1
    assert boundaries.is_periodic("periodic") and not boundaries.is_periodic("wall")
    # exact on stored words (as the comparisons they replace were): a model's bc=("Periodic",) is refused by its check
    assert not boundaries.all_periodic(("Periodic",)) and not boundaries.pins_value(("Dirichlet",))
