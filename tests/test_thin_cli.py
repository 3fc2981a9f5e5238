"""The CLI parses and dispatches: every command is a library call with its config, the options' defaults are the
configs', and a refused command or --help answers before JAX or torch is imported."""

import json
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
    (["compare", "burgers1d", "--out", "cmp", "--modes", "one-step", "--set", "n_frames=4", "--unroll", "4"], 2,
     "needs trajectories of at least 6 frames"),
]


@pytest.mark.parametrize("argv, code, said", LIGHT)
def test_help_and_refusals_import_neither_jax_nor_torch(tmp_path, argv, code, said):
    script = ("import contextlib, io, json, sys\nfrom pdestream import cli\nout, err = io.StringIO(), io.StringIO()\n"
              "with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):\n"
              f"    try:\n        rc = cli.main({argv!r})\n    except SystemExit as e:\n        rc = e.code\n"
              "print(json.dumps([rc, out.getvalue() + err.getvalue(), 'jax' in sys.modules, 'torch' in sys.modules]))")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    rc, said_there, jax, torch = json.loads(res.stdout.strip().splitlines()[-1])
    assert rc == code and said in said_there, (rc, said_there, res.stderr)
    assert not jax and not torch, f"{argv}: jax imported {jax}, torch imported {torch}"
    assert list(tmp_path.iterdir()) == []


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
