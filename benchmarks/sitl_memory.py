"""Memory and time of one solver-in-the-loop optimizer step against the unroll length, with and without
rematerialisation (``--remat``; issue 29's long unrolls).

    nice python -m benchmarks.sitl_memory [--pde ns2d] [--fine-n 256] [--coarse-n 64] [--batch 16]
        [--unrolls 4,16,32] [--out DIR]

Each (unroll, remat) runs in a fresh process: it builds the corrector (compare's FNO, width 32 / 12 modes / 3
layers) on the coarse solver of the PDE, takes one warm-up step at unroll 1 (JAX and torch compile and allocate),
reads its peak resident memory (``ru_maxrss``), then one optimizer step (forward and backward) at the unroll
and reads the peak again, with the step's wall time. The batch is standard normal states and targets, the
parameters at their domains' middle: memory and time do not depend on the values. Printed: a table of the peak's growth over the
warm-up's (what the unrolled step itself held) and the step's seconds; written to DIR/sitl_memory.json.
Figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
import torch
from pdestream import datasets, generator
from pdestream.surrogate.fno import COMPARE_FNO
from pdestream.surrogate.models import build_model
from pdestream.surrogate.modes import make_mode
a = json.loads(sys.argv[1])
torch.set_num_threads(1)
pde = generator.get_pde(a["pde"], n=a["fine_n"])
c = len(pde.FIELDS)
g = torch.Generator().manual_seed(0)
space = tuple(pde.grid.shape)
x = torch.randn(a["batch"], 1, c, *space, generator=g)
params = torch.stack([torch.full((a["batch"],), float(sum(dom.bounds) / 2)) for dom in pde.param_domains.values()], 1)
def step(k):
    mode = make_mode({"name": "solver-in-the-loop", "unroll": k, "coarse_n": a["coarse_n"],
                      "remat": a["remat"]}).bind(pde)
    y = torch.randn(a["batch"], k, c, *space, generator=g)
    batch = {"x": x, "y": y, "params": params}
    norm = datasets.Normalization.from_batch(batch, len(space))
    t0 = time.perf_counter()
    loss, _ = mode.step_loss(model, batch, norm, 1)
    loss.backward()
    return time.perf_counter() - t0
torch.manual_seed(0)
model = build_model("fno", len(space), c, c, params.shape[1], **COMPARE_FNO)
step(1)
warm = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
seconds = step(a["unroll"])
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"warm_mib": warm, "peak_mib": peak, "seconds": seconds}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.sitl_memory", description=__doc__.splitlines()[0])
    ap.add_argument("--pde", default="ns2d")
    ap.add_argument("--fine-n", type=int, default=256)
    ap.add_argument("--coarse-n", type=int, default=64)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--unrolls", default="4,16,32")
    ap.add_argument("--out", default="/tmp/sitl_memory")
    a = ap.parse_args(argv)
    rows = []
    print(f"{a.pde} {a.fine_n} -> {a.coarse_n}, batch {a.batch}, compare's FNO; one optimizer step after a warm-up")
    print("| unroll | remat | peak growth over the warm-up (MiB) | peak (MiB) | step (s) |\n| --- | --- | --- | --- | --- |")
    for k in (int(u) for u in a.unrolls.split(",")):
        for remat in (False, True):
            args = json.dumps({"pde": a.pde, "fine_n": a.fine_n, "coarse_n": a.coarse_n, "batch": a.batch,
                               "unroll": k, "remat": remat})
            res = subprocess.run([sys.executable, "-c", CHILD, args], capture_output=True, text=True)
            if res.returncode != 0:
                print(f"| {k} | {remat} | failed: {res.stderr.strip().splitlines()[-1][:80]} | | |", flush=True)
                continue
            r = {**json.loads(res.stdout.strip().splitlines()[-1]), "unroll": k, "remat": remat}
            rows.append(r)
            print(f"| {k} | {'on' if remat else 'off'} | {r['peak_mib'] - r['warm_mib']:.0f} | {r['peak_mib']:.0f} | "
                  f"{r['seconds']:.2f} |", flush=True)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "sitl_memory.json").write_text(json.dumps({"args": vars(a), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
