"""End-to-end refusals and small runs over the whole catalog through the `pdestream` CLI (in-process).

Cheap checks (no solve) run for every entry; the few that solve use one entry per kind of failure found by the
adversarial pass over the catalog."""

import numpy as np
import pytest

from pdestream import cli
from pdestream import generator as g

NAMES = list(g.PDES)


def run_cli(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def refused_in_one_line(capsys, tmp_path, name, *sets):
    """`generate NAME --set ...` is refused: exit 2, one stderr line, nothing written."""
    out = tmp_path / "x.zarr"
    argv = ["generate", name, "--n", "2", "--out", str(out)]
    for s in sets:
        argv += ["--set", s]
    code, _, err = run_cli(capsys, *argv)
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not out.exists() and list(tmp_path.iterdir()) == []
    return err.strip()


@pytest.mark.parametrize("name", NAMES)
def test_a_non_finite_parameter_value_is_named_as_such(capsys, tmp_path, name):
    # 'nan' and '1e400' are numbers to float(); the refusal said "expected a number or one of ..." before
    pde = g.get_pde(name)
    param = next(iter(pde.PARAMS), None)
    if param is None:
        pytest.skip(f"{name} has no parameters")
    for value in ("nan", "1e400"):
        err = refused_in_one_line(capsys, tmp_path, name, f"{param}={value}")
        assert f"'{value}' is not a finite number" in err and name in err and param in err, err


@pytest.mark.parametrize("name", NAMES)
def test_an_unknown_ic_kind_names_the_entry_and_only_the_kinds_that_fit_it(capsys, tmp_path, name):
    pde = g.get_pde(name)
    err = refused_in_one_line(capsys, tmp_path, name, "ic=bogus")
    fitting = pde.fitting_ic_kinds()
    assert err.startswith(f"pdestream: error: {name}: unknown ic kind 'bogus'; allowed: {', '.join(fitting)}"), err
    # every kind it offers is accepted (or its defaults refused by the entry's own rule on ic.* settings), every
    # other kind of the vocabulary is refused for its field count
    for kind in pde.IC_KINDS:
        if kind in fitting:
            try:
                assert g.get_pde(name, ic=kind).ic.kind == kind
            except ValueError as err:
                assert f"{name}: ic." in str(err) and "unknown" not in str(err) and "fields" not in str(err)
        else:
            with pytest.raises(ValueError, match=f"{name}: ic='{kind}' not allowed"):
                g.get_pde(name, ic=kind)


@pytest.mark.parametrize("name", NAMES)
def test_an_unknown_setting_is_refused_naming_the_allowed_ones(capsys, tmp_path, name):
    err = refused_in_one_line(capsys, tmp_path, name, "bogus=1")
    assert f"{name}: unknown setting 'bogus'; allowed: n, " in err, err


@pytest.mark.parametrize("name", ["fisher_kpp1d", "fisher_kpp2d"])
def test_fisher_kpp_refuses_initial_conditions_that_go_negative(capsys, tmp_path, name):
    # where u < 0 the reaction -r u^2 blows up in finite time: every trajectory of ic=grf or ic.offset=0 was
    # refused after solving as "blew up ... a smaller dt", which no dt fixes
    err = refused_in_one_line(capsys, tmp_path, name, "ic=grf")
    assert "unknown ic kind 'grf'; allowed: fourier" in err
    err = refused_in_one_line(capsys, tmp_path, name, "ic.offset=0.2")
    assert "ic.offset=0.2 with ic.amplitude=0.5 not allowed" in err and "need ic.offset >= ic.amplitude" in err
    assert g.get_pde(name, **{"ic.offset": 0.6}).ic.offset == 0.6


def test_grayscott3d_with_a_grf_initial_condition_takes_a_step_that_does_not_blow_up():
    # the step was dt = 1 whatever the IC; a GRF reaches |u0| ~ 4-5 on this grid and all 8 trajectories blew up
    pde = g.get_pde("grayscott3d", ic="grf", n=16, length=0.16, n_frames=3)
    bound = pde.ic.bound(pde.grid)
    assert bound > 2 and pde.stable_dt() <= 1 / bound**2
    assert g.get_pde("grayscott3d").stable_dt() == 1.0  # the spots' step (and samples) unchanged
    traj = g.sample(pde.replace(t_end=5 * pde.stable_dt()), range(4), seed=0)
    assert np.isfinite(np.asarray(traj.u)).all()


TINY_TRAIN = ["--steps", "2", "--batch-size", "2", "--test-samples", "1", "--checkpoint-every", "0"]


def test_train_on_a_steady_entry_defaults_to_its_operator_view(capsys, tmp_path):
    # the default view was next_step for every entry, so `pdestream train darcy2d` was refused until --view operator
    code, out, err = run_cli(capsys, "train", "darcy2d", "--set", "n=17", *TINY_TRAIN, "--out", str(tmp_path / "r"))
    assert code == 0, err
    assert "rel L2" in out and (tmp_path / "r" / "model.pt").exists()


@pytest.mark.parametrize("mode", ["pushforward", "oracle", "solver-in-the-loop"])
def test_an_unrolling_mode_on_a_steady_entry_is_refused_without_pointing_at_next_step(capsys, tmp_path, mode):
    code, _, err = run_cli(capsys, "train", "darcy2d", "--set", "n=17", "--mode", mode, *TINY_TRAIN,
                           "--out", str(tmp_path / "r"))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"--mode {mode} unrolls over frames and darcy2d is steady" in err and "--view next_step" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", NAMES)
def test_compare_defaults_never_refine_an_entry_and_fit_its_settings(name):
    # compare put n=64, n_frames=11 on every entry: 8x the points of a 3D entry (a reservoir refused for 16.5 GiB),
    # and an n_frames that darcy2d does not have ("unknown setting 'n_frames'", never typed by the user)
    from pdestream.experiments.command import compare_settings

    assert compare_settings(name, {"n": "16"})["n"] == "16"  # the user's own setting wins
    pde = g.get_pde(name, compare_settings(name, {}))
    assert pde.n == min(64, g.get_pde(name).n)


def test_a_budget_comparison_whose_arms_barely_trained_says_so():
    # compare grayscott2d --quick: 20 s per arm trained 0-1 steps per arm and the table ranked them anyway
    from pdestream.experiments.budget import MIN_STEPS, too_few_steps_note

    note = too_few_steps_note([{"arm": "precomputed", "steps": 0}, {"arm": "fifo", "steps": MIN_STEPS},
                               {"arm": "reservoir", "steps": 1}])
    assert note.startswith("**Not a comparison:** precomputed (0), reservoir (1) trained fewer than")
    assert too_few_steps_note([{"arm": "fifo", "steps": MIN_STEPS}]) == ""


@pytest.mark.slow
def test_compare_trains_a_3d_entry(capsys, tmp_path):
    # compare on a 3D entry was refused (no 3D model) until the 3D FNO; now both arms train (n=8: ~30 s)
    code, out, err = run_cli(capsys, "compare", "advection3d", "--steps", "2", "--seeds", "1", "--set", "n=8",
                             "--set", "ic.max_mode=2", "--out", str(tmp_path / "c"))
    assert code == 0 and "| cache |" in out and "| stream |" in out, err


def test_compare_budget_runs_on_the_steady_entry(capsys, tmp_path):
    # compare darcy2d --quick: refused for n_frames, then "operator: t_in=0 must come before t_out=-1", then the
    # training loop normalized the input field with the solution's statistics and fed both fields to the model
    code, out, err = run_cli(capsys, "compare", "darcy2d", "--quick", "--budget", "2", "--arms", "fifo,precomputed",
                             "--set", "n=17", "--test-samples", "4", "--out", str(tmp_path / "c"))
    assert code == 0, err
    assert "| fifo |" in out and "| precomputed |" in out and (tmp_path / "c" / "compare.png").exists()


def test_a_coarse_grid_the_entry_refuses_is_named_as_coarse_n(capsys, tmp_path):
    # the refusal spoke of ic.max_mode on n=16 while the user had set --coarse-n 16 (and n=32)
    code, _, err = run_cli(capsys, "train", "ks1d", "--set", "n=32", "--set", "length=12.566", "--set", "n_frames=3",
                           "--mode", "solver-in-the-loop", "--unroll", "1", "--coarse-n", "16", *TINY_TRAIN, "--out", str(tmp_path / "r"))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "solver-in-the-loop: --coarse-n 16 not allowed: ks1d: ic.max_mode=8 not allowed on n=16" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", NAMES)
def test_a_domain_on_a_fixed_setting_names_the_entry_and_the_settings_that_take_domains(capsys, tmp_path, name):
    err = refused_in_one_line(capsys, tmp_path, name, "n=uniform(8, 16)")
    params = ", ".join(g.PDES[name].PARAMS)
    assert err == (f"pdestream: error: {name}: bad value for n: 'uniform(8, 16)' is not an integer; n takes one value "
                   f"for every sample, only the parameters ({params}) take domains"), err
