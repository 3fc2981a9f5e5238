"""Cost of the solver as an oracle and as a differentiable step, against a plain forward solve of the same batch.

``python -m benchmarks.interactive_bench [--device cpu|cuda] [--quick] [--batch B]``

Per PDE (burgers1d n=256, batch 32; ns2d 64x64, batch 16; their default frames and steps), in one process:
- plain solve: ``generator.solve`` of the batch from the same states, the PDE's whole window (n_frames - 1 frames);
- ``SolverOracle`` k=1 and k=5 frames (torch tensors in and out, on the device, input checks included), with
  parameters seen before (memoised ETDRK4 coefficients, as in an unrolled loop) and with new ones each call;
- ``SolverStep`` forward (the VJP program) and forward + backward, gradients for the state only (the
  solver-in-the-loop case: coefficients memoised) and for state and parameters (coefficients differentiated).
Printed: median and fastest ms per call, and the ratio to the plain solve's cost of the same number of frames
(plain solve ms / (n_frames - 1) * k, fastest calls): how much dearer a frame is when asked for by torch. Figures, not pass/fail.
Compilation is excluded (two warm-up calls). Default device: cuda when torch sees one, else cpu.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import torch

CASES = (("burgers1d", {}, 32), ("ns2d", {}, 16))


def _timed(fn, sync, min_s: float, max_calls: int) -> tuple[float, float]:
    """(median, min) seconds of fn() after two warm-up calls, over >= 3 calls and about min_s seconds."""
    for _ in range(2):
        fn()
        sync()
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < 3 or (time.perf_counter() - start < min_s and len(times) < max_calls):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times)


def bench_case(name: str, settings: dict, batch: int, device: torch.device, min_s: float) -> list[tuple]:
    """Rows (what, frames, seconds per call) for one PDE; the plain solve first."""
    import jax

    from pdestream import generator
    from pdestream.datasets import SolverOracle, SolverStep, _bridge

    pde = generator.get_pde(name, **settings)
    t = _bridge.sample_tensors(pde, range(batch), seed=0)  # on JAX's default device: brought to the CPU first
    state, params_cpu = t["u"][:, 1].cpu().contiguous(), t["params"].cpu()  # a state from inside a trajectory
    u, params = state.to(device), params_cpu.to(device)
    cuda = device.type == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    jax_device = _bridge._jax_device(device)
    u0 = jax.device_put(state.numpy(), jax_device)
    p0 = {n: jax.device_put(params_cpu[:, j].numpy(), jax_device) for j, n in enumerate(pde.PARAMS)}

    rows = [("plain solve (generator.solve)", pde.n_frames - 1,
             _timed(lambda: generator.solve(pde, u0, p0).u.block_until_ready(), sync, min_s, 50))]
    oracle = SolverOracle(pde)
    for k in (1, 5):
        rows.append((f"SolverOracle k={k}", k, _timed(lambda: oracle(u, params, frames=k), sync, min_s, 200)))
    calls = iter(range(1, 10**9))  # parameters never seen before: the ETDRK4 coefficients are computed again
    rows.append(("SolverOracle k=1, new parameters each call", 1,
                 _timed(lambda: oracle(u, params * (1 + 1e-6 * next(calls)), frames=1), sync, min_s, 200)))
    step = SolverStep(pde)
    g = torch.randn_like(u)
    for label, wrt_params in (("state", False), ("state+params", True)):
        u_g, p_g = u.clone().requires_grad_(True), params.clone().requires_grad_(wrt_params)
        rows.append((f"SolverStep forward, grad {label}", 1, _timed(lambda: step(u_g, p_g), sync, min_s, 200)))

        def forward_backward():
            u_g.grad = p_g.grad = None
            (step(u_g, p_g) * g).sum().backward()

        rows.append((f"SolverStep forward+backward, grad {label}", 1, _timed(forward_backward, sync, min_s, 200)))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.interactive_bench", description=__doc__.splitlines()[0])
    p.add_argument("--device", choices=("cpu", "cuda"), default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--quick", action="store_true", help="fewer timed calls (about 0.3 s per row)")
    p.add_argument("--batch", type=int, help="one batch size for every PDE (default: 32 for 1D, 16 for 2D)")
    args = p.parse_args(argv)
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        print("interactive_bench: error: --device cuda but torch sees no CUDA device; allowed here: cpu",
              file=sys.stderr)
        return 2
    if args.batch is not None and args.batch < 1:
        print(f"interactive_bench: error: --batch {args.batch} not allowed: need >= 1", file=sys.stderr)
        return 2
    from pdestream.datasets import _bridge

    _bridge.configure_jax()
    min_s = 0.3 if args.quick else 1.5
    print(f"device {device}; torch threads {torch.get_num_threads()}; >= 3 timed calls after 2 warm-ups; "
          "ratios from the fastest call (the least disturbed by other load)")
    print("| PDE | batch | what | frames | median ms/call | min ms/call | min ms/frame | x plain solve per frame |")
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for name, settings, batch in CASES:
        batch = args.batch or batch
        try:
            rows = bench_case(name, settings, batch, device, min_s)
        except ValueError as err:  # e.g. a CUDA state with a CPU-only JAX: the bridge's one line
            print(f"interactive_bench: error: {err}", file=sys.stderr)
            return 2
        base = rows[0][2][1] / rows[0][1]  # seconds per frame inside a plain solve
        for what, frames, (median, fastest) in rows:
            print(f"| {name} | {batch} | {what} | {frames} | {1e3 * median:.2f} | {1e3 * fastest:.2f} | "
                  f"{1e3 * fastest / frames:.3f} | {fastest / frames / base:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
