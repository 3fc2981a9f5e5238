"""`pdestream export --to the-well|pdebench` and `pdestream import`: the files are read by The Well's own
WellDataset and by plain h5py as PDEBench's loaders read them, equal the cache, and read back exactly."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import xarray as xr

from pdestream import cli, datasets
from pdestream.datasets import schema
from pdestream.datasets.cache import open_cache
from pdestream.datasets.export import FORMATS, export_cache, import_export, read_export
from pdestream.datasets.stats import read_stats

ENTRIES = {  # tiny caches: a 1D entry, a 2D entry of two fields, a steady 2D entry (PDEBench's Darcy layout)
    "burgers1d": ["--n", "3", "--set", "n=32", "--set", "n_frames=4"],
    "wave2d": ["--n", "2", "--set", "n=16", "--set", "n_frames=3"],
    "darcy2d": ["--n", "2", "--set", "n=16"],
    "euler1d": ["--n", "2", "--set", "n=16", "--set", "n_frames=3", "--set", "t_end=0.02"],  # PDEBench's CFD names
    # an incompressible flow: PDEBench's velocity [N, T, x, y, 2] and particles [..., 1]
    "smoke2d": ["--n", "2", "--set", "n=32", "--set", "n_frames=3", "--set", "t_end=0.05"],
    # a flow with per-sample outputs (drag, lift [N, T], sdf [N, y, x]): kept in the pdestream group
    "channel2d": ["--n", "2", "--set", "n_frames=3", "--set", "t_start=0", "--set", "t_end=0.05"],
}


def _generate(root: Path, entries: dict) -> dict[str, Path]:
    """{entry: the cache generated from its argv} under ``root``."""
    out = {}
    for name, argv in entries.items():
        out[name] = root / f"{name}.h5"
        assert cli.main(["generate", name, *argv, "--out", str(out[name])]) == 0
    return out


@pytest.fixture(scope="module")
def caches(tmp_path_factory):
    return _generate(tmp_path_factory.mktemp("caches"), ENTRIES)


def _fields(path) -> dict[str, np.ndarray]:
    """Every field (inputs first) of a cache in the generator's order [N, (T,) x(, y)], and its parameters."""
    with open_cache(path) as ds:
        names = (*ds.attrs["pdestream_inputs"].split(), *ds.attrs["pdestream_fields"].split())
        arrays = {n: schema.from_disk(ds[n].values, schema.space_ndim(ds[n].dims)) for n in names}
        params = {p: ds[p].values for p in ds.attrs["pdestream_params"].split()}
        coords = {d: ds[d].values for d in ("time", "x", "y") if d in ds.coords}
    return arrays, params, coords


def _same_attrs(a, b) -> bool:
    return set(a) == set(b) and all(np.array_equal(np.asarray(a[k]), np.asarray(b[k])) for k in a)


def _reads_back_and_imports_as(export: Path, cache: Path, again: Path) -> Path:
    """The export read back (``read_export``) and imported to ``again`` equal ``cache``, attributes too; returns
    the imported cache."""
    with open_cache(cache) as ds:
        original = ds.load()
    back = read_export(export)
    xr.testing.assert_equal(back, original)
    assert _same_attrs(back.attrs, original.attrs)
    assert all(_same_attrs(back[v].attrs, original[v].attrs) for v in original.variables)
    imported = import_export(export, again)
    with open_cache(imported) as ds:
        xr.testing.assert_equal(ds.load(), original)
        assert _same_attrs(ds.attrs, original.attrs)
    return imported


@pytest.mark.parametrize("name", ["burgers1d", "wave2d"])
def test_the_wells_own_dataset_class_reads_the_export(caches, tmp_path, name):
    well = pytest.importorskip("the_well.data")
    out = tmp_path / "data" / "train" / f"{name}.hdf5"
    out.parent.mkdir(parents=True)
    export_cache(caches[name], "the-well", out)
    fields, params, coords = _fields(caches[name])
    n = len(next(iter(params.values())))
    ds = well.WellDataset(path=str(tmp_path), well_split_name="train", n_steps_input=1, full_trajectory_mode=True)
    meta = ds.metadata
    assert meta.dataset_name == name and meta.n_trajectories_per_file == [n]
    assert meta.field_names[0] == list(fields) and meta.constant_scalar_names == list(params)
    assert meta.boundary_condition_types == ["PERIODIC"] and len(ds) == n
    expected = np.stack(list(fields.values()), -1)  # [N, T, x(, y), C]: The Well's channel-last order
    for i in range(n):
        item = ds[i]  # full trajectory i: the first frame as input, the others as output
        got = np.concatenate([item["input_fields"].numpy(), item["output_fields"].numpy()], 0)
        np.testing.assert_array_equal(got, expected[i])
        np.testing.assert_array_equal(item["constant_scalars"].numpy(), [params[p][i] for p in params])
        assert (item["boundary_conditions"].numpy() == 2).all()  # BoundaryCondition.PERIODIC on every side
    from the_well.utils.export import hdf5_to_xarray  # The Well's own reader of one file

    with h5py.File(out, "r") as f:
        plain = hdf5_to_xarray(f)
    for k, v in fields.items():
        np.testing.assert_array_equal(plain[k].values, v)
    grid = np.stack(np.meshgrid(*(coords[d] for d in ("x", "y") if d in coords), indexing="ij"), -1)
    np.testing.assert_array_equal(item["space_grid"].numpy(), grid)


@pytest.mark.parametrize("name", ["smoke2d", "channel2d"])
def test_the_well_holds_a_flows_velocity_as_one_vector_field(caches, tmp_path, name):
    # adv50: u, v were written as scalar t0 fields; The Well stores a velocity as t1_fields/velocity [N, T, x, y, 2]
    out = tmp_path / "data" / "train" / f"{name}.hdf5"
    out.parent.mkdir(parents=True)
    export_cache(caches[name], "the-well", out)
    fields, _, _ = _fields(caches[name])
    with h5py.File(out, "r") as f:
        assert [str(x) for x in f["t1_fields"].attrs["field_names"]] == ["velocity"]
        v = f["t1_fields"]["velocity"]
        np.testing.assert_array_equal(v[...], np.stack([fields["u"], fields["v"]], -1))
        assert list(v.attrs["dim_varying"]) == [True, True] and v.attrs["sample_varying"] and v.attrs["time_varying"]
        rest = [k for k in fields if k not in ("u", "v")]
        assert [str(x) for x in f["t0_fields"].attrs["field_names"]] == rest and set(f["t0_fields"]) == set(rest)
    stats = read_stats(tmp_path / "stats.yaml")  # The Well's statistics of a vector field: one value per component
    assert stats["mean"]["velocity"] == [stats["mean"]["u"], stats["mean"]["v"]]
    assert stats["std"]["velocity"] == [stats["std"]["u"], stats["std"]["v"]]


def test_the_wells_own_dataset_class_reads_a_flows_velocity_and_its_statistics(caches, tmp_path):
    well = pytest.importorskip("the_well.data")
    out = tmp_path / "data" / "train" / "smoke2d.hdf5"
    out.parent.mkdir(parents=True)
    export_cache(caches["smoke2d"], "the-well", out)
    fields, _, _ = _fields(caches["smoke2d"])
    raw = well.WellDataset(path=str(tmp_path), well_split_name="train", n_steps_input=1, full_trajectory_mode=True)
    assert raw.metadata.field_names == {0: ["p", "smoke"], 1: ["velocity_x", "velocity_y"], 2: []}
    item = raw[0]
    got = np.concatenate([item["input_fields"].numpy(), item["output_fields"].numpy()], 0)  # [T, x, y, 4]
    for c, name in enumerate(("p", "smoke", "u", "v")):
        np.testing.assert_array_equal(got[..., c], fields[name][0])
    from the_well.data.normalization import ZScoreNormalization

    normed = well.WellDataset(path=str(tmp_path), well_split_name="train", n_steps_input=1, full_trajectory_mode=True,
                              use_normalization=True, normalization_type=ZScoreNormalization)  # stats.yaml's
    # velocity: one mean and std per component
    item = normed[0]
    got = np.concatenate([item["input_fields"].numpy(), item["output_fields"].numpy()], 0)
    stats = read_stats(tmp_path / "stats.yaml")
    for c, name in ((2, "u"), (3, "v")):
        want = (fields[name][0] - stats["mean"][name]) / stats["std"][name]
        np.testing.assert_allclose(got[..., c], want, rtol=1e-4, atol=1e-4)


def test_a_steady_cache_goes_to_pdebench_only(caches, tmp_path, capsys):
    out = tmp_path / "darcy.hdf5"
    assert cli.main(["export", str(caches["darcy2d"]), "--to", "the-well", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "steady" in err and "--to pdebench" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", list(ENTRIES))
def test_pdebench_layout_read_as_pdebenchs_loaders_do(caches, tmp_path, name):
    out = tmp_path / f"{name}.h5"
    export_cache(caches[name], "pdebench", out)
    fields, params, coords = _fields(caches[name])
    with h5py.File(out, "r") as f:
        np.testing.assert_array_equal(f["x-coordinate"][...], coords["x"])
        if "y" in coords:
            np.testing.assert_array_equal(f["y-coordinate"][...], coords["y"])
        if name == "darcy2d":  # Darcy's layout: the input as nu (where its loader reads it), the solution as tensor
            assert "t-coordinate" not in f and "a" not in f
            np.testing.assert_array_equal(f["nu"][...], fields["a"])
            np.testing.assert_array_equal(f["tensor"][...], fields["u"][:, None])
        else:
            np.testing.assert_array_equal(f["t-coordinate"][...], coords["time"])
            if name in ("smoke2d", "channel2d"):  # PDEBench's incompressible NS files: velocity, particles, t
                np.testing.assert_array_equal(f["velocity"][...], np.stack([fields["u"], fields["v"]], -1))
                if "smoke" in fields:
                    np.testing.assert_array_equal(f["particles"][...], fields["smoke"][..., None])
                np.testing.assert_array_equal(f["t"][...], np.broadcast_to(coords["time"], f["t"].shape))
                for k in set(fields) - {"u", "v", "smoke"}:  # p (and solid) as themselves
                    np.testing.assert_array_equal(f[k][...], fields[k])
                assert not {"u", "v", "smoke", "tensor"} & set(f)
            elif len(fields) == 1:  # one field: "tensor" [N, T, x(, y)]
                np.testing.assert_array_equal(np.array(f["tensor"], dtype=np.float32), fields["u"])
            else:  # several: one dataset per field, as PDEBench's CFD files (a compressible flow: their names)
                assert "tensor" not in f
                names = {"rho": "density", "u": "Vx", "p": "pressure"} if name == "euler1d" else {k: k for k in fields}
                assert set(names) == set(fields)
                for k, v in fields.items():
                    np.testing.assert_array_equal(f[names[k]][...], v)
        for p, v in params.items():
            np.testing.assert_array_equal(f[p][...], v)


@pytest.mark.parametrize("to", list(FORMATS))
@pytest.mark.parametrize("name", list(ENTRIES))
def test_read_back_and_import_equal_the_cache(caches, tmp_path, name, to):
    if to == "the-well" and name == "darcy2d":
        pytest.skip("steady: The Well holds time series")
    out = tmp_path / "e.hdf5"
    export_cache(caches[name], to, out)
    cache = _reads_back_and_imports_as(out, caches[name], tmp_path / "again.h5")
    a, b = datasets.CachedTrajectories(caches[name]), datasets.CachedTrajectories(cache)
    assert len(a) == len(b) and a.config == b.config
    for k in range(len(a)):
        assert all(np.array_equal(a[k][key], b[k][key]) for key in a[k])


def _err(capsys, argv) -> str:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pdestream: error: ") and "Traceback" not in err
    return err


def test_refusals_are_one_line(caches, tmp_path, capsys):
    cache = str(caches["burgers1d"])
    out = tmp_path / "b.h5"
    assert "--to 'hdf5' not allowed; allowed: the-well, pdebench" in _err(
        capsys, ["export", cache, "--to", "hdf5", "--out", str(out)])
    assert "must end in .h5 or .hdf5" in _err(capsys, ["export", cache, "--to", "pdebench", "--out", str(tmp_path / "b.nc")])
    assert not list(tmp_path.iterdir())

    incomplete = tmp_path / "incomplete.h5"
    shutil.copy(cache, incomplete)
    with h5py.File(incomplete, "r+") as f:
        f["complete"][1] = 0
        f.attrs["pdestream_complete"] = 0
    assert "incomplete (2 of 3 samples written)" in _err(capsys, ["export", str(incomplete), "--to", "pdebench",
                                                                  "--out", str(out)])
    assert not out.exists()

    assert cli.main(["export", cache, "--to", "pdebench", "--out", str(out)]) == 0
    capsys.readouterr()
    assert "exists; pass --overwrite" in _err(capsys, ["export", cache, "--to", "the-well", "--out", str(out)])
    assert cli.main(["export", cache, "--to", "the-well", "--out", str(out), "--overwrite"]) == 0  # ours: replaced
    assert read_export(out).attrs["pde"] == "burgers1d"
    capsys.readouterr()
    other = tmp_path / "other.h5"  # not an export of ours: never replaced
    other.write_bytes(b"user data")
    assert "refusing to overwrite" in _err(capsys, ["export", cache, "--to", "pdebench", "--out", str(other),
                                                    "--overwrite"])
    assert other.read_bytes() == b"user data"

    foreign = tmp_path / "pdebench.hdf5"  # a file PDEBench wrote: no PDE config to train with
    with h5py.File(foreign, "w") as f:
        f["tensor"] = np.zeros((2, 3, 8), np.float32)
        f["x-coordinate"] = np.linspace(0, 1, 8)
        f["t-coordinate"] = np.linspace(0, 1, 3)
    assert "pdebench file not written by pdestream" in _err(capsys, ["import", str(foreign), "--out",
                                                                     str(tmp_path / "c.h5")])
    assert "neither a The Well nor a PDEBench" in _err(capsys, ["import", cache, "--out", str(tmp_path / "c.h5")])
    assert "exists; choose another path" in _err(capsys, ["import", str(out), "--out", str(other)])
    assert "cache " + str(out) + " was written with other settings (n: cache 32 vs asked 64)" in _err(
        capsys, ["train", "burgers1d", "--source", str(out), "--set", "n=64", "--out", str(tmp_path / "run")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.h5", "incomplete.h5", "other.h5", "pdebench.hdf5"]


def test_train_on_an_export_equals_training_on_the_cache(caches, tmp_path):
    """`train --source EXPORT` reads the export through a temporary cache, removed when the command exits."""
    out = tmp_path / "e.h5"
    export_cache(caches["burgers1d"], "pdebench", out)
    (tmp_path / "tmp").mkdir()
    env = {**os.environ, "TMPDIR": str(tmp_path / "tmp")}
    losses = []
    for source, run in ((caches["burgers1d"], "run_cache"), (out, "run_export")):
        argv = [sys.executable, str(Path(cli.__file__)), "train", "burgers1d", "--source", str(source), "--set", "n=32",
                "--set", "n_frames=4", "--steps", "3", "--batch-size", "2", "--test-samples", "1",
                "--out", str(tmp_path / run)]
        subprocess.run(argv, env=env, check=True, capture_output=True)
        losses.append(json.loads((tmp_path / run / "metrics.json").read_text())["final_loss"])
    assert losses[0] == losses[1]
    assert json.loads((tmp_path / "run_export" / "run.json").read_text())["source"] == str(out)
    assert not list((tmp_path / "tmp").glob("pdestream-import-*"))


def test_train_on_a_cache_or_export_without_naming_the_pde_trains_the_caches(caches, tmp_path):
    """`train --source PATH` without a PDE name was refused ("no PDE named"), though the cache (or export) names its
    PDE; it trains the cache's, as `train NAME --source PATH` does."""
    out = tmp_path / "e.h5"
    export_cache(caches["burgers1d"], "pdebench", out)
    losses = []
    for source, name in ((caches["burgers1d"], ["burgers1d"]), (caches["burgers1d"], []), (out, [])):
        run = tmp_path / f"run{len(losses)}"
        assert cli.main(["train", *name, "--source", str(source), "--steps", "2", "--batch-size", "2",
                         "--test-samples", "1", "--threads", "1", "--model-set", "width=4", "--model-set", "modes=2",
                         "--model-set", "layers=1", "--out", str(run)]) == 0
        losses.append(json.loads((run / "metrics.json").read_text())["final_loss"])
        assert json.loads((run / "run.json").read_text())["pde"]["pde"] == "burgers1d"
    assert losses[0] == losses[1] == losses[2]


@pytest.mark.parametrize("suffix", [".h5", ".zarr"])
def test_an_import_never_replaces_a_cache_another_process_made_meanwhile(caches, tmp_path, monkeypatch, suffix):
    # two `pdestream import` runs writing the same new file both exited 0; the file held only the second's data
    from pdestream.datasets import store

    export = tmp_path / "e.h5"
    export_cache(caches["burgers1d"], "the-well", export)
    out = tmp_path / f"c{suffix}"
    fmt = store.format_of(out)
    real = type(fmt).mark_complete

    def the_other_import_finishes_first(self, handle):
        real(self, handle)
        out.mkdir() if suffix == ".zarr" else out.write_bytes(b"the other import's cache")
        if suffix == ".zarr":
            (out / "theirs").write_text("the other import's cache")

    monkeypatch.setattr(type(fmt), "mark_complete", the_other_import_finishes_first)
    with pytest.raises(FileExistsError, match=r"exists \(another process wrote it meanwhile\)"):
        import_export(export, out)
    kept = (out / "theirs") if suffix == ".zarr" else out
    assert kept.read_bytes() == b"the other import's cache"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["e.h5", out.name])  # no temp left behind


def test_an_export_never_replaces_a_file_another_export_made_meanwhile(caches, tmp_path, monkeypatch):
    out = tmp_path / "e.h5"
    fmt = FORMATS["pdebench"]
    real = type(fmt).write

    def the_other_export_finishes_first(self, ds, path):
        real(self, ds, path)
        out.write_bytes(b"theirs")

    monkeypatch.setattr(type(fmt), "write", the_other_export_finishes_first)
    with pytest.raises(FileExistsError, match="another process wrote it meanwhile"):
        export_cache(caches["burgers1d"], "pdebench", out)
    assert out.read_bytes() == b"theirs" and [p.name for p in tmp_path.iterdir()] == ["e.h5"]


def _put_nan(dataset, index) -> None:
    values = dataset[()]
    values[index] = np.nan
    dataset[...] = values


@pytest.mark.parametrize("damage, words", [
    (lambda f: f["t0_fields"].__delitem__("u"), "damaged the-well export: u is missing"),  # was a KeyError
    (lambda f: f["scalars"].__delitem__("nu"), "damaged the-well export: nu is missing"),
    (lambda f: f.attrs.__setitem__("pdestream_params", "nu kappa"), "parameter kappa is listed but not in the file"),
    (lambda f: f.attrs.__setitem__("pdestream_config", "{not json"), "pdestream_config attribute is not a JSON object"),
    # a NaN put into an export was imported silently, rc 0 (and trained on)
    (lambda f: _put_nan(f["t0_fields"]["u"], (1, 0, 3)), r"u holds NaN/Inf in 1 sample\(s\) \(rows \[1\]\)"),
    (lambda f: _put_nan(f["scalars"]["nu"], (0,)), r"nu holds NaN/Inf in 1 sample\(s\) \(rows \[0\]\)"),
])
def test_a_damaged_export_is_refused_in_one_line_and_nothing_is_written(caches, tmp_path, damage, words):
    export = tmp_path / "e.h5"
    export_cache(caches["burgers1d"], "the-well", export)
    with h5py.File(export, "r+") as f:
        damage(f)
    with pytest.raises(ValueError, match=words) as err:
        import_export(export, tmp_path / "c.h5")  # the bad config was imported with rc 0, then refused by readers
    assert "\n" not in str(err.value) and [p.name for p in tmp_path.iterdir()] == ["e.h5"]


@pytest.mark.parametrize("to", list(FORMATS))
def test_a_flows_velocity_naming_other_components_than_it_holds_is_refused_in_one_line(caches, tmp_path, to):
    """adv51: a velocity whose pdestream_names lists three components over its two was an IndexError traceback."""
    export = tmp_path / "e.h5"
    export_cache(caches["smoke2d"], to, export)
    with h5py.File(export, "r+") as f:
        dset = f["t1_fields"]["velocity"] if "t1_fields" in f else f["velocity"]
        dset.attrs["pdestream_names"] = "u v w"
    with pytest.raises(ValueError, match=r"damaged .* export: velocity holds 2 components but pdestream_names "
                                         r"lists 3 \(u v w\); export the cache again") as err:
        import_export(export, tmp_path / "c.h5")
    assert "\n" not in str(err.value) and [p.name for p in tmp_path.iterdir()] == ["e.h5"]


PER_SEED = {  # the sets PDEBench ships per seed (its FNODatasetMult / UNetDatasetMult files), tiny
    "diffusion_sorption1d": ["--n", "3", "--set", "n=16", "--set", "n_frames=3", "--set", "t_end=1"],
    "diffusion_reaction2d": ["--n", "3", "--set", "n=32", "--set", "n_frames=3", "--set", "t_end=0.1"],
    "shallow_water2d": ["--n", "3", "--set", "n=16", "--set", "n_frames=3", "--set", "t_end=0.1"],
}


@pytest.fixture(scope="module")
def per_seed_caches(tmp_path_factory):
    return _generate(tmp_path_factory.mktemp("per_seed"), PER_SEED)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(PER_SEED))
def test_pdebench_per_seed_sets_are_laid_out_as_its_mult_loaders_read_them(per_seed_caches, tmp_path, name):
    """Every top-level key a sample's group ("0000", ...: the loaders take each key for one and split by sorted
    name), ``data`` [T, x(, y), C] with PDEBench's channels, ``grid/x``(, ``grid/y``), ``grid/t``; our other
    fields beside ``data``; and read back and imported, the cache again."""
    from pdestream.datasets.pdebench_seeds import PER_SEED_CHANNELS

    out = tmp_path / f"{name}.h5"
    export_cache(per_seed_caches[name], "pdebench", out)
    fields, params, coords = _fields(per_seed_caches[name])
    channels = PER_SEED_CHANNELS[name]
    with h5py.File(out, "r") as f:
        assert sorted(f.keys()) == ["0000", "0001", "0002"]
        for i, key in enumerate(sorted(f.keys())):
            g = f[key]
            stacked = g["data"][()]
            assert stacked.shape == (*fields[channels[0]].shape[1:], len(channels))
            for c, field in enumerate(channels):
                np.testing.assert_array_equal(stacked[..., c], fields[field][i])
            for field in set(fields) - set(channels):  # shallow water's hu, hv
                np.testing.assert_array_equal(g[field][()], fields[field][i])
            np.testing.assert_array_equal(g["grid/t"][()], coords["time"])
            for d in ("x", "y"):
                if d in coords:
                    np.testing.assert_array_equal(g[f"grid/{d}"][()], coords[d])
            assert all(g.attrs[p] == params[p][i] for p in params)
    _reads_back_and_imports_as(out, per_seed_caches[name], tmp_path / "again.h5")


def test_an_export_without_its_outputs_is_refused_not_imported_damaged(caches, tmp_path):
    """A flow's outputs (drag, lift, sdf) travel in the pdestream group; an export that lacks them (written before
    they were kept) is one line, not a cache that then reads as damaged."""
    out = tmp_path / "e.hdf5"
    export_cache(caches["channel2d"], "pdebench", out)
    with h5py.File(out, "r") as f:
        assert sorted(f["pdestream/outputs"]) == ["drag", "lift", "sdf"]
    with h5py.File(out, "a") as f:
        del f["pdestream/outputs"]
    with pytest.raises(ValueError, match="damaged pdebench export: its output drag is missing"):
        read_export(out)
    with pytest.raises(ValueError, match="its output drag is missing"):
        import_export(out, tmp_path / "again.h5")
    assert not (tmp_path / "again.h5").exists()


@pytest.fixture(scope="module")
def sorption_cache(tmp_path_factory):
    return _generate(tmp_path_factory.mktemp("sorption"), {"diffusion_sorption1d": PER_SEED["diffusion_sorption1d"]})


def _truncate(f, key) -> None:
    values = f[key][()]
    del f[key]
    f[key] = values[:1]


@pytest.mark.parametrize("to, damage, words", [
    # a sample's group deleted: imported with rc 0, then the cache read as damaged ("2 samples stored, 3 expected")
    ("pdebench", lambda f: f.__delitem__("0001"), "lists 3 samples .pdestream_n_samples., 2 are in the file"),
    ("pdebench", lambda f: f.attrs.__setitem__("pdestream_n_samples", 5), "lists 5 samples"),
    ("pdebench", lambda f: f.attrs.__setitem__("pdestream_n_samples", "many"), "lists many samples"),
    # was numpy's "all input arrays must have the same shape", naming neither the file nor the array
    ("pdebench", lambda f: _truncate(f, "0000/data"), "damaged pdebench export: .*shape"),
    # was imported with rc 0, then refused by every reader
    ("pdebench", lambda f: f.attrs.__setitem__("pdestream_schema", 99), "cache schema 99"),
    # was xarray's "conflicting sizes for dimension 'sample'", naming neither the file nor the fix
    ("the-well", lambda f: _truncate(f, "t0_fields/u"), "damaged the-well export: .*size"),
])
def test_a_damaged_per_seed_or_resized_export_is_refused_in_one_line(sorption_cache, tmp_path, to, damage, words):
    export = tmp_path / "e.h5"
    export_cache(sorption_cache["diffusion_sorption1d"], to, export)
    with h5py.File(export, "r+") as f:
        damage(f)
    with pytest.raises(ValueError, match=words) as err:
        import_export(export, tmp_path / "c.h5")
    assert "\n" not in str(err.value) and str(export) in str(err.value)
    assert [p.name for p in tmp_path.iterdir()] == ["e.h5"]


def test_an_export_given_where_a_cache_goes_says_import_it(caches, tmp_path, capsys):
    """inspect / export of an export said "is not a pdestream cache (missing complete, sample)"."""
    out = tmp_path / "e.hdf5"
    export_cache(caches["burgers1d"], "pdebench", out)
    for argv in (["inspect", str(out)], ["export", str(out), "--to", "the-well", "--out", str(tmp_path / "w.hdf5")]):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "is an export written by `pdestream export --to pdebench`" in err \
            and f"pdestream import {out} --out" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.hdf5"]


def test_a_damaged_cache_is_not_exported(caches, tmp_path):
    """A cache holding a NaN (a deleted Zarr chunk reads as one) was exported with rc 0, into a file `import` then
    refuses ("holds NaN/Inf"); it is refused, naming the samples and the repair, and nothing is written."""
    cache = tmp_path / "c.h5"
    shutil.copy(caches["burgers1d"], cache)
    with h5py.File(cache, "r+") as f:
        _put_nan(f["u"], (2, 1, 3))
    with pytest.raises(ValueError) as err:
        export_cache(cache, "pdebench", tmp_path / "e.hdf5")
    assert "samples 2 hold non-finite or missing data" in str(err.value) and "--resume" in str(err.value), \
        str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.h5"]


@pytest.mark.parametrize("name, to", [("burgers1d", "pdebench"), ("channel2d", "the-well")])
def test_export_reads_each_block_once_and_checks_it_there(caches, tmp_path, monkeypatch, name, to):
    """adv50: the NaN check read the cache a second time (24-27% of an export's time); it is folded into the
    export's own read, so every block of every variable is read once."""
    from pdestream.datasets import export

    reads, real = [], export._block

    def counted(ds, var, lo=None, hi=None):
        reads.append((var, lo))
        return real(ds, var, lo, hi)

    monkeypatch.setattr(export, "_block", counted)
    export_cache(caches[name], to, tmp_path / "e.hdf5")
    with open_cache(caches[name]) as ds:
        variables = [v for v in ds.data_vars if ds[v].dtype.kind == "f"] + ds.attrs["pdestream_params"].split()
    assert sorted(set(v for v, _ in reads)) == sorted(variables) and len(reads) == len(set(reads)), reads


def test_generate_overwrite_never_replaces_an_export(caches, tmp_path, capsys):
    """`generate --overwrite` replaces only a cache; an export at the path was replaced by a cache (rc 0)."""
    out = tmp_path / "e.hdf5"
    export_cache(caches["burgers1d"], "pdebench", out)
    before = out.read_bytes()
    code = cli.main(["generate", "burgers1d", *ENTRIES["burgers1d"], "--out", str(out), "--overwrite"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "it is a pdestream export (pdebench layout)" in err, err
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["e.hdf5"]
