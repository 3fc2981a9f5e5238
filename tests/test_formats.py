"""The two cache formats behind one interface (datasets.store), and the failures a cache meets on disk: a full
disk, a file held open by another process, a truncated chunk, a missing variable, a garbled config attribute, a
long but legal name. Each is one line naming the path and the cause (the CLI exits 2, no traceback) and leaves
nothing behind; a lazy reader notices that its cache was replaced by an --overwrite instead of serving mixed data."""

import errno
import json
import os
import pickle
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_data_safety import SMALL, digest, generate, listing, run_cli

from pdestream import datasets
from pdestream.datasets import cache as cache_mod
from pdestream.datasets.store import HDF5, ZARR, CacheSettings, format_of

FORMATS = ["h5", "zarr"]


def one_line_error(code, err, *parts):
    """The CLI refused with one line that says each of ``parts``."""
    assert code == 2 and err.startswith("pdestream: error: ") and err.count("\n") == 1, err
    for part in parts:
        assert str(part) in err, (part, err)


@pytest.fixture(params=FORMATS)
def cache(request, tmp_path, capsys):
    """A complete 4-sample cache (seed 0) and its sha256."""
    path = tmp_path / f"c.{request.param}"
    assert generate(capsys, path)[0] == 0
    return path, digest(path)


# --- the interface ----------------------------------------------------------------------------------
def test_formats_by_suffix_and_their_declared_differences():
    assert format_of("a.h5") is HDF5 and format_of("a.HDF5") is HDF5 and format_of("a.zarr") is ZARR
    assert not HDF5.parallel_writers and ZARR.parallel_writers  # the Dask executor asks this, not the suffix
    with pytest.raises(ValueError, match=r"must end in .h5, .hdf5 or .zarr \(got '.nc'\)"):
        format_of("a.nc")


def test_settings_round_trip_through_the_attributes(cache):
    path, _ = cache
    s = cache_mod.cache_settings(path)
    assert (s.seed, s.n_samples, s.on_blowup, s.fields, s.params) == (0, 4, "raise", ("u",), ("nu",))
    assert s.config["pde"] == "burgers1d" and s.config["n"] == 32 and s.block == 4
    assert s.differences(s) == []
    other = CacheSettings(**{**s.__dict__, "seed": 1, "config": {**s.config, "n": 64}, "config_hash": "x"})
    diff = s.differences(other)
    assert "seed: cache 0 vs asked 1" in diff and any("n: cache 32 vs asked 64" in d for d in diff)


# --- disk full ----------------------------------------------------------------------------------------
def _full_disk(monkeypatch, after: int = 0):
    """Writes of blocks fail with ENOSPC after ``after`` successful ones (as on a full disk)."""
    real, calls = cache_mod.write_block, []

    def write(*args, **kwargs):
        calls.append(1)
        if len(calls) > after:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(*args, **kwargs)
    monkeypatch.setattr(cache_mod, "write_block", write)


@pytest.mark.parametrize("suffix", FORMATS)
def test_disk_full_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch, suffix):
    path = tmp_path / f"new.{suffix}"
    _full_disk(monkeypatch)
    code, _, err = generate(capsys, path)
    one_line_error(code, err, f"cannot write {path} (samples 0..3): no space left on device; nothing was kept")
    assert listing(tmp_path) == []


def test_disk_full_at_creation_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    def create(self, path, lay, block):
        path.mkdir()  # a part made, then the disk fills
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    # the class, not the instance: undoing a patch of an instance leaves the bound method on it, which then hides
    # every later test's patch of the class (test_write_limits' import failed to fail after this file in one worker)
    monkeypatch.setattr(type(ZARR), "create", create)
    code, _, err = generate(capsys, tmp_path / "new.zarr")
    one_line_error(code, err, f"cannot create {tmp_path / 'new.zarr'}: no space left on device; nothing was kept")
    assert listing(tmp_path) == []


def test_disk_full_during_overwrite_keeps_the_old_cache(cache, capsys, monkeypatch):
    path, sha = cache
    _full_disk(monkeypatch)
    code, _, err = generate(capsys, path, "--overwrite", seed=1)
    one_line_error(code, err, f"cannot write {path}", "no space left on device; the old cache is unchanged")
    assert digest(path) == sha and listing(path.parent) == [path.name]


def test_disk_full_after_a_block_keeps_it_for_resume(tmp_path, capsys, monkeypatch):
    path = tmp_path / "part.zarr"
    _full_disk(monkeypatch, after=1)
    code, _, err = generate(capsys, path, "--block", 2)
    one_line_error(code, err, f"cannot write {path} (samples 2..3): no space left on device; the samples "
                              "written so far are kept: free space and finish it with --resume")
    monkeypatch.undo()
    assert generate(capsys, path, "--block", 2, "--resume")[0] == 0
    assert listing(tmp_path) == ["part.zarr"]


def test_disk_full_marking_complete(tmp_path, capsys, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(type(ZARR), "mark_complete", full)  # the class (see above)
    code, _, err = generate(capsys, tmp_path / "c.zarr")
    one_line_error(code, err, f"cannot mark {tmp_path / 'c.zarr'} complete: no space left on device")


def test_h5py_errors_are_reduced_to_their_cause():
    err = OSError(28, "Can't synchronously write data (file write failed: time = ..., errno = 28, error message = "
                      "'No space left on device', buf = 0x7f, total write size = 1077200)")
    assert cache_mod.os_error_cause(err) == "no space left on device"
    assert cache_mod.os_error_cause(OSError(errno.EIO, os.strerror(errno.EIO))) == os.strerror(errno.EIO)


# --- a file held open by another process ------------------------------------------------------------------
def _holder(path: Path, mode: str) -> subprocess.Popen:
    """Another process holding the HDF5 file at ``path`` open in ``mode`` until killed."""
    code = f"import h5py, sys, time; f = h5py.File({str(path)!r}, {mode!r}); print('open', flush=True); time.sleep(60)"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "open"
    return proc


def test_resume_of_an_hdf5_file_held_open_elsewhere(tmp_path, capsys, monkeypatch):
    path = tmp_path / "held.h5"
    _full_disk(monkeypatch, after=1)  # an incomplete cache, to be resumed
    assert generate(capsys, path, "--block", 2)[0] == 2
    monkeypatch.undo()
    sha = digest(path)
    reader = _holder(path, "r")
    try:
        code, _, err = generate(capsys, path, "--block", 2, "--resume")
    finally:
        reader.kill()
        reader.wait()
    one_line_error(code, err, f"{path} is held open by another process", "close that program or wait")
    assert digest(path) == sha and listing(tmp_path) == ["held.h5"]


def test_reading_an_hdf5_file_a_writer_holds(tmp_path, capsys):
    path = tmp_path / "w.h5"
    assert generate(capsys, path)[0] == 0
    writer = _holder(path, "r+")
    try:
        code, _, err = run_cli(capsys, "inspect", path)
    finally:
        writer.kill()
        writer.wait()
    one_line_error(code, err, f"{path} is open for writing by another process")


# --- a truncated chunk, a missing variable, a garbled attribute -------------------------------------------
def _chunk(path: Path, name: str) -> Path:
    return next(p for p in sorted((path / name).rglob("*")) if p.is_file() and p.name != "zarr.json")


def test_truncated_field_chunk(tmp_path, capsys):
    path = tmp_path / "t.zarr"
    assert generate(capsys, path)[0] == 0
    chunk = _chunk(path, "u")
    chunk.write_bytes(chunk.read_bytes()[: chunk.stat().st_size // 2])
    for in_memory in (True, False):
        data = datasets.CachedTrajectories(path, in_memory=in_memory)
        with pytest.raises(ValueError) as caught:
            data[0]
        msg = str(caught.value)
        assert msg.startswith(str(path)) and "\n" not in msg, msg
    code, out, _ = run_cli(capsys, "inspect", path)
    assert code == 0 and "DAMAGED" in out  # inspect reports it
    code, _, err = run_cli(capsys, "train", "burgers1d", "--source", path, "--out", tmp_path / "run", "--steps", 1,
                           "--batch-size", 2, "--test-samples", 1, *SMALL)
    one_line_error(code, err, str(path))
    assert generate(capsys, path, "--resume")[0] == 0  # recomputed
    assert np.isfinite(datasets.open_cache(path)["u"].values).all()


@pytest.mark.parametrize("name", ["complete", "nu"])
def test_truncated_small_chunk_is_named_when_opened(tmp_path, capsys, name):
    path = tmp_path / "t.zarr"
    assert generate(capsys, path)[0] == 0
    chunk = _chunk(path, name)
    chunk.write_bytes(chunk.read_bytes()[:1])
    code, _, err = run_cli(capsys, "inspect", path)
    one_line_error(code, err, f"{path} is damaged: cannot read {name}")


def test_truncated_hdf5_file(tmp_path, capsys):
    path = tmp_path / "t.h5"
    assert generate(capsys, path)[0] == 0
    path.write_bytes(path.read_bytes()[:2000])
    code, _, err = run_cli(capsys, "inspect", path)
    one_line_error(code, err, f"{path} is not a readable hdf5 cache (truncated or corrupted?)")


def _drop_variable(path: Path, name: str) -> None:
    if path.suffix == ".zarr":
        shutil.rmtree(path / name)  # the consolidated metadata still lists it
    else:
        with h5py.File(path, "r+") as f:
            del f[name]


@pytest.mark.parametrize("name", ["u", "nu"])
def test_missing_variable(cache, capsys, name):
    path, _ = cache
    _drop_variable(path, name)
    sha = digest(path)
    message = f"{path} is damaged: variable {name} missing"
    for argv in (["inspect", path], ["generate", "burgers1d", "--n", 4, "--out", path, "--resume", *SMALL]):
        code, _, err = run_cli(capsys, *argv)
        one_line_error(code, err, message)
    with pytest.raises(ValueError, match=message):
        datasets.CachedTrajectories(path)
    assert digest(path) == sha and listing(path.parent) == [path.name]


def _set_attr(path: Path, name: str, value) -> None:
    if path.suffix == ".zarr":
        meta = json.loads((path / "zarr.json").read_text())
        meta["attributes"][name] = value
        (path / "zarr.json").write_text(json.dumps(meta))
    else:
        with h5py.File(path, "r+") as f:
            f.attrs[name] = value


@pytest.mark.parametrize("name, value, what", [
    ("pdestream_config", "{not json", "is not a JSON object"),
    ("pdestream_config", "[1, 2]", "is not a JSON object"),
    ("pdestream_seed", "zero", "is not an integer >= 0"),
    ("pdestream_on_blowup", "explode", "is not 'raise' or 'redraw'"),
])
def test_garbled_attribute(cache, capsys, tmp_path, name, value, what):
    path, _ = cache
    _set_attr(path, name, value)
    sha = digest(path)
    message = f"{path} is damaged: attribute {name} = {value!r} {what}"
    for argv in (["inspect", path], ["generate", "burgers1d", "--n", 4, "--out", path, "--resume", *SMALL],
                 ["train", "burgers1d", "--source", path, "--out", tmp_path / "run", "--steps", 1, *SMALL]):
        code, _, err = run_cli(capsys, *argv)
        one_line_error(code, err, message)
    assert digest(path) == sha and listing(path.parent) == [path.name]
    assert generate(capsys, path, "--overwrite")[0] == 0  # still ours: --overwrite replaces it


def test_config_of_an_unknown_pde(cache):
    path, _ = cache
    _set_attr(path, "pdestream_config", json.dumps({"pde": "nosuchpde"}))
    with pytest.raises(ValueError, match=f"^{path}: its stored PDE config cannot be used: .*nosuchpde"):
        _ = datasets.CachedTrajectories(path).pde


# --- file names -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", FORMATS)
def test_long_but_legal_name_works_end_to_end(tmp_path, capsys, monkeypatch, suffix):
    """A 250-byte name: the hidden lock and work copies beside it use a digest, not NAME + more."""
    path = tmp_path / ("x" * (250 - len(suffix) - 1) + "." + suffix)
    assert len(path.name) == 250
    assert generate(capsys, path, "--block", 2)[0] == 0
    assert generate(capsys, path, "--overwrite", seed=1)[0] == 0
    assert listing(tmp_path) == [path.name]
    _full_disk(monkeypatch, after=1)
    path.unlink() if path.is_file() else shutil.rmtree(path)
    assert generate(capsys, path, "--block", 2)[0] == 2
    monkeypatch.undo()
    assert generate(capsys, path, "--block", 2, "--resume")[0] == 0
    code, out, _ = run_cli(capsys, "inspect", path)
    assert code == 0 and "4 of 4 complete" in out and listing(tmp_path) == [path.name]
    assert datasets.CachedTrajectories(path)[3]["u"].shape == (5, 1, 32)


def test_name_longer_than_the_filesystem_allows(tmp_path, capsys):
    path = tmp_path / ("x" * 300 + ".h5")
    code, _, err = generate(capsys, path)
    one_line_error(code, err, f"cannot write {path}: its name is 303 bytes long, the filesystem allows at most 255")
    assert listing(tmp_path) == []


def test_dask_writer_takes_a_catalog_name(tmp_path):
    pytest.importorskip("distributed")
    from distributed import LocalCluster

    from pdestream.datasets.distributed import write_cache_dask

    with LocalCluster(n_workers=1, processes=False, dashboard_address=":0") as c:
        done = write_cache_dask("burgers1d", tmp_path / "d.zarr", 1, scheduler=c.scheduler_address, block=1,
                                progress=False)
    assert done.written == 1 and cache_mod.cache_settings(tmp_path / "d.zarr").config["pde"] == "burgers1d"


# --- a lazy reader while the cache is replaced --------------------------------------------------------------
@pytest.mark.parametrize("in_memory", [False, True])
def test_reader_notices_its_cache_was_replaced(cache, capsys, in_memory):
    """Per-example reads (and a whole-cache read not yet made) after an --overwrite: one line, not the new data."""
    path, _ = cache
    reader = datasets.CachedTrajectories(path, in_memory=in_memory)
    if not in_memory:
        assert int(reader[1]["index"]) == 1  # reads before the swap are fine
    worker = pickle.loads(pickle.dumps(reader))  # as a spawned DataLoader worker gets it
    assert generate(capsys, path, "--overwrite", seed=1)[0] == 0  # built beside, swapped in
    for r in (reader, worker):
        with pytest.raises(ValueError, match=f"^the cache at {path} was replaced while open; reopen it$"):
            r[2]
    fresh = datasets.CachedTrajectories(path, in_memory=in_memory)
    assert fresh.seed == 1 and np.isfinite(fresh[2]["u"].numpy()).all()


def test_reader_keeps_serving_a_cache_resumed_in_place(tmp_path, capsys, monkeypatch):
    """No false alarm: --resume writes into the same store, which a reader of the written samples may keep reading."""
    path = tmp_path / "r.zarr"
    _full_disk(monkeypatch, after=1)
    assert generate(capsys, path, "--block", 2)[0] == 2
    monkeypatch.undo()
    reader = datasets.CachedTrajectories(path, allow_incomplete=True, in_memory=False)
    before = reader[1]["u"].clone()
    assert generate(capsys, path, "--block", 2, "--resume")[0] == 0
    assert np.array_equal(reader[1]["u"].numpy(), before.numpy()) and len(reader) == 2


def test_reader_during_an_overwrite_in_another_process(tmp_path, capsys):
    """Items read while another process overwrites the cache are the old cache's (matching the index and params
    the reader reports) until the reader says the cache was replaced; never NaN, never the new data."""
    path = tmp_path / "c.zarr"
    assert generate(capsys, path, "--block", 2, n=8)[0] == 0
    reader = datasets.CachedTrajectories(path, in_memory=False)
    want = [reader[k]["u"].numpy().copy() for k in range(len(reader))]
    script = textwrap.dedent(f"""
        import sys
        from pdestream import cli
        sys.exit(cli.main(["generate", "burgers1d", "--n", "8", "--seed", "1", "--block", "2", "--out", {str(path)!r},
                           "--overwrite", *{SMALL!r}]))
    """)
    writer = subprocess.Popen([sys.executable, "-c", script])
    served, replaced = 0, False
    try:
        while not replaced:
            for k in range(len(reader)):
                try:
                    item = reader[k]
                except ValueError as err:
                    assert str(err) == f"the cache at {path} was replaced while open; reopen it"
                    replaced = True
                    break
                assert int(item["index"]) == k and np.array_equal(item["u"].numpy(), want[k]), k
                served += 1
            assert replaced or writer.poll() in (None, 0)
    finally:
        assert writer.wait(timeout=120) == 0
    assert served >= len(reader)


# --- inspect's statistics -------------------------------------------------------------------------------------
def test_field_stats_are_the_float64_moments_of_the_finite_samples():
    import xarray as xr

    from pdestream.datasets.inspect import field_stats

    a = (np.random.default_rng(0).normal(size=(10, 5, 16)) * 3 + 1).astype(np.float32)
    a[4, 2, 3] = np.nan  # a damaged sample: left out, and named
    ds = xr.Dataset({"u": (("sample", "time", "x"), a)})
    s = field_stats(ds, "u", np.arange(10), block=3)
    good = np.delete(a, 4, axis=0).astype(np.float64)
    assert s["damaged"] == [4] and s["min"] == good.min() and s["max"] == good.max()
    assert abs(s["mean"] - good.mean()) < 1e-12 and abs(s["std"] - good.std()) < 1e-12
    const = field_stats(xr.Dataset({"u": (("sample", "x"), np.full((3, 4), 2.0, np.float32))}), "u", np.arange(3))
    assert (const["mean"], const["std"]) == (2.0, 0.0)


def test_dask_writer_disk_full_is_one_line(tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    from distributed import LocalCluster

    from pdestream.datasets.distributed import write_cache_dask

    _full_disk(monkeypatch)  # tasks run in this process (threads), so they see the patched write
    with LocalCluster(n_workers=1, processes=False, dashboard_address=":0") as c:
        with pytest.raises(ValueError, match=f"^cannot write {tmp_path / 'd.zarr'}: no space left on device; "
                                             "nothing was kept$"):
            write_cache_dask("burgers1d", tmp_path / "d.zarr", 2, scheduler=c.scheduler_address, block=1,
                             progress=False)
    assert listing(tmp_path) == []
