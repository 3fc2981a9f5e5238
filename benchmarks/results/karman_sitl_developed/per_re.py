"""Per held-out trajectory: Re, and each arm's rollout-mean error (relative L2 over the 40 frames), for the saved
weights of karman_sitl --small --re 60,100 --t-start 8 --window 4 (this directory's seed*/): which trajectories
carry solver-in-the-loop's margin over pairs. The test sets are karman_sitl's (stratified_test_set, same seed),
solved in chunks of 8 instead of padded to 32 (the same trajectories: the check line compares the means with
summary.json).

    nice -n 5 python benchmarks/results/karman_sitl_developed/per_re.py [SEED ...]   # default 0
"""
import json
import sys
from pathlib import Path

import numpy as np
import torch

from pdestream import datasets, generator
from pdestream.experiments.budget import stratified_test_set
from pdestream.experiments.interactive_compare import _identity_norm
from pdestream.surrogate.checkpoint import load_checkpoint
from pdestream.surrogate.evaluate import rollout_errors
from pdestream.surrogate.modes import make_mode

torch.set_num_threads(1)
HERE = Path(__file__).parent
pde = generator.get_pde("karman2d", n=32, radius="uniform(0.13, 0.16)", re="uniform(60, 100)", t_start=8.0,
                        t_end=12.0, n_frames=41)
shifted = pde.replace(re="uniform(106, 110)")
ARMS = {"coarse": None, "pairs": "sitl_unroll1", "noise": "sitl_unroll1_noise", "sitl": "sitl_unroll3"}
for seed in [int(s) for s in sys.argv[1:]] or [0]:
    out = HERE / f"seed{seed}"
    summary = json.loads((out / "summary.json").read_text())
    for where, test_pde in (("inside", pde), ("beyond", shifted)):
        mode = make_mode({"name": "solver-in-the-loop", "unroll": 1, "coarse_n": 16}).bind(test_pde)
        test = stratified_test_set(test_pde, 8, seed, chunk=8)
        re = torch.cat([b["params"][:, list(pde.PARAMS).index("re")] for b in test]).numpy()
        per = {}
        for arm, run in ARMS.items():
            model, norm = (None, _identity_norm(pde)) if run is None else load_checkpoint(out / run / "model.pt")[:2]
            per[arm] = rollout_errors(model, norm, test, datasets.NextStep(1, 1), mode).relative().mean(1)  # [N]
        key = next(k for k in summary if k.startswith(f"{where}|solver-in-the-loop"))
        print(f"seed {seed} {where}: check, rollout mean pairs {per['pairs'].mean():.4f} (summary "
              f"{summary[where + '|pairs (unroll 1)'][0]:.4f}), solver-in-the-loop {per['sitl'].mean():.4f} "
              f"(summary {summary[key][0]:.4f})")
        print("| Re | coarse | pairs | pairs + noise | solver-in-the-loop | pairs / solver-in-the-loop |")
        print("| --- | --- | --- | --- | --- | --- |")
        for k in np.argsort(re):
            print(f"| {re[k]:.1f} | {per['coarse'][k]:.4f} | {per['pairs'][k]:.4f} | {per['noise'][k]:.4f} | "
                  f"{per['sitl'][k]:.4f} | {per['pairs'][k] / per['sitl'][k]:.2f} |", flush=True)
