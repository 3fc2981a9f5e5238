"""The solver as an oracle for torch states and a differentiable solver step (issue 12, items 1-2).

Checked against things other than the code under test: frames the sampler produced (advance frame i by one frame
-> frame i+1), jax.grad of an independently composed scalar function, and central finite differences in float64.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

from pdestream import generator
from pdestream.datasets import SolverOracle, SolverStep, _bridge
from pdestream.generator.spectral import interactive, rollout
from pdestream.generator.spectral.rollout import _coefficients

# tiny, quick configurations: few frames, few internal steps per frame
BURGERS = dict(n=64, t_end=0.1, n_frames=6)
NS2D = dict(n=32, t_end=0.6, n_frames=4)
KDV = dict(n=32, t_end=0.3, n_frames=4)


def trajectories(name, settings, count=5):
    pde = generator.get_pde(name, **settings)
    return pde, _bridge.sample_tensors(pde, range(count), seed=3)


def rel(a, b):
    return float((a - b).abs().max() / b.abs().max())


# wave1d steps in its own basis (state_basis): the round trip fields -> basis amplifies rounding a little
@pytest.mark.parametrize("name, settings, tol", [("burgers1d", BURGERS, 1e-6), ("ns2d", NS2D, 1e-6),
                                                 ("wave1d", dict(n=64, n_frames=4), 5e-6)])
def test_one_frame_from_a_sampled_frame_is_the_next_sampled_frame(name, settings, tol):
    pde, t = trajectories(name, settings)
    oracle = SolverOracle(pde)
    u, params = t["u"], t["params"]
    for i in range(pde.n_frames - 1):
        assert rel(oracle(u[:, i], params), u[:, i + 1]) < tol  # float32 rounding (re-entering Fourier space)
    k = pde.n_frames - 1
    assert rel(oracle(u[:, 0], params, frames=k), u[:, k]) < tol
    # not a constant map: a frame later is far from the frame itself
    assert rel(oracle(u[:, 0], params), u[:, 0]) > 1e-3


def test_config_dict_and_catalog_name_give_the_same_solver():
    pde, t = trajectories("burgers1d", BURGERS, 2)
    by_dict = SolverOracle(pde.config())(t["u"][:, 1], t["params"])
    by_name = SolverOracle("burgers1d")
    assert by_name.param_names == ["nu"] and SolverOracle(pde).param_names == ["nu"]
    assert torch.equal(by_dict, SolverOracle(pde)(t["u"][:, 1], t["params"]))


@pytest.mark.parametrize("name, settings", [("burgers1d", BURGERS), ("ns2d", NS2D), ("kdv1d", KDV)])
def test_an_element_alone_and_in_a_batch_is_bit_identical(name, settings):
    pde, t = trajectories(name, settings)
    oracle = SolverOracle(pde)
    u, params = t["u"][:, 1], t["params"]
    batch = oracle(u, params, frames=2)
    for j in range(len(u)):
        assert torch.equal(oracle(u[j : j + 1], params[j : j + 1], frames=2)[0], batch[j])
    assert torch.equal(oracle(u[[3, 1]], params[[3, 1]], frames=2), batch[[3, 1]])
    # the differentiable step is another program: equal to rounding only (as its docstring says)
    step = SolverStep(pde, frames=2)
    with_grad = step(u.clone().requires_grad_(True), params)
    assert rel(with_grad.detach(), batch) < 1e-6
    with torch.no_grad():  # without gradients the step runs the oracle's program
        assert torch.equal(step(u, params), batch)


def test_new_parameters_and_states_never_recompile():
    pde, t = trajectories("burgers1d", BURGERS, 8)
    oracle = SolverOracle(pde)
    oracle(t["u"][:, 0], t["params"])
    before = _advance_compiled(pde), interactive._setup(pde)._cache_size()
    oracle(t["u"][:, 2], t["params"].flip(0) * 0.9)
    assert (_advance_compiled(pde), interactive._setup(pde)._cache_size()) == before


def _advance_compiled(pde) -> int:
    """Programs compiled so far for ``interactive.advance``'s bounded calls (generator.rollout.advance_bounded)."""
    return sum(f._cache_size() for f in (*rollout.compiled_state(pde), rollout.compiled_stages(pde)[3]))


def test_memoised_coefficients_give_the_bits_of_fresh_ones():
    pde, t = trajectories("kdv1d", KDV, 3)
    oracle = SolverOracle(pde)
    again = oracle(t["u"][:, 1], t["params"])  # coefficients of these parameters now memoised
    interactive._cache.clear()
    fresh = oracle(t["u"][:, 1], t["params"])
    assert torch.equal(again, fresh) and torch.equal(oracle(t["u"][:, 1], t["params"]), fresh)
    assert any(key[0] == pde for key in interactive._cache)


def test_the_coefficient_cache_stays_within_its_bytes(monkeypatch):
    pde, t = trajectories("burgers1d", BURGERS, 8)
    oracle = SolverOracle(pde)
    interactive._cache.clear()
    one_chunk = None
    for i in range(6):  # new parameters each call: a new chunk each time
        oracle(t["u"][:, 0], t["params"] * (1 + 0.01 * i))
        one_chunk = one_chunk or interactive._cache_bytes[0]
        monkeypatch.setattr(interactive, "COEFFICIENT_CACHE_BYTES", 3 * one_chunk)
    held = sum(interactive._nbytes(c) for c in interactive._cache.values())
    assert len(interactive._cache) == 3 and held == interactive._cache_bytes[0] <= 3 * one_chunk


def independent_scalar(pde, frames, g):
    """sum(g * u_k) composed without generator.interactive's chunking or its VJP plumbing: jax.grad's reference."""
    def f(u, p):
        c = jax.vmap(lambda q: _coefficients(pde, q))(p)
        return jnp.sum(g * jax.vmap(lambda a, q, cc: interactive._advance_one(pde, frames, a, q, cc))(u, p, c))
    return f


@pytest.mark.parametrize("name, settings", [("burgers1d", BURGERS), ("ns2d", NS2D), ("kdv1d", KDV)])
def test_vjp_equals_jax_grad_to_float32_rounding(name, settings):
    pde, t = trajectories(name, settings, 3)
    u = jnp.asarray(t["u"][:, 1].numpy())
    p = {n: jnp.asarray(t["params"][:, j].numpy()) for j, n in enumerate(pde.PARAMS)}
    g = jax.random.normal(jax.random.key(0), u.shape)
    _, _, vjp = interactive.advance_vjp(pde, u, p, 2)
    g_u, g_p = vjp(g)
    ref_u, ref_p = jax.grad(independent_scalar(pde, 2, g), argnums=(0, 1))(u, p)
    assert float(jnp.max(jnp.abs(g_u - ref_u)) / jnp.max(jnp.abs(ref_u))) < 2e-6
    for n in pde.PARAMS:
        assert float(jnp.max(jnp.abs(g_p[n] - ref_p[n])) / jnp.max(jnp.abs(ref_p[n]))) < 2e-6, n
        assert float(jnp.min(jnp.abs(ref_p[n]))) > 0  # the parameter does move the result


def test_torch_step_gradients_are_the_jax_vjp_for_non_contiguous_inputs():
    pde, t = trajectories("kdv1d", KDV, 4)
    step = SolverStep(pde, frames=2)
    base = t["u"][:, 1]
    u = base.transpose(0, 2).contiguous().transpose(0, 2).requires_grad_(True)  # same values, not contiguous
    params = t["params"].t().contiguous().t().requires_grad_(True)
    assert not u.is_contiguous() and not params.is_contiguous()
    g = torch.randn(base.shape, generator=torch.Generator().manual_seed(0))
    out = step(u, params)
    (out * g.expand(2, *g.shape)[0]).sum().backward()
    _, _, vjp = interactive.advance_vjp(pde, jnp.asarray(base.numpy()),
                                        {n: jnp.asarray(t["params"][:, j].numpy()) for j, n in enumerate(pde.PARAMS)}, 2)
    ref_u, ref_p = vjp(jnp.asarray(g.numpy()))
    assert torch.equal(u.grad, torch.from_numpy(np.array(ref_u)))
    assert torch.equal(params.grad, torch.stack([torch.from_numpy(np.array(ref_p[n])) for n in pde.PARAMS], 1))


def test_state_only_gradients_and_a_reused_graph():
    pde, t = trajectories("burgers1d", BURGERS, 3)
    step = SolverStep(pde)
    u = t["u"][:, 1].clone().requires_grad_(True)
    params = t["params"]  # no gradient wanted for the parameters
    out = step(u, params)
    loss = (out**2).sum()
    (first,) = torch.autograd.grad(loss, u, retain_graph=True)
    (second,) = torch.autograd.grad(loss, u)
    assert torch.equal(first, second) and first.abs().max() > 0
    # unrolled: two steps of one frame equal one step of two frames, gradients included (to rounding)
    u2 = t["u"][:, 1].clone().requires_grad_(True)
    (SolverStep(pde, frames=2)(u2, params) ** 2).sum().backward()
    u1 = t["u"][:, 1].clone().requires_grad_(True)
    (step(step(u1, params), params) ** 2).sum().backward()
    assert rel(u1.grad, u2.grad) < 1e-5


@pytest.mark.parametrize("name, settings", [("burgers1d", dict(n=16, t_end=0.02, n_frames=2)),
                                            ("ns2d", dict(n=8, t_end=0.1, n_frames=2, forcing_wavenumber=1))])
def test_gradients_match_float64_finite_differences(name, settings):
    pde, t = trajectories(name, settings, 2)
    with jax.enable_x64(True):  # scoped: switched back off for every other test
        step = SolverStep(pde)
        u = t["u"][:, 0].double().requires_grad_(True)
        params = t["params"].double().requires_grad_(True)
        # every entry of the Jacobian, state and parameter columns, central differences, 1e-6 relative
        assert torch.autograd.gradcheck(step, (u, params), eps=1e-6, atol=1e-9, rtol=1e-6, fast_mode=False)
        out = step(u, params)
        assert out.dtype == torch.float64
    assert not jax.config.jax_enable_x64


def test_x64_outside_its_scope_is_refused_in_one_line():
    pde, t = trajectories("burgers1d", BURGERS, 2)
    with pytest.raises(ValueError, match="float64 only with jax_enable_x64"):
        SolverOracle(pde)(t["u"][:, 0].double(), t["params"])


def bad_inputs():
    u = torch.zeros(2, 1, 64)
    p = torch.full((2, 1), 0.05)
    return [
        (lambda o: o(u[..., :32], p), r"state has shape \[2, 1, 32\]; expected \[B, 1, 64\]"),
        (lambda o: o(u[0], p), r"state has shape \[1, 64\]"),
        (lambda o: o(u, p, frames=0), r"frames=0 not allowed: need an integer >= 1"),
        (lambda o: o(u, p, frames=1.5), r"frames=1.5 not allowed"),
        (lambda o: o(u, p[:1]), r"params \[1, 1\] not allowed: need a tensor \[2, 1\] with columns \['nu'\]"),
        (lambda o: o(u, torch.full((2, 1), 5.0)), r"nu=5 not allowed: outside its domain loguniform\(0.01, 0.1\)"),
        (lambda o: o(u, torch.full((2, 1), float("nan"))), r"nu=nan not allowed"),
        (lambda o: o(u.to(torch.float16), p), r"state dtype torch.float16 not allowed: float32"),
        (lambda o: o(u.numpy(), p), r"state must be a torch.Tensor \[B, 1, 64\], got ndarray"),
        (lambda o: o(u.to("meta"), p), r"params are on cpu but the state is on meta"),
        (lambda o: o(u.to("meta"), p.to("meta")), r"state is on meta; allowed: cpu, or cuda"),
        (lambda o: o(torch.full((2, 1, 64), float("inf")), p), r"state has NaN/Inf in batch entries \[0, 1\]"),
        (lambda o: SolverStep(o.pde, frames=0), r"frames=0 not allowed"),
        (lambda o: SolverStep(o.pde)(u.requires_grad_(True), p[:1]), r"params \[1, 1\] not allowed"),
        (lambda o: SolverOracle("burgers"), r"unknown PDE 'burgers'"),
    ]


@pytest.mark.parametrize("call, message", bad_inputs())
def test_bad_input_is_refused_in_one_line(call, message):
    oracle = SolverOracle(generator.get_pde("burgers1d", n=64))
    with pytest.raises(ValueError, match=message) as err:
        call(oracle)
    assert "\n" not in str(err.value)


def test_a_steady_pde_is_refused_in_one_line():
    steady = [name for name, cls in generator.PDES.items() if getattr(cls, "STEADY", False)]
    if not steady:
        pytest.skip("no steady PDE in the catalog")
    with pytest.raises(ValueError, match=f"{steady[0]}: a steady PDE has no frames to advance") as err:
        SolverOracle(steady[0])
    assert "\n" not in str(err.value)


def test_a_cuda_state_without_jax_gpu_is_refused_in_one_line():
    if any(d.platform == "gpu" for d in jax.devices()):
        pytest.skip("JAX has a GPU here")
    with pytest.raises(ValueError, match=r"state is on cuda:0 but JAX has no such device") as err:
        _bridge._jax_device(torch.device("cuda:0"))
    assert "\n" not in str(err.value)


def test_a_blow_up_raises_instead_of_returning_nan():
    pde = generator.get_pde("burgers1d", n=64)
    x = torch.linspace(0, 2 * np.pi, 65)[:-1]
    u = (1e4 * torch.sin(x)).reshape(1, 1, 64)  # far beyond the amplitude the step was chosen for
    with pytest.raises(generator.BlowUpError, match=r"blew up \(NaN/Inf\) advancing batch entries \[0\]"):
        SolverOracle(pde)(u, torch.full((1, 1), 0.01), frames=5)
