"""The training reservoir on the training device: ``python -m benchmarks.device_reservoir_bench [--parts ...]``.

All at the FNO Burgers set-up (burgers1d n=1024, nu=0.1, u0 -> u(1); FNO width 64, 16 modes, 4 layers; batch 20;
operator view), on the CPU or, where torch and JAX both see one, the GPU:

1. ``handover``: a reservoir of 1000 trajectories (no solver running) hands out batches; per batch, the host time
   of the draw (bookkeeping), the gather and the hand-over to the model's device (``to_device``), in
   microseconds (median of 300 batches), against one training step (forward, backward, Adam; median of 10) in
   the same process. Storage on the host (``device="cpu"``, the reservoir before this) and, with a GPU, on it.
2. ``solver`` (GPU): trajectories/s of ``generator.sample`` at batch 16, 128 and 1024 on the GPU, with the GPU's
   call sizes (whole batch, ~2**28 point-steps a call) and with the CPU's (the cache-sized chunks and 2**24),
   against two FFT floors of the same shape and step count: one rfft + irfft pair a step, and the step's own
   four pairs (ETDRK4: one nonlinear term per stage), each a jitted loop of n_steps.
3. ``training`` (GPU): the set-up trained for ``--seconds`` per arm through ``surrogate.train.train``, the JAX
   solver on the same GPU (thread producer, async, max_reuse 50): the loop's wait share (time in next(batch)
   and the hand-over over the loop's time), steps/s, the solver's trajectories/s and mean reuse, for storage on
   the host against on the GPU, and solve batches of 128 and 1024; the wait split into waiting for solves,
   inserting them, gathering batches (host clocks) and, of the solves, the first batch's (start-up).
Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numpy as np
import torch

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # torch trains on the same GPU

N, NU, MODEL, BATCH = 1024, 0.1, {"width": 64, "modes": 16, "layers": 4}, 20


def burgers():
    from pdestream import generator

    return generator.get_pde("burgers1d", n=N, nu=NU, t_end=1.0, n_frames=2)


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def fno(pde, device):
    from pdestream.surrogate.models import build_model

    torch.manual_seed(0)
    return build_model("fno", pde.NDIM, len(pde.FIELDS), len(pde.FIELDS), len(pde.PARAMS), bc=pde.grid.bc,
                       **MODEL).to(device)


def step_seconds(pde, device, norm, batch: dict, reps: int = 10) -> float:
    """Median seconds of one training step on ``batch`` (as the loop does it: loss, backward, Adam, loss.item())."""
    from pdestream.surrogate.modes import OneStep

    model, mode = fno(pde, device), OneStep()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    times = []
    for r in range(reps + 2):
        t0 = time.perf_counter()
        loss, _ = mode.step_loss(model, batch, norm, r)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        loss.item()
        times.append(time.perf_counter() - t0)
    return statistics.median(times[2:])


def filled_stream(pde, storage, u, params, capacity: int = 1000):
    """A ReservoirStream whose store holds ``capacity`` copies of the solved ``u`` [16, ...] (indices distinct),
    drawn without a producer: its batches are the reservoir's own cost alone."""
    from pdestream import datasets

    stream = datasets.ReservoirStream(pde, view="operator", batch_size=BATCH, capacity=capacity, max_reuse=10**6,
                                      warmup=16, solve_batch=16, mode="deterministic", device=storage)
    for lo in range(0, capacity, len(u)):
        m = min(len(u), capacity - lo)
        stream.res.insert(u[:m], params[:m], np.arange(lo, lo + m))
    stream._t_first = time.perf_counter()
    return stream


def handover(devices: list[torch.device]) -> None:
    from pdestream import datasets
    from pdestream.surrogate.data import to_device

    pde = burgers()
    solved = datasets.sample_tensors(pde, np.arange(16), 0)
    u, params = solved["u"].cpu(), solved["params"].cpu()
    norm = datasets.compute_normalization(pde, n=16, solve_batch=16)
    print(f"\n1. per batch: burgers1d n={N}, operator view, batch {BATCH}, 1000 trajectories held; torch threads "
          f"{torch.get_num_threads()}")
    print("| model on | storage | draw us | gather us | hand-over us | draw+gather+hand-over us | training step ms "
          "| share of the step | batch on |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    for model_dev in devices:
        for storage in dict.fromkeys([torch.device("cpu"), model_dev]):
            stream = filled_stream(pde, storage, u, params)
            draw, gath, hand = [], [], []
            for _ in range(300 + 20):
                t0 = time.perf_counter()
                slots, starts = stream._draw(BATCH)
                t1 = time.perf_counter()
                batch = stream._gather(slots, starts)
                t2 = time.perf_counter()
                batch = to_device(batch, model_dev)
                t3 = time.perf_counter()
                draw.append(t1 - t0)
                gath.append(t2 - t1)
                hand.append(t3 - t2)
                sync(model_dev)  # (the loop's step syncs at loss.item(); not counted, as there)
            d, g, h = (statistics.median(x[20:]) * 1e6 for x in (draw, gath, hand))
            step = step_seconds(pde, model_dev, norm.to(model_dev), batch)
            where = sorted({str(v.device) for v in batch.values() if isinstance(v, torch.Tensor)})
            print(f"| {model_dev} | {storage} | {d:.0f} | {g:.0f} | {h:.0f} | {d + g + h:.0f} | {step * 1e3:.2f} | "
                  f"{100 * (d + g + h) / (step * 1e6):.2f}% | {', '.join(where)} |", flush=True)
            stream.close()


def timed(fn, reps: int) -> float:
    fn()  # compile
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def fft_floor(batch: int, n: int, steps: int, pairs: int):
    """A jitted loop of ``steps`` iterations of ``pairs`` rfft + irfft pairs on float32 [batch, n]."""
    import jax
    import jax.numpy as jnp

    damp = jnp.exp(-1e-6 * jnp.arange(n // 2 + 1, dtype=jnp.float32))  # keeps values bounded, transforms live

    def body(_, x):
        for _ in range(pairs):
            x = jnp.fft.irfft(jnp.fft.rfft(x) * damp, n=n)
        return x

    run = jax.jit(lambda x: jax.lax.fori_loop(0, steps, body, x))
    x0 = jnp.ones((batch, n), jnp.float32)
    return lambda: jax.block_until_ready(run(x0))


def solver(batches: tuple[int, ...], reps: int) -> None:
    import jax

    from pdestream import generator
    from pdestream.generator import dispatch
    from pdestream.generator.spectral import rollout

    pde = burgers()
    steps = pde.steps_per_frame * (pde.n_frames - 1)
    print(f"\n2. solver on {jax.devices()[0].device_kind}: burgers1d n={N}, {steps} ETDRK4 steps a trajectory; "
          f"median of {reps} solves after one")
    print("| batch | traj/s, GPU call sizes | traj/s, CPU call sizes | floor traj/s, 1 pair/step | "
          "floor traj/s, 4 pairs/step | x 1-pair floor | x 4-pair floor |")
    print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    start = 0

    def solve(batch):
        nonlocal start
        start += batch
        return lambda: generator.sample(pde, np.arange(start, start + batch), 0).u.block_until_ready()

    for b in batches:
        gpu = b / timed(solve(b), reps)
        saved = rollout.ACCELERATOR_EVOLVE_BYTES
        rollout.ACCELERATOR_EVOLVE_BYTES = rollout.EVOLVE_BYTES
        try:
            with dispatch.call_size(dispatch.DISPATCH_WORK):
                cpu_sizes = b / timed(solve(b), reps)
        finally:
            rollout.ACCELERATOR_EVOLVE_BYTES = saved
        one = b / timed(fft_floor(b, N, steps, 1), reps)
        four = b / timed(fft_floor(b, N, steps, 4), reps)
        print(f"| {b} | {gpu:.0f} | {cpu_sizes:.0f} | {one:.0f} | {four:.0f} | {one / gpu:.2f} | {four / gpu:.2f} |",
              flush=True)


def training(seconds: float, arms: list[tuple[str, int]], device: torch.device) -> None:
    from pdestream import datasets
    from pdestream.surrogate.train import Stop, train

    pde = burgers()
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "the CPU"
    print(f"\n3. training on {name} for {seconds:g} s per arm, solver on the same device "
          "(thread producer, async, max_reuse 50, warm-up one solve batch)")
    print("| storage | solve batch | wait share | of it: solves | inserts | gathers | first batch | steps | steps/s | "
          "solver traj/s | mean reuse |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for storage, solve_batch in arms:
        stream = datasets.ReservoirStream(pde, view="operator", batch_size=BATCH, capacity=max(1000, 4 * solve_batch),
                                          max_reuse=50, solve_batch=solve_batch, warmup=solve_batch, mode="async",
                                          device=storage)
        norm = stream.normalization(n=64)  # compiles the solve at this batch too: not in the arm's clock
        model = fno(pde, device)
        loader = torch.utils.data.DataLoader(stream, batch_size=None)
        first = [0.0]  # the first batch's wait (the first solve batch: start-up, whatever the reservoir)

        def after_step(step, _fraction, elapsed):
            if step == 1:
                first[0] = stream.t_wait

        with tempfile.TemporaryDirectory() as tmp:
            try:
                s = train(model, loader, Stop(seconds=seconds), tmp, normalizer=norm, log_every=10**9,
                          label=f"{storage}/{solve_batch}", after_step=after_step)
            finally:
                st = stream.stats()
                stream.close()
        loop = s["t_data"] + s["t_compute"]
        parts = (stream.t_wait, stream.t_insert, stream.t_gather, first[0])
        print(f"| {storage} | {solve_batch} | {100 * s['data_share']:.1f}% | "
              + " | ".join(f"{100 * t / loop:.1f}%" for t in parts)
              + f" | {s['steps']} | {s['steps'] / loop:.1f} | {st['solver_traj_per_s']:.0f} | {st['reuse_mean']:.2f} |",
              flush=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.device_reservoir_bench", description=__doc__.splitlines()[0])
    p.add_argument("--parts", default="handover,solver,training", help="comma list: handover, solver, training")
    p.add_argument("--seconds", type=float, default=30.0, help="wall-clock seconds per training arm")
    p.add_argument("--batches", default="16,128,1024", help="solve batches of the solver part")
    p.add_argument("--reps", type=int, default=3, help="timed solves per batch (solver part)")
    p.add_argument("--arms", default="cpu:128,cuda:128,cuda:1024", help="training arms, storage:solve batch")
    p.add_argument("--threads", type=int, default=1, help="torch threads on the CPU (1: the solver keeps a core)")
    args = p.parse_args(argv)
    import jax

    torch.set_num_threads(args.threads)
    gpu = torch.cuda.is_available() and any(d.platform == "gpu" for d in jax.devices())
    parts = set(args.parts.split(","))
    print(f"JAX {jax.__version__} ({jax.default_backend()}); torch {torch.__version__}"
          f"{' on ' + torch.cuda.get_device_name() if gpu else ' (CPU)'}")
    if "handover" in parts:
        handover([torch.device("cpu")] + ([torch.device("cuda", torch.cuda.current_device())] if gpu else []))
    if not gpu and parts - {"handover"}:
        print("\nsolver and training parts: no GPU for both torch and JAX here; skipped")
        return
    if "solver" in parts:
        solver(tuple(int(b) for b in args.batches.split(",")), args.reps)
    if "training" in parts:
        arms = [(a.split(":")[0], int(a.split(":")[1])) for a in args.arms.split(",")]
        training(args.seconds, arms, torch.device("cuda", torch.cuda.current_device()))


if __name__ == "__main__":
    main()
