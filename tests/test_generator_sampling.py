"""Sampler contract: determinism, no recompilation, registry-wide sanity, initial conditions, bad input."""

import functools

import jax
import numpy as np
import pytest

from pdestream import generator as g
from pdestream.generator.spectral.rollout import compiled_coefficients, compiled_setup, compiled_stages

# Small but non-trivial versions of every catalog entry, by one rule (no per-PDE code): a coarser grid with the
# same spacing (length shrinks with n, so CFL steps and resolution stay those of the default), 4 frames, and at
# most ~40 internal steps.
SMALL_N = {1: 64, 2: 32, 3: 16}


# The time-dependent entries; a steady one (darcy2d: no frames, no IC) has the same contract checked in
# tests/test_darcy.py (shapes, key discipline, bit-identity, no recompilation, refusals). The spectral family's
# (ETDRK4 rollouts of a drawn IC) are SPECTRAL; the flows' (MAC solver from rest) is checked in tests/test_flows.py.
TIMED = [name for name, cls in g.PDES.items() if not cls.STEADY]
SPECTRAL = [name for name, cls in g.PDES.items() if issubclass(cls, g.PDE)]


@functools.lru_cache(maxsize=None)
def small(name):
    pde = g.get_pde(name)
    n = min(pde.n, SMALL_N[pde.NDIM])
    coarse = pde.replace(n=n, length=pde.length * n / pde.n, n_frames=4)
    return coarse.replace(t_end=min(coarse.t_end, 40 * coarse.stable_dt()))


def test_every_catalog_entry_has_a_small_version():
    for name in SPECTRAL:
        pde = small(name)
        assert pde.n <= SMALL_N[pde.NDIM] and pde.steps_per_frame * (pde.n_frames - 1) <= 45, name


def dealiased(pde, field):
    """The 2/3-rule projection of a field, computed with numpy (independently of the solver)."""
    axes = tuple(range(-pde.NDIM, 0))
    f = np.fft.rfftn(np.asarray(field, np.float64), axes=axes)
    return np.fft.irfftn(f * pde.grid.dealias_mask(), s=pde.grid.shape, axes=axes)


@pytest.mark.parametrize("name", SPECTRAL)
def test_registry_sweep_shapes_finite_first_frame_and_params(name):
    pde = small(name)
    traj = g.sample(pde, [0, 7, 3], seed=11)
    u = np.asarray(traj.u)
    assert u.shape == (3, pde.n_frames, len(pde.FIELDS), *pde.grid.shape) and u.dtype == np.float32
    assert np.isfinite(u).all()
    assert traj.t.shape == (pde.n_frames,) and traj.t[0] == 0 and np.isclose(traj.t[-1], pde.t_end)
    assert list(traj.indices) == [0, 7, 3]
    # frame 0 is the initial condition drawn from the IC key of each sample (dealiased)
    for b, i in enumerate(traj.indices):
        _, k_ic = jax.random.split(g.sample_keys(11, np.array([i]))[0])
        ic = np.asarray(pde.sample_ic(k_ic))
        np.testing.assert_allclose(u[b, 0], dealiased(pde, ic), atol=1e-5 * max(1.0, np.abs(ic).max()))
    for pname, dom in pde.param_domains.items():
        lo, hi = dom.bounds
        assert np.all((np.asarray(traj.params[pname]) >= lo) & (np.asarray(traj.params[pname]) <= hi))
    assert np.abs(u[:, -1] - u[:, 0]).max() > 0  # it evolved


@pytest.mark.parametrize("name", SPECTRAL)
def test_sample_is_bit_identical_alone_and_in_any_batch(name):
    pde = small(name)
    alone = np.asarray(g.sample(pde, [5], seed=3).u[0])
    in_batch = np.asarray(g.sample(pde, [9, 5, 2], seed=3).u[1])
    in_bigger = np.asarray(g.sample(pde, list(range(12)), seed=3).u[5])
    assert np.array_equal(alone, in_batch) and np.array_equal(alone, in_bigger)
    other_seed = np.asarray(g.sample(pde, [5], seed=4).u[0])
    assert not np.array_equal(alone, other_seed)


@pytest.mark.parametrize("name", SPECTRAL)
def test_default_grids_resolve_their_defaults(name):
    # the top fifth of the retained (2/3-rule) modes holds a small share of the peak amplitude at every frame
    pde = g.get_pde(name)
    u = np.asarray(g.sample(pde, range(2), seed=0).u)
    uh = np.abs(np.fft.rfftn(u, axes=tuple(range(3, u.ndim))))
    m = pde.grid.max_abs_mode()
    band = (m > 0.8 * pde.n / 3) & (m <= pde.n // 3)
    tail = uh[..., band].max(-1) / uh.reshape(*uh.shape[:3], -1).max(-1)
    assert tail.max() < 0.05, (name, tail.max())


@pytest.mark.parametrize("name", SPECTRAL)
def test_new_parameters_never_recompile(name):
    pde = small(name)
    g.sample(pde, [7, 8, 11], seed=5)
    sizes = compiled_setup(pde)._cache_size(), _stages_compiled(pde)  # (other tests share the cache)
    for seed, idx in ((0, [0, 1, 2]), (1, [5, 6, 9]), (2, [100, 3, 4])):
        g.sample(pde, idx, seed=seed)
    # explicit values (a point of each domain) go through the same programs
    point = {k: float(np.mean(d.bounds)) if not isinstance(d, g.Choice) else d.options[0]
             for k, d in pde.param_domains.items()}
    g.sample(pde, [0, 1, 2], seed=0, params=point)
    assert (compiled_setup(pde)._cache_size(), _stages_compiled(pde)) == sizes


def _stages_compiled(pde):
    """Programs compiled so far for the rollout's bounded calls (generator.rollout.compiled_stages, both the
    per-sample and the shared-coefficient variants)."""
    return sum(f._cache_size() for shared in (False, True) for f in compiled_stages(pde, shared))


@pytest.mark.parametrize("name", ["ks1d", "burgers1d", "ks2d", "wave1d"])
def test_fixed_parameters_share_one_sample_coefficients_with_the_same_bits(name):
    """All parameters fixed: the set-up skips the coefficients and the rollout takes one copy for the batch
    (rollout.shared_coefficients), bit-identical to the samples of the drawn domain given those values, in
    whole-frame calls and in calls of one step."""
    from pdestream.generator import dispatch
    from pdestream.generator.spectral.rollout import shared_coefficients

    free = small(name)
    values = {k: float(np.mean(d.bounds)) for k, d in free.param_domains.items()}
    fixed = free.replace(dt=free.step_dt, **{k: repr(v) for k, v in values.items()})  # (KS: dt from the nu bounds)
    assert shared_coefficients(fixed) and not shared_coefficients(free)
    idx = np.arange(5)
    for work in (dispatch.DISPATCH_WORK, 1):  # whole frames per call; a frame in pieces of one step
        with dispatch.call_size(work):
            u = np.asarray(g.sample(fixed, idx, seed=2).u)
            ref = np.asarray(g.sample(free, idx, seed=2, params=values).u)
        assert np.isfinite(u).all() and np.array_equal(u, ref), (name, work)


def test_a_pde_without_parameters_samples():
    """No parameters: the per-sample coefficients (rollout.shared_coefficients is False; there is nothing to map
    the shared coefficients' program over)."""
    import dataclasses
    from typing import ClassVar

    from pdestream.generator.spectral.ks import KS
    from pdestream.generator.spectral.rollout import shared_coefficients

    @dataclasses.dataclass(frozen=True)
    class Unparametrised(KS):
        NAME: ClassVar[str] = "ks_no_params"
        PARAMS: ClassVar[dict] = {}

        def linear(self, grid, p):
            (k,) = grid.wavenumbers()
            return (k**2 - k**4)[None]

        def stable_dt(self):
            return 0.05

    pde = Unparametrised(n=64, length=25.0, t_end=1.0, n_frames=3, nu=1.0)
    assert not pde.param_domains and not shared_coefficients(pde)
    assert np.isfinite(np.asarray(g.sample(pde, [0, 1, 2]).u)).all()


def test_solve_never_recompiles_for_new_parameters():
    pde = g.get_pde("burgers1d", n=32, n_frames=3, t_end=0.1)
    x = pde.grid.coords()
    sizes = []
    for nu in (0.01, 0.03, 0.09):
        g.solve(pde, np.sin(2 * np.pi * x)[None, None].repeat(2, 0), {"nu": [nu, nu / 2]})
        sizes.append((compiled_coefficients(pde)._cache_size(), _stages_compiled(pde)))
    assert sizes[0][0] == 1 and sizes[0] == sizes[1] == sizes[2]


@pytest.mark.parametrize("name", TIMED)
def test_bad_values_of_every_entry_are_refused_in_one_line(name):
    pde = g.PDES[name]()
    bad = {"n": 7, "t_end": -1.0, "n_frames": 1, "length": 0.0}
    for key, value in bad.items():
        with pytest.raises(ValueError) as err:
            g.get_pde(name, **{key: value})
        msg = str(err.value)
        assert msg.startswith(f"{name}: ") and f"{key}=" in msg and "\n" not in msg, msg
    for pname, domain in pde.param_domains.items():
        outside = max(domain.bounds) + 1.0 + abs(max(domain.bounds))
        with pytest.raises(ValueError) as err:
            g.sample(pde, [0], params={pname: outside})
        msg = str(err.value)
        assert f"{pname}=" in msg and str(domain) in msg and "\n" not in msg, msg
        if pde.PARAMS[pname].positive:
            with pytest.raises(ValueError, match=f"{pname}=.*> 0"):
                g.get_pde(name, **{pname: "uniform(-1, 1)"})
    with pytest.raises(ValueError, match=f"{name}: unknown setting 'no_such_setting'; allowed: n, "):
        g.get_pde(name, no_such_setting=1)


def test_grf_has_the_declared_pointwise_variance():
    sigma, tau, alpha, length = 2.0, 3.0, 2.0, 1.0
    ic = g.GaussianRandomField(sigma=sigma, tau=tau, alpha=alpha, zero_mean=False)
    for ndim, n in ((1, 64), (2, 16)):
        grid = g.Grid(ndim, n, length)
        keys = jax.random.split(jax.random.key(0), 4000 // n ** (ndim - 1))
        u = np.asarray(jax.vmap(lambda k: ic.sample(k, grid, 1))(keys), np.float64)
        # closed form: Var u(x) = sum over retained modes m of sigma^2 (|2 pi m / L|^2 + tau^2)^-alpha / L^d
        m = np.arange(-(n // 3), n // 3 + 1)
        m2 = sum(x**2 for x in np.meshgrid(*([m] * ndim), indexing="ij"))
        expected = (sigma**2 * ((2 * np.pi / length) ** 2 * m2 + tau**2) ** -alpha).sum() / length**ndim
        # ~4000 x n correlated draws: a few percent of sampling error
        assert abs(u.var() / expected - 1) < 0.1, (ndim, u.var(), expected)


def test_fno_burgers_setup_is_a_config():
    pde = g.get_pde("burgers1d", n=1024, nu=0.1, t_end=1.0, n_frames=2)
    assert (pde.ic.sigma, pde.ic.tau, pde.ic.alpha) == (25.0, 5.0, 2.0)  # N(0, 625 (-Lap + 25 I)^-2)
    assert str(pde.nu) == "0.1" and pde.times().tolist() == [0.0, 1.0]
    assert g.from_config(pde.config()) == pde


def test_overrides_from_strings_and_config_round_trip():
    pde = g.get_pde("ns2d", {"n": "32", "nu": "loguniform(1e-2, 2e-2)", "forcing": "none", "ic.alpha": "3"})
    assert pde.n == 32 and pde.nu == g.LogUniform(1e-2, 2e-2) and pde.forcing == "none" and pde.ic.alpha == 3.0
    assert g.from_config(pde.config()) == pde
    assert pde.config_hash() != g.get_pde("ns2d").config_hash()


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda: g.get_pde("navier"), ["navier", "burgers1d"]),
        (lambda: g.get_pde("burgers1d", nu="loguniform(1e-3)"), ["loguniform(1e-3)", "2 number"]),
        (lambda: g.get_pde("burgers1d", nu="gauss(0, 1)"), ["gauss", "uniform"]),
        (lambda: g.get_pde("burgers1d", nu="uniform(0.1, abc)"), ["abc", "not a number"]),
        (lambda: g.get_pde("burgers1d", nu=-0.1), ["nu=-0.1", "> 0"]),
        (lambda: g.get_pde("burgers1d", nu="uniform(-0.1, 0.2)"), ["nu=uniform(-0.1, 0.2)", "> 0"]),
        (lambda: g.get_pde("burgers1d", n=-64), ["n=-64", ">= 8"]),
        (lambda: g.get_pde("burgers1d", n="many"), ["many", "int"]),
        (lambda: g.get_pde("burgers1d", dt=1.0), ["dt=1.0", "unstable", "dt <="]),
        (lambda: g.get_pde("burgers1d", viscosity=0.1), ["viscosity", "nu"]),
        (lambda: g.get_pde("burgers1d", **{"ic.gamma": 1}), ["ic.gamma", "ic.sigma"]),
        (lambda: g.get_pde("burgers1d", ic="smooth"), ["smooth", "grf"]),
        (lambda: g.get_pde("ns2d", forcing="shear"), ["shear", "kolmogorov"]),
        (lambda: g.sample("burgers1d", [-1]), ["-1", "indices"]),
        (lambda: g.sample("burgers1d", [0], on_blowup="ignore"), ["ignore", "redraw"]),
        (lambda: g.solve("burgers1d", np.zeros(7), {"nu": 0.1}), ["(7,)", "256"]),
        (lambda: g.solve("burgers1d", np.zeros(256), {"nu": -1.0}), ["nu", "> 0"]),
        (lambda: g.solve("burgers1d", np.zeros(256), {"mu": 1.0}), ["nu", "mu"]),
    ],
)
def test_bad_input_names_the_value_and_what_is_allowed(call, words):
    with pytest.raises(ValueError) as err:
        call()
    for word in words:
        assert word in str(err.value), (word, str(err.value))


def test_blow_up_is_reported_with_index_and_parameters():
    # an absurd velocity bound makes the derived step far too large for the advection: the solve blows up
    pde = g.get_pde("ns2d", n=32, n_frames=3, t_end=20.0, velocity_bound=1e-3, nu=0.01)
    with pytest.raises(g.BlowUpError) as err:
        g.sample(pde, [4, 2], seed=0)
    assert "index 4" in str(err.value) and "nu=0.01" in str(err.value) and "redraw" in str(err.value)
    with pytest.raises(g.BlowUpError, match="blew up"):
        g.sample(pde, [4], seed=0, on_blowup="redraw", max_redraws=2)


# --- explicit parameters: sample identity (config, seed, index, params) -----------------------------
@pytest.mark.parametrize("name, settings", [("burgers1d", {"n": 64, "n_frames": 4}),
                                            ("grayscott2d", {"n": 32, "n_frames": 3, "t_end": 20.0})])
def test_explicit_params_equal_the_drawn_sample_bit_for_bit(name, settings):
    pde = g.get_pde(name, **settings)
    drawn = g.sample(pde, [3, 4, 5], seed=7)
    values = {k: np.asarray(v) for k, v in drawn.params.items()}
    # alone, in another batch, in another order: the same bits as the drawn samples
    again = g.sample(pde, [5, 3, 4], seed=7, params={k: v[[2, 0, 1]] for k, v in values.items()})
    assert np.array_equal(np.asarray(again.u), np.asarray(drawn.u)[[2, 0, 1]])
    one = g.sample(pde, [4], seed=7, params={k: v[1:2] for k, v in values.items()})
    assert np.array_equal(np.asarray(one.u[0]), np.asarray(drawn.u[1]))


def test_explicit_params_change_the_solution_but_not_the_ic():
    pde = g.get_pde("burgers1d", n=64, n_frames=4)
    a = g.sample(pde, [0, 0], seed=1, params={"nu": [0.01, 0.1]})
    assert np.allclose(np.asarray(a.params["nu"]), [0.01, 0.1])
    assert np.array_equal(np.asarray(a.u[0, 0]), np.asarray(a.u[1, 0]))  # same key: same IC
    assert not np.allclose(np.asarray(a.u[0, -1]), np.asarray(a.u[1, -1]))  # other nu: other solution
    # a subset of parameters: the others are drawn from the key as usual
    gs = g.get_pde("grayscott2d", n=32, n_frames=2, t_end=10.0)
    drawn = g.sample(gs, [2], seed=0)
    part = g.sample(gs, [2], seed=0, params={"F": 0.04})
    assert float(part.params["F"][0]) == np.float32(0.04)
    assert float(part.params["k"][0]) == float(drawn.params["k"][0])


@pytest.mark.parametrize("params, message", [
    ({"nu": 0.5}, "nu=0.5 not allowed: outside its domain loguniform(0.01, 0.1)"),
    ({"nu": float("nan")}, "nu=nan not allowed"),
    ({"mu": 0.05}, "unknown parameter(s) ['mu']"),
    ({"nu": [0.05, 0.05, 0.05]}, "expected a scalar or [2]"),
])
def test_explicit_params_are_checked(params, message):
    with pytest.raises(ValueError) as err:
        g.sample("burgers1d", [0, 1], params=params)
    assert message in str(err.value)
