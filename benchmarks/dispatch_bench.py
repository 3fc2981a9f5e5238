"""What bounded calls cost: a rollout as one compiled call vs in calls of ~DISPATCH_WORK point-steps each
(generator.rollout.evolve_bounded, which lets Ctrl-C and a closed consumer stop a solve within one call).

Same process, same inputs, runs alternated, median of N: prints seconds per rollout both ways, their ratio,
the number of calls and the median seconds per call (the interrupt latency). Figures, not pass/fail.
Run: ``python -m benchmarks.dispatch_bench [--quick]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from pdestream import generator
from pdestream.generator import chunked, dispatch, sampler
from pdestream.generator.spectral import rollout

CASES = [  # (name, settings, batch): defaults of the catalog and two long rollouts
    ("burgers1d", {}, 64),
    ("burgers1d", {"n": 1024}, 64),
    ("burgers1d", {"n": 128, "t_end": 200}, 16),
    ("ns2d", {}, 16),
    ("grayscott2d", {}, 16),
]


def _inputs(pde, batch):
    keys = sampler.sample_keys(0, np.arange(batch))
    p = len(pde.PARAMS)
    parts = [rollout.compiled_setup(pde)(keys[i: i + rollout.SETUP_CHUNK],
                                         np.zeros((rollout.SETUP_CHUNK, p), np.float32),
                                         np.zeros((rollout.SETUP_CHUNK, p), bool))
             for i in range(0, batch, rollout.SETUP_CHUNK)]
    return chunked.join(parts, batch)


def run(quick: bool = False) -> list[dict]:
    reps = 3 if quick else 5
    rows = []
    for name, settings, batch in CASES[:3] if quick else CASES:
        pde = generator.get_pde(name, settings)
        params, u0, coeffs = _inputs(pde, batch)
        one = rollout.compiled_evolve(pde)

        def bounded():
            return jax.block_until_ready(rollout.evolve_bounded(pde, [(u0, params, coeffs)]))

        jax.block_until_ready(one(u0, params, coeffs))  # compile both
        ref = bounded()[0][0]
        assert bool(jnp.array_equal(ref, one(u0, params, coeffs)[0])), "bounded calls changed the bits"
        t_one, t_bounded = [], []
        for _ in range(reps):
            t0 = time.perf_counter()
            jax.block_until_ready(one(u0, params, coeffs))
            t_one.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            bounded()
            t_bounded.append(time.perf_counter() - t0)
        per_step = batch * len(pde.FIELDS) * pde.n**pde.NDIM + dispatch.step_overhead()
        steps = (pde.n_frames - 1) * pde.steps_per_frame
        n_calls = max(1, -(-steps * per_step // dispatch.work()))
        row = {"case": f"{name} {settings or 'defaults'} B={batch}", "one_call_s": statistics.median(t_one),
               "bounded_s": statistics.median(t_bounded), "calls": n_calls}
        row["ratio"] = row["bounded_s"] / row["one_call_s"]
        row["s_per_call"] = row["bounded_s"] / n_calls
        rows.append(row)
        print(f"{row['case']:<45} one call {row['one_call_s']:7.3f} s  bounded {row['bounded_s']:7.3f} s  "
              f"ratio {row['ratio']:.3f}  ~{n_calls} calls, {row['s_per_call']:.3f} s per call", flush=True)
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    run(parser.parse_args().quick)
