"""The PDE's JAX solver as a function of torch tensors: an oracle, and a differentiable solver step.

    oracle = SolverOracle("burgers1d")       # a catalog name, a generator PDE or a PDE.config() dict
    oracle.param_names                       # column order of params [B, P], as batch["params"] of the stream
    oracle(u, params, frames=1)              # u [B, C, *space] -> [B, C, *space], `frames` frames later; no autograd
    step = SolverStep("burgers1d", frames=1) # nn.Module: forward(u, params) differentiable w.r.t. u and params

One frame is the PDE config's ``frame_dt`` (its own ETDRK4 steps), so ``oracle(batch["x"][:, 0], batch["params"])``
of a next-step batch reproduces ``batch["y"][:, 0]`` to float32 rounding. Tensors stay on their device: CPU, or a
CUDA device when JAX has its CUDA build (JAX then runs on the same GPU and exchanges buffers by DLPack). States
must be float32 (float64 only with ``jax_enable_x64`` on, for gradient checks). Bad input (shape, device, dtype,
frames < 1, parameters outside their domains, NaN in the state) raises ValueError with one line; a NaN/Inf result
raises generator's BlowUpError. Sample identity: the oracle gives an element the same bits alone or in any batch;
SolverStep's forward is a different compiled program (equal to the oracle to float32 rounding).
"""

from __future__ import annotations

import torch

from . import _bridge


class SolverOracle:
    """Advance torch states with the PDE's solver (no autograd: the result is a constant target)."""

    def __init__(self, pde):
        _bridge.configure_jax()
        self.pde = _bridge.solver_pde(pde)
        if getattr(self.pde, "STEADY", False):
            raise ValueError(f"{self.pde.NAME}: a steady PDE has no frames to advance; allowed: time-dependent PDEs")
        if not getattr(self.pde, "ADVANCES", True):
            raise ValueError(f"{self.pde.NAME}: its solver does not advance a given state (an external solver makes "
                             "whole trajectories); allowed: --mode one-step, or a catalog / spectral PDE")
        _bridge.refuse_refined(self.pde)  # now, not at the first state it is given
        self.param_names: list[str] = list(self.pde.PARAMS)

    def __call__(self, u: torch.Tensor, params: torch.Tensor | None = None, frames: int = 1) -> torch.Tensor:
        """u [B, C, *space], params [B, P] -> u ``frames`` frames later, [B, C, *space] on u's device."""
        with torch.no_grad():
            return _bridge.solver_advance(self.pde, u, params, frames)

    def __repr__(self) -> str:
        return f"SolverOracle({self.pde.NAME}, params={self.param_names})"


class _SolverFunction(torch.autograd.Function):
    """forward: the JAX solver; backward: its JAX VJP (residuals kept in the VJP closure, nothing else)."""

    @staticmethod
    def forward(ctx, u, params, pde, frames):
        out, ctx.vjp = _bridge.solver_advance_vjp(pde, u, params, frames, wrt_params=bool(ctx.needs_input_grad[1]))
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        g_u, g_p = ctx.vjp(grad.contiguous())
        return (g_u if ctx.needs_input_grad[0] else None), (g_p if ctx.needs_input_grad[1] else None), None, None


class SolverStep(torch.nn.Module):
    """A differentiable solver step: forward(u [B, C, *space], params [B, P]) -> [B, C, *space], ``frames`` frames
    later; gradients w.r.t. u and, when params.requires_grad, params (backward = the JAX VJP, once-differentiable).
    Without any input needing a gradient it runs the oracle's cheaper program."""

    def __init__(self, pde, frames: int = 1):
        super().__init__()
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
            raise ValueError(f"frames={frames!r} not allowed: need an integer >= 1")
        self.oracle = SolverOracle(pde)
        self.pde, self.frames = self.oracle.pde, frames
        self.param_names = self.oracle.param_names

    def forward(self, u: torch.Tensor, params: torch.Tensor | None = None) -> torch.Tensor:
        """u [B, C, *space], params [B, P] -> u ``frames`` frames (of frame_dt) later, [B, C, *space] on u's device."""
        if params is None and not self.param_names and isinstance(u, torch.Tensor):
            params = u.new_zeros((u.shape[0], 0))
        grads = torch.is_grad_enabled() and any(isinstance(t, torch.Tensor) and t.requires_grad for t in (u, params))
        if not grads:
            return _bridge.solver_advance(self.pde, u, params, self.frames)
        return _SolverFunction.apply(u, params, self.pde, self.frames)

    def extra_repr(self) -> str:
        return f"{self.pde.NAME}, frames={self.frames}"
