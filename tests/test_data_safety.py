"""Data safety of `pdestream generate` / `compare` end to end: a failed or refused command leaves the old data
byte-identical (sha256 of the HDF5 file, or of every file under a Zarr directory) and nothing else behind;
--overwrite replaces only a pdestream cache, and only once the new one is complete; marking a Zarr cache
complete survives a kill at any write; one writer per cache whatever the format; compare keeps earlier output."""

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import zarr

from pdestream import cli, datasets
from pdestream.datasets import cache as cache_mod
from pdestream.datasets import store as store_mod
from pdestream.datasets.cache import is_complete
from pdestream.experiments.command import check_compare_out

SMALL = ["--set", "n=32", "--set", "n_frames=5"]


def run_cli(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def digest(path: Path) -> str:
    """sha256 over a file, or over every file (relative name and bytes) under a directory; a link by its target."""
    h = hashlib.sha256()
    if path.is_symlink():
        h.update(b"link:" + os.readlink(path).encode())
    elif path.is_file():
        h.update(path.read_bytes())
    else:
        for root, dirs, files in sorted(os.walk(path)):
            dirs.sort()
            for f in sorted(files):
                p = Path(root) / f
                h.update(str(p.relative_to(path)).encode() + b"\0" + p.read_bytes())
    return h.hexdigest()


def listing(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


def generate(capsys, path, *extra, n=4, seed=0):
    code, out, err = run_cli(capsys, "generate", "burgers1d", "--n", n, "--seed", seed, "--out", path, *SMALL, *extra)
    return code, out, err


@pytest.fixture(params=["h5", "zarr"])
def old_cache(request, tmp_path, capsys):
    """A complete cache (seed 0, 4 samples) and its sha256."""
    path = tmp_path / f"old.{request.param}"
    assert generate(capsys, path)[0] == 0
    return path, digest(path)


def assert_untouched(path: Path, sha: str, err: str = "", code: int | None = None):
    assert digest(path) == sha, "the old data changed"
    assert listing(path.parent) == [path.name], f"left behind: {listing(path.parent)}"
    ds = datasets.open_cache(path)
    assert is_complete(ds) and ds.attrs["pdestream_seed"] == 0
    ds.close()
    if code is not None:
        assert code == 2 and err.startswith("pdestream: error: ") and err.count("\n") == 1, err


# --- 1. a failing --overwrite keeps the old cache --------------------------------------------------------
def test_overwrite_refused_setting_keeps_the_old_cache(old_cache, capsys):
    """A NaN setting (caught when parsed, or failing later in the solve) never reaches the old cache."""
    path, sha = old_cache
    code, _, err = generate(capsys, path, "--overwrite", "--set", "ic.mean=nan", seed=1)
    assert code == 2 and "nan" in err.lower(), err
    assert_untouched(path, sha)


@pytest.mark.parametrize("failure", ["blowup", "ctrl_c"])
def test_overwrite_failing_mid_run_keeps_the_old_cache(old_cache, capsys, monkeypatch, failure):
    """The second block fails (a blow-up, or Ctrl-C) after the first was written to the new cache."""
    path, sha = old_cache
    real, calls = cache_mod.solve_block, []

    def second_block_fails(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            if failure == "ctrl_c":
                raise KeyboardInterrupt
            raise ValueError("burgers1d: sample 2 blew up (NaN/Inf)")
        return real(*args, **kwargs)

    monkeypatch.setattr(cache_mod, "solve_block", second_block_fails)
    code, _, err = generate(capsys, path, "--overwrite", "--block", "2", seed=1)
    assert len(calls) >= 2
    if failure == "ctrl_c":
        assert code == 130 and err == f"pdestream: interrupted; {path} is unchanged\n"
    else:
        assert code == 2 and "blew up" in err
    assert_untouched(path, sha)


def test_overwrite_with_unreachable_scheduler_keeps_the_old_cache(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    from pdestream.datasets import distributed

    path = tmp_path / "old.zarr"
    assert generate(capsys, path)[0] == 0
    sha = digest(path)
    monkeypatch.setattr(distributed, "CONNECT_TIMEOUT", "1s")
    code, _, err = generate(capsys, path, "--overwrite", "--executor", "dask", "--scheduler", "tcp://127.0.0.1:1",
                            seed=1)
    assert code == 2 and "cannot reach the Dask scheduler" in err, err
    assert_untouched(path, sha, err, code)


@pytest.mark.parametrize("exchange", ["renameat2", "two renames"])
def test_successful_overwrite_replaces_and_leaves_nothing_else(old_cache, capsys, monkeypatch, exchange):
    path, sha = old_cache
    if exchange == "two renames":  # where the atomic exchange is unsupported: old aside, new in, old deleted
        monkeypatch.setattr(store_mod, "_exchange", lambda a, b: False)
    code, out, err = generate(capsys, path, "--overwrite", n=6, seed=1)
    assert code == 0 and "wrote 6 samples" in out, err
    assert digest(path) != sha and listing(path.parent) == [path.name]
    ds = datasets.open_cache(path)
    assert is_complete(ds) and ds.attrs["pdestream_seed"] == 1 and ds.sizes["sample"] == 6


def test_successful_dask_overwrite_replaces(tmp_path, capsys):
    pytest.importorskip("distributed")
    path = tmp_path / "old.zarr"
    assert generate(capsys, path)[0] == 0
    sha = digest(path)
    code, out, err = generate(capsys, path, "--overwrite", "--executor", "dask", "--workers", "1", n=6, seed=1)
    assert code == 0 and "wrote 6 samples" in out, err
    assert digest(path) != sha and listing(path.parent) == [path.name]
    ref = tmp_path / "ref" / "ref.zarr"
    ref.parent.mkdir()
    assert generate(capsys, ref, n=6, seed=1)[0] == 0
    a, b = datasets.open_cache(path), datasets.open_cache(ref)
    assert is_complete(a) and a.attrs == b.attrs
    np.testing.assert_array_equal(a["u"].values, b["u"].values)


# --- a real Ctrl-C / kill -9 during an --overwrite (subprocess) ---------------------------------------------
SLOW = ["burgers1d", "--n", "24", "--seed", "5", "--block", "4", "--set", "n=64", "--set", "n_frames=6",
        "--set", "t_end=100", "--overwrite"]


def _overwriter_with_4_samples_flagged(path: Path):
    """An `--overwrite` subprocess of ``path`` (HDF5), returned once its hidden new cache has 4 samples flagged."""
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.cli", "generate", *SLOW, "--out", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        for tmp in path.parent.glob(f".{path.name}.{proc.pid}.tmp.h5"):
            try:
                with h5py.File(tmp, "r", locking=False) as f:
                    if f["complete"][:].sum() >= 4:
                        return proc
            except (OSError, KeyError):
                pass
        time.sleep(0.005)
    return proc


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL])
def test_signal_during_overwrite_keeps_the_old_cache(tmp_path, capsys, sig):
    path = tmp_path / "old.h5"
    assert generate(capsys, path)[0] == 0
    sha = digest(path)
    proc = _overwriter_with_4_samples_flagged(path)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == (130 if sig == signal.SIGINT else -sig), "the writer finished first: use a slower config"
    if sig == signal.SIGINT:
        assert err == f"pdestream: interrupted; {path} is unchanged\n"
        assert_untouched(path, sha)
        return
    assert digest(path) == sha  # kill -9 cannot clean up: the new cache stays hidden beside the old one ...
    assert f".{path.name}.{proc.pid}.tmp.h5" in listing(tmp_path)
    code, out, err = generate(capsys, path, "--overwrite", seed=1)  # ... and the next writer removes it
    assert code == 0, err
    assert listing(tmp_path) == [path.name] and datasets.open_cache(path).attrs["pdestream_seed"] == 1


# --- 2. --overwrite replaces only what is ours ---------------------------------------------------------------
def _foreign_zarr(p):
    zarr.open_group(p, mode="w", zarr_format=3, attributes={"owner": "me"}).create_array(
        "data", shape=(3,), dtype="f4")
    (p / "notes.txt").write_text("my notes")


def _plain_dir_zarr(p):
    p.mkdir()
    (p / "notes.txt").write_text("keep me")


def _foreign_h5(p):
    with h5py.File(p, "w") as f:
        f["data"] = np.arange(5.0)


def _plain_file_zarr(p):
    p.write_text("notes, not a store")


def _garbage_h5(p):
    p.write_bytes(b"not HDF5" * 100)


def _our_zarr_with_user_file(p, capsys):
    assert generate(capsys, p)[0] == 0
    (p / "README.txt").write_text("a user's file inside the store")


@pytest.mark.parametrize("name, make, what", [
    ("user.zarr", _foreign_zarr, "a Zarr store without pdestream's attributes"),
    ("dir.zarr", _plain_dir_zarr, "not a Zarr store"),
    ("user.h5", _foreign_h5, "an HDF5 file without pdestream's attributes"),
    ("notes.zarr", _plain_file_zarr, "a file, not a Zarr store"),
    ("garbage.h5", _garbage_h5, "not a readable HDF5 file"),
    ("ours.zarr", _our_zarr_with_user_file, "other files in it (README.txt)"),
])
def test_overwrite_refuses_what_is_not_ours(tmp_path, capsys, name, make, what):
    path = tmp_path / name
    make(path, capsys) if make is _our_zarr_with_user_file else make(path)
    sha = digest(path)
    code, out, err = generate(capsys, path, "--overwrite")
    assert code == 2 and out == "" and err.startswith("pdestream: error: ") and err.count("\n") == 1, err
    assert f"refusing to overwrite {path}" in err and what in err, err
    assert digest(path) == sha and listing(tmp_path) == [name]


@pytest.mark.parametrize("suffix", ["h5", "zarr"])
@pytest.mark.parametrize("mode", ["--overwrite", "--resume", None])
def test_symlinked_cache_is_refused_and_untouched(tmp_path, capsys, suffix, mode):
    real = tmp_path / "real" / f"c.{suffix}"
    real.parent.mkdir()
    assert generate(capsys, real)[0] == 0
    link = tmp_path / f"link.{suffix}"
    link.symlink_to(real)
    sha_real, sha_link = digest(real), digest(link)
    code, out, err = generate(capsys, link, *([mode] if mode else []), seed=1 if mode == "--overwrite" else 0)
    assert code == 2 and err.count("\n") == 1 and "is a symlink to" in err and str(real) in err, err
    assert digest(real) == sha_real and digest(link) == sha_link
    assert listing(tmp_path) == ["link." + suffix, "real"] and listing(real.parent) == [real.name]


# --- 3. marking a Zarr cache complete survives a kill at any write -----------------------------------------
class Killed(BaseException):
    """Raised by the audit hook at the chosen write: the process 'dies' before that write happens."""


_WRITES = {"armed": False, "left": 0}


def _kill_at_write(event, args):
    if not _WRITES["armed"]:
        return
    write = event in ("os.rename", "os.remove", "os.rmdir", "shutil.rmtree", "os.truncate")
    if event == "open":
        mode, flags = args[1], args[2]
        write = (mode is not None and any(c in mode for c in "wax+")) or \
            (mode is None and bool(flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC)))
    if write:
        if _WRITES["left"] == 0:
            _WRITES["armed"] = False
            raise Killed(f"{event} {args[0]}")
        _WRITES["left"] -= 1


sys.addaudithook(_kill_at_write)  # inert unless a test arms it (audit hooks cannot be removed)


def _flags_written(capsys, path):
    """A Zarr cache with every block written and flagged: the state just before mark_complete."""
    assert generate(capsys, path)[0] == 0
    store = zarr.open_group(path, mode="r+", zarr_format=3, use_consolidated=False)
    meta = json.loads((path / "zarr.json").read_text())
    meta["attributes"]["pdestream_complete"] = 0
    (path / "zarr.json").write_text(json.dumps(meta))
    assert store["complete"][:].all()


def test_mark_complete_killed_at_any_write_recovers(tmp_path, capsys):
    """A kill before each file write of mark_complete in turn: the cache still opens (inspect), and --resume
    finishes it without recomputing a sample; past the last write it is complete."""
    for k in range(20):
        path = tmp_path / f"k{k}.zarr"
        _flags_written(capsys, path)
        _WRITES.update(armed=True, left=k)
        try:
            store_mod.ZARR.mark_complete(store_mod.ZARR.open(path, writable=True))  # what the writers call
        except Killed:
            pass
        finished = _WRITES["armed"]
        _WRITES["armed"] = False
        code, out, err = run_cli(capsys, "inspect", path)
        assert code == 0, f"kill before write {k}: {err}"
        code, out, err = generate(capsys, path, "--resume")
        assert code == 0 and "already complete: all 4 samples were written" in out, f"kill before write {k}: {err}"
        assert is_complete(datasets.open_cache(path))
        assert [p.name for p in path.iterdir() if p.name.startswith(".")] == []  # no temp left inside
        if finished:
            break
    else:
        raise AssertionError("mark_complete made more than 20 writes")


def test_cache_cut_between_attributes_and_consolidation_recovers(tmp_path, capsys):
    """The state an older writer left when killed between its two metadata writes (flag set, consolidated
    entry gone): inspect reads it and --resume repairs it."""
    path = tmp_path / "cut.zarr"
    assert generate(capsys, path)[0] == 0
    meta = json.loads((path / "zarr.json").read_text())
    del meta["consolidated_metadata"]
    (path / "zarr.json").write_text(json.dumps(meta))
    code, out, err = run_cli(capsys, "inspect", path)
    assert code == 0 and "4 of 4 complete, complete" in out, err
    code, out, err = generate(capsys, path, "--resume")
    assert code == 0, err
    assert json.loads((path / "zarr.json").read_text())["consolidated_metadata"]
    assert is_complete(datasets.open_cache(path))


# --- 4. one writer per cache ----------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", ["h5", "zarr"])
def test_second_writer_is_refused(tmp_path, capsys, suffix):
    path = tmp_path / f"c.{suffix}"
    lock = tmp_path / f".c.{suffix}.lock"
    slow = [a for a in SLOW if a != "--overwrite"]
    proc = subprocess.Popen([sys.executable, "-m", "pdestream.cli", "generate", *slow, "--out", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (path.exists() and lock.exists()) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        assert proc.poll() is None, "the first writer finished before the second started: use a slower config"
        for mode in ("--overwrite", "--resume"):
            code, out, err = generate(capsys, path, mode, "--set", "t_end=100")
            assert code == 2 and err.count("\n") == 1, err
            assert f"{path} is being written by another process (pid {proc.pid})" in err, err
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 0 and "wrote 24 samples" in out, err
    ds = datasets.open_cache(path)
    assert is_complete(ds) and ds.attrs["pdestream_seed"] == 5 and not np.isnan(ds["u"].values).any()
    assert listing(tmp_path) == [path.name]  # the lock file is gone


# --- 5. compare --out keeps an earlier run ------------------------------------------------------------------
@pytest.mark.parametrize("earlier", ["compare.json", "compare.md", "cache.h5", "cache_seed0/model.pt",
                                     "fifo/arm.json"])
def test_compare_refuses_an_out_dir_with_earlier_output(tmp_path, capsys, earlier):
    out = tmp_path / "cmp"
    (out / earlier).parent.mkdir(parents=True, exist_ok=True)
    (out / earlier).write_text("earlier run")
    sha = digest(out)
    for extra in ([], ["--quick"]):
        code, stdout, err = run_cli(capsys, "compare", "--out", out, *extra)
        assert code == 2 and stdout == "" and err.count("\n") == 1, err
        assert "already holds compare output" in err and "--overwrite" in err, err
    assert digest(out) == sha and listing(tmp_path) == ["cmp"]


def test_compare_out_check_lets_new_dirs_and_overwrite_through(tmp_path):
    check_compare_out(str(tmp_path / "new"), overwrite=False)
    (tmp_path / "notes.txt").write_text("unrelated")
    check_compare_out(str(tmp_path), overwrite=False)  # a directory without compare output
    (tmp_path / "compare.json").write_text("{}")
    check_compare_out(str(tmp_path), overwrite=True)
    with pytest.raises(FileExistsError):
        check_compare_out(str(tmp_path), overwrite=False)
    with pytest.raises(NotADirectoryError):
        check_compare_out(str(tmp_path / "notes.txt"), overwrite=False)


# --- a damaged cache that claims completeness -----------------------------------------------------------------
def _nan_in_h5(path, j):
    with h5py.File(path, "r+") as f:
        f["u"][j] = np.nan  # NaN bytes in the file


def _deleted_field_chunk(path, j):
    per_chunk = zarr.open_group(path, mode="r", zarr_format=3)["u"].chunks[0]
    (path / "u" / "c" / str(j // per_chunk) / "0" / "0").unlink()  # now reads as the fill value NaN


def _deleted_param_chunk(path, j):
    for chunk in (path / "nu" / "c").iterdir():
        chunk.unlink()


@pytest.mark.parametrize("suffix, damage", [("h5", _nan_in_h5), ("zarr", _deleted_field_chunk),
                                            ("zarr", _deleted_param_chunk)])
def test_damaged_cache_is_reported_and_resume_recomputes_it(tmp_path, capsys, suffix, damage):
    path = tmp_path / f"c.{suffix}"
    assert generate(capsys, path, "--block", "2", n=6, seed=2)[0] == 0  # Zarr: 2 samples per chunk
    want = datasets.open_cache(path)
    want_u, want_nu = want["u"].values, want["nu"].values
    want.close()
    sha = digest(path)
    damage(path, 3)
    with pytest.raises(ValueError, match=r"damaged samples .*3"):
        whole = datasets.CachedTrajectories(path)  # the parameter check of __init__, or the read of all samples
        try:
            whole[0]
        finally:
            whole.close()  # this process may not hold the HDF5 file open when it resumes below
    if damage is not _deleted_param_chunk:
        lazy = datasets.CachedTrajectories(path, in_memory=False)
        lazy[0]
        with pytest.raises(ValueError, match="damaged samples 3:"):
            lazy[3]
        lazy.close()
    code, out, err = run_cli(capsys, "inspect", path)
    assert code == 0 and "DAMAGED: samples" in out and "3" in out.split("DAMAGED: samples")[1].split("hold")[0], out
    code, out, err = generate(capsys, path, "--resume", n=6, seed=2)
    assert code == 0 and "damaged samples recomputed" in out, (out, err)
    got = datasets.open_cache(path)
    assert is_complete(got)
    np.testing.assert_array_equal(got["u"].values, want_u)
    np.testing.assert_array_equal(got["nu"].values, want_nu)
    if suffix == "zarr":
        assert digest(path) == sha  # bit-identical to the cache before the damage
    assert "DAMAGED" not in run_cli(capsys, "inspect", path)[1]
