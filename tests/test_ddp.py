"""Many ranks: one reservoir per DDP rank fed with disjoint samples, training with averaged gradients, rank-keyed
resume. The 2-rank tests spawn two gloo ranks on the CPU with torch.multiprocessing (rendezvous through a file);
tiny: burgers1d n=32, 4 frames, an FNO of width 8, a few steps."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as tmp
from test_reservoir import take

from pdestream import cli, generator
from pdestream.datasets.ranks import RankReservoirStream, RankStates, check_world, placement
from pdestream.datasets.reservoir import ReservoirStream

try:
    import distributed
except ImportError:  # the optional dask extra
    distributed = None

SETTINGS = {"n": 32, "n_frames": 4}
PDE = generator.get_pde("burgers1d", **SETTINGS)
SEED = 3
STREAM = dict(seed=SEED, view="operator", batch_size=4, capacity=8, max_reuse=2, solve_batch=4, mode="deterministic",
              draw="least_used")
RESERVOIR = {"kind": "reservoir", "capacity": 8, "max_reuse": 2.0, "solve_batch": 4, "warmup": 4,
             "mode": "deterministic", "draw": "uniform"}
TINY_MODEL = {"width": 8, "modes": 4, "layers": 2}
STEPS, HALF = 8, 4


def same(a, b) -> bool:
    return len(a) == len(b) and all(x.keys() == y.keys() and all(torch.equal(x[k], y[k]) for k in x) for x, y in zip(a, b))


# --- one process: the rank's stream alone -------------------------------------------------------------
def test_one_rank_is_the_plain_reservoir_bit_for_bit():
    plain = take(ReservoirStream(PDE, **STREAM), 8)
    assert same(take(RankReservoirStream(PDE, rank=0, world_size=1, **STREAM), 8), plain)


def test_ranks_solve_disjoint_samples_that_cover_the_budget_within_the_bound():
    got = [take(RankReservoirStream(PDE, rank=r, world_size=2, sim_budget=10, **STREAM)) for r in (0, 1)]
    seen = [[i for b in batches for i in b["index"].tolist()] for batches in got]
    assert set(seen[0]) == {0, 2, 4, 6, 8} and set(seen[1]) == {1, 3, 5, 7, 9}  # rank r: k * 2 + r
    for r in (0, 1):  # every solve used up to its bound (operator view: 1 use = 1 example), never more
        assert all(seen[r].count(i) == 2 for i in set(seen[r]))
    ref = generator.sample(PDE, [7], SEED)  # a rank's example == the sample solved alone
    b, k = next((b, k) for b in got[1] for k, i in enumerate(b["index"].tolist()) if i == 7)
    assert np.array_equal(b["x"][k].numpy(), np.asarray(ref.u[0, 0])) and b["params"][k, 0].item() == float(ref.params["nu"][0])


def test_rank_states_and_run_refuse_another_world_size_in_one_line(tmp_path):
    stream = RankReservoirStream(PDE, rank=1, world_size=2, **STREAM)
    take(stream, 2)
    state = stream.state_dict()
    assert (state["rank"], state["world_size"]) == (1, 2)
    for bad in (dict(rank=0, world_size=2), dict(rank=1, world_size=3)):
        with pytest.raises(ValueError, match="^reservoir state was saved by rank 1 of 2; this stream is rank") as err:
            RankReservoirStream(PDE, **bad, **STREAM).load_state_dict(state)
        assert "\n" not in str(err.value)
    keyed = {"kind": "ranks", "world_size": 2, "ranks": [state, state]}
    for world in (1, 3):
        with pytest.raises(ValueError, match=rf"^the checkpoint was saved by 2 rank\(s\) and this run has {world}: "
                                             r"resume it with the same world size \(--ddp 2"):
            check_world(keyed, world)
    with pytest.raises(ValueError, match="saved by 1 rank"):
        RankStates(stream, 1, 2).load_state_dict(state)  # one process's state on two ranks
    with pytest.raises(ValueError, match="rank=2 not allowed; must be an integer in \\[0, 2\\)"):
        placement(2, 2)


# --- two gloo ranks -----------------------------------------------------------------------------------
def _rank_main(rank: int, world: int, work: str) -> None:
    """One rank (spawned): the stream twice, then training runs; what the tests compare to work/rank{rank}.pt."""
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{work}/rendezvous", rank=rank, world_size=world)
    from pdestream.surrogate import build_model
    from pdestream.surrogate.data import train_loader
    from pdestream.surrogate.runs import resume_run, train_run
    from pdestream.surrogate.train import train

    try:
        out = {"placement": placement()}
        # (1, 2) this rank's batches (placement from torch.distributed), twice from scratch
        runs = [take(RankReservoirStream(PDE, sim_budget=12, **STREAM)) for _ in range(2)]
        out["same_rerun"], out["batches"] = same(*runs), runs[0]
        # (3) the training loop on this rank's reservoir: the weights after STEPS steps, and who wrote files
        loader, _ = train_loader(PDE, "stream", "operator", 4, data_seed=SEED, data_cfg=RESERVOIR)
        torch.manual_seed(rank)  # different initial weights on purpose: rank 0's are broadcast
        model = build_model("fno", 1, 1, 1, 1, **TINY_MODEL)
        summary = train(model, loader, STEPS, Path(work) / f"direct{rank}", log_every=2, schedule="constant")
        loader.dataset.close()
        out["weights"], out["summary"] = model.state_dict(), {k: summary[k] for k in ("ranks", "examples_seen")}
        # (4) an uninterrupted run; a run of HALF steps extended by a resume to STEPS (constant schedule)
        kw = dict(model="fno", model_cfg=TINY_MODEL, view="operator", batch_size=4, schedule="constant", seed=SEED,
                  n_test=2, checkpoint_every=HALF, data_cfg=RESERVOIR)
        train_run(PDE, "stream", Path(work) / "whole", steps=STEPS, **kw)
        train_run(PDE, "stream", Path(work) / "half", steps=HALF, **kw)
        _, out["resumed_at"] = resume_run(Path(work) / "half", steps=STEPS)
        torch.save(out, Path(work) / f"rank{rank}.pt")
    finally:
        dist.destroy_process_group()


def _spawn(work: Path, world: int = 2) -> list[dict]:
    tmp.start_processes(_rank_main, args=(world, str(work)), nprocs=world, start_method="spawn", join=True)
    return [torch.load(work / f"rank{r}.pt", weights_only=False) for r in range(world)]


@pytest.mark.slow
def test_two_gloo_ranks_disjoint_reproducible_equal_weights_and_exact_resume(tmp_path, capsys):
    got = _spawn(tmp_path)
    assert [g["placement"] for g in got] == [(0, 2), (1, 2)]
    # (1) disjoint samples that together are 0..11, each used up to the bound; identity: == solved alone
    seen = [[i for b in g["batches"] for i in b["index"].tolist()] for g in got]
    assert set(seen[0]) == set(range(0, 12, 2)) and set(seen[1]) == set(range(1, 12, 2))
    assert all(s.count(i) == 2 for s in seen for i in set(s))
    ref = np.asarray(generator.sample(PDE, [5], SEED).u[0])
    b, k = next((b, k) for b in got[1]["batches"] for k, i in enumerate(b["index"].tolist()) if i == 5)
    assert np.array_equal(b["x"][k].numpy(), ref[0]) and np.array_equal(b["y"][k].numpy(), ref[-1])
    # (2) a rerun gives each rank the same batch sequence, bit for bit (and the ranks' sequences differ)
    assert got[0]["same_rerun"] and got[1]["same_rerun"] and not same(got[0]["batches"], got[1]["batches"])
    # (3) the weights are equal on both ranks after the steps; the examples are both ranks'; rank 0 wrote alone
    w0, w1 = got[0]["weights"], got[1]["weights"]
    assert w0.keys() == w1.keys() and all(torch.equal(w0[k], w1[k]) for k in w0)
    assert got[0]["summary"] == got[1]["summary"] == {"ranks": 2, "examples_seen": 2 * 4 * STEPS}
    assert (tmp_path / "direct0" / "model.pt").is_file() and not (tmp_path / "direct1").exists()
    # (4) resumed from the checkpoint at HALF steps: the uninterrupted run's weights and data states, bit for bit
    assert got[0]["resumed_at"] == got[1]["resumed_at"] == HALF
    whole, half = (torch.load(tmp_path / d / "model.pt", weights_only=True)["model"] for d in ("whole", "half"))
    assert all(torch.equal(whole[k], half[k]) for k in whole)
    ckpts = [torch.load(tmp_path / d / "checkpoint.pt", weights_only=True) for d in ("whole", "half")]
    assert ckpts[0]["data"] == ckpts[1]["data"] and ckpts[0]["data"]["state"]["world_size"] == 2
    states = ckpts[0]["data"]["state"]["ranks"]
    assert [(s["rank"], s["world_size"]) for s in states] == [(0, 2), (1, 2)]
    assert set(states[0]["reservoir"]["storage"]["index"]).isdisjoint(states[1]["reservoir"]["storage"]["index"])
    assert json.loads((tmp_path / "whole" / "run.json").read_text())["world_size"] == 2
    # (5) resuming with another world size is refused in one line: here (one process) and by the CLI's --ddp
    from pdestream.surrogate.runs import resume_run

    with pytest.raises(ValueError, match=r"trained on 2 rank\(s\) and this one has 1; resume it with the same "
                                         r"world size \(--ddp 2\)") as err:
        resume_run(tmp_path / "whole", steps=2 * STEPS)
    assert "\n" not in str(err.value)
    assert cli.main(["train", "--resume", str(tmp_path / "whole"), "--steps", str(2 * STEPS), "--ddp", "3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trained on 2 rank(s) and this one has 3" in err, err


@pytest.mark.slow
@pytest.mark.skipif(distributed is None, reason="dask not installed: pip install -e '.[dask]'")
def test_cli_ddp_one_dask_pool_equals_a_thread_per_rank_and_resumes(tmp_path, capfd):
    common = ["train", "burgers1d", "--set", "n=32", "--set", "n_frames=4", "--view", "operator",
              *[a for k, v in TINY_MODEL.items() for a in ("--model-set", f"{k}={v}")], "--batch-size", "4",
              "--test-samples", "2", "--reservoir", "--reservoir-mode", "deterministic", "--capacity", "8",
              "--solve-batch", "4", "--schedule", "constant", "--threads", "1", "--ddp", "2", "--seed", str(SEED)]
    threads, pool = tmp_path / "threads", tmp_path / "pool"
    assert cli.main([*common, "--steps", str(STEPS), "--out", str(threads)]) == 0
    out = capfd.readouterr().out  # (rank 0 prints from its own process: captured at the file descriptor)
    assert "on 2 ranks" in out and out.count("trained fno") == 1  # rank 0 alone reports
    # one embedded Dask cluster that both ranks' reservoirs submit to; half the steps, then resumed to STEPS
    assert cli.main([*common, "--steps", str(HALF), "--producer", "dask", "--workers", "1", "--out", str(pool)]) == 0
    assert cli.main(["train", "--resume", str(pool), "--steps", str(STEPS), "--ddp", "2", "--threads", "1"]) == 0
    assert f"resumed {pool} at step {HALF} of {STEPS}" in capfd.readouterr().out
    a, b = (torch.load(d / "model.pt", weights_only=True)["model"] for d in (threads, pool))
    assert all(torch.equal(a[k], b[k]) for k in a)  # who solves changes nothing: sample identity
    (tmp_path / "x.h5").touch()
    assert cli.main([*common, "--steps", "2", "--source", str(tmp_path / "x.h5"), "--out", str(tmp_path / "c")]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and "--ddp goes with --source stream" in err and not (tmp_path / "c").exists()


def test_more_ranks_than_cores_or_gpus_are_refused_in_one_line(tmp_path, capsys):
    # 64 ranks were started on a 2-core machine; --device cuda without a GPU failed inside the ranks
    import os

    base = ["train", "burgers1d", "--set", "n=32", "--set", "n_frames=3", "--source", "stream", "--steps", "1"]
    cores = len(os.sched_getaffinity(0))
    assert cli.main([*base, "--ddp", str(cores + 1), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--ddp {cores + 1} not allowed on the CPU here: {cores} core(s)" in err, err
    if not torch.cuda.is_available():
        assert cli.main([*base, "--ddp", "2", "--device", "cuda", "--out", str(tmp_path / "b")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "torch sees no GPU here" in err, err
    assert list(tmp_path.iterdir()) == []
