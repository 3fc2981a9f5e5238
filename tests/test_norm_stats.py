"""Normalization statistics computed once and applied everywhere: split-invariant Welford/Chan moments, the
stats file beside a cache (The Well's stats.yaml layout) and in a The Well export, run.json's record, and the
training statistics applied to the test set (never the test set's own)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from pdestream import cli, datasets, generator
from pdestream.datasets.normalize import Moments, Normalization
from pdestream.datasets.stats import cache_stats, read_stats, stats_path


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    out = tmp_path_factory.mktemp("norm") / "b.h5"
    assert cli.main(["generate", "burgers1d", "--n", "6", "--set", "n=32", "--set", "n_frames=4", "--out", str(out)]) == 0
    return out


def _moments(u, p, parts):
    """Moments over samples split into ``parts`` (lo, hi) ranges, each read in blocks of 5 and merged in that order."""
    total = None
    for lo, hi in parts:
        m = Moments(1)
        for a in range(lo, hi, 5):
            b = min(a + 5, hi)
            m.add(torch.from_numpy(u[a:b]), torch.from_numpy(p[a:b]), index=np.arange(a, b))
        total = m if total is None else total.merge(m)
    return total


def test_moments_are_bit_identical_however_the_samples_were_split():
    rng = np.random.default_rng(0)
    u = rng.normal(1e3, 2.0, (12, 4, 2, 32))  # [N, T, C, x]: a large mean, where E[u^2] - E[u]^2 loses digits
    p = rng.normal(0.5, 0.1, (12, 3))
    whole = _moments(u, p, [(0, 12)])
    for split in ([(0, 5), (5, 10), (10, 12)], [(8, 12), (0, 3), (3, 8)]):  # 3 partial results, any order
        got = _moments(u, p, split)
        for slot in (0, 1):
            (n1, m1, v1), (n2, m2, v2) = whole.raw(slot), got.raw(slot)
            assert n1 == n2 and m1.tobytes() == m2.tobytes() and v1.tobytes() == v2.tobytes()
    flat = u.transpose(2, 0, 1, 3).reshape(2, -1)
    n, mean, var = whole.raw(0)
    assert n == flat.shape[1]
    np.testing.assert_allclose(mean, flat.mean(1), rtol=1e-14)
    np.testing.assert_allclose(np.sqrt(var), flat.std(1), rtol=1e-10)
    np.testing.assert_allclose(whole.raw(1)[2], p.var(0), rtol=1e-10)
    with pytest.raises(ValueError, match=r"samples \[3\] are in both") as err:
        _moments(u, p, [(0, 4)]).merge(_moments(u, p, [(3, 6)]))
    assert "\n" not in str(err.value)


def test_a_caches_statistics_do_not_depend_on_its_read_size(cache):
    ds = datasets.CachedTrajectories(cache)
    a, b = ds.moments(chunk=6)[0].raw(0), ds.moments(chunk=4)[0].raw(0)
    assert a[1].tobytes() == b[1].tobytes() and a[2].tobytes() == b[2].tobytes()


def test_inspect_stats_writes_the_wells_layout_beside_the_cache(cache, capsys):
    assert cli.main(["inspect", str(cache), "--stats"]) == 0
    path = stats_path(cache)
    assert f"stats: {path}" in capsys.readouterr().out and path.name == "b.h5.stats.yaml"
    stats = read_stats(path)
    u = datasets.CachedTrajectories(cache, view="whole")
    data = np.stack([u[i]["u"].double().numpy() for i in range(len(u))])  # [N, T, C, x]
    for c, name in enumerate(u.fields):
        np.testing.assert_allclose(stats["mean"][name], data[:, :, c].mean(), rtol=1e-6)
        np.testing.assert_allclose(stats["std"][name], data[:, :, c].std(), rtol=1e-5)
        np.testing.assert_allclose(stats["rms"][name], np.sqrt((data[:, :, c] ** 2).mean()), rtol=1e-5)
        np.testing.assert_allclose(stats["std_delta"][name], np.diff(data[:, :, c], axis=1).std(), rtol=1e-5)
    assert stats["pdestream"]["normalization"] == json.loads(json.dumps(u.normalization().to_dict()))
    yaml = pytest.importorskip("yaml")  # The Well reads stats.yaml with PyYAML: the same numbers, as floats
    assert yaml.safe_load(path.read_text()) == stats


def test_the_well_export_carries_the_statistics(cache, tmp_path):
    from pdestream.datasets.export import export_cache

    train = tmp_path / "well" / "data" / "train"
    train.mkdir(parents=True)
    export_cache(cache, "the-well", train / "b.hdf5")
    assert read_stats(tmp_path / "well" / "stats.yaml") == json.loads(json.dumps(cache_stats(cache)))
    (tmp_path / "well" / "stats.yaml").write_text("mean: {u: 1.0}\n")  # someone else's: left alone
    export_cache(cache, "the-well", train / "b.hdf5", overwrite=True)
    assert (tmp_path / "well" / "stats.yaml").read_text() == "mean: {u: 1.0}\n"


def test_incomplete_or_foreign_stats_are_one_line(tmp_path):
    for text, says in (('{"mean": {"u": 1.0}}', "not a statistics file written by pdestream"),
                       ("mean: {u: 1.0}\n", "cannot read statistics")):
        (tmp_path / "s.yaml").write_text(text)
        with pytest.raises(ValueError, match=says) as err:
            read_stats(tmp_path / "s.yaml")
        assert "\n" not in str(err.value)


def test_training_records_its_statistics_and_applies_them_to_the_test_set(cache, tmp_path):
    from pdestream.surrogate.checkpoint import load_checkpoint
    from pdestream.surrogate.data import test_set
    from pdestream.surrogate.evaluate import test_errors
    from pdestream.surrogate.runs import resume_run, train_run

    pde = generator.get_pde("burgers1d", n=32, n_frames=4)
    test = test_set(pde, 0, 3)
    s = train_run(pde, str(cache), tmp_path / "run", model_cfg={"width": 4, "modes": 2, "layers": 1}, steps=2,
                  batch_size=4, tests={"test": test}, checkpoint_every=0)
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    train_norm = datasets.CachedTrajectories(cache).normalization()  # the training data's statistics
    assert run["normalization"] == json.loads(json.dumps(train_norm.to_dict()))
    model, used, _ = load_checkpoint(tmp_path / "run" / "model.pt")
    assert used.to_dict() == train_norm.to_dict()
    view = datasets.for_sample(datasets.make_view("next_step"), pde.n_frames, 0)
    own = Normalization.from_batch(test[0], 1)  # the test set's own statistics: must not be the ones applied
    assert not torch.equal(own.mean, train_norm.mean)
    assert s["test"]["test"]["rel_l2"] == test_errors(model, train_norm, view, test)["rel_l2"]
    assert s["test"]["test"]["rel_l2"] != test_errors(model, own, view, test)["rel_l2"]
    assert resume_run(tmp_path / "run", steps=3)[1] == 2  # an extension goes on with the recorded statistics
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["normalization"] == json.loads(json.dumps(train_norm.to_dict())) and run["steps"] == 3
    run["normalization"]["mean"] = [m + 1.0 for m in run["normalization"]["mean"]]  # a resume never trains on others
    (tmp_path / "run" / "run.json").write_text(json.dumps(run))
    with pytest.raises(ValueError, match="normalization statistics differ") as err:
        resume_run(tmp_path / "run", steps=4)
    assert "\n" not in str(err.value)
