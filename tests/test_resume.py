"""Resumable training runs: checkpoint.pt, run.json, `train --resume`, and the data-source hooks of the loop.

The kill tests run real processes: the run SIGKILLs itself (kill -9: no cleanup, no atexit) when the loop asks
for a given batch, a few steps after a checkpoint, so the resumed run must redo those steps. The resumed run
must end with the uninterrupted run's weights, bit for bit (one torch thread, CPU).
"""

import copy
import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch.utils.data import DataLoader, IterableDataset

from pdestream import cli
from pdestream.surrogate import build_model
from pdestream.surrogate.data import EpochBatchSampler
from pdestream.surrogate.predict import relative_errors, stack_frames
from pdestream.surrogate.train import TIMINGS, _postfix, forever, train

torch.set_num_threads(1)

ROOT = Path(__file__).resolve().parents[1]
TINY_PDE = ["--set", "n=32", "--set", "n_frames=5"]
TINY_MODEL = ["--model-set", "width=8", "--model-set", "modes=4", "--model-set", "layers=2"]
STEPS = 30
CHECKPOINT_KEYS = {"format", "step", "steps", "model", "spec", "optimizer", "scheduler", "torch_rng", "normalization",
                   "rows", "counters", "data", "meta"}

# Runs the CLI (spec "argv") or train_run (spec "train_run") in a fresh process with one torch thread; with
# "kill_at" the process SIGKILLs itself when the training loop asks for that batch.
RUNNER = r"""
import json, os, signal, sys
import torch
torch.set_num_threads(1)
import pdestream.surrogate.train as T

spec = json.loads(sys.argv[1])
if spec.get("kill_at"):
    real_forever = T.forever

    def dying(loader):
        for n, batch in enumerate(real_forever(loader), 1):
            if n == spec["kill_at"]:
                os.kill(os.getpid(), signal.SIGKILL)
            yield batch

    T.forever = dying
if "argv" in spec:
    from pdestream import cli
    sys.exit(cli.main(spec["argv"]))
from pdestream import datasets, generator
from pdestream.surrogate.runs import train_run
kw = spec["train_run"]
pde = generator.get_pde(kw.pop("pde"), kw.pop("pde_set"))
train_run(pde, view=datasets.make_view(kw.pop("view"), **kw.pop("view_args")), **kw)
"""


def run_process(spec: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", RUNNER, json.dumps(spec)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)


def load(path: Path) -> dict:
    return torch.load(path, map_location="cpu", weights_only=True)


def without_timings(rows: list[dict]) -> list[dict]:
    """Rows (or summaries, with their nested data_stats) without the values a resume may change."""
    def strip(d):
        return {k: strip(v) if isinstance(v, dict) else v for k, v in d.items() if k not in TIMINGS}

    return [strip(row) for row in rows]


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def assert_same_run(a: Path, b: Path) -> None:
    """Same weights bit for bit (model.pt and the final checkpoint), same metrics apart from timings."""
    ma, mb = load(a / "model.pt"), load(b / "model.pt")
    assert ma["model"].keys() == mb["model"].keys()
    for key in ma["model"]:
        assert torch.equal(ma["model"][key], mb["model"][key]), key
    ca, cb = load(a / "checkpoint.pt"), load(b / "checkpoint.pt")
    for group in ("model",):
        assert all(torch.equal(ca[group][k], cb[group][k]) for k in ca[group])
    for pa, pb in zip(ca["optimizer"]["state"].values(), cb["optimizer"]["state"].values()):
        assert all(torch.equal(pa[k], pb[k]) for k in pa)
    assert ca["scheduler"] == cb["scheduler"] and ca["data"] == cb["data"] and torch.equal(ca["torch_rng"], cb["torch_rng"])
    assert without_timings(read_csv(a / "metrics.csv")) == without_timings(read_csv(b / "metrics.csv"))
    sa, sb = (json.loads((d / "metrics.json").read_text()) for d in (a, b))
    assert without_timings([sa]) == without_timings([sb])
    ra, rb = ({k: v for k, v in json.loads((d / "run.json").read_text()).items() if k != "extended"}
              for d in (a, b))  # an extended run says so (test_resume_with_more_steps_...) and is otherwise the same
    assert ra == rb


def kill_and_resume(whole: Path, killed: Path, fresh: dict, kill_at: int) -> dict:
    """Run ``fresh`` uninterrupted into ``whole`` and killed at batch ``kill_at`` into ``killed``; resume the
    killed one with the CLI. Returns the killed run's checkpoint as it stood after the kill."""
    done = run_process(fresh(whole))
    assert done.returncode == 0, done.stderr
    dead = run_process({**fresh(killed), "kill_at": kill_at})
    assert dead.returncode == -9, dead.stderr
    assert not (killed / "metrics.json").exists() and not (killed / "model.pt").exists()
    ckpt = load(killed / "checkpoint.pt")  # plain containers and tensors only
    (killed / ".checkpoint.pt.x1y2.tmp").write_bytes(b"half a checkpoint")  # as a kill during a write leaves it
    resumed = run_process({"argv": ["train", "--resume", str(killed), "--threads", "1"]})
    assert resumed.returncode == 0, resumed.stderr
    assert f"resumed {killed} at step {ckpt['step']} of {STEPS}" in resumed.stdout
    assert_same_run(whole, killed)
    assert not list(killed.glob(".*.tmp"))
    return ckpt


def test_kill9_and_resume_on_the_stream_is_bit_identical(tmp_path, capsys):
    def fresh(out):
        return {"argv": ["train", "burgers1d", *TINY_PDE, *TINY_MODEL, "--steps", str(STEPS), "--batch-size", "8",
                         "--checkpoint-every", "10", "--test-samples", "2", "--threads", "1", "--out", str(out)]}

    ckpt = kill_and_resume(tmp_path / "whole", tmp_path / "killed", fresh, kill_at=26)  # steps 21..25 redone
    assert set(ckpt) == CHECKPOINT_KEYS and ckpt["step"] == 20 and ckpt["steps"] == STEPS
    assert ckpt["torch_rng"].dtype == torch.uint8 and ckpt["spec"]["width"] == 8
    assert ckpt["data"]["owner"] == "dataset" and ckpt["data"]["state"]["consumed"] == [20 * 8]
    assert [r["step"] for r in ckpt["rows"]] == [10, 20] and ckpt["counters"]["examples"] == 160
    assert ckpt["normalization"]["samples"] == 64  # the stream's calibration draw, not recomputed on resume
    assert ckpt["optimizer"]["state"] and ckpt["scheduler"]["last_epoch"] == 20
    settings = json.loads((tmp_path / "killed" / "run.json").read_text())
    assert settings["pde"]["pde"] == "burgers1d" and settings["pde"]["n"] == 32 and settings["source"] == "stream"
    assert {k: settings[k] for k in ("model", "view", "steps", "batch_size", "checkpoint_every", "data_cfg")} == {
        "model": "fno", "view": "next_step", "steps": STEPS, "batch_size": 8, "checkpoint_every": 10, "data_cfg": None}
    assert settings["model_cfg"] == {"width": "8", "modes": "4", "layers": "2"} and settings["view_args"]["k_in"] == 1

    # a finished run is not resumed again, whatever it was (uninterrupted or resumed), and is left as it is
    for run in (tmp_path / "whole", tmp_path / "killed"):
        before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
        assert cli.main(["train", "--resume", str(run)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("pdestream: error:") and "already complete" in err, err
        assert {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == before


def test_kill9_and_resume_on_a_cache_is_bit_identical(tmp_path):
    from pdestream import datasets, generator

    pde_set = {"n": "32", "n_frames": "5"}
    cache = tmp_path / "c.h5"
    datasets.write_cache(generator.get_pde("burgers1d", pde_set), cache, 6, seed=0, progress=False)

    def fresh(out):  # random next-step windows: the cache draws them from the global torch RNG (restored on resume)
        return {"train_run": {"pde": "burgers1d", "pde_set": pde_set, "source": str(cache), "out_dir": str(out),
                              "model_cfg": {"width": 8, "modes": 4, "layers": 2}, "view": "next_step",
                              "view_args": {"windows": 2}, "steps": STEPS, "batch_size": 4, "checkpoint_every": 10,
                              "n_test": 2, "seed": 3, "data_cfg": {"opaque": [1, 2]}}}

    # 6 samples x 2 windows = 12 examples = 3 batches per epoch: the checkpoint at step 20 is mid-epoch 6
    ckpt = kill_and_resume(tmp_path / "whole", tmp_path / "killed", fresh, kill_at=25)
    assert ckpt["step"] == 20 and ckpt["data"]["owner"] == "batch_sampler"
    assert ckpt["data"]["state"] == {"sampler": "epoch_batch", "seed": 3, "n": 12, "batch_size": 4, "drop_last": True,
                                     "epoch": 6, "consumed": 2}
    assert ckpt["normalization"]["samples"] == 6  # the cache's stored samples
    settings = json.loads((tmp_path / "killed" / "run.json").read_text())
    assert settings["view_args"] == {"k_in": 1, "k_out": 1, "windows": 2} and settings["data_cfg"] == {"opaque": [1, 2]}


@pytest.mark.parametrize("n,batch_size,drop_last", [(10, 4, True), (3, 4, False), (9, 3, True), (7, 3, False)])
def test_epoch_batch_sampler_seeds_each_epoch_and_resumes_anywhere(n, batch_size, drop_last):
    """Epoch e's order is randperm(n) from a generator seeded for (seed, e) alone (it used to replay the draws a
    shuffling DataLoader makes internally), and a state taken after any batch continues exactly."""
    epochs, seed = 4, 5
    reference = []
    for e in range(epochs):
        order = torch.randperm(n, generator=torch.Generator().manual_seed((seed << 32) + e)).tolist()
        batches = [order[b:b + batch_size] for b in range(0, n, batch_size)]
        reference += [b for b in batches if len(b) == batch_size or not drop_last]
    sampler = EpochBatchSampler(n, batch_size, seed=5, drop_last=drop_last)
    it = forever(sampler)
    assert [next(it) for _ in reference] == reference
    for k in range(len(reference)):  # a state taken after any batch, epoch ends included, continues exactly
        first = EpochBatchSampler(n, batch_size, seed=5, drop_last=drop_last)
        it = forever(first)
        for _ in range(k):
            next(it)
        second = EpochBatchSampler(n, batch_size, seed=5, drop_last=drop_last)
        second.load_state_dict(first.state_dict())
        it = forever(second)
        assert [next(it) for _ in reference[k:]] == reference[k:], k
    with pytest.raises(ValueError, match="sampler state has seed=5 but this cache source has seed=6"):
        EpochBatchSampler(n, batch_size, seed=6, drop_last=drop_last).load_state_dict(sampler.state_dict())


def test_resume_refusals(tmp_path, capsys):
    def refused(argv, needle):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("pdestream: error:") and needle in err, err
        assert "Traceback" not in err

    refused(["train", "--resume", str(tmp_path / "nowhere")], f"--resume {tmp_path / 'nowhere'}: no such run directory")
    assert not (tmp_path / "nowhere").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    refused(["train", "--resume", str(empty)], f"{empty}: not a resumable training run, no run.json or checkpoint.pt")
    (empty / "run.json").write_text("{}")
    refused(["train", "--resume", str(empty)], "no checkpoint.pt (killed before its first checkpoint?")
    (empty / "checkpoint.pt").write_bytes(b"not a checkpoint")
    refused(["train", "--resume", str(empty)], "run.json is not a pdestream run file")
    (empty / "run.json").write_text(json.dumps({"format": 1, "steps": 5}))
    refused(["train", "--resume", str(empty)], "checkpoint.pt is damaged (not a torch.save file")
    assert sorted(p.name for p in empty.iterdir()) == ["checkpoint.pt", "run.json"]
    # settings given with --resume are refused, all named in one line, before the directory is even looked at
    refused(["train", "burgers1d", "--resume", str(empty), "--steps", "5", "--set", "n=64"],
            "drop PDE name, --set (only --threads, --steps and --ddp may go with it)")
    refused(["train", "--resume", str(empty), "--out", str(tmp_path / "o"), "--overwrite"], "drop --out, --overwrite")
    refused(["train", "burgers1d", *TINY_PDE, "--steps", "2"], "give --out RUN_DIR for a new run")
    # a new run is not started over an unfinished one
    refused(["train", "burgers1d", *TINY_PDE, "--steps", "2", "--out", str(empty)],
            f"already holds a run (run.json, checkpoint.pt); pass --resume {empty} to continue it")
    refused(["train", "burgers1d", *TINY_PDE, "--checkpoint-every", "-1", "--out", str(tmp_path / "neg")],
            "--checkpoint-every=-1 not allowed")
    assert not (tmp_path / "neg").exists() and not (tmp_path / "o").exists()


class FakeSource(IterableDataset):
    """A data source with both hooks: it records what the loop reports and offers statistics."""

    def __init__(self, batch_size=4, n=16):
        self.batch_size, self.n, self.reports, self.stats_calls = batch_size, n, [], 0

    def __iter__(self):
        gen = torch.Generator().manual_seed(0)
        for i in range(1000):
            x = torch.randn(self.batch_size, 1, 1, self.n, generator=gen)  # [B, k_in, C, n]
            yield {"x": x, "y": 0.5 * x + 1, "params": torch.rand(self.batch_size, 1, generator=gen),
                   "index": torch.arange(self.batch_size) + i * self.batch_size}

    def report_losses(self, batch: dict, per_example: torch.Tensor) -> None:
        self.reports.append((batch, per_example))

    def stats(self) -> dict:
        self.stats_calls += 1
        return {"wait_share": 0.25, "reuse_mean": float(self.stats_calls), "inserted": 7}


def test_report_losses_and_stats_hooks(tmp_path):
    source = FakeSource()
    torch.manual_seed(0)
    model = build_model("fno", 1, 1, 1, 1, width=8, modes=4, layers=2)
    before = copy.deepcopy(model)
    summary = train(model, DataLoader(source, batch_size=None), 6, tmp_path, log_every=2)
    assert len(source.reports) == 6
    for _batch, per_example in source.reports:
        assert per_example.dtype == torch.float64 and per_example.shape == (4,) and per_example.device.type == "cpu"
        assert not per_example.requires_grad and bool((per_example > 0).all())
    # the first report is the initial model's error on the first batch: ||pred - target|| / ||target||, normalized
    batch, reported = source.reports[0]
    norm = summary["normalizer"]
    with torch.no_grad():
        pred = before(stack_frames(norm.normalize(batch["x"]), 1), norm.normalize_params(batch["params"])).double()
    target = stack_frames(norm.normalize(batch["y"]), 1).double()
    expected = torch.stack([(p - t).norm() / t.norm() for p, t in zip(pred, target)])
    torch.testing.assert_close(reported, expected, rtol=1e-5, atol=0)
    torch.testing.assert_close(relative_errors(torch.zeros(2, 3), torch.ones(2, 3)), torch.ones(2, dtype=torch.float64))
    # stats: one call per logged row, their items in each row, the last ones in the summary
    rows = read_csv(tmp_path / "metrics.csv")
    assert source.stats_calls == 3 and [r["reuse_mean"] for r in rows] == ["1.0", "2.0", "3.0"]
    assert all(r["wait_share"] == "0.25" and r["inserted"] == "7" for r in rows) and rows[0]["loss"]
    expected_stats = {"wait_share": 0.25, "reuse_mean": 3.0, "inserted": 7}
    assert summary["data_stats"] == expected_stats
    assert json.loads((tmp_path / "metrics.json").read_text())["data_stats"] == expected_stats
    assert load(tmp_path / "checkpoint.pt")["counters"]["data_stats"] == expected_stats
    assert list(_postfix(0.5, expected_stats)) == ["loss", "wait_share", "reuse_mean"]


def test_a_source_without_hooks_still_trains_and_checkpoints(tmp_path):
    class Plain(FakeSource):
        report_losses = stats = None

    model = build_model("fno", 1, 1, 1, 1, width=8, modes=4, layers=2)
    summary = train(model, DataLoader(Plain(), batch_size=None), 4, tmp_path, log_every=2, checkpoint_every=2)
    assert "data_stats" not in summary and "reuse_mean" not in read_csv(tmp_path / "metrics.csv")[0]
    ckpt = load(tmp_path / "checkpoint.pt")
    assert ckpt["step"] == 4 and ckpt["data"] is None  # a plain IterableDataset has no state to save


def test_a_damaged_checkpoint_or_run_file_is_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"format": 1, "steps": 5}))
    torch.save([1, 2, 3], run / "checkpoint.pt")
    assert cli.main(["train", "--resume", str(run)]) == 2
    assert "holds a list, not a dict" in capsys.readouterr().err
    torch.save({"format": 1, "step": 2}, run / "checkpoint.pt")
    assert cli.main(["train", "--resume", str(run)]) == 2
    assert "not a complete pdestream checkpoint: it lacks steps, model" in capsys.readouterr().err
    model = build_model("fno", 1, 1, 1, 1, width=8, modes=4, layers=2)
    train(model, DataLoader(FakeSource(), batch_size=None), 4, tmp_path / "ok", checkpoint_every=2)
    (run / "checkpoint.pt").write_bytes((tmp_path / "ok" / "checkpoint.pt").read_bytes())
    assert cli.main(["train", "--resume", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run.json is damaged: it lacks pde, source, model" in err and "Traceback" not in err


def test_resume_refuses_a_checkpoint_of_another_pde(tmp_path):
    def fit(meta, resume=None):
        torch.manual_seed(0)
        model = build_model("fno", 1, 1, 1, 1, width=8, modes=4, layers=2)
        return train(model, DataLoader(FakeSource(), batch_size=None), 4, tmp_path, checkpoint_every=2, meta=meta,
                     resume=resume)

    mine = {"pde": {"pde": "burgers1d", "n": 32, "nu": "0.01"}, "view": "next_step", "mode": {"name": "one-step"}}
    fit(mine)
    ckpt = load(tmp_path / "checkpoint.pt")
    ckpt["step"] = 2  # as if killed after its first checkpoint
    other = {**mine, "pde": {"pde": "burgers1d", "n": 64, "nu": "0.01"}}
    with pytest.raises(ValueError, match=r"belongs to another run: its PDE configuration is \{'n': 32\}, this run's is "
                                         r"\{'n': 64\}"):
        fit(other, resume=ckpt)
    with pytest.raises(ValueError, match="its training mode is"):
        fit({**mine, "mode": {"name": "oracle"}}, resume=ckpt)


def _tiny_train(out, *extra):
    return ["train", "burgers1d", *TINY_PDE, *TINY_MODEL, "--steps", "4", "--batch-size", "4", "--test-samples", "2",
            "--checkpoint-every", "2", "--threads", "1", "--out", str(out), *extra]


def _files(d: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir()) if p.is_file()}


def test_overwrite_never_loses_the_old_run_before_the_new_one_has_value(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    assert cli.main(_tiny_train(out)) == 0
    (out / "notes.txt").write_text("mine")  # not a run file: never removed
    old = _files(out)
    # a run that diverges: refused in one line, the old run byte for byte as it was, no staging directory left
    assert cli.main(_tiny_train(out, "--overwrite", "--lr", "1e30")) == 2
    assert "training diverged" in capsys.readouterr().err
    assert _files(out) == old and sorted(p.name for p in tmp_path.iterdir()) == ["run"]

    # Ctrl-C before the new run's first checkpoint: the old run stays, the new one's files go
    from pdestream.surrogate import train as T

    real = T.forever

    def interrupted(loader):
        for n, batch in enumerate(real(loader), 1):
            if n == 2:
                raise KeyboardInterrupt
            yield batch

    monkeypatch.setattr(T, "forever", interrupted)
    assert cli.main(_tiny_train(out, "--overwrite", "--seed", "1")) != 0
    assert "still holds the earlier run, untouched" in capsys.readouterr().err
    assert _files(out) == old and sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    monkeypatch.setattr(T, "forever", real)

    # a successful overwrite: the new run in place, the user's file kept, nothing beside it
    assert cli.main(_tiny_train(out, "--overwrite", "--seed", "1")) == 0
    new = _files(out)
    assert new["notes.txt"] == b"mine" and new["checkpoint.pt"] != old["checkpoint.pt"] and "metrics.json" in new
    assert json.loads(new["run.json"])["seed"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_refused_fresh_train_leaves_nothing(tmp_path, capsys):
    out = tmp_path / "fresh"
    # refused once the stream starts, after run.json was written (the corrected command was then refused)
    assert cli.main(_tiny_train(out, "--reservoir", "--producer", "dask", "--scheduler", "tcp://127.0.0.1:9")) == 2
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err
    assert not out.exists()


def test_reservoir_options_without_reservoir_and_zero_workers_are_refused(tmp_path, capsys):
    out = tmp_path / "r"
    assert cli.main(_tiny_train(out, "--capacity", "64", "--proposal", "loss")) == 2
    assert "--capacity, --proposal go with --reservoir" in capsys.readouterr().err
    assert cli.main(_tiny_train(out, "--reservoir", "--producer", "dask", "--workers", "0")) == 2
    assert "--workers=0 not allowed; must be >= 1" in capsys.readouterr().err
    assert cli.main(_tiny_train(out, "--reservoir", "--priority-floor", "0.5")) == 2
    assert "--priority-floor goes with --draw priority (prioritized replay)" in capsys.readouterr().err
    # proposal settings where no proposal uses them were silently ignored
    assert cli.main(_tiny_train(out, "--reservoir", "--proposal-floor", "0.5")) == 2
    assert "--proposal-floor goes with --proposal loss / active / generative" in capsys.readouterr().err
    assert cli.main(_tiny_train(out, "--reservoir", "--proposal-gate", "off")) == 2
    assert "--proposal-gate goes with --proposal loss / active / generative; nothing here uses it" in capsys.readouterr().err
    assert cli.main(_tiny_train(out, "--reservoir", "--proposal", "loss", "--proposal-ensemble", "3")) == 2
    # adv52: the words named every group's options for each ("... (--proposal-floor, ...) or --proposal active (the
    # others)"): now the proposal that uses this one, and the one given
    assert "--proposal-ensemble goes with --proposal active (not loss); nothing here uses it" in capsys.readouterr().err
    assert cli.main(["compare", "burgers1d", "--quick", "--arms", "fifo,reservoir", "--proposal-kappa", "2",
                     "--out", str(out)]) == 2
    assert "--proposal-kappa goes with the arm reservoir_active; nothing here uses it" in capsys.readouterr().err
    assert not out.exists()


def test_resume_with_more_steps_extends_a_finished_run_to_the_uninterrupted_longer_one(tmp_path, capsys):
    """`train --resume RUN --steps N` (constant schedule): the 20-step run extended to 30 ends bit for bit as
    the 30-step run; run.json records the extension; fewer steps than done, or the same total, are refused."""
    def fresh(out, steps):
        return {"argv": ["train", "burgers1d", *TINY_PDE, *TINY_MODEL, "--steps", str(steps), "--batch-size", "8",
                         "--schedule", "constant", "--checkpoint-every", "10", "--test-samples", "2", "--threads",
                         "1", "--out", str(out)]}

    whole, short = tmp_path / "whole", tmp_path / "short"
    for out, steps in ((whole, 30), (short, 20)):
        done = run_process(fresh(out, steps))
        assert done.returncode == 0, done.stderr
    first = load(short / "model.pt")["model"]
    extended = run_process({"argv": ["train", "--resume", str(short), "--steps", "30", "--threads", "1"]})
    assert extended.returncode == 0, extended.stderr
    assert f"extending {short} from 20 to 30 steps at its step 20" in extended.stdout
    assert_same_run(whole, short)
    assert not all(torch.equal(first[k], load(short / "model.pt")["model"][k]) for k in first)  # it did train on
    settings = json.loads((short / "run.json").read_text())
    assert settings["steps"] == 30 and settings["extended"] == [{"steps": 20, "at_step": 20}]
    assert settings["schedule"] == "constant"

    before = {p.name: p.stat().st_mtime_ns for p in short.iterdir()}
    for steps, needle in (("29", "the run already did 30 steps; allowed: an integer >= 30"),
                          ("30", "already complete (30 of 30 steps; see metrics.json); --steps N extends it")):
        assert cli.main(["train", "--resume", str(short), "--steps", steps]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err and "Traceback" not in err, err
    assert {p.name: p.stat().st_mtime_ns for p in short.iterdir()} == before
    assert cli.main(["train", "burgers1d", *TINY_PDE, "--schedule", "linear", "--out", str(tmp_path / "bad")]) == 2
    assert "unknown schedule 'linear'; allowed: cosine, onecycle, constant" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("name", ["cosine", "onecycle", "constant"])
def test_a_longer_run_replans_its_schedule_as_if_planned_so_from_the_start(name):
    from pdestream.surrogate.checkpoint import replan_schedule
    from pdestream.surrogate.train import make_schedule

    def adam():
        return torch.optim.Adam(torch.nn.Linear(2, 2).parameters(), lr=1e-2)

    short = adam()
    sched = make_schedule(short, name, 20, 1e-2)
    for _ in range(12):  # the checkpoint of a 20-step run at step 12
        short.step()
        sched.step()
    longer = adam()
    replanned = make_schedule(longer, name, 50, 1e-2)
    fresh = replanned.state_dict()
    longer.load_state_dict(copy.deepcopy(short.state_dict()))  # as checkpoint.restore does
    replan_schedule(replanned, longer, fresh, 12)
    reference = adam()
    planned = make_schedule(reference, name, 50, 1e-2)
    for _ in range(12):
        reference.step()
        planned.step()
    got, want = longer.param_groups[0], reference.param_groups[0]
    assert got["lr"] == want["lr"] and got["betas"] == want["betas"]
    assert (got["lr"] != short.param_groups[0]["lr"]) == (name != "constant")  # the 20-step curve was elsewhere


def test_a_run_being_resumed_refuses_a_second_resume_in_one_line(tmp_path, capsys):
    # two `train --resume RUN` at once both ran and both wrote the run
    import fcntl
    import os

    out = tmp_path / "run"
    assert cli.main(_tiny_train(out)) == 0
    capsys.readouterr()
    before = _files(out)
    fd = os.open(out, os.O_RDONLY)  # what the first resume holds while it trains (the same lock, taken here)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert cli.main(["train", "--resume", str(out), "--steps", "6"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is being trained by another process right now" in err, err
        assert _files(out) == before  # nothing touched
    finally:
        os.close(fd)
    assert cli.main(["train", "--resume", str(out), "--steps", "6"]) == 0  # free again: it resumes


def test_the_resume_line_says_whether_the_plan_grows_or_shrinks():
    """adv52: a run planned for 100000 steps, stopped at 1000 and resumed with --steps 1002 was "extending ... from
    100000 to 1002 steps"."""
    from pdestream.surrogate.launch import replan_line

    assert replan_line("r", 20, 30, 20) == ("extending r from 20 to 30 steps at its step 20; the cosine schedule is "
                                            "re-planned for 30 steps")
    assert replan_line("r", 100000, 1002, 1000, "constant").startswith("shortening r from 100000 to 1002 steps at its "
                                                                       "step 1000; the constant schedule")


def test_a_damaged_model_file_is_one_line(tmp_path):
    """adv52: load_checkpoint (a finished arm read back, predict) raised torch's UnpicklingError, a traceback."""
    from pdestream.surrogate.checkpoint import load_checkpoint

    (tmp_path / "model.pt").write_bytes(b"garbage\n")
    with pytest.raises(ValueError) as err:
        load_checkpoint(tmp_path / "model.pt")
    assert str(err.value).startswith(f"{tmp_path / 'model.pt'} is damaged (torch cannot read it: UnpicklingError)")
    assert "\n" not in str(err.value)
