"""Training modes (surrogate/modes.py): one-step, pushforward, oracle, solver-in-the-loop; their CLI and resume.

Tiny grids (burgers1d n=32, 11 frames) and tiny FNOs, so the whole file runs in seconds.
"""

import json

import pytest
import torch

from pdestream import cli, datasets, generator
from pdestream.surrogate import build_model
from pdestream.surrogate.modes import (
    Oracle,
    Pushforward,
    SolverInTheLoop,
    check_fits,
    make_mode,
    subsample,
    training_view,
)
from pdestream.surrogate.runs import resume_run, train_run
from tests.interrupt import interrupted_at

torch.set_num_threads(1)

PDE = generator.get_pde("burgers1d", n=32, n_frames=11)
FINE = generator.get_pde("burgers1d", n=64, n_frames=11)
TINY = {"width": 8, "modes": 4, "layers": 2}


def batch_of(pde, k_out: int, size: int = 6) -> dict:
    stream = datasets.TrajectoryStream(pde, seed=0, view=datasets.NextStep(1, k_out), batch_size=size, solve_batch=4)
    return next(iter(stream))


def norm_of(batch: dict) -> datasets.Normalization:
    return datasets.Normalization.from_batch(batch, 1)


def net(c_in: int = 1, c_out: int = 1, seed: int = 0):
    torch.manual_seed(seed)
    return build_model("fno", 1, c_in, c_out, 1, **TINY)


def bound(settings: dict, pde=PDE):
    return make_mode(settings).bind(pde, 0)


def train_steps(mode, pde, k_out: int, steps: int = 12) -> tuple[list[float], torch.nn.Module]:
    """A few Adam steps of ``mode`` on one fixed batch; the losses and the model."""
    batch = batch_of(pde, k_out)
    norm, model = norm_of(batch), net()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for step in range(1, steps + 1):
        loss, per = mode.step_loss(model, batch, norm, step)
        assert per.shape == (len(batch["x"]),) and per.dtype == torch.float64 and torch.isfinite(per).all()
        opt.zero_grad()
        loss.backward()
        if step == 1:  # every parameter of the network gets a finite, not all-zero gradient
            grads = [p.grad for p in model.parameters()]
            assert all(g is not None and torch.isfinite(g).all() for g in grads)
            assert sum(float(g.abs().sum()) for g in grads) > 0
        opt.step()
        losses.append(loss.item())
    return losses, model


@pytest.mark.parametrize("settings, pde, k_out", [
    ({"name": "one-step"}, PDE, 1),
    ({"name": "pushforward", "unroll": 3}, PDE, 3),
    ({"name": "oracle", "unroll": 3}, PDE, 1),
    ({"name": "solver-in-the-loop", "unroll": 3, "coarse_n": 16}, FINE, 3),
])
def test_each_mode_trains(settings, pde, k_out):
    losses, _ = train_steps(bound(settings, pde), pde, k_out)
    assert all(torch.isfinite(torch.tensor(losses)))
    assert min(losses[-3:]) < losses[0]  # fitting one batch: the loss goes down


def test_pushforward_gradient_skips_the_unrolled_steps():
    batch = batch_of(PDE, 3)
    norm, model = norm_of(batch), net()
    mode = bound({"name": "pushforward", "unroll": 3})
    n = mode.draws(1, 6)
    assert set(n.tolist()) <= {0, 1, 2} and len(set(n.tolist())) > 1
    loss, _ = mode.step_loss(model, batch, norm, 1)
    loss.backward()
    got = [p.grad.clone() for p in model.parameters()]
    p = norm.normalize_params(batch["params"])
    target = norm.normalize(batch["y"][torch.arange(6), n])  # the frame n+1 ahead of each example

    def by_hand(detach: bool):
        model.zero_grad()
        w = norm.normalize(batch["x"]).clone()
        for i in range(6):  # example i: n[i] network steps, detached or not
            for _ in range(int(n[i])):
                nxt = model(w[i : i + 1, 0], p[i : i + 1])[:, None]
                w = torch.cat([w[:i], nxt.detach() if detach else nxt, w[i + 1 :]])
        torch.nn.functional.mse_loss(model(w[:, 0], p), target).backward()
        return [q.grad for q in model.parameters()]

    # the same loss with the unrolled steps detached by hand: the same gradients (to rounding: other batching)
    assert all(torch.allclose(a, b, rtol=1e-4, atol=1e-7) for a, b in zip(got, by_hand(detach=True)))
    # with the gradient through the unrolled steps they differ (so the check above can fail)
    assert not all(torch.allclose(a, b, rtol=1e-4, atol=1e-7) for a, b in zip(got, by_hand(detach=False)))


def test_oracle_pairs_are_the_solvers_answers():
    batch = batch_of(PDE, 1, size=8)
    norm, model = norm_of(batch), net()
    mode = bound({"name": "oracle", "unroll": 3})
    step = 5
    j = mode.draws(step, 8)
    assert set(j.tolist()) <= {0, 1, 2, 3} and torch.equal(j, mode.draws(step, 8))  # a pure function of the step
    reached = mode.reached(model, norm, batch, step)
    p = norm.normalize_params(batch["params"])
    with torch.no_grad():  # the network unrolled j steps by hand
        w = norm.normalize(batch["x"])
        for i in range(8):
            for _ in range(int(j[i])):
                w[i : i + 1] = model(w[i : i + 1, 0], p[i : i + 1])[:, None]
    assert torch.allclose(reached, w, atol=1e-6)
    solver = datasets.SolverOracle(PDE)
    states = norm.denormalize(reached[:, -1])
    answer = solver(states, batch["params"])
    # from the stream's own state (j = 0) the solver's answer is the stream's next frame
    zero = j == 0
    assert zero.any() and (~zero).any()
    assert torch.allclose(answer[zero], batch["y"][zero, 0], rtol=1e-4, atol=1e-5)
    # the loss is the network's error on (reached state, solver answer)
    loss, _ = mode.step_loss(model, batch, norm, step)
    want = torch.nn.functional.mse_loss(model(reached[:, 0], p), norm.normalize(answer))
    assert torch.allclose(loss, want, rtol=1e-5)


def test_oracle_drops_states_the_solver_cannot_advance():
    batch = batch_of(PDE, 1, size=4)
    mode = Oracle(1, solver=datasets.SolverOracle(PDE))
    u = batch["x"][:, 0].clone()
    u[1] = float("nan")
    out = mode.answer(u, batch["params"])
    assert torch.isnan(out[1]).all() and torch.isfinite(out[[0, 2, 3]]).all()


def test_oracle_keeps_the_states_a_refusing_solver_takes_one_by_one():
    """A batch the solver refuses (a ValueError, e.g. BlowUpError) is solved state by state: the refused state's
    row is NaN, the others the solver's answers."""
    batch = batch_of(PDE, 1, size=4)
    solver = datasets.SolverOracle(PDE)

    def refusing(u, params, frames=1):
        if bool((u.abs() > 1e3).any()):
            raise ValueError("blew up")
        return solver(u, params, frames=frames)

    u = batch["x"][:, 0].clone()
    u[2] = 1e4
    out = Oracle(1, solver=refusing).answer(u, batch["params"])
    assert torch.isnan(out[2]).all()
    keep = [0, 1, 3]
    assert torch.equal(out[keep], solver(u[keep], batch["params"][keep]))


def test_solver_in_the_loop_differentiates_through_the_coarse_solver():
    batch = batch_of(FINE, 2)
    norm, model = norm_of(batch), net()
    mode = bound({"name": "solver-in-the-loop", "unroll": 2, "coarse_n": 16}, FINE)
    assert mode.factor == 4
    loss, _ = mode.step_loss(model, batch, norm, 1)
    loss.backward()
    through = [p.grad.clone() for p in model.parameters()]
    model.zero_grad()
    solver = mode.step
    mode.step = lambda s, params: solver(s.detach(), params)  # the solver as a constant: other gradients
    mode.step_loss(model, batch, norm, 1)[0].backward()
    assert not all(torch.allclose(a, b.grad) for a, b in zip(through, model.parameters()))
    # the coarse solver alone follows the fine solution subsampled (its rollout is what the network corrects)
    u = torch.cat([batch["x"], batch["y"]], 1)
    pred, truth = mode.rollout(None, norm, u, batch["params"])
    assert pred.shape == truth.shape == (6, 2, 1, 16)
    assert torch.equal(truth, subsample(u[:, 1:], 4, 1))
    assert float(((pred - truth).norm() / truth.norm())) < 0.05


def test_bad_settings_are_one_line():
    cases = [
        (lambda: make_mode({"name": "dagger"}), "unknown mode 'dagger'; allowed: one-step, pushforward"),
        (lambda: make_mode({"name": "pushforward", "unroll": 0}), "--unroll=0 not allowed"),
        (lambda: make_mode({"name": "one-step", "unroll": 3}), "--unroll=3 goes with"),
        (lambda: make_mode({"name": "oracle", "unroll": 2, "coarse_n": 16}), "--coarse-n=16 goes with solver-in-the-loop, not oracle"),
        (lambda: bound({"name": "solver-in-the-loop", "unroll": 2, "coarse_n": 24}, FINE),
         "coarse n=24 does not fit the fine grid n=64"),
        (lambda: training_view(Pushforward(2), datasets.Operator()), "needs the next_step view, not 'operator'"),
        (lambda: training_view(SolverInTheLoop(2), datasets.NextStep(2, 1)), "--k-in=2 not allowed"),
        (lambda: bound({"name": "oracle", "unroll": 2}, PDE.replace(refine=2)), "refine=2 not allowed here"),
        (lambda: bound({"name": "solver-in-the-loop", "unroll": 2, "coarse_n": 16}, PDE.replace(refine=2)),
         "solver-in-the-loop: refine=2 not allowed"),
        (lambda: check_fits(Pushforward(11), datasets.NextStep(1, 11), PDE), "allowed: --unroll <= 10"),
    ]
    for call, message in cases:
        with pytest.raises(ValueError, match=None) as err:
            call()
        assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


class Described:
    """Any view object, seen only through what it declares (ViewProtocol): not a NextStep nor any view class."""

    def __init__(self, view):
        self.view = view

    def __getattr__(self, name):
        return getattr(self.view, name)


def test_modes_ask_the_view_not_its_class():
    windows = Described(datasets.NextStep(2, 1, 4))
    assert training_view(Pushforward(3), windows) == datasets.NextStep(2, 3, 4)
    assert training_view(Oracle(3), windows) == datasets.NextStep(2, 1, 4)
    assert make_mode({"name": "one-step"}).frames_ahead(Described(datasets.NextStep(1, 3))) == 3
    assert make_mode({"name": "one-step"}).frames_ahead(Described(datasets.Operator())) == 1
    assert Pushforward(2).channels(PDE, windows) == (2, 1)
    check_fits(Pushforward(8), Described(datasets.NextStep(1, 8)), PDE)  # 9 of 11 frames: fits
    for call, message in [
        (lambda: training_view(Oracle(2), Described(datasets.Operator())), "needs the next_step view, not 'operator'"),
        (lambda: check_fits(Pushforward(11), Described(datasets.NextStep(1, 11)), PDE), "allowed: --unroll <= 10"),
        (lambda: training_view(SolverInTheLoop(2), windows), "--k-in=2 not allowed"),
        (lambda: datasets.Operator().ahead(2), "the 'operator' view has no frames ahead"),
    ]:
        with pytest.raises(ValueError) as err:
            call()
        assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


@pytest.mark.parametrize("argv, message", [
    (["--mode", "one-step", "--unroll", "3"], "--unroll=3 goes with pushforward, oracle or solver-in-the-loop, not one-step"),
    (["--mode", "pushforward", "--k-out", "2"], "--k-out=2 goes with --mode one-step"),
    (["--mode", "oracle", "--unroll", "0"], "--unroll=0 not allowed"),
    (["--mode", "pushforward", "--view", "operator"], "needs the next_step view"),
    (["--mode", "pushforward", "--unroll", "11"], "allowed: --unroll <= 10"),
    # --k-in alone too long: it said "allowed: --unroll <= -2" (and offered one-step an --unroll it does not take)
    (["--k-in", "13"], "allowed: --k-in <= 10 (or --set n_frames=14)"),
    (["--mode", "pushforward", "--k-in", "13"], "allowed: --k-in <= 7 (or --set n_frames=17)"),
    # adv52: the noise mode (no --unroll) was offered "--unroll <= 2", and one-step named an "--unroll 1"
    (["--mode", "noise", "--k-in", "9", "--k-out", "3"], "--mode noise with --k-in 9 and --k-out 3 needs 12 frames per "
                                                         "window but the trajectories have 11; allowed: --k-in <= 8"),
    (["--mode", "solver-in-the-loop", "--coarse-n", "12"], "coarse n=12 does not fit the fine grid n=32"),
    (["--mode", "oracle", "--set", "refine=2"], "burgers1d: refine=2 not allowed here"),
    (["--mode", "solver-in-the-loop", "--coarse-n", "16", "--set", "refine=2"], "solver-in-the-loop: refine=2 not"),
])
def test_cli_refuses_bad_modes_in_one_line(tmp_path, capsys, argv, message):
    out = tmp_path / "run"
    rc = cli.main(["train", "burgers1d", "--set", "n=32", "--set", "n_frames=11", "--steps", "2", "--out", str(out),
                   *argv])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (out / "run.json").exists()


def test_resume_continues_a_mode_run_exactly(tmp_path, monkeypatch):
    kw = dict(model_cfg=TINY, steps=6, batch_size=4, n_test=2, checkpoint_every=3,
              mode={"name": "oracle", "unroll": 2})
    whole = train_run(PDE, "stream", tmp_path / "whole", **kw)
    with interrupted_at(monkeypatch, 5), pytest.raises(KeyboardInterrupt):
        train_run(PDE, "stream", tmp_path / "cut", **kw)
    settings = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert settings["mode"] == {"name": "oracle", "unroll": 2} and settings["view_args"]["k_out"] == 1
    resumed, step = resume_run(tmp_path / "cut")
    assert step == 3 and resumed["mode"] == whole["mode"] == {"name": "oracle", "unroll": 2}
    a = torch.load(tmp_path / "whole" / "model.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_cli_compare_modes_quick(tmp_path, capsys):
    out = tmp_path / "cmp"
    rc = cli.main(["compare", "burgers1d", "--modes", "one-step,pushforward,oracle,solver-in-the-loop", "--quick",
                   "--unroll", "2", "--out", str(out)])
    text = capsys.readouterr().out
    assert rc == 0, text
    for name in ("compare.md", "compare.csv", "compare.json", "compare.png"):
        assert (out / name).is_file()
    result = json.loads((out / "compare.json").read_text())
    arms = [a["arm"] for a in result["arms"]]
    assert arms == ["one-step", "pushforward", "oracle", "coarse solver", "pairs (unroll 1)",
                    "pairs + noise (unroll 1)", "solver-in-the-loop (unroll 2)"]
    for a in result["arms"]:
        assert len(a["curve"]) == 10 and all(v == v for v in a["curve"])  # 10 frames rolled out, no NaN
        assert a["steps"] == (0 if a["arm"] == "coarse solver" else 20)
    assert "| oracle | 32 |" in text and "| coarse solver | 16 |" in text
    # a second run into the same directory is refused; mode options without --modes are refused
    assert cli.main(["compare", "--modes", "one-step", "--quick", "--out", str(out)]) == 2
    assert "holds a comparison with other --modes; rerun with its own settings" in capsys.readouterr().err
    assert cli.main(["compare", "--unroll", "3", "--out", str(tmp_path / "other")]) == 2
    assert not (tmp_path / "other").exists()
    assert cli.main(["compare", "--modes", "one-step,dagger", "--quick", "--out", str(tmp_path / "other")]) == 2
    assert "--modes one-step,dagger not allowed; choose from one-step" in capsys.readouterr().err


# --- the training loss: mse or relative -----------------------------------------------------------------
def test_relative_loss_is_the_mean_per_example_relative_l2_and_weighs_small_targets_alike():
    from pdestream.surrogate.modes import objective

    target = torch.tensor([[3.0, 4.0], [0.003, 0.004]])  # norms 5 and 0.005
    pred = target * torch.tensor([[1.1], [1.2]])  # 10% and 20% off
    assert objective("relative", pred, target).item() == pytest.approx(0.15)
    assert objective("mse", pred, target).item() == pytest.approx((0.3**2 + 0.4**2) / 4 + (0.0006**2 + 0.0008**2) / 4)
    # how much each example's relative error moves the loss: pred_i = (1 + s_i) target_i, d loss / d s_i equal
    # for both under "relative", the small one's a millionth of the large one's under MSE
    for loss, ratio in (("relative", 1.0), ("mse", 1e-6)):
        s = torch.tensor([0.1, 0.2], requires_grad=True)
        objective(loss, (1 + s)[:, None] * target, target).backward()
        got = float(s.grad[1] / s.grad[0]) * (0.1 / 0.2 if loss == "mse" else 1.0)  # (MSE's grows with s)
        assert got == pytest.approx(ratio, rel=1e-3), (loss, got)


@pytest.mark.parametrize("settings, pde, k_out", [
    ({"name": "one-step", "loss": "relative"}, PDE, 1),
    ({"name": "pushforward", "unroll": 3, "loss": "relative"}, PDE, 3),
    ({"name": "oracle", "unroll": 2, "loss": "relative"}, PDE, 1),
    ({"name": "solver-in-the-loop", "unroll": 2, "coarse_n": 16, "loss": "relative"}, FINE, 2),
])
def test_each_mode_trains_on_the_relative_loss(settings, pde, k_out):
    mode = bound(settings, pde)
    plain = {k: v for k, v in settings.items() if k != "loss"}
    assert mode.settings() == {**plain, "loss": "relative"} and bound(plain, pde).settings() == plain
    # the loss is the mean of the per-example relative errors the mode reports; the same mode on MSE is not
    batch = batch_of(pde, k_out)
    loss, per = mode.step_loss(net(), batch, norm_of(batch), 1)
    assert loss.item() == pytest.approx(per.mean().item(), rel=1e-4)
    mse, per_mse = bound(plain, pde).step_loss(net(), batch, norm_of(batch), 1)
    assert torch.allclose(per, per_mse) and abs(mse.item() - per.mean().item()) > 1e-3 * per.mean().item()
    losses, _ = train_steps(mode, pde, k_out)
    if settings["name"] != "oracle":  # (the oracle's states move with the network: 12 steps need not go down)
        assert min(losses[-3:]) < losses[0]


def test_cli_train_loss_relative_is_recorded_and_a_resume_keeps_it(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["train", "burgers1d", "--set", "n=32", "--set", "n_frames=11", "--steps", "4", "--batch-size", "4",
            "--model-set", "width=8", "--model-set", "modes=4", "--model-set", "layers=2", "--test-samples", "2"]
    assert cli.main([*args, "--loss", "relative", "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["mode"] == {"name": "one-step", "loss": "relative"}
    assert cli.main(["train", "--resume", str(out), "--steps", "6"]) == 0
    assert json.loads((out / "run.json").read_text())["mode"] == {"name": "one-step", "loss": "relative"}
    capsys.readouterr()
    assert cli.main(["compare", "burgers1d", "--loss", "relative", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "--loss relative goes with --budget or --sim-budget" in err and err.count("\n") == 1
    assert not (tmp_path / "c").exists()


def test_a_comparison_of_other_pde_settings_is_refused_naming_them(tmp_path):
    """adv51: `compare --modes` over a comparison of another grid said "holds a comparison with other the PDE"."""
    from pdestream.experiments.interactive_config import InteractiveConfig, check_same_comparison

    have = generator.get_pde("burgers1d", n=32, n_frames=4)
    (tmp_path / "compare.json").write_text(json.dumps({"pde": have.config(), "config": {"modes": ["one-step"]}}))
    cfg = InteractiveConfig(modes=("one-step",))
    with pytest.raises(ValueError, match=r"holds a comparison with other PDE settings \(n: the comparison's 32, "
                                         r"asked 48\); rerun with its own settings"):
        check_same_comparison(tmp_path, have.replace({"n": 48}), cfg)
    with pytest.raises(ValueError, match=r"with other --modes and PDE \(the comparison's burgers1d, asked ks1d\);"):
        check_same_comparison(tmp_path, generator.get_pde("ks1d"), InteractiveConfig(modes=("oracle",)))
    check_same_comparison(tmp_path, have, cfg)  # the same comparison: goes on


def test_modes_that_do_not_unroll_are_not_refused_for_the_default_unroll():
    """adv51: `compare --modes one-step,noise` on 4 frames was refused with "--unroll 4 needs trajectories of at
    least 6 frames", an option not given that neither mode takes (with --unroll 1 the same arms ran)."""
    from pdestream.experiments.interactive_config import InteractiveConfig

    short = generator.get_pde("burgers1d", n=32, n_frames=4)
    InteractiveConfig(modes=("one-step", "noise")).check(short)
    with pytest.raises(ValueError, match=r"^--unroll 4 needs trajectories of at least 6 frames; burgers1d has "):
        InteractiveConfig(modes=("one-step", "pushforward")).check(short)
    with pytest.raises(ValueError, match=r"^--k-in 4 needs trajectories of at least 6 frames; burgers1d has "):
        InteractiveConfig(modes=("one-step",), k_in=4).check(short)
