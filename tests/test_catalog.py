"""The catalog and the declared interfaces: one list of entries, names that carry the dimension, abstract PDE
methods, the operator-shape check, one IC protocol, no registry filled at import time."""

import dataclasses
import pickle
import subprocess
import sys
from typing import Any, ClassVar

import pytest

from pdestream import generator as g
from pdestream.generator import catalog
from pdestream.generator.spectral.base import PDE, LinearPDE
from pdestream.generator.spectral.diffusion import Diffusion


def test_every_entry_is_declared_once_with_a_group_and_its_dimension_in_its_name():
    names = [e.name for e in catalog.ENTRIES]
    assert len(names) == len(set(names)) and list(g.PDES) == names
    for entry in catalog.ENTRIES:
        cls = g.PDES[entry.name]
        assert entry.group in g.GROUPS and g.GROUP[entry.name] == entry.group
        assert cls.NAME == entry.name and entry.name.endswith(f"{cls.NDIM}d"), entry
        assert entry.fixed.get("ndim", cls.NDIM) == cls.NDIM
        assert issubclass(cls, entry.pde)


def test_every_entry_pickles_by_reference_and_rebuilds_from_its_config():
    for name in g.PDES:
        pde = g.get_pde(name)
        assert pickle.loads(pickle.dumps(pde)) == pde
        assert g.from_config(pde.config()) == pde


def test_a_non_string_or_unknown_name_gets_one_line():
    for bad in (3, None, ["burgers1d"], "nosuchpde"):
        with pytest.raises(ValueError) as err:
            g.get_pde(bad)
        msg = str(err.value)
        assert msg.startswith(f"unknown PDE {bad!r}; allowed: advection1d, ") and "\n" not in msg
    for bad, near in (("burgers", "burgers1d or burgers2d or burgers3d"), ("burgers4d", "burgers3d or burgers2d or burgers1d")):
        with pytest.raises(ValueError, match=f"^unknown PDE '{bad}'; did you mean {near}.*; allowed: advection1d"):
            g.get_pde(bad)


def test_settings_of_other_dimensions_are_not_settings_of_an_entry():
    assert "c_x" not in g.get_pde("advection1d").config() and "c" not in g.get_pde("advection2d").config()
    assert list(g.get_pde("advection3d").PARAMS) == ["c_x", "c_y", "c_z"]
    with pytest.raises(ValueError, match="advection1d: unknown setting 'c_x'; allowed: n, length"):
        g.get_pde("advection1d", c_x=0.5)


def test_a_dimension_generic_class_is_built_through_the_catalog():
    with pytest.raises(TypeError, match="build it as a catalog entry"):
        Diffusion()
    with pytest.raises(TypeError, match=r"needs fixed=\{'ndim': d\} with d in \[1, 2, 3\]"):
        catalog.entry_class(catalog.Entry("diffusion4d", Diffusion, {"ndim": 4}, "linear"))
    with pytest.raises(TypeError, match="group 'misc'"):
        catalog.entry_class(catalog.Entry("diffusion2d", Diffusion, {"ndim": 2}, "misc"))


def test_a_pde_missing_a_required_method_cannot_be_built():
    @dataclasses.dataclass(frozen=True)
    class NoStep(PDE):
        NAME: ClassVar[str] = "nostep1d"
        nu: Any = 0.1

        def linear(self, grid, p):
            return grid.laplacian()[None]

        def nonlinear(self, grid, p):
            return None

    with pytest.raises(TypeError, match="abstract method.*stable_dt"):
        NoStep()


def test_an_operator_of_the_wrong_shape_is_refused_naming_the_pde():
    @dataclasses.dataclass(frozen=True)
    class Wrong(LinearPDE):
        NAME: ClassVar[str] = "wrong2d"
        NDIM: ClassVar[int] = 2
        n: int = 16
        ic: Any = g.FourierSeries()

        def linear(self, grid, p):
            return grid.laplacian()  # missing the field axis: [n, n//2+1], not [1, n, n//2+1]

    with pytest.raises(ValueError) as err:
        Wrong()
    msg = str(err.value)
    assert msg.startswith("wrong2d: linear(grid, p) has shape (16, 9); the state is [C, *kshape] = (1, 16, 9)"), msg


def test_every_spectral_entry_has_operators_of_the_states_shape():
    """Building a catalog entry skips the operator-shape check (so it needs no JAX); it is made here, for each
    spectral entry at its defaults, and for a walled variant where the entry has walls."""
    from pdestream.generator.spectral.base import PDE, check_operators, is_catalog_class

    checked = 0
    for name, cls in g.PDES.items():
        if not issubclass(cls, PDE):
            continue
        assert is_catalog_class(cls), name
        check_operators(cls())
        checked += 1
    assert checked >= 25
    walled = g.get_pde("burgers1d", {"bc": "dirichlet"})
    assert is_catalog_class(type(walled))
    check_operators(walled)
    assert not is_catalog_class(type("Mine", (PDE,), {"NAME": "burgers1d", "__module__": "mypdes"}))


def test_initial_conditions_follow_one_protocol():
    for kind, cls in g.IC_KINDS.items():
        ic = cls()
        assert isinstance(ic, g.InitialCondition) and ic.kind == kind
        grid = g.Grid(1, 32, 1.0) if kind == "sines" else g.Grid(2, 16, 1.0)  # sines: PDEBench's 1D measure
        ic.check(grid)
        assert ic.bound(grid) > 0
    assert g.make_ic({"kind": "grf", "alpha": "3"}) == g.GaussianRandomField(alpha=3.0)
    with pytest.raises(ValueError, match="unknown ic kind 'gauss'; allowed: fourier, grf, spots, sines"):
        g.make_ic("gauss")


def test_no_module_fills_a_registry_at_import_time():
    # IC_KINDS is complete when generator.ics is imported alone; importing every PDE module changes nothing
    code = ("import pdestream.generator.ics as ics; before = dict(ics.IC_KINDS); import pdestream.generator; "
            "assert dict(ics.IC_KINDS) == before, (before, ics.IC_KINDS); print(sorted(before))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['fourier', 'grf', 'sines', 'spots']"


def test_list_groups_the_catalog_and_says_each_dimension(capsys):
    from pdestream import cli

    assert cli.main(["list"]) == 0
    out = capsys.readouterr().out
    headers = [line for line in out.splitlines() if line.startswith("== ")]
    groups = [h.split()[1] for h in headers]
    assert groups == [grp for grp in g.GROUPS if grp in g.GROUP.values()]
    for name, cls in g.PDES.items():
        line = f"[{cls.NDIM}D] {name}: "
        assert out.count(line) == 1, name
        # under its own group's header
        assert out.rfind("== ", 0, out.index(line)) == out.index(f"== {g.GROUP[name]} ")
