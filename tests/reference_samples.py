"""The bits of every catalog entry's samples, configuration, hash and description, recorded once so that a
refactor of the generator can be checked against them (tests/test_reference_samples.py).

``python -m tests.reference_samples`` rewrites tests/data/reference_samples.json from the current code: do that
only for a deliberate change of the numerics (and bump generator.NUMERICS with it).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from pdestream import generator

PATH = Path(__file__).parent / "data" / "reference_samples.json"
SMALL = {"darcy2d": {"n": 9}}  # the steady entry: nodes per side; every other entry: the settings below


def small(name: str) -> dict:
    """A configuration of entry ``name`` that solves in well under a second: a 16-point grid (or the smallest the
    entry allows), 3 frames over a tenth of the default time window (and of a flow's warm-up)."""
    if name in SMALL:
        return SMALL[name]
    pde = generator.get_pde(name)
    if pde.STEADY:
        return {"n": 16}
    for n in (16, 24, 32, 48):  # the smallest grid the entry's IC allows
        try:
            generator.get_pde(name, n=n)
            break
        except ValueError:
            continue
    if getattr(pde, "t_start", 0.0) > 0:  # a flow's warm-up: a tenth of it, then a tenth of its recorded window
        start = pde.t_start / 10
        return {"n": n, "n_frames": 3, "t_start": start, "t_end": start + (pde.t_end - pde.t_start) / 10}
    return {"n": n, "n_frames": 3, "t_end": pde.t_end / 10}


def digest(*arrays) -> str:
    """sha256 of the arrays' bytes, dtypes and shapes (first 16 hex digits)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


# walled configurations recorded too (keys "name[bc]"): their bits are a promise from now on, like the entries'
WALLED = {"burgers1d[dirichlet]": ("burgers1d", {"bc": "dirichlet", "bc_lo": "uniform(0, 1)"}),
          "allen_cahn2d[x=dirichlet,y=neumann]": ("allen_cahn2d", {"bc": "x=dirichlet,y=neumann"}),
          "ks1d[dirichlet]": ("ks1d", {"bc": "dirichlet"}),
          "diffusion2d[neumann]": ("diffusion2d", {"bc": "neumann"})}


def record(key: str) -> dict:
    """Configuration, hash, description and sample digests of entry ``key`` (a catalog name or a WALLED key): its
    defaults and a small configuration, samples 0..2 of seed 0 at the small one (u, parameters, inputs)."""
    name, walls = WALLED.get(key, (key, {}))
    default = generator.get_pde(name, walls)
    pde = generator.get_pde(name, {**small(name), **walls})
    traj = generator.sample(pde, [0, 1, 2], seed=0, on_blowup="redraw")  # a coarse grid may blow up: redraws too
    arrays = [traj.u, traj.redraws, *(traj.params[k] for k in sorted(traj.params))]
    if traj.inputs is not None:
        arrays.append(traj.inputs)
    return {"config": default.config(), "hash": default.config_hash(), "describe": default.describe(),
            "small_config": pde.config(), "small_hash": pde.config_hash(), "small_describe": pde.describe(),
            "samples": digest(*arrays), "sample_1_alone": digest(generator.sample(pde, [1], seed=0, on_blowup="redraw").u)}


DYNAMICS = ("burgers1d", "wave1d", "ns2d")  # entries whose solve() and interactive.advance() bits are recorded too


def record_dynamics(name: str) -> dict:
    """Digests of ``solve`` from samples 0..2's first frames and of ``interactive.advance`` by 2 frames."""
    pde = generator.get_pde(name, small(name))
    traj = generator.sample(pde, [0, 1, 2], seed=0)
    u0, params = traj.u[:, 0], {k: np.asarray(v) for k, v in traj.params.items()}
    solved = generator.solve(pde, u0, params)
    advanced, finite = generator.interactive.advance(pde, u0, params, 2)
    return {"solve": digest(solved.u), "advance": digest(advanced, finite)}


def main() -> None:
    out = {"numerics": generator.NUMERICS, "entries": {name: record(name) for name in [*generator.PDES, *WALLED]},
           "dynamics": {name: record_dynamics(name) for name in DYNAMICS}}
    PATH.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {PATH} ({len(out['entries'])} entries)")


if __name__ == "__main__":
    main()
