"""The surrogate package's structure: no import circle, one place for each piece of model-side logic."""

import ast
import re
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]


def _imports(package: str) -> dict[str, set[str]]:
    """module -> the modules of ``package`` it imports, anywhere in the file (a function-local import counts)."""
    graph = {}
    for path in (ROOT / package).glob("*.py"):
        mod, deps = path.stem, set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level == 1 and node.module:
                    deps.add(node.module.split(".")[0])
                elif node.level == 1:
                    deps.update(a.name for a in node.names)
                elif node.module and node.module.startswith(package + "."):
                    deps.add(node.module.split(".")[1])
        graph[mod] = deps - {mod}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state, stack = {}, []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state and (found := visit(d)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_surrogate_has_no_import_circle():
    """Counting function-local imports too: a local import that only hides a circle is still one."""
    assert _cycle(_imports("surrogate")) is None


def test_the_cycle_finder_finds_a_circle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_frames_are_stacked_into_channels_in_one_place():
    """``flatten(1, ...)`` of frames into channels is written only in surrogate/predict.py."""
    found = [p.name for p in (ROOT / "surrogate").glob("*.py") if p.name != "predict.py"
             and (".flatten(1, 2)" in p.read_text() or "u.flatten(1, u.ndim" in p.read_text())]
    assert found == []


class _Persistence(torch.nn.Module):
    """A 'network' that predicts no change: its rollout repeats the first frame (errors known by hand)."""

    ndim = 1

    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(()))

    def forward(self, x, p):
        return x + 0 * self.w


def _identity_norm(c: int, p: int):
    from pdestream.datasets.normalize import Normalization

    return Normalization(tuple(f"f{i}" for i in range(c)), torch.zeros(c), torch.ones(c),
                         tuple(f"p{i}" for i in range(p)), torch.zeros(p), torch.ones(p), 1)


def test_one_evaluator_against_hand_computed_errors():
    """Per-frame and whole-trajectory relative L2 of a persistence rollout, and the one-step and rollout figures
    a run reports, all from the one evaluator and equal to the errors computed by hand."""
    from pdestream import datasets
    from pdestream.surrogate.evaluate import error_stats, rollout_errors, test_errors

    gen = torch.Generator().manual_seed(0)
    u = torch.randn(5, 4, 1, 16, generator=gen)  # [N, T, C, x]
    test = [{"u": u[:3], "params": torch.zeros(3, 1), "index": torch.arange(3)},
            {"u": u[3:], "params": torch.zeros(2, 1), "index": torch.arange(3, 5)}]
    model, norm, view = _Persistence(), _identity_norm(1, 1), datasets.NextStep(1, 1)
    errors = rollout_errors(model, norm, test, view)
    by_hand = ((u[:, 1:] - u[:, :1]).flatten(2).norm(dim=2) / u[:, 1:].flatten(2).norm(dim=2)).double()  # [N, 3]
    assert errors.relative() == pytest.approx(by_hand.numpy(), rel=1e-6)
    whole = ((u[:, 1:] - u[:, :1]).flatten(1).norm(dim=1) / u[:, 1:].flatten(1).norm(dim=1)).double()
    assert errors.trajectory() == pytest.approx(whole.numpy(), rel=1e-6)
    assert error_stats(errors.trajectory())["max"] == pytest.approx(float(whole.max()), rel=1e-6)
    report = test_errors(model, norm, view, test)
    one_step = ((u[:, 1:] - u[:, :-1]).flatten(2).norm(dim=2) / u[:, 1:].flatten(2).norm(dim=2)).mean()
    assert report["rel_l2"] == pytest.approx(float(one_step), rel=1e-5)
    assert report["rollout"] == pytest.approx(by_hand.mean(0).tolist(), rel=1e-6)


def test_rollout_error_is_defined_once():
    """evaluate.py, modes.py and budget.py share one rollout-error definition: no module but evaluate.py loops
    rel_l2 over predicted frames."""
    found = [p.name for p in (ROOT / "surrogate").glob("*.py") if p.name != "evaluate.py"
             and "rel_l2(pred[:, j]" in p.read_text()]
    assert found == []


class _Batches(torch.utils.data.IterableDataset):
    """``n`` random batches {"x", "y": [4, 1, 16], "params": [4, 1], "index": [4]}, the same on every pass."""

    def __init__(self, n: int):
        self.n = n

    def __iter__(self):
        gen = torch.Generator().manual_seed(0)
        for i in range(self.n):
            x = torch.randn(4, 1, 16, generator=gen)
            yield {"x": x, "y": x.roll(1, -1), "params": torch.rand(4, 1, generator=gen), "index": torch.arange(4) + 4 * i}


def _model():
    from pdestream.surrogate import build_model

    torch.manual_seed(0)
    return build_model("fno", 1, 1, 1, 1, width=4, modes=2, layers=1)


class FakeClock:
    """``time.perf_counter`` for a module under test: 0.01 s more at every reading, whatever the machine does."""

    now = 1000.0

    def perf_counter(self) -> float:
        self.now += 0.01
        return self.now


def test_one_loop_stops_on_steps_seconds_or_the_end_of_one_pass(tmp_path, monkeypatch):
    """The loop that `train`, `compare` and the budget arms share: a stop rule, and a hook after every step."""
    from pdestream.surrogate import train as train_module
    from pdestream.surrogate.train import Stop, train

    seen = []
    s = train(_model(), torch.utils.data.DataLoader(_Batches(3), batch_size=None), Stop(steps=7), tmp_path / "a",
              after_step=lambda step, fraction, elapsed: seen.append((step, fraction)))
    assert s["steps"] == 7 and s["stop"] == "steps" and seen[-1] == (7, 1.0) and [a for a, _ in seen] == list(range(1, 8))
    s = train(_model(), torch.utils.data.DataLoader(_Batches(3), batch_size=None), Stop(steps=7, once=True),
              tmp_path / "b")
    assert s["steps"] == 3 and s["stop"] == "data"  # one pass of 3 batches, not 7 steps over epochs
    clock = FakeClock()  # a run of seconds by a clock that moves 0.01 s a reading: the same on any machine
    monkeypatch.setattr(train_module, "time", clock)
    elapsed = []
    s = train(_model(), torch.utils.data.DataLoader(_Batches(10**6), batch_size=None), Stop(seconds=0.5),
              tmp_path / "c", started=clock.now - 0.25, after_step=lambda step, fraction, t: elapsed.append(t))
    # it stops at the first step that ends past the deadline (0.25 s of it spent before the call)
    assert s["stop"] == "seconds" and s["steps"] == len(elapsed) >= 1
    assert max(elapsed[:-1], default=0) < 0.5 <= elapsed[-1] <= s["wall"] < 0.5 + 0.1
    rows = (tmp_path / "c" / "metrics.csv").read_text().splitlines()
    assert rows[-1].split(",")[0] == str(s["steps"])  # the last step is logged wherever the clock ended the run
    with pytest.raises(ValueError, match="schedule 'onecycle' needs a number of steps"):
        train(_model(), torch.utils.data.DataLoader(_Batches(3), batch_size=None), Stop(seconds=1.0), tmp_path / "d",
              schedule="onecycle")
    with pytest.raises(ValueError, match="exactly one"):
        Stop(steps=3, seconds=1.0).check()


def test_a_mode_owns_its_settings_defaults_and_cli_choices():
    """One table (surrogate/mode_table.py) gives the CLI's choices and help, the defaults and the checks; the
    modes are one class per row; nothing switches on a mode's class."""
    import subprocess
    import sys

    from pdestream import cli
    from pdestream.surrogate.mode_table import DEFAULTS, MODE_NAMES, mode_settings
    from pdestream.surrogate.modes import MODES, make_mode

    assert tuple(MODES) == MODE_NAMES
    train = next(a for a in cli.build_parser()._subparsers._group_actions[0].choices["train"]._actions
                 if a.dest == "mode")
    assert tuple(train.choices) == MODE_NAMES
    assert make_mode({"name": "solver-in-the-loop"}).settings() == {
        "name": "solver-in-the-loop", "unroll": DEFAULTS["unroll"], "coarse_n": DEFAULTS["coarse_n"]}
    assert make_mode({"name": "noise"}).settings()["noise"] == mode_settings("noise")["noise"] == DEFAULTS["noise"]
    assert make_mode({"name": "pushforward"}).settings() == mode_settings("pushforward") == {
        "name": "pushforward", "unroll": DEFAULTS["unroll"]}
    with pytest.raises(ValueError, match="--coarse-n=8 goes with solver-in-the-loop, not pushforward"):
        mode_settings("pushforward", coarse_n=8)
    for path in [*(ROOT / "surrogate").glob("*.py"), ROOT / "cli.py"]:
        text = path.read_text()
        if path.name != "mode_table.py":  # the coarse grid's default is written once
            assert not re.search(r"coarse_n[^\n]{0,24}\b64\b|\b64\b[^\n]{0,24}coarse_n", text), path.name
        assert "isinstance(mode" not in text, path.name
        assert '"one-step", "pushforward"' not in text or path.name == "mode_table.py", path.name
    # the CLI's parser reads the table without loading torch
    code = "import sys; from pdestream import cli; cli.build_parser(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert out.stdout.strip() == "False", out.stderr


def test_long_phases_report_plain_lines_when_stderr_is_not_a_terminal(tmp_path, capsys, monkeypatch):
    """Training and any phase longer than phases.EVERY seconds (test sets, rollouts) print plain periodic
    lines in a log (stderr is not a terminal under pytest's capture); a quick phase prints nothing."""
    import threading

    from pdestream.surrogate import phases
    from pdestream.surrogate.train import train

    with phases.phase("quick"):
        pass
    ticked, line = threading.Event(), phases._line

    def counted(text):  # the phase below lasts until its ticker has printed twice (no sleep racing the ticker)
        line(text)
        counted.n = getattr(counted, "n", 0) + ("still running" in text)
        if counted.n >= 2:
            ticked.set()

    monkeypatch.setattr(phases, "_line", counted)
    with phases.phase("building the test set", every=0.05):
        assert ticked.wait(60), "the phase printed no periodic lines"  # 60 s: only a hang guard
    err = capsys.readouterr().err
    assert "quick" not in err and err.count("building the test set: still running") >= 2
    assert re.search(r"building the test set: done in \d+ s", err)  # 0 s unless the machine is loaded
    monkeypatch.setattr(phases, "EVERY", 0.0)
    train(_model(), torch.utils.data.DataLoader(_Batches(3), batch_size=None), 4, tmp_path, log_every=1, label="arm")
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("arm: step")]
    assert lines[0].startswith("arm: step 1/4, ") and "loss" in lines[0] and len(lines) == 4


def _help_of(command: str, dest: str) -> str:
    from pdestream import cli

    sub = cli.build_parser()._subparsers._group_actions[0].choices[command]
    return next(a.help for a in sub._actions if a.dest == dest)


def test_lr_defaults_are_stated_where_train_and_compare_differ():
    """Both defaults show in --help (argparse adds them); compare's says why it differs from train's."""
    assert "three times" not in _help_of("train", "lr")
    assert "three times train's 1e-3, for the comparisons' small models" in _help_of("compare", "lr")


def test_compare_quick_alone_says_what_it_runs(tmp_path, capsys, monkeypatch):
    from pdestream import cli
    from pdestream.experiments import budget

    ran = []

    def stub(pde, out, cfg, shift_overrides=None):
        ran.append(cfg)
        Path(out).mkdir(parents=True)
        (Path(out) / "compare.md").write_text("table\n")

    monkeypatch.setattr(budget, "budget_compare", stub)
    assert cli.main(["compare", "--quick", "--out", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    assert ran[0].budget_s == 20.0 and "compare --quick: the budget comparison of the data routes" in out


def test_the_two_waiting_figures_are_named_apart(capsys):
    """The loop's data share (normalization draw included) and the reservoir's wait for solves (its own clock)
    were printed as two unexplained 'waiting' percentages."""
    from pdestream.surrogate.launch import run_report

    s = {"steps": 10, "wall": 5.0, "t_data": 1.0, "t_compute": 4.0, "data_share": 0.2, "trajectories_seen": 8,
         "final_loss": 0.1, "test": {"test": {"rel_l2": 0.1, "nrmse": 0.1}},
         "data_stats": {"inserted": 8, "evicted": 0, "reuse_mean": 1.0, "reuse_max": 2.0, "wait_share": 0.05}}
    print(run_report(s, "fno", "stream", 4, "run"))
    out = capsys.readouterr().out
    assert "waiting for data 1.0 s = 20.0% of the loop, normalization draw included" in out
    assert "waiting for solves 5.0% of the time since the first batch (the reservoir's own clock" in out


def test_one_set_of_argument_checks(tmp_path):
    """Every surrogate config refuses the same bad values in the same words (surrogate/checks.py): a bool is no
    count, a learning rate must be finite and > 0."""
    from pdestream import generator
    from pdestream.experiments.budget import BudgetConfig
    from pdestream.experiments.compare import CompareConfig, compare
    from pdestream.experiments.interactive_compare import InteractiveConfig

    pde = generator.get_pde("burgers1d", n=32, n_frames=6)
    cases = [
        (lambda: BudgetConfig(sim_budget=4, steps=True).check(), "--steps=True not allowed; must be an integer >= 1"),
        (lambda: BudgetConfig(sim_budget=4, lr=float("inf")).check(), "--lr=inf not allowed; must be a number > 0"),
        (lambda: InteractiveConfig(steps=True).check(pde), "--steps=True not allowed; must be an integer >= 1"),
        (lambda: InteractiveConfig(lr=0.0).check(pde), "--lr=0.0 not allowed; must be a number > 0"),
        (lambda: compare(pde, tmp_path / "c", CompareConfig(cache_samples=True)),
         "--cache-samples=True not allowed; must be an integer >= 1"),
        (lambda: compare(pde, tmp_path / "c", CompareConfig(lr=-1.0)), "--lr=-1.0 not allowed; must be a number > 0"),
    ]
    for call, message in cases:
        with pytest.raises(ValueError) as err:
            call()
        assert str(err.value) == message and "\n" not in str(err.value)
    assert not (tmp_path / "c").exists()
