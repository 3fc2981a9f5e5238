"""A command-line solver for tests/external_solvers.py's Cmd: reads {params, seed, settings} JSON, writes u."""

import json
import sys

import numpy as np

spec, out = sys.argv[1], sys.argv[2]
job = json.load(open(spec))
s = job["settings"]
if s["exit_code"]:
    print("solver: the mesh is inverted", file=sys.stderr)
    sys.exit(s["exit_code"])
u0 = np.random.default_rng(job["seed"]).standard_normal(s["n"])
t = np.linspace(0.0, s["t_end"], s["n_frames"]).astype(np.float32)  # as Decay: the same bits
u = np.exp(-job["params"]["k"] * t)[:, None, None] * u0[None, None, :]
if out.endswith(".h5"):
    import h5py

    with h5py.File(out, "w") as f:
        f["u"] = u
else:
    np.save(out, u)
