"""The CLI parses and dispatches: every command is a library call with its config, the options' defaults are the
configs', and a refused command or --help answers before JAX or torch is imported."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pdestream import catalog_names, cli

ROOT = Path(__file__).resolve().parents[1]

# each: argv for cli.main, the exit status, what stderr (or stdout) says
LIGHT = [
    (["--help"], 0, "generate"),
    (["train", "burgers1d"], 2, "give --out RUN_DIR for a new run"),
    (["generate", "nosuchpde", "--n", "2", "--out", "x.h5"], 2, "unknown PDE 'nosuchpde'"),
    (["train", "nosuchpde", "--out", "run"], 2, "unknown PDE 'nosuchpde'"),
    (["compare", "burgers1d", "--out", "cmp", "--loss", "relative"], 2, "--loss relative goes with --budget"),
    # a bad --set value: the problem's own checks run without JAX (generator.lazy_jax) or torch
    (["generate", "burgers1d", "--n", "2", "--out", "x.h5", "--set", "n=-4"], 2, "n=-4 not allowed"),
    (["generate", "karman2d", "--n", "2", "--out", "x.h5", "--set", "re=abc"], 2, "parameter re: bad domain 'abc'"),
    (["generate", "pdearena_smoke2d", "--n", "2", "--out", "x.h5", "--set", "refine=0"], 2, "refine=0 not allowed"),
    (["train", "burgers1d", "--out", "run", "--set", "nu=abc"], 2, "parameter nu: bad domain 'abc'"),
    (["compare", "ks1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--set", "n=7"], 2, "n=7 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--budget", "5", "--shift-set", "nu=abc"], 2,
     "parameter nu: bad domain 'abc'"),
    (["compare", "burgers1d", "--out", "cmp", "--shift", "0"], 2, "--shift 0 would test on the training domain"),
    # train's own numbers: each imported torch before its refusal (3-4 s at load 8)
    (["train", "burgers1d", "--out", "run", "--threads", "0"], 2, "--threads=0 not allowed; must be >= 1"),
    (["train", "burgers1d", "--out", "run", "--batch-size", "0"], 2, "batch_size=0 not allowed"),
    (["train", "burgers1d", "--out", "run", "--lr", "nan"], 2, "lr=nan not allowed; must be a number > 0"),
    (["train", "burgers1d", "--out", "run", "--steps", "0"], 2, "steps=0 not allowed"),
    # adv51: these imported torch (3.6-5.3 s at load 5-8) before the same refusal
    (["train", "burgers1d", "--out", "run", "--seed", "-1"], 2, "--seed=-1 not allowed; must be an integer in [0, 2**31)"),
    (["train", "burgers1d", "--out", "run", "--k-in", "0"], 2, "--k-in=0 not allowed; must be an integer >= 1"),
    (["train", "burgers1d", "--out", "run", "--k-out", "-1"], 2, "--k-out=-1 not allowed; must be an integer >= 1"),
    (["train", "burgers1d", "--out", "run", "--solver-workers", "-1"], 2,
     "--solver-workers=-1 not allowed; must be an integer in [0, 256]"),
    (["train", "burgers1d", "--out", "run", "--solver-timeout", "nan"], 2,
     "--solver-timeout=nan not allowed; must be a number of seconds > 0"),
    (["train", "--resume", "run", "--solver-timeout", "inf"], 2,
     "--solver-timeout=inf not allowed; must be a number of seconds > 0"),
    (["train", "--resume", "run", "--threads", "0"], 2, "--threads=0 not allowed; must be >= 1"),
    (["train", "--resume", "run", "--ddp", "0"], 2, "--ddp=0 not allowed; must be an integer >= 1 (ranks)"),
    (["train", "--resume", "nowhere", "--steps", "8"], 2, "--resume nowhere: no such run directory"),
    # compare --modes' own options (stop 49): each imported torch before its refusal (3-6 s at load 8)
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step", "--clip", "1"], 2, "--clip goes with"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--clip", "-3"], 2, "--clip='-3'"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step", "--remat"], 2, "--remat goes with"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step", "--restrict", "points"], 2,
     "--restrict points goes with the corrector's arms"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--restrict", "spline"], 2,
     "--restrict='spline' not allowed; allowed: fourier, points"),
    (["compare", "burgers1d", "--out", "cmp", "--restrict", "points"], 2, "--remat and --restrict go with --modes"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--pairs-steps", "0"], 2,
     "--pairs-steps=0 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--budget", "-1"], 2,
     "--budget=-1.0 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--unroll-schedule", "0:1"], 2,
     "--unroll-schedule '0:1' not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step,nosuchmode"], 2, "--modes one-step,nosuchmode"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "pushforward", "--set", "n_frames=4", "--unroll", "4"], 2,
     "needs trajectories of at least 6 frames"),
    # adv51: one-step and noise take no --unroll (the window check refused the default one they do not take)
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step,noise", "--unroll", "4"], 2,
     "--unroll 4 goes with the modes that unroll (--modes ...,pushforward, oracle or solver-in-the-loop)"),
    # adv51: train --reservoir's numbers were refused when the reservoir was built, after torch (5-21 s at load 6-8)
    (["train", "burgers1d", "--out", "run", "--reservoir", "--capacity", "0"], 2,
     "capacity=0 not allowed; must be an integer >= 1"),
    (["train", "burgers1d", "--out", "run", "--reservoir", "--capacity", "4"], 2,
     "capacity=4 not allowed: must be >= batch_size (32)"),
    (["train", "burgers1d", "--out", "run", "--reservoir", "--max-reuse", "inf"], 2,
     "max_reuse=inf not allowed; must be a finite number >= 1"),
    (["train", "burgers1d", "--out", "run", "--reservoir", "--target-reuse", "0"], 2, "target_reuse=0.0 not allowed"),
    (["train", "burgers1d", "--out", "run", "--reservoir", "--draw", "priority", "--priority-floor", "nan"], 2,
     "priority_floor=nan not allowed"),
    (["train", "burgers1d", "--out", "run", "--reservoir", "--proposal", "loss", "--proposal-floor", "nan"], 2,
     "proposal floor=nan not allowed; must be in (0, 1]"),
    (["train", "burgers1d", "--out", "run", "--reservoir", "--proposal", "active", "--proposal-ensemble", "1"], 2,
     "proposal ensemble=1 not allowed; must be an integer >= 2"),
    # adv52: an ensemble of 10**8 trained (rc 0 at 2 steps); a longer run failed at its second refit
    (["train", "burgers1d", "--out", "run", "--reservoir", "--proposal", "active", "--proposal-ensemble", "100000000"],
     2, "proposal ensemble=100000000 not allowed; must be an integer >= 2"),
    (["train", "burgers1d", "--out", "run", "--reservoir", "--proposal", "active", "--proposal-kappa", "-1"], 2,
     "proposal kappa=-1.0 not allowed; must be in [0, 100]"),
    # adv51: the budget comparison's and the cache/stream comparison's numbers imported torch (4-7 s at load 5-8)
    (["compare", "burgers1d", "--out", "cmp", "--budget", "-1"], 2, "--budget=-1.0 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--quick", "--budget", "1e400"], 2, "--budget=inf not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--sim-budget", "0"], 2, "--sim-budget=0 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--budget", "5", "--sim-budget", "4"], 2, "give exactly one budget"),
    (["compare", "burgers1d", "--out", "cmp", "--quick", "--precompute-share", "nan"], 2,
     "precompute share=nan not allowed; must be in (0, 1)"),
    (["compare", "burgers1d", "--out", "cmp", "--quick", "--sim-warmup-share", "inf"], 2,
     "sim warm-up share=inf not allowed; must be in [0, 1]"),
    (["compare", "burgers1d", "--out", "cmp", "--sim-budget", "16", "--priority-cap", "0.5"], 2,
     "--priority-cap=0.5 not allowed; must be a number >= 1"),
    (["compare", "burgers1d", "--out", "cmp", "--budget", "5", "--seeds", "-1"], 2, "--seeds=-1 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--steps", "0"], 2, "--steps=0 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--lr", "inf"], 2, "--lr=inf not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--cache-samples", "0"], 2, "--cache-samples=0 not allowed"),
    (["compare", "burgers1d", "--out", "cmp", "--quick", "--capacity", "0"], 2,
     "capacity=0 not allowed; must be an integer >= 1"),
    (["compare", "burgers1d", "--out", "cmp", "--budget", "5", "--max-reuse", "nan"], 2,
     "max_reuse=nan not allowed; must be a finite number >= 1"),
    # adv51: --cache-samples -1 went unread (rc 0) where no cache of that size is written
    (["compare", "burgers1d", "--out", "cmp", "--quick", "--cache-samples", "-1"], 2,
     "goes with the cache/stream comparison (no --budget"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step", "--cache-samples", "8"], 2,
     "goes with the cache/stream comparison (no --budget"),
    # adv51: these ran (rc 0) with the option unread where no arm takes it
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step", "--fine-n", "64"], 2,
     "--fine-n 64 goes with the corrector's arms (--modes ...,solver-in-the-loop)"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step,pushforward", "--coarse-n", "16"], 2,
     "--coarse-n 16 goes with the corrector's arms (--modes ...,solver-in-the-loop)"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step", "--corrector-start", "zero"], 2,
     "--corrector-start zero goes with the corrector's arms (--modes ...,solver-in-the-loop)"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step,oracle", "--noise", "0.1"], 2,
     "--noise 0.1 goes with the noise mode or the corrector's arms (--modes ...,noise or ...,solver-in-the-loop)"),
    # adv52: the coarse grid offered was one the PDE refuses (15 for burgers1d, whose n is even; 4, below its 8)
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--set", "n_frames=6", "--fine-n", "30",
      "--coarse-n", "16"], 2, "coarse n=16 does not fit the fine grid n=30; allowed: a proper divisor of 30, e.g. 10"),
    (["train", "burgers1d", "--out", "run", "--mode", "solver-in-the-loop", "--set", "n=8", "--coarse-n", "16"], 2,
     "coarse n=16 does not fit the fine grid n=8; no proper divisor of 8 is a grid burgers1d takes: choose a finer "
     "grid"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--fine-n", "0"], 2,
     "--fine-n 0 not allowed: burgers1d: n=0 not allowed"),
    # adv52: --k-in 2 with the corrector was refused after torch; compare trained the other arms first (7 s)
    (["train", "burgers1d", "--out", "run", "--mode", "solver-in-the-loop", "--k-in", "2"], 2,
     "--mode solver-in-the-loop corrects one state at a time: --k-in=2 not allowed; use 1"),
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step,solver-in-the-loop", "--set", "n_frames=8",
      "--k-in", "2"], 2, "--mode solver-in-the-loop corrects one state at a time: --k-in=2 not allowed; use 1"),
    # adv52: a steady entry refused a mode that unrolls only after torch; --k-in / --k-out on the operator view (a
    # steady entry's default) ran rc 0, unread
    (["train", "poisson1d", "--out", "run", "--mode", "noise"], 2,
     "--mode noise perturbs input frames and poisson1d is steady (no frames); allowed: --mode one-step"),
    (["train", "poisson1d", "--out", "run", "--k-out", "2"], 2,
     "--k-out 2 goes with --view next_step; poisson1d is steady: its samples (input field -> solution) have no frames"),
    (["train", "poisson1d", "--out", "run", "--view", "next_step"], 2,
     "--view next_step needs a time axis and poisson1d is steady (no frames); allowed: --view operator"),
    (["train", "burgers1d", "--out", "run", "--view", "operator", "--k-in", "2"], 2,
     "--k-in 2 goes with --view next_step, not operator (u(t=0) -> u(t_end))"),
    # adv50: a coarse grid that does not fit the fine one was refused only when the corrector was bound (torch)
    (["compare", "burgers1d", "--out", "cmp", "--modes", "solver-in-the-loop", "--set", "n=32", "--coarse-n", "12"],
     2, "coarse n=12 does not fit the fine grid n=32"),
    (["train", "burgers1d", "--out", "run", "--mode", "solver-in-the-loop", "--set", "n=32", "--coarse-n", "12"],
     2, "coarse n=12 does not fit the fine grid n=32"),
]


def _light(argv, cwd) -> tuple[int, str, bool, bool]:
    """(exit status, stdout + stderr, JAX imported, torch imported) of ``cli.main(argv)`` in a fresh process."""
    script = ("import contextlib, io, json, sys\nfrom pdestream import cli\nout, err = io.StringIO(), io.StringIO()\n"
              "with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):\n"
              f"    try:\n        rc = cli.main({argv!r})\n    except SystemExit as e:\n        rc = e.code\n"
              "print(json.dumps([rc, out.getvalue() + err.getvalue(), 'jax' in sys.modules, 'torch' in sys.modules]))")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=cwd, timeout=120)
    assert res.stdout.strip(), res.stderr
    return tuple(json.loads(res.stdout.strip().splitlines()[-1]))


@pytest.mark.parametrize("argv, code, said", LIGHT)
def test_help_and_refusals_import_neither_jax_nor_torch(tmp_path, argv, code, said):
    rc, said_there, jax, torch = _light(argv, tmp_path)
    assert rc == code and said in said_there, (rc, said_there)
    assert not jax and not torch, f"{argv}: jax imported {jax}, torch imported {torch}"
    assert list(tmp_path.iterdir()) == []


TINY_TRAIN = ["--set", "n=16", "--set", "n_frames=3", "--batch-size", "2", "--test-samples", "1", "--threads", "1",
              "--model-set", "width=4", "--model-set", "modes=2", "--model-set", "layers=1"]
TINY_MODES = ["compare", "burgers1d", "--quick", "--modes", "one-step", "--test-samples", "2", "--threads", "1"]


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished 2-step run and a finished one-arm `compare --modes` (2 steps) under one directory."""
    root = tmp_path_factory.mktemp("finished")
    assert cli.main(["train", "burgers1d", *TINY_TRAIN, "--steps", "2", "--out", str(root / "run")]) == 0
    assert cli.main([*TINY_MODES, "--steps", "2", "--out", str(root / "cmp")]) == 0
    unfinished = root / "unfinished"  # the run as if stopped at its checkpoint of step 2 of 5
    shutil.copytree(root / "run", unfinished)
    (unfinished / "metrics.json").unlink()
    settings = json.loads((unfinished / "run.json").read_text())
    (unfinished / "run.json").write_text(json.dumps({**settings, "steps": 5}))
    for name, extra in (("c.h5", []), ("walls.h5", ["--set", "bc=dirichlet"]), ("z.zarr", [])):  # caches to train from
        assert cli.main(["generate", "burgers1d", "--n", "2", "--set", "n=16", "--set", "n_frames=3", *extra,
                         "--out", str(root / name)]) == 0
    for name, data in (("empty", b""), ("garbage", b"garbage\n")):  # checkpoint.pt emptied / overwritten
        shutil.copytree(unfinished, root / name)
        (root / name / "checkpoint.pt").write_bytes(data)
    for name, file, data in (("cmp_json", "run.json", b"{bad"), ("cmp_model", "model.pt", b"garbage\n")):
        shutil.copytree(root / "cmp", root / name)  # a finished arm's run.json / model.pt damaged
        (root / name / "one-step" / file).write_bytes(data)
    # a run trained on a cache that was then replaced by one of other settings (walls)
    shutil.copy(root / "c.h5", root / "src.h5")
    assert cli.main(["train", "--source", str(root / "src.h5"), *TINY_TRAIN[4:], "--steps", "2", "--out",
                     str(root / "on_cache")]) == 0
    shutil.copy(root / "walls.h5", root / "src.h5")
    shutil.copytree(root / "on_cache", root / "gone")  # a run whose cache is no longer there
    settings = json.loads((root / "gone" / "run.json").read_text())
    (root / "gone" / "run.json").write_text(json.dumps({**settings, "source": str(root / "moved.h5")}))
    import h5py

    for name, attrs in (("cut.h5", {"pdestream_complete": 0}), ("garbled.h5", {"pdestream_config": "{not json"}),
                        ("noname.h5", {"pdestream_config": '{"pde": 5}'}),
                        ("unknown.h5", {"pdestream_config": '{"pde": "nosuchpde", "n": 16}'}),
                        ("badn.h5", {"pdestream_config": '{"pde": "burgers1d", "n": "abc", "n_frames": 3}'})):
        shutil.copy(root / "c.h5", root / name)  # an interrupted generate's cache; one whose config is damaged
        with h5py.File(root / name, "r+") as f:
            f.attrs.update(attrs)
            if name == "cut.h5":
                f["complete"][1] = 0
    return root


def _unchanged(root):
    return {str(p): p.stat().st_mtime_ns for p in root.rglob("*")}


@pytest.mark.parametrize("argv, said", [
    # adv50: each was refused only after torch was imported (read_run loads checkpoint.pt; the arms were bound)
    (["train", "--resume", "{root}/run", "--steps", "1"], "the run already did 2 steps; allowed: an integer >= 2"),
    (["train", "--resume", "{root}/run"], "the run is already complete (2 of 2 steps; see metrics.json)"),
    ([*TINY_MODES, "--steps", "3", "--out", "{root}/cmp"], "holds a finished run with other settings (steps: the "
                                                            "run's 2, asked 3)"),
    # adv50: `train --resume` extended an arm of a comparison, which that comparison then refused
    (["train", "--resume", "{root}/cmp/one-step", "--steps", "4"], "is the one-step arm of the comparison in {root}/cmp"),
    # adv51: an unfinished run's step is in checkpoint.pt, read by torch (now: its pickle, torch-free)
    (["train", "--resume", "{root}/unfinished", "--steps", "1"], "the run already did 2 steps; allowed: an integer >= 2"),
    # adv51: the corrector's coarse grid against a cache's fine grid was refused only once the cache was open (torch)
    (["train", "--source", "{root}/c.h5", "--mode", "solver-in-the-loop", "--coarse-n", "12", "--out", "{root}/new"],
     "coarse n=12 does not fit the fine grid n=16"),
    (["train", "--source", "{root}/walls.h5", "--mode", "solver-in-the-loop", "--coarse-n", "8", "--restrict",
      "fourier", "--out", "{root}/new"], "--restrict fourier does not act on burgers1d (no periodic axis"),
    # a cache of another PDE, or of other --set, was refused once the loader opened it (torch)
    (["train", "--source", "{root}/c.h5", "--set", "bc=dirichlet", "--out", "{root}/new"],
     "was written with other settings (bc: cache 'periodic' vs asked 'dirichlet')"),
    (["train", "ns2d", "--source", "{root}/c.h5", "--out", "{root}/new"], "holds 'burgers1d' samples, not 'ns2d'"),
    # adv52: a run's cache replaced by one of other settings was refused after torch as "the checkpoint belongs to
    # another run"
    (["train", "--resume", "{root}/on_cache", "--steps", "4"], "--resume {root}/on_cache: its cache {root}/src.h5 "
                                                               "now holds other data (bc: the run's unset, the cache's "
                                                               "'dirichlet';"),
    # adv52: a finished arm's damaged run.json read as "other settings" (every key None, a 700-character line); its
    # damaged model.pt was a traceback (torch's UnpicklingError) after the test set was built
    ([*TINY_MODES, "--steps", "2", "--out", "{root}/cmp_json"], "{root}/cmp_json/one-step/run.json is damaged (not a "
                                                                "JSON object); pass --overwrite"),
    ([*TINY_MODES, "--steps", "2", "--out", "{root}/cmp_model"], "{root}/cmp_model/one-step/model.pt is damaged (not a "
                                                                 "torch.save file: truncated or overwritten); pass "
                                                                 "--overwrite"),
    # adv52: a run whose cache is gone was said after torch ("no cache at ...")
    (["train", "--resume", "{root}/gone", "--steps", "4"], "--resume {root}/gone: its cache {root}/moved.h5 is not "
                                                           "there"),
    # adv52: a run written into a Zarr cache's directory (rc 0): its files among the arrays, which a later
    # `generate --overwrite` then refuses as foreign entries
    (["train", "--source", "{root}/z.zarr", "--out", "{root}/z.zarr"], "--out {root}/z.zarr is a Zarr cache"),
    (["train", "--source", "{root}/c.h5", "--out", "{root}/z.zarr/run"], "--out {root}/z.zarr/run is inside the Zarr "
                                                                         "cache {root}/z.zarr"),
    ([*TINY_MODES, "--steps", "2", "--out", "{root}/z.zarr"], "--out {root}/z.zarr is a Zarr cache"),
    # adv52: an --out that holds a run was refused after torch (check_new)
    (["train", "--source", "{root}/c.h5", "--out", "{root}/run"], "{root}/run already holds a run (run.json, "
                                                                  "checkpoint.pt, model.pt, metrics.json); pass --resume"),
    # adv52: another initial condition was said as two whole dicts of its settings (a 400-character line)
    (["train", "--source", "{root}/c.h5", "--set", "ic=sines", "--out", "{root}/new"],
     "was written with other settings (ic.kind: cache 'grf' vs asked 'sines')\n"),
    # adv52: an interrupted generate's cache, a damaged config or a missing path were refused after torch (2-5 s),
    # and without a PDE named the damaged cache read "no PDE named"
    (["train", "--source", "{root}/cut.h5", "--out", "{root}/new"], "cut.h5 is incomplete (1 of 2 samples written)"),
    (["train", "--source", "{root}/garbled.h5", "--out", "{root}/new"], "garbled.h5 is damaged: attribute "
                                                                          "pdestream_config = '{{not json'"),
    (["train", "burgers1d", "--source", "{root}/garbled.h5", "--out", "{root}/new"], "garbled.h5 is damaged"),
    (["train", "--source", "{root}/none.h5", "--out", "{root}/new"], "--source {root}/none.h5: no such cache"),
    # adv52: a stored config naming no PDE read "no PDE named" (or "holds 5 samples"); one that does not build
    # named a setting the user never gave ("burgers1d: bad value for n")
    (["train", "--source", "{root}/noname.h5", "--out", "{root}/new"], "noname.h5 is damaged: its stored config "
                                                                        "(pdestream_config) names no PDE (5)"),
    (["train", "burgers1d", "--source", "{root}/noname.h5", "--out", "{root}/new"], "noname.h5 is damaged"),
    (["train", "--source", "{root}/unknown.h5", "--out", "{root}/new"], "unknown.h5 holds samples of 'nosuchpde', a "
                                                                         "PDE not known here: unknown PDE 'nosuchpde'"),
    (["train", "--source", "{root}/badn.h5", "--out", "{root}/new"], "badn.h5: its stored config does not build "
                                                                      "here: burgers1d: bad value for n"),
    # adv52: a window longer than the cache's trajectories was refused by the view after torch (4.6 s), in words
    # naming k_out (the unroll the user gave or left at its default was not named)
    (["train", "--source", "{root}/c.h5", "--mode", "solver-in-the-loop", "--coarse-n", "8", "--out", "{root}/new"],
     "--mode solver-in-the-loop with --unroll 4 and --k-in 1 needs 5 frames per window but the trajectories have 3; "
     "allowed: --unroll <= 2"),
    (["train", "--source", "{root}/c.h5", "--k-in", "3", "--out", "{root}/new"],
     "--mode one-step with --k-in 3 and --k-out 1 needs 4 frames per window but the trajectories have 3; allowed: "
     "--k-in <= 2 (or a cache of 4 frames)"),
    # adv52: an empty or overwritten checkpoint.pt was said after torch, as "(EOFError: )" or in torch's words
    # advising weights_only=False
    (["train", "--resume", "{root}/empty", "--steps", "9"], "{root}/empty/checkpoint.pt is damaged (empty)"),
    (["train", "--resume", "{root}/garbage", "--steps", "9"], "{root}/garbage/checkpoint.pt is damaged (not a "
                                                               "torch.save file"),
    # adv52: a finished arm of --k-in 1 was read back for --k-in 2 and failed in the rollout (the model's input
    # channels); --view operator with --modes ran rc 0 on the next-step view, the option unread
    ([*TINY_MODES, "--steps", "2", "--k-in", "2", "--out", "{root}/cmp"], "holds a finished run with other settings "
                                                                          "(k_in: the run's 1, asked 2)"),
    ([*TINY_MODES, "--steps", "2", "--view", "operator", "--out", "{root}/new"], "--view operator not allowed with "
                                                                                 "--modes"),
])
def test_refusals_read_from_run_json_come_before_torch(finished, argv, said):
    before = _unchanged(finished)
    argv = [a.format(root=finished) for a in argv]
    rc, err, jax, torch = _light(argv, finished)
    assert rc == 2 and said.format(root=finished) in err and err.count("\n") == 1, err
    assert not torch and not jax, f"{argv}: torch imported {torch}, jax imported {jax}"
    assert _unchanged(finished) == before


def test_every_entry_refuses_bad_settings_and_builds_its_defaults_without_jax():
    """Each catalog entry: an unknown setting, n=-4 and a bad domain for its first parameter refused, its defaults
    built, in one process that never imports JAX (the first entry that did is named)."""
    script = """
import json, sys
from pdestream import generator
from pdestream.catalog_names import NAMES
for name in NAMES:
    cls = generator.pde_class(name)
    bad = [{"bogus": "1"}, {"n": "-4"}] + [{p: "abc"} for p in list(cls.PARAMS)[:1]]
    for settings in bad:
        try:
            generator.get_pde(name, settings)
            raise SystemExit(f"{name}: {settings} was accepted")
        except ValueError:
            pass
    generator.get_pde(name)
    if "jax" in sys.modules:
        raise SystemExit(f"{name}: building it imported JAX")
print("ok", len(NAMES))
"""
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stdout.startswith("ok"), res.stdout + res.stderr


def test_the_jax_free_names_are_the_catalogs():
    from pdestream import generator

    assert list(catalog_names.NAMES.items()) == [(n, generator.GROUP[n]) for n in generator.PDES]
    for name in ("burgers1d", "mypkg.module:MyPDE", "exponax:Burgers", None):
        catalog_names.check_name(name)  # passes by form; the catalog loads it
    with pytest.raises(ValueError) as err:
        generator.pde_class("burgrs")
    assert str(err.value) == catalog_names.unknown_pde("burgrs", generator.user.names())


def test_the_options_defaults_are_the_configs():
    from pdestream.datasets.generate import GenerateConfig
    from pdestream.experiments.command import CompareCommand
    from pdestream.surrogate.config import TrainConfig

    parse = cli.build_parser().parse_args
    assert cli.train_config(parse(["train", "burgers1d", "--out", "run"])) == TrainConfig(pde="burgers1d", out="run")
    args = vars(parse(["generate", "burgers1d", "--n", "2", "--out", "a.h5"]))
    for key, value in vars(GenerateConfig()).items():
        if key in args and key not in ("n", "out", "pde"):
            assert args[key] == value, key
    got, want = vars(cli.compare_command(parse(["compare", "--out", "cmp"]))), vars(CompareCommand(out="cmp"))
    assert {k: v for k, v in got.items() if k != "reservoir"} == {k: v for k, v in want.items() if k != "reservoir"}


def test_generate_and_train_are_callable_with_their_configs(tmp_path, capsys):
    from pdestream.datasets import open_cache
    from pdestream.datasets.generate import GenerateConfig, generate
    from pdestream.surrogate.config import TrainConfig
    from pdestream.surrogate.launch import train

    tiny = {"n": 32, "n_frames": 4}
    cache = tmp_path / "b.h5"
    line = generate(GenerateConfig(pde="burgers1d", settings=tiny, n=3, out=str(cache), seed=1))
    assert str(cache) in line
    with open_cache(cache) as ds:
        assert ds.sizes["sample"] == 3
    lines = []
    s = train(TrainConfig(pde="burgers1d", settings=tiny, source=str(cache), out=str(tmp_path / "run"), steps=2,
                          batch_size=2, test_samples=1, threads=1,
                          model_cfg={"width": 4, "modes": 2, "layers": 1}), log=lines.append)
    assert s["steps"] == 2 and (tmp_path / "run" / "metrics.json").is_file()
    assert lines and lines[0].startswith("trained fno on ")
    # the same through the command line, which builds the same config
    assert cli.main(["train", "burgers1d", "--set", "n=32", "--set", "n_frames=4", "--source", str(cache), "--out",
                     str(tmp_path / "run2"), "--steps", "2", "--batch-size", "2", "--test-samples", "1",
                     "--threads", "1", "--model-set", "width=4", "--model-set", "modes=2", "--model-set",
                     "layers=1"]) == 0
    assert "trained fno on" in capsys.readouterr().out


def test_the_cli_only_parses_and_dispatches():
    text = (ROOT / "cli.py").read_text()
    assert len(text.splitlines()) < 400
    for heavy in ("import jax", "import torch", "os._exit", "signal.signal", "multiprocessing", "shutil"):
        assert heavy not in text, heavy


def test_the_command_finds_a_plug_in_in_the_current_directory(tmp_path):
    # `pdestream generate mypdes.damped:DampedBurgers` failed as the guide writes it (ModuleNotFoundError without
    # PYTHONPATH=.): the console script's sys.path holds its bin directory, not the current one
    import os
    import re
    import shutil

    script = shutil.which("pdestream") or pytest.skip("the pdestream command is not installed")
    guide = (Path(__file__).resolve().parent.parent / "docs" / "guides" / "own-pde.md").read_text()
    (tmp_path / "mypdes").mkdir()
    (tmp_path / "mypdes" / "__init__.py").write_text("")
    (tmp_path / "mypdes" / "damped.py").write_text(re.search(r"```python\n(.*?)```", guide, re.S).group(1))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([script, "list", "mypdes.damped:DampedBurgers"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "damped" in out.stdout.lower(), out.stderr


@pytest.mark.parametrize("extra, said", [
    (["--k-in", "9"], "--k-in 9 goes with --view next_step"),
    (["--k-out", "2"], "--k-out 2 goes with --view next_step"),
])
def test_compare_refuses_frames_options_with_the_operator_view(tmp_path, capsys, extra, said):
    assert cli.main(["compare", "burgers1d", "--out", str(tmp_path / "c"), *extra]) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1, err


@pytest.mark.parametrize("argv, option, value, allowed", [  # adv50: argparse printed its whole usage (30 lines)
    (["train", "burgers1d", "--out", "run", "--steps", "abc"], "--steps", "'abc'", "a whole number"),
    (["train", "burgers1d", "--out", "run", "--lr", "fast"], "--lr", "'fast'", "a number, e.g. --lr 0.001"),
    (["generate", "burgers1d", "--out", "x.h5", "--n", "2x"], "--n", "'2x'", "a whole number"),
    (["compare", "burgers1d", "--out", "cmp", "--budget", "1min"], "--budget", "'1min'", "a number"),
    (["compare", "burgers1d", "--out", "cmp", "--seeds", "1.5"], "--seeds", "'1.5'", "allowed: a whole number"),
    (["train", "burgers1d", "--out", "run", "--view", "nope"], "--view", "'nope'", "next_step"),
])
def test_a_bad_option_value_is_one_line_naming_it(capsys, argv, option, value, allowed):
    with pytest.raises(SystemExit) as exit:
        cli.main(argv)
    err = capsys.readouterr().err
    assert exit.value.code == 2 and err.count("\n") == 1 and err.startswith("pdestream: error: "), err
    assert option in err and value in err and allowed in err and "usage" not in err, err
