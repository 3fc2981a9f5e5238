"""How far ahead is an entry predictable? The growth of a small initial-condition perturbation, and the horizon rule
of issue 30's suite.

``python -m benchmarks.predictability [--pdes burgers1d,kdv1d,...] [--n 8] [--eps 1e-4] [--set n=32 ...]``

For each entry: ``--n`` samples of its defaults (``--set`` applies to every entry; n_frames is set to 65 so a frame
is t_end / 64), each initial state u0 and a copy perturbed by ``eps`` times u0's RMS times white noise (seeded),
both advanced with the entry's own solver (``datasets.SolverOracle``) to t_end / 64, / 32, ..., / 1. Printed per
time: the median over samples of the amplification ||u'(t) - u(t)|| / ||u'(0) - u(0)|| (a chaotic flow grows it
exponentially; a diffusive one shrinks it) and the median relative distance ||u(t) - u0|| / ||u0|| (how far the
state has moved: an operator over a horizon where it has barely moved is close to the identity).

**The horizon rule** (issue 30, written 2026-11-27 before any unit at a new horizon ran): an entry's operator is
learned over the longest of t_end, t_end / 2, t_end / 4, ... at which the median amplification is at most
``MAX_AMPLIFICATION`` (10: one decade). Beyond that the map u0 -> u(t) depends on details of u0 at 10x less than
the perturbation's size (1e-4 relative), which an FNO trained on a few hundred samples cannot resolve: the target is
not a function of the input at the accuracy asked. Entries that keep their t_end under the rule are unchanged.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

MAX_AMPLIFICATION = 10.0
DEFAULT_PDES = ("burgers1d", "kdv1d", "fisher_kpp1d", "ns2d", "burgers2d", "grayscott2d", "ks2d")
HALVINGS = 6  # t_end / 64 .. t_end


def growth(name: str, n: int = 8, eps: float = 1e-4, settings: dict | None = None, seed: int = 0) -> dict:
    """{"t": [K+1] times t_end / 2^k ascending, "amplification": [K+1] medians, "moved": [K+1] medians, "t_end"}
    for ``n`` samples of ``name`` (seed ``seed``) with ``settings`` (strings as --set takes them) applied."""
    import torch

    from pdestream import datasets, generator

    pde = generator.get_pde(name).replace({**(settings or {}), "n_frames": str(2 ** HALVINGS + 1)})
    data = datasets.sample_tensors(pde, np.arange(n), seed)
    u0, params = data["u"][:, 0], data["params"]
    rms = u0.flatten(1).pow(2).mean(1).sqrt().clamp_min(1e-12).view(-1, *[1] * (u0.dim() - 1))
    noise = torch.randn(u0.shape, generator=torch.Generator().manual_seed(seed), dtype=u0.dtype)
    u1 = u0 + eps * rms * noise
    oracle = datasets.SolverOracle(pde)

    def norm(x):
        return x.flatten(1).norm(dim=1)

    d0 = norm(u1 - u0)
    a, b, frames = u0, u1, 0
    t, amp, moved = [], [], []
    for k in range(HALVINGS, -1, -1):
        target = 2 ** (HALVINGS - k)  # frames of t_end / 64 each
        a, b = oracle(a, params, target - frames), oracle(b, params, target - frames)
        frames = target
        t.append(float(pde.times()[frames]))
        amp.append(float((norm(b - a) / d0).median()))
        moved.append(float((norm(a - u0) / norm(u0).clamp_min(1e-12)).median()))
    return {"t": t, "amplification": amp, "moved": moved, "t_end": float(pde.times()[-1])}


def horizon(g: dict) -> float:
    """The rule in the module docstring: the longest t_end / 2^k with median amplification <= MAX_AMPLIFICATION
    (t_end / 64 if none: the caller reports it)."""
    ok = [t for t, a in zip(g["t"], g["amplification"]) if a <= MAX_AMPLIFICATION]
    return max(ok) if ok else g["t"][0]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.predictability", description=__doc__.splitlines()[0])
    p.add_argument("--pdes", default=",".join(DEFAULT_PDES), help="comma-separated catalog entries")
    p.add_argument("--n", type=int, default=8, help="samples per entry (default 8)")
    p.add_argument("--eps", type=float, default=1e-4, help="relative size of the perturbation (default 1e-4)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a setting for every entry")
    a = p.parse_args(argv)
    from pdestream.catalog_names import NAMES

    pdes = [x for x in a.pdes.split(",") if x]
    bad = [x for x in pdes if x not in NAMES]
    if bad or not pdes or a.n < 1 or not 0 < a.eps < 1:
        sys.exit(f"--pdes {a.pdes!r} / --n {a.n} / --eps {a.eps}: need catalog entries (unknown: {', '.join(bad) or '-'}),"
                 " n >= 1 and 0 < eps < 1")
    bad_set = [kv for kv in a.set if "=" not in kv or not kv.split("=", 1)[0]]
    if bad_set:
        sys.exit(f"--set {bad_set[0]!r}: need KEY=VALUE, e.g. --set n=64")
    settings = dict(kv.split("=", 1) for kv in a.set)
    print("| entry | t_end | " + " | ".join(f"t_end/{2 ** k}" for k in range(HALVINGS, -1, -1)) + " | horizon |")
    print("|---" * (HALVINGS + 4) + "|")
    for i, name in enumerate(pdes):
        print(f"[{i + 1}/{len(pdes)}] {name} ...", file=sys.stderr, flush=True)
        try:
            g = growth(name, a.n, a.eps, settings)
        except ValueError as err:  # a setting the entry refuses, a steady entry, a blow-up: one line
            sys.exit(str(err).splitlines()[0])
        cells = [f"{amp:.3g} ({mv:.2f})" for amp, mv in zip(g["amplification"], g["moved"])]
        print(f"| {name} | {g['t_end']:g} | " + " | ".join(cells) + f" | {horizon(g):g} |", flush=True)
    print(f"\ncells: median amplification of a {a.eps:g} relative IC perturbation (median ||u(t) - u0|| / ||u0||); "
          f"horizon: the longest t_end / 2^k with amplification <= {MAX_AMPLIFICATION:g}")


if __name__ == "__main__":
    main()
