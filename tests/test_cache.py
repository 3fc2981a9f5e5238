"""HDF5/Zarr cache: schema seen by plain xarray, bit-identity with the generator and the stream,
completion tracking and resume, and clear errors for files that are not (whole) caches."""

import threading

import h5py
import numpy as np
import pytest
import torch
import xarray as xr

from pdestream import datasets, generator
from pdestream.datasets import cache as cache_mod
from pdestream.datasets.cache import is_complete

SEED = 3
N = 10
BLOCK = 4  # 10 samples: blocks 0-3, 4-7 and a short last one (padded to 4)


@pytest.fixture(scope="module")
def pde():
    return generator.get_pde("burgers1d", {"n": "32", "n_frames": "6"})


@pytest.fixture(scope="module")
def reference(pde):
    """Samples 0..N-1 solved in ONE batch: the cache writes blocks of 4, so equality is batch-independence."""
    traj = generator.sample(pde, np.arange(N), SEED)
    return np.array(traj.u), {k: np.array(v) for k, v in traj.params.items()}


@pytest.fixture(scope="module", params=["h5", "zarr"])
def cached(request, pde, tmp_path_factory):
    path = tmp_path_factory.mktemp("cache") / f"burgers.{request.param}"
    summary = datasets.write_cache(pde, path, N, seed=SEED, block=BLOCK, progress=False)
    assert summary.written == N and summary.n_samples == N
    return path


def _plain_open(path):
    return xr.open_zarr(path) if str(path).endswith(".zarr") else xr.open_dataset(path, engine="h5netcdf")


def test_plain_xarray_sees_the_schema(cached, pde, reference):
    ds = _plain_open(cached)
    assert ds["u"].dims == ("sample", "time", "x") and ds["u"].dtype == np.float32
    assert list(ds.data_vars) == ["u"]
    assert {"sample", "time", "x", "nu", "complete", "redraws"} <= set(ds.coords)
    np.testing.assert_array_equal(ds["sample"].values, np.arange(N))
    assert ds["sample"].dtype == np.int64
    np.testing.assert_array_equal(ds["time"].values, pde.times())
    np.testing.assert_array_equal(ds["x"].values, pde.grid.coords())
    assert ds["nu"].attrs["units"] == "length^2/time" and ds["nu"].attrs["long_name"] == "viscosity"
    assert ds["u"].attrs["long_name"] and ds["time"].attrs["units"]
    a = ds.attrs
    assert a["pde"] == "burgers1d" and a["equation"] == pde.EQUATION
    assert generator.from_config(__import__("json").loads(a["pdestream_config"])) == pde
    assert a["pdestream_config_hash"] == pde.config_hash() and a["pdestream_seed"] == SEED
    assert a["jax_version"] and a["jax_threefry_partitionable"] in (0, 1) and a["pdestream_version"]
    assert a["pdestream_complete"] == 1 and (ds["complete"].values == 1).all()
    u, params = reference
    np.testing.assert_array_equal(ds["u"].values, u[:, :, 0])  # bit for bit
    np.testing.assert_array_equal(ds["nu"].values, params["nu"])


def test_open_cache_and_loader_match_the_generator(cached, reference):
    ds = datasets.open_cache(cached)
    assert is_complete(ds)
    u, params = reference
    loader = datasets.CachedTrajectories(cached, view="whole")
    assert len(loader) == N and loader.param_names == ["nu"] and loader.pde.NAME == "burgers1d"
    for i in (0, 5, N - 1):
        ex = loader[i]
        assert torch.equal(ex["u"], torch.from_numpy(u[i])) and int(ex["index"]) == i
        assert ex["params"].tolist() == [float(params["nu"][i])]


def test_loader_equals_the_stream(cached, pde):
    stream = datasets.TrajectoryStream(pde, seed=SEED, view="whole", batch_size=N, n_samples=N, shuffle=False,
                                       resample=False, solve_batch=8)
    streamed = {}
    for batch in torch.utils.data.DataLoader(stream, batch_size=None):
        for k, i in enumerate(batch["index"].tolist()):
            streamed[i] = (batch["u"][k], batch["params"][k])
    assert sorted(streamed) == list(range(N))
    loader = datasets.CachedTrajectories(cached, view="whole")
    for i in range(N):
        assert torch.equal(loader[i]["u"], streamed[i][0]) and torch.equal(loader[i]["params"], streamed[i][1])


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # the forked workers only read files, never JAX
def test_loader_workers_open_their_own_file(cached, reference):
    loader = datasets.CachedTrajectories(cached, view="whole")
    loader[0]  # the parent now holds a handle; workers must not use it
    state = loader.__getstate__()
    assert state["_store"] is None  # nothing open crosses a pickle (spawn)
    batches = torch.utils.data.DataLoader(loader, batch_size=4, num_workers=2, multiprocessing_context="fork")
    got = torch.cat([b["u"] for b in batches])
    assert torch.equal(got, torch.from_numpy(reference[0]))


def test_next_step_indexes_sample_start_pairs(cached, reference):
    u, _ = reference
    loader = datasets.CachedTrajectories(cached, view="next_step", k_in=2, k_out=1)
    starts = 6 - 2 - 1 + 1
    assert len(loader) == N * starts
    ex = loader[7 * starts + 2]  # sample 7, window starting at frame 2
    assert int(ex["index"]) == 7 and ex["t0"].item() == pytest.approx(0.4)
    assert torch.equal(ex["x"], torch.from_numpy(u[7, 2:4])) and torch.equal(ex["y"], torch.from_numpy(u[7, 4:5]))
    batch = next(iter(torch.utils.data.DataLoader(loader, batch_size=8, shuffle=True)))
    assert batch["x"].shape == (8, 2, 1, 32) and batch["params"].shape == (8, 1)
    random_windows = datasets.CachedTrajectories(cached, view="next_step", windows=3)
    assert len(random_windows) == 3 * N and random_windows[4]["x"].shape == (1, 1, 32)


def test_two_dimensional_two_fields(tmp_path):
    pde = generator.get_pde("grayscott2d", {"n": "16", "n_frames": "3", "t_end": "4"})
    path = tmp_path / "gs.zarr"
    datasets.write_cache(pde, path, 3, seed=1, progress=False)
    ds = xr.open_zarr(path)
    assert list(ds.data_vars) == ["u", "v"] and ds["v"].dims == ("sample", "time", "y", "x")  # plots x across
    assert {"y", "F", "k", "Du", "Dv"} <= set(ds.coords)
    traj = generator.sample(pde, [2], 1)
    u = np.array(traj.u[0])  # [T, C=2, 16, 16]
    np.testing.assert_array_equal(ds["v"].values[2], u[:, 1].transpose(0, 2, 1))  # stored (y, x)
    loader = datasets.CachedTrajectories(path, view="operator")
    assert loader.param_names == ["F", "k", "Du", "Dv"]
    assert torch.equal(loader[2]["y"], torch.from_numpy(u[-1]))
    assert loader[2]["params"].tolist() == [float(traj.params[n][0]) for n in loader.param_names]


def _interrupted(pde, path, monkeypatch):
    """A write that dies in its second block, as a crash would: the first block is done, the rest not."""
    real, calls = generator.sample, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(generator, "sample", failing)
    with pytest.raises(KeyboardInterrupt):
        datasets.write_cache(pde, path, N, seed=SEED, block=BLOCK, progress=False)
    monkeypatch.setattr(generator, "sample", real)


def test_prefetch_stops_when_consumer_and_producer_both_fail():
    """The consumer fails (a full disk, Ctrl-C) with a solved item waiting, then the producer's solve in
    flight raises: closing must still return (the producer's error hand-over must not block)."""
    from pdestream.datasets._prefetch import prefetch

    in_flight, release = threading.Event(), threading.Event()

    def items():
        yield 1
        yield 2  # waits in the queue while the consumer works on 1
        in_flight.set()
        release.wait(10)
        raise RuntimeError("solve failed")

    solved = prefetch(items)
    assert next(solved) == 1
    assert in_flight.wait(10)
    closer = threading.Thread(target=solved.close, daemon=True)
    closer.start()
    release.set()
    closer.join(10)
    assert not closer.is_alive(), "prefetch.close() hung"
    errors = prefetch(lambda: iter([ValueError("an item, not an error"), 3]))
    assert [type(x) for x in errors] == [ValueError, int]  # exception objects as items pass through
    with pytest.raises(RuntimeError, match="solve failed"):
        list(prefetch(items))


def test_failed_write_stops_the_writer(pde, tmp_path, monkeypatch):
    """A failure before any sample is written removes the new cache (nothing to resume); after a written
    block it keeps the incomplete cache for --resume."""
    real, calls = cache_mod.write_block, []

    def full_disk_after(k):
        def write(*args, **kwargs):
            calls.append(1)
            if len(calls) > k:
                raise OSError(28, "No space left on device")
            real(*args, **kwargs)
        return write

    monkeypatch.setattr(cache_mod, "write_block", full_disk_after(0))
    with pytest.raises(ValueError, match=r"^cannot write \S*full.h5 \(samples 0..3\): no space left on device; "
                                         "nothing was kept$"):
        datasets.write_cache(pde, tmp_path / "full.h5", N, seed=SEED, block=BLOCK, progress=False)
    assert list(tmp_path.iterdir()) == []
    calls.clear()
    monkeypatch.setattr(cache_mod, "write_block", full_disk_after(1))
    with pytest.raises(ValueError, match="no space left on device; the samples written so far are kept: free "
                                         "space and finish it with --resume"):
        datasets.write_cache(pde, tmp_path / "full.h5", N, seed=SEED, block=BLOCK, progress=False)
    ds = datasets.open_cache(tmp_path / "full.h5")
    assert not is_complete(ds) and int(ds["complete"].sum()) == BLOCK
    assert [p.name for p in tmp_path.iterdir()] == ["full.h5"]  # no lock or temp left behind


@pytest.mark.parametrize("suffix", ["h5", "zarr"])
def test_interrupted_reads_incomplete_then_resumes_identically(pde, tmp_path, monkeypatch, reference, suffix):
    path = tmp_path / f"part.{suffix}"
    _interrupted(pde, path, monkeypatch)
    ds = datasets.open_cache(path)
    assert not is_complete(ds) and ds.attrs["pdestream_complete"] == 0
    assert ds["complete"].values.tolist() == [1] * BLOCK + [0] * (N - BLOCK)
    ds.close()
    with pytest.raises(ValueError, match="incomplete .4 of 10"):
        datasets.CachedTrajectories(path)
    assert len(datasets.CachedTrajectories(path, allow_incomplete=True)) == BLOCK
    assert datasets.open_cache(path, complete_only=True).sizes["sample"] == BLOCK
    with pytest.raises(FileExistsError, match="--resume"):
        datasets.write_cache(pde, path, N, seed=SEED, progress=False)
    with pytest.raises(ValueError, match="different set-up.*seed"):
        datasets.write_cache(pde, path, N, seed=SEED + 1, resume=True, progress=False)
    with pytest.raises(ValueError, match="different set-up.*config_hash"):
        datasets.write_cache(pde.replace(nu="0.05"), path, N, seed=SEED, resume=True, progress=False)
    # a setting the config names only when it is not the default: the message says "its default", not "(unset)"
    with pytest.raises(ValueError, match="t_start: cache its default vs asked 0.01"):
        datasets.write_cache(pde.replace(t_start=0.01), path, N, seed=SEED, resume=True, progress=False)
    done = datasets.write_cache(pde, path, N, seed=SEED, resume=True, progress=False)
    assert done.written == N - BLOCK
    part = datasets.open_cache(path)
    assert is_complete(part)
    np.testing.assert_array_equal(part["u"].values, reference[0][:, :, 0])
    np.testing.assert_array_equal(part["nu"].values, reference[1]["nu"])


def test_refusals(pde, tmp_path):
    with pytest.raises(ValueError, match="exclude each other"):
        datasets.write_cache(pde, tmp_path / "a.h5", 4, resume=True, overwrite=True)
    with pytest.raises(ValueError, match="must end in .h5, .hdf5 or .zarr"):
        datasets.write_cache(pde, tmp_path / "a.nc", 4)
    with pytest.raises(ValueError, match="n_samples=0"):
        datasets.write_cache(pde, tmp_path / "a.h5", 0)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        datasets.write_cache(pde, tmp_path / "no" / "a.h5", 4)
    (tmp_path / "mine.zarr").mkdir()
    (tmp_path / "mine.zarr" / "notes.txt").write_text("keep me")
    with pytest.raises(ValueError, match="not a Zarr store"):
        datasets.write_cache(pde, tmp_path / "mine.zarr", 4, overwrite=True, progress=False)
    assert (tmp_path / "mine.zarr" / "notes.txt").exists()


def test_unreadable_and_foreign_files_get_one_line_errors(cached, tmp_path):
    def one_line(path, match):
        with pytest.raises(ValueError, match=match) as err:
            datasets.open_cache(path)
        assert "\n" not in str(err.value)
        with pytest.raises(ValueError):
            datasets.CachedTrajectories(path)

    one_line(tmp_path / "missing.h5", "does not exist")
    (tmp_path / "garbage.h5").write_bytes(b"not an HDF5 file at all" * 100)
    one_line(tmp_path / "garbage.h5", "not a readable hdf5 cache")
    with h5py.File(tmp_path / "foreign.h5", "w") as f:
        f["data"] = np.zeros(3)
    one_line(tmp_path / "foreign.h5", "not a pdestream cache")
    if str(cached).endswith(".h5"):
        blob = cached.read_bytes()
        (tmp_path / "truncated.h5").write_bytes(blob[: len(blob) // 2])
        one_line(tmp_path / "truncated.h5", "not a readable hdf5 cache")
    else:
        import shutil

        broken = tmp_path / "broken.zarr"
        shutil.copytree(cached, broken)
        (broken / "zarr.json").write_text("{ truncated")
        one_line(broken, "not a readable zarr cache")
        corrupt = tmp_path / "corrupt.zarr"
        shutil.copytree(cached, corrupt)
        per_chunk = xr.open_zarr(corrupt)["u"].encoding["chunks"][0]
        assert per_chunk < N
        chunk = corrupt / "u" / "c" / str((N - 1) // per_chunk) / "0" / "0"  # holds sample N - 1
        data = bytearray(chunk.read_bytes())
        data[len(data) // 2] ^= 0xFF  # one flipped byte: the zstd checksum must catch it
        chunk.write_bytes(bytes(data))
        with pytest.raises(ValueError, match="cannot read its samples"):  # read whole: fails at once
            datasets.CachedTrajectories(corrupt)[0]
        loader = datasets.CachedTrajectories(corrupt, in_memory=False)  # per example: names the sample
        with pytest.raises(ValueError, match=f"cannot read sample {N - 1}"):
            loader[N - 1]
        assert torch.equal(loader[0]["u"], datasets.CachedTrajectories(cached)[0]["u"])


def test_hdf5_flags_are_zeroed_at_creation(cached):
    """An unwritten sample must read as incomplete even where HDF5 reuses freed space with stale bytes:
    the flag arrays are filled with 0 when the file is created; field data is never filled (no cost)."""
    if not str(cached).endswith(".h5"):
        pytest.skip("Zarr chunks that were never written read as the fill value 0")
    with h5py.File(cached, "r") as f:
        for name, zeroed in (("complete", True), ("redraws", True), ("u", False)):
            plist = f[name].id.get_create_plist()
            want = h5py.h5d.FILL_TIME_ALLOC if zeroed else h5py.h5d.FILL_TIME_NEVER
            assert plist.get_fill_time() == want, name
        fill = np.ones((), np.int8)
        f["complete"].id.get_create_plist().get_fill_value(fill)
        assert fill == 0


def test_default_block_bounds_memory(pde):
    assert cache_mod.default_block(pde, 5) == 5
    big = generator.get_pde("ns2d", {"n": "256"})
    assert 1 <= cache_mod.default_block(big, 10_000) * 4 * big.n_frames * 256 * 256 <= cache_mod.TARGET_BLOCK_BYTES


def test_only_the_bridge_reaches_jax():
    """House rule: in datasets/ only _bridge.py imports jax or generator (also inside functions); surrogate/
    never does. Scans the source, so a lazy import in a rarely run function is caught too."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    files = [p for p in sorted((root / "datasets").glob("*.py")) if p.name != "_bridge.py"]
    files += sorted((root / "surrogate").glob("*.py"))
    assert len(files) > 5
    offenders = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            else:
                continue
            offenders += [f"{path.relative_to(root)}:{node.lineno} {n}" for n in names
                          if n.split(".")[0] in ("jax", "jaxlib", "generator", "equinox", "exponax")]
    assert offenders == []


def test_loader_close_releases_the_file(cached):
    loader = datasets.CachedTrajectories(cached)
    first = loader[0]["u"]
    handle = loader._store
    loader.close()
    if str(cached).endswith(".h5"):
        assert not handle  # h5py: a closed file is falsy
        with h5py.File(cached, "r+"):  # no handle of ours left: HDF5 lets a writer in
            pass
    assert torch.equal(loader[0]["u"], first)  # the next read reopens
    loader.close()
    loader.close()  # twice is harmless


@pytest.mark.parametrize("suffix", [".h5", ".zarr"])
def test_in_memory_and_per_example_reads_give_the_same_examples(tmp_path, suffix):
    pde = generator.get_pde("burgers1d", n=32, n_frames=6, t_end=0.1)
    path = tmp_path / f"c{suffix}"
    datasets.write_cache(pde, path, 6, seed=2, progress=False)
    whole = datasets.CachedTrajectories(path, view="next_step", k_in=2, in_memory=True)
    per_example = datasets.CachedTrajectories(path, view="next_step", k_in=2, in_memory=False)
    assert whole.in_memory and not per_example.in_memory and len(whole) == len(per_example) == 6 * 4
    for k in range(len(whole)):
        a, b = whole[k], per_example[k]
        assert a.keys() == b.keys() and all(torch.equal(a[key], b[key]) for key in a)


def test_resume_of_a_zarr_cache_without_its_complete_flags_says_what_to_do(tmp_path, capsys):
    import shutil

    from pdestream import cli

    path = tmp_path / "c.zarr"
    argv = ["generate", "burgers1d", "--n", "4", "--set", "n=32", "--set", "n_frames=3", "--out", str(path)]
    assert cli.main(argv) == 0
    shutil.rmtree(path / "complete")
    before = sorted(p.name for p in path.iterdir())
    assert cli.main([*argv, "--resume"]) == 2  # it crashed with KeyError: 'complete'
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "complete" in err and "missing" in err and "--overwrite" in err, err
    assert sorted(p.name for p in path.iterdir()) == before
    assert cli.main(["inspect", str(path)]) == 2  # it advised the --resume that is refused above
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "complete missing" in err and "--overwrite" in err and "--resume" not in err, err


def test_a_source_tree_that_is_not_installed_still_writes_caches(pde, tmp_path, monkeypatch):
    # found running from a checkout on PYTHONPATH: the cache's version attribute raised PackageNotFoundError
    import importlib.metadata as md

    def missing(name):
        raise md.PackageNotFoundError(name)

    monkeypatch.setattr(md, "version", missing)
    path = tmp_path / "c.h5"
    datasets.write_cache(pde, path, 2, progress=False)
    with _plain_open(path) as ds:
        assert is_complete(ds)
        assert ds.attrs["pdestream_version"] == "unknown (not installed)"
