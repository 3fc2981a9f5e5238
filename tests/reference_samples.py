"""Every catalog entry's configuration, hash, description and samples, recorded once so that a refactor of the
generator can be checked against them (tests/test_reference_samples.py).

A sample's bits are a promise on one machine and jaxlib only: XLA compiles for the host's instruction set, and
with XLA_FLAGS=--xla_cpu_max_isa=SSE4_2 or AVX every entry's bits changed on an AVX-512 host (by 1e-7 to 2e-5 of
the largest value; the flows' also with --xla_cpu_prefer_vector_width until their sums got a fixed order). So
the fields are recorded as a fingerprint (``fingerprint``: root mean square per sample and frame, a few fixed
values; the drawn parameters and inputs too: jax.random's transforms are compiled code), compared to RTOL of
the largest recorded value; redraws keep an exact digest; and a sample alone equals it in a batch, bit for bit,
in one process.

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
# Small versions of every flow entry (16 cells across, a short window, bodies large enough for the grid), shared
# with tests/test_flows.py: an entry's tests run in one xdist worker (--dist loadgroup), which then compiles one
# program for both files (a flow's compile is 10-25 s, its reference solve at the default grid was 30-50 s).
FLOW_SMALL = {
    "karman2d": dict(n=16, radius="uniform(0.15, 0.2)", re="uniform(20, 40)", t_start=0.3, t_end=0.6, n_frames=3),
    "cavity2d": dict(n=16, re="uniform(100, 400)", t_end=0.4, n_frames=3),
    "channel2d": dict(n=16, size_min=0.13, size_max=0.2, re="uniform(100, 200)", t_start=0.2, t_end=0.4, n_frames=3),
    "smoke2d": dict(n=16, radius="uniform(0.13, 0.15)", source_y=0.3, t_end=0.4, n_frames=3),
}
# plume3d: the smallest grid whose heater is 4 cells across and 2 cells off the walls (not in FLOW_SMALL: the 2D
# flows' tests run on those)
SMALL = {"darcy2d": {"n": 9}, **FLOW_SMALL,  # darcy2d: nodes per side; every other entry: the settings below
         "plume3d": dict(n=12, radius=0.17, source_z=0.35, nu="loguniform(0.004, 0.01)", t_end=1.0, n_frames=3)}


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


# Fingerprints' spread measured across --xla_cpu_max_isa SSE4_2/AVX vs native AVX-512: at most 3.7e-6 (smoke2d),
# any single value 1.7e-5 (grayscott2d); a flipped CG stop moves a flow by up to its tolerance 1e-5: 1e-3 is 60x.
RTOL = 1e-3
PICKS = 8  # values per sample in a fingerprint, at evenly spaced flat indices of its last frame


def fingerprint(u) -> dict:
    """float64 summary of fields u [batch, frames, ...]: root mean square per sample and frame, and PICKS values of
    each sample's last frame."""
    u = np.asarray(u, np.float64)
    flat = u.reshape(*u.shape[:2], -1)
    picks = np.linspace(0, flat.shape[-1] - 1, PICKS).round().astype(int)
    return {"rms": np.sqrt(np.mean(flat**2, -1)).tolist(), "values": flat[:, -1, picks].tolist()}


def close(got: dict, want: dict) -> list:
    """The fingerprint keys where got differs from want by more than RTOL of want's largest magnitude."""
    bad = []
    for k in want:
        a, b = np.asarray(got[k], np.float64), np.asarray(want[k], np.float64)
        if a.shape != b.shape or not np.abs(a - b).max(initial=0) <= RTOL * np.abs(b).max(initial=0):
            bad.append(k)
    return bad


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
    """Configuration, hash, description and samples of entry ``key`` (a catalog name or a WALLED key): its defaults
    and a small configuration, samples 0..2 of seed 0 at the small one (the fingerprint of u, parameters, inputs
    and outputs; the digest of redraws), and whether sample 1 alone has the bits of sample 1 in that batch."""
    name, walls = WALLED.get(key, (key, {}))
    default = generator.get_pde(name, walls)
    pde = generator.get_pde(name, {**small(name), **walls})
    traj = generator.sample(pde, [0, 1, 2], seed=0, on_blowup="redraw")  # a coarse grid may blow up: redraws too
    prints = fingerprint(traj.u)
    prints.update({f"param {k}": np.asarray(traj.params[k], np.float64).tolist() for k in sorted(traj.params)})
    if traj.inputs is not None:
        prints.update({f"inputs {k}": v for k, v in fingerprint(traj.inputs).items()})
    for name, out in (traj.outputs or {}).items():  # karman2d's drag, lift, sdf, strouhal, ...: values a user reads
        values = np.asarray(out, np.float64).reshape(len(traj.indices), 1, -1)
        prints.update({f"output {name} {k}": v for k, v in fingerprint(values).items()})
    alone = generator.sample(pde, [1], seed=0, on_blowup="redraw")
    return {"config": default.config(), "hash": default.config_hash(), "describe": default.describe(),
            "small_config": pde.config(), "small_hash": pde.config_hash(), "small_describe": pde.describe(),
            "redraws": digest(traj.redraws), "fingerprint": prints,
            "sample_1_alone_is_batched": bool(np.array_equal(np.asarray(alone.u[0]), np.asarray(traj.u[1])))}


DYNAMICS = ("burgers1d", "wave1d", "ns2d")  # entries whose solve() and interactive.advance() bits are recorded too


def record_dynamics(name: str) -> dict:
    """Fingerprints of ``solve`` from samples 0..2's first frames and of ``interactive.advance`` by 2 frames."""
    pde = generator.get_pde(name, small(name))
    traj = generator.sample(pde, [0, 1, 2], seed=0)
    u0, params = traj.u[:, 0], {k: np.asarray(v) for k, v in traj.params.items()}
    solved = generator.solve(pde, u0, params)
    advanced, finite = generator.interactive.advance(pde, u0, params, 2)
    return {"solve": fingerprint(solved.u), "advance": fingerprint(advanced), "finite": digest(finite)}


def main() -> None:
    out = {"numerics": generator.NUMERICS, "entries": {name: record(name) for name in [*generator.PDES, *WALLED]},
           "dynamics": {name: record_dynamics(name) for name in DYNAMICS}}
    PATH.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {PATH} ({len(out['entries'])} entries)")


if __name__ == "__main__":
    main()
