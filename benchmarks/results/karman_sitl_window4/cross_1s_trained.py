"""Seed 0's 1 s-trained pairs and solver-in-the-loop correctors (stop 47) rolled out over the 4 s window.

    nice -n 5 python benchmarks/results/karman_sitl_window4/cross_1s_trained.py RUNS OUT.json

RUNS: a karman_sitl --small seed-0 out directory with sitl_unroll1/model.pt and sitl_unroll3/model.pt (their
weights are not committed). Prints rollout mean / p95 per test set and arm, and the per-frame ratio pairs / sitl
(at the frame, and averaged over frames 1..frame); writes them, with the errors per frame, to OUT.json.
"""
import json
import sys

import numpy as np
import torch

from pdestream import datasets, generator
from pdestream.experiments.budget import stratified_test_set
from pdestream.experiments.interactive_compare import _identity_norm
from pdestream.surrogate.checkpoint import load_checkpoint
from pdestream.surrogate.evaluate import rollout_errors
from pdestream.surrogate.modes import make_mode

torch.set_num_threads(1)
src = sys.argv[1]
pde = generator.get_pde("karman2d", n=32, radius="uniform(0.13, 0.16)", re="uniform(40, 80)", t_start=2.0, t_end=6.0, n_frames=41)
lo, hi = pde.re.bounds
shifted = pde.replace(re=f"uniform({hi + 0.15 * (hi - lo):g}, {hi + 0.25 * (hi - lo):g})")
out = {}
for where, tp in (("inside", pde), ("beyond", shifted)):
    mode = make_mode({"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16}).bind(tp)
    test = stratified_test_set(tp, 8, 0)
    for arm, run in (("coarse", None), ("pairs", "sitl_unroll1"), ("sitl", "sitl_unroll3")):
        model, norm = (None, _identity_norm(pde)) if run is None else load_checkpoint(f"{src}/{run}/model.pt")[:2]
        e = rollout_errors(model, norm, test, datasets.NextStep(1, 1), mode).relative()
        out[f"{where}|{arm}"] = [float(e.mean()), float(np.percentile(e.mean(1), 95)), e.mean(0).tolist()]
        print(where, arm, f"{e.mean():.4f} {np.percentile(e.mean(1), 95):.4f}", flush=True)
    p, s = np.array(out[f"{where}|pairs"][2]), np.array(out[f"{where}|sitl"][2])
    for f in (1, 5, 10, 20, 30, 40):
        print(f"{where} frame {f}: at {p[f-1]/s[f-1]:.2f}, up to {p[:f].mean()/s[:f].mean():.2f}", flush=True)
json.dump(out, open(sys.argv[2], "w"))
