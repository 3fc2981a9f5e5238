"""Clear one-line refusals of bad settings (issue 13): checked where parsed, limits named, nothing left behind;
the JAX compilation cache directory check; --scheduler checks; shipped example configs."""

import argparse
import dataclasses
import math
import os
import re
import socket
import threading
from pathlib import Path

import numpy as np
import pytest

from pdestream import cli, settings
from pdestream import generator as g
from pdestream.generator import problem as base  # the limits every problem obeys

ROOT = Path(__file__).resolve().parents[1]


def refused(argv, capsys, *words):
    """Run the CLI; assert exit 2 with one line `pdestream: error: ...` holding every word, no traceback."""
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("pdestream: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, (word, err)
    return err


def numeric_settings():
    """(pde, key) for every non-parameter number of every PDE and of its default IC."""
    for name, cls in g.PDES.items():
        pde = cls()
        for f in dataclasses.fields(cls):
            if f.name in cls.config_fields() and f.name not in cls.PARAMS and not isinstance(f.default, (bool, str)):
                yield name, f.name
        for f in dataclasses.fields(pde.ic):  # domain strings (euler1d's Riemann states) as at the PDE level
            if not isinstance(f.default, (bool, str)):
                yield name, f"ic.{f.name}"


# --- every number is finite, checked where it is parsed --------------------------------------------------
@pytest.mark.parametrize("name, key", list(numeric_settings()))
@pytest.mark.parametrize("value", ["nan", "inf", "-inf", float("nan"), float("inf")])
def test_nan_and_infinity_are_refused_for_every_numeric_setting(name, key, value):
    with pytest.raises(ValueError) as err:
        g.get_pde(name, {key: value})
    message = str(err.value)
    assert key in message and ("must be a finite number" in message or "is not an integer" in message), message


def test_objects_built_directly_are_checked_too():
    with pytest.raises(ValueError, match="drag=nan not allowed"):
        g.PDES["ns2d"](drag=float("nan"))
    with pytest.raises(ValueError, match="ic.amplitude=inf not allowed"):
        g.PDES["advection1d"](ic=g.FourierSeries(amplitude=math.inf))
    with pytest.raises(ValueError, match="finite"):
        g.Fixed(float("nan"))
    with pytest.raises(ValueError, match="finite"):
        g.Choice((0.1, float("inf")))


def test_numpy_scalars_become_plain_values():
    pde = g.get_pde("burgers1d", n=np.int64(64), t_end=np.float64(0.5), **{"ic.mean": np.float32(0.0)})
    assert type(pde.n) is int and type(pde.t_end) is float and type(pde.ic.mean) is float
    assert pde == g.get_pde("burgers1d", n=64, t_end=0.5) and pde.config_hash() == g.get_pde("burgers1d", n=64, t_end=0.5).config_hash()


def test_a_number_for_a_domain_text_setting_is_that_fixed_value():
    # from Python, ic.rho_l=1 means what --set ic.rho_l=1 means (it was refused as "not a name")
    assert g.get_pde("euler1d", **{"ic.rho_l": 1}) == g.get_pde("euler1d", **{"ic.rho_l": "1"})
    with pytest.raises(ValueError, match="ic.rho_l"):
        g.get_pde("euler1d", **{"ic.rho_l": math.nan})


@pytest.mark.parametrize("key, value, words", [
    ("n", 64.0, ["n", "64.0", "an integer"]),
    ("forcing", ["none"], ["forcing", "['none']", "a name"]),
    ("ic.zero_mean", 1, ["ic.zero_mean", "true or false"]),
    ("velocity_bound", "fast", ["velocity_bound", "'fast'", "a number"]),
])
def test_values_of_the_wrong_kind_name_the_setting(key, value, words):
    with pytest.raises(ValueError) as err:
        g.get_pde("ns2d", {key: value})
    for word in words:
        assert word in str(err.value), (word, str(err.value))


def test_cli_nan_is_one_line_and_creates_nothing(tmp_path, capsys):
    out = tmp_path / "c.h5"
    refused(["generate", "burgers1d", "--n", "2", "--set", "ic.mean=nan", "--out", str(out)], capsys,
            "ic.mean=nan", "finite")
    refused(["generate", "ns2d", "--n", "2", "--set", "drag=inf", "--out", str(out)], capsys, "drag=inf")
    assert list(tmp_path.iterdir()) == []


# --- config files ----------------------------------------------------------------------------------------
def args_for(path, sets=()):
    return argparse.Namespace(config=str(path), set=list(sets))


def test_a_dotted_toml_key_works_like_set(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('pde = "ns2d"\nn = 32\nic.alpha = 3.5\nic.mean = 0.5\n')
    from_file = settings.pde_from_args(None, args_for(path))
    from_set = settings.pde_from_args("ns2d", argparse.Namespace(config=None, set=["n=32", "ic.alpha=3.5", "ic.mean=0.5"]))
    assert from_file == from_set and from_file.ic.sigma == 12.0  # the PDE's own IC, two fields changed
    assert g.get_pde("ns2d", ic={"alpha": 3.5}).ic == dataclasses.replace(g.get_pde("ns2d").ic, alpha=3.5)


@pytest.mark.parametrize("text, words", [
    ('name = ["burgers1d"]\n', ["PDE name must be a string", "['burgers1d']"]),
    ('pde = "burgers1d"\nic = ["grf"]\n', ["bad ic ['grf']", "grf"]),
    ('pde = "burgers1d"\nic = {kind = ["grf"]}\n', ["unknown ic kind ['grf']", "fourier"]),
    ('pde = "ns2d"\nforcing = ["none"]\n', ["forcing", "['none']"]),
    ('pde = "burgers1d"\nic.mean = nan\n', ["ic.mean=nan", "finite"]),
    ('pde = "burgers1d"\nic.sigma = inf\n', ["ic.sigma=inf", "finite"]),
])
def test_config_values_of_the_wrong_type_get_one_line(tmp_path, capsys, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    refused(["generate", "--config", str(path), "--n", "2", "--out", str(tmp_path / "c.h5")], capsys, *words)
    assert not (tmp_path / "c.h5").exists()


def test_a_config_that_is_not_utf8_names_the_file(tmp_path, capsys):
    path = tmp_path / "latin1.toml"
    path.write_bytes('pde = "burgers1d"\n# viscosit\xe9\n'.encode("latin-1"))
    refused(["generate", "--config", str(path), "--n", "2", "--out", str(tmp_path / "c.h5")], capsys,
            str(path), "not UTF-8", "0xe9")


# --- initial conditions fit the PDE -----------------------------------------------------------------------
@pytest.mark.parametrize("name", ["burgers1d", "ns2d", "advection1d"])
def test_an_ic_with_another_field_count_is_refused(name):
    with pytest.raises(ValueError) as err:
        g.get_pde(name, ic="spots")
    assert "ic='spots' not allowed" in str(err.value) and "2 fields" in str(err.value) and "grf" in str(err.value)


def test_ics_that_fit_are_accepted():
    assert g.get_pde("grayscott2d", ic="spots").ic.kind == "spots"
    assert g.get_pde("grayscott2d", ic="grf", n=32).ic.kind == "grf"  # one independent draw per field



@pytest.mark.parametrize("name", ["grayscott2d", "grayscott3d"])
def test_grayscott_spots_concentrations_stay_in_their_physical_range(name):
    # issue 21: overlapping spots drove u to -0.24 and zero-mean noise v to -0.015 at t = 0; 0 <= u, v <= 1 is
    # also the IC's declared bound (the reaction step is chosen from it)
    pde = g.get_pde(name, n_frames=2, t_end=1.0)
    import jax

    ic = np.stack([np.asarray(pde.sample_ic(jax.random.PRNGKey(i))) for i in range(8)])  # what it draws
    frame0 = np.asarray(g.sample(pde, list(range(8)), seed=0).u)[:, 0]  # the IC's projection the solver evolves
    for u in [ic, frame0]:
        assert u.min() >= -1e-6 and u.max() <= pde.ic.bound(pde.grid) + 1e-6
    assert frame0[:, 1].max() <= pde.ic.height + pde.ic.noise + 1e-6  # spots at most `height` tall
    assert frame0[:, 0].min() >= 1 - 2 * pde.ic.height - pde.ic.noise - 1e-6


def test_grayscott_spots_refuse_a_height_that_leaves_the_range():
    with pytest.raises(ValueError, match=r"ic.height=0.6.*2 height \+ noise <= 1"):
        g.get_pde("grayscott2d", {"ic.height": "0.6"})

# --- limits on the frame/step arithmetic, named and checked before anything runs ----------------------------
@pytest.mark.parametrize("name, settings, limit", [
    ("burgers1d", {"t_end": "1e300"}, str(base.MAX_STEPS)),
    ("burgers1d", {"dt": "1e-12"}, str(base.MAX_STEPS)),
    ("ks1d", {"t_end": "1e7"}, str(base.MAX_STEPS)),
    ("burgers1d", {"ic.mean": "1e6"}, str(base.MAX_STEPS)),  # a large IC shrinks the CFL step
    ("advection1d", {"ic.offset": "1e30"}, f"{base.MAX_IC_BOUND:g}"),  # linear: no step limit, float32 is
    ("burgers1d", {"n": str(2**40)}, str(base.MAX_GRID_POINTS)),
    ("ns2d", {"n": "8192"}, str(base.MAX_GRID_POINTS)),
    ("burgers1d", {"n_frames": str(10**12)}, "GiB"),
    ("ns2d", {"n": "2048", "n_frames": "200"}, "GiB"),
    ("grayscott2d", {"ic.n_spots": "100000"}, "256"),
])
def test_exploding_settings_are_refused_up_front_naming_the_limit(name, settings, limit):
    import tracemalloc

    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as err:
            g.get_pde(name, settings)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20, peak  # refused before any array of that size (numpy's are traced) or any solve
    assert "limit" in str(err.value) or "<=" in str(err.value)
    assert limit in str(err.value), str(err.value)


def test_every_default_is_well_inside_the_limits():
    for name in (n for n, cls in g.PDES.items() if not cls.STEADY):  # a steady PDE takes no time steps
        pde = g.get_pde(name)
        assert pde.steps_per_frame * (pde.n_frames - 1) <= base.MAX_STEPS // 100


def test_exploding_settings_on_the_cli_leave_nothing(tmp_path, capsys):
    refused(["generate", "burgers1d", "--n", "2", "--set", "t_end=1e300", "--out", str(tmp_path / "c.zarr")],
            capsys, "t_end=1e+300", str(base.MAX_STEPS))
    assert list(tmp_path.iterdir()) == []


# --- messages and entry points ------------------------------------------------------------------------------
def test_write_cache_takes_a_catalog_name(tmp_path):
    from pdestream import datasets

    pde = g.get_pde("burgers1d")
    done = datasets.write_cache("burgers1d", tmp_path / "a.h5", 1, block=1, progress=False)
    assert done.written == 1
    ds = datasets.open_cache(tmp_path / "a.h5")
    assert ds.attrs["pdestream_config_hash"] == pde.config_hash()
    ds.close()


def test_resume_mismatch_names_the_settings_without_numpy_reprs(tmp_path, capsys):
    out = str(tmp_path / "c.h5")
    small = ["--set", "n=32", "--set", "n_frames=3"]
    assert cli.main(["generate", "burgers1d", "--n", "2", *small, "--out", out]) == 0
    capsys.readouterr()
    err = refused(["generate", "burgers1d", "--n", "2", "--set", "n=64", "--set", "n_frames=3",
                   "--set", "ic.alpha=3", "--seed", "1", "--out", out, "--resume"], capsys,
                  "n: cache 32 vs asked 64", "ic.alpha: cache 2.0 vs asked 3.0", "seed: cache 0 vs asked 1")
    assert "np." not in err


def test_list_marks_fixed_values_as_fixed(capsys):
    assert cli.main(["list"]) == 0
    out = capsys.readouterr().out
    assert "Du = 2e-05 (fixed)" in out and "Dv = 1e-05 (fixed)" in out
    grayscott = out[out.index("grayscott2d:"):out.index("grayscott3d:")]  # its Du is fixed (diffusion_reaction2d's is not)
    assert not re.search(r"\bDu ~", grayscott) and "nu ~ loguniform(0.01, 0.1)" in out


def test_bench_without_the_extra_says_what_to_install(monkeypatch, capsys):
    import importlib.util

    import benchmarks.__main__ as bench

    ran = []
    monkeypatch.setattr(bench, "run", lambda *a: ran.append(a))  # never run a benchmark here
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "exponax" else real(n, *a))
    for argv, words in ((["--only", "generator"], ("exponax", "pip install", ".[bench]")),
                        ([], ("exponax", ".[bench]", "--only stream"))):
        assert bench.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and all(w in err for w in words), err
    assert ran == []
    assert bench.main(["--only", "stream"]) == 0 and len(ran) == 1  # a family without extras is not refused


# --- the JAX compilation cache directory --------------------------------------------------------------------
@pytest.fixture
def jax_cache_setting():
    import jax

    before = jax.config.jax_compilation_cache_dir
    g._REFUSED_CACHE_DIRS.clear()
    yield jax
    jax.config.update("jax_compilation_cache_dir", before)
    g._REFUSED_CACHE_DIRS.clear()


def test_a_cache_dir_writable_by_others_is_not_used(tmp_path, jax_cache_setting):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    with pytest.warns(UserWarning, match="writable by others"):
        g.enable_compilation_cache(shared)
    assert jax_cache_setting.config.jax_compilation_cache_dir != str(shared)
    group = tmp_path / "group"
    group.mkdir()
    group.chmod(0o770)
    with pytest.warns(UserWarning, match="writable by its group"):
        g.enable_compilation_cache(group)
    assert jax_cache_setting.config.jax_compilation_cache_dir != str(group)


def test_a_cache_dir_owned_by_someone_else_is_not_used(tmp_path, monkeypatch, jax_cache_setting):
    theirs = tmp_path / "theirs"
    theirs.mkdir(mode=0o700)
    monkeypatch.setattr(os, "getuid", lambda: os.stat(theirs).st_uid + 1)  # as if another user ran this
    with pytest.warns(UserWarning, match="owned by uid"):
        g.enable_compilation_cache(theirs)
    assert jax_cache_setting.config.jax_compilation_cache_dir != str(theirs)


def test_a_private_cache_dir_is_used_and_configure_jax_checks_it(tmp_path, monkeypatch, jax_cache_setting, recwarn):
    from pdestream.datasets import _bridge

    mine = tmp_path / "mine"
    g.enable_compilation_cache(mine)
    assert jax_cache_setting.config.jax_compilation_cache_dir == str(mine) and not recwarn.list
    # bounded, so JAX locks each entry's read and write: no process reads a program another is still writing
    assert jax_cache_setting.config.jax_compilation_cache_max_size == g.CACHE_MAX_BYTES
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o757)
    monkeypatch.setenv(_bridge.CACHE_ENV, str(shared))
    with pytest.warns(UserWarning, match="not using the JAX compilation cache"):
        _bridge.configure_jax()
    assert jax_cache_setting.config.jax_compilation_cache_dir == str(mine)


# --- --scheduler -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("address", ["foo", "tcp:/host:8786", "http://host:8786", "tcp://host:99999",
                                     "tcp://host", "tcp://ho st:8786", ""])
def test_a_malformed_scheduler_address_is_refused_before_connecting(address, monkeypatch):
    from pdestream.datasets import distributed

    monkeypatch.setattr(socket, "create_connection", lambda *a, **k: pytest.fail("connected"))
    with pytest.raises(ValueError, match="SCHEME://HOST:PORT"):
        distributed.probe_scheduler(address)


def test_well_formed_addresses_parse():
    from pdestream.datasets.distributed import check_scheduler

    assert check_scheduler("tcp://10.0.0.5:8786") == ("tcp", "10.0.0.5", 8786)
    assert check_scheduler("node7:8786") == ("tcp", "node7", 8786)
    assert check_scheduler("tls://[::1]:8786") == ("tls", "::1", 8786)


def _server(reply: bytes | None, release: threading.Event):
    """A local TCP server accepting one connection; it sends ``reply`` and holds the connection open until
    ``release`` is set (b"": silent and open); None: it closes the connection at once."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)

    def serve():
        conn, _ = srv.accept()
        if reply:
            conn.sendall(reply)
        if reply is not None:
            release.wait(120)
        conn.close()
        srv.close()

    threading.Thread(target=serve, daemon=True).start()
    return f"tcp://127.0.0.1:{srv.getsockname()[1]}"


@pytest.mark.parametrize("reply", [b"HTTP/1.1 400 Bad Request\r\n\r\n", None, b""])
def test_something_that_is_not_a_scheduler_is_refused_in_seconds(reply, monkeypatch):
    from pdestream.datasets import distributed

    monkeypatch.setattr(distributed, "PROBE_TIMEOUT", 0.5)
    release, outcome = threading.Event(), {}
    address = _server(reply, release)  # a silent server stays open: without its timeout the probe would wait forever

    def probe():
        try:
            distributed.probe_scheduler(address)
        except ValueError as err:
            outcome["error"] = str(err)

    prober = threading.Thread(target=probe, daemon=True)
    prober.start()
    prober.join(60)  # only a hang guard: the probe's own timeout is 0.5 s
    release.set()
    assert not prober.is_alive(), "the probe waited on a server that never answers"
    assert "does not answer like a Dask scheduler" in outcome.get("error", ""), outcome


def test_an_unreachable_scheduler_fails_fast_and_creates_nothing(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "c.zarr"
    import distributed

    made = []

    def client(*args, **kwargs):  # Dask's client may wait ~20 s on an address nobody serves: the probe refuses first
        made.append(args)
        raise OSError("connection refused")

    monkeypatch.setattr(distributed, "Client", client)
    refused(["generate", "burgers1d", "--n", "2", "--set", "n=32", "--set", "n_frames=3", "--executor", "dask",
             "--scheduler", f"tcp://127.0.0.1:{port}", "--out", str(out)], capsys, "cannot reach", str(port))
    refused(["generate", "burgers1d", "--n", "2", "--executor", "dask", "--scheduler", "nonsense",
             "--out", str(out)], capsys, "'nonsense'", "tcp://")
    assert made == [] and list(tmp_path.iterdir()) == []


def test_a_real_scheduler_passes_the_probe():
    dist = pytest.importorskip("distributed")
    from pdestream.datasets.distributed import probe_scheduler

    with dist.LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=":0") as cluster:
        probe_scheduler(cluster.scheduler_address)


# --- shipped example configs ----------------------------------------------------------------------------------
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))


def test_example_configs_are_shipped():
    assert {p.name for p in CONFIGS} >= {"ns2d.toml", "burgers_fno.toml"}


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_each_example_config_parses_builds_and_solves(path):
    pde = settings.pde_from_args(None, args_for(path))
    assert pde.NAME in g.PDES
    small = pde.replace(n=32, n_frames=2, t_end=pde.t_end / 100)
    assert np.isfinite(np.asarray(g.sample(small, [0]).u)).all()


def test_the_fno_config_is_the_fno_setup():
    pde = settings.pde_from_args(None, args_for(ROOT / "configs" / "burgers_fno.toml"))
    assert pde == g.get_pde("burgers1d", n=1024, nu=0.1, t_end=1.0, n_frames=2)


def test_readme_configs_exist():  # the README and the docs pages
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    named = re.findall(r"--config (?:\{repository\}/)?(\S+)", "".join(p.read_text() for p in pages))  # (test_docs' stand-ins)
    assert named and all((ROOT / p).is_file() for p in named), named


def test_train_names_a_dotted_ic_key_that_differs_from_the_cache(tmp_path, capsys):
    cache = tmp_path / "c.h5"
    assert cli.main(["generate", "burgers1d", "--n", "2", "--set", "n=32", "--set", "n_frames=3",
                     "--out", str(cache)]) == 0
    (tmp_path / "other.toml").write_text("n = 32\nn_frames = 3\nic.alpha = 3.0\n")
    capsys.readouterr()
    refused(["train", "burgers1d", "--source", str(cache), "--config", str(tmp_path / "other.toml"),
             "--steps", "1", "--out", str(tmp_path / "run")], capsys, "ic.alpha: cache 2.0 vs asked 3.0")


def test_cache_entries_without_access_times_get_them(tmp_path, jax_cache_setting, recwarn):
    """JAX's bounded cache reads every entry's KEY-atime on each write; entries of an unbounded cache (or cut
    short by a kill) have none and made every later write fail with a warning, so nothing was cached again."""
    mine = tmp_path / "old"
    mine.mkdir(mode=0o700)
    (mine / "jit_f-abc-cache").write_bytes(b"program")
    (mine / "jit_g-def-cache").write_bytes(b"program")
    (mine / "jit_g-def-atime").write_bytes((7).to_bytes(8, "little"))
    g.enable_compilation_cache(mine)
    written = int.from_bytes((mine / "jit_f-abc-atime").read_bytes(), "little")
    assert written == (mine / "jit_f-abc-cache").stat().st_mtime_ns
    assert int.from_bytes((mine / "jit_g-def-atime").read_bytes(), "little") == 7  # an existing one is kept
    assert g.give_entries_access_times(mine) == 0 and not recwarn.list
