"""Schaefer-Turek 2D-1's grid study averaged over the cut cells' alignment (issue 28; docs/results/flows.md, "An
alignment-averaged grid study"): reads the JSON lines of benchmarks/flow_bodies.py run at several --shift-x and
prints, per grid, each shift's row and the mean / std / half range over the shifts, then the orders of the means
(against the published interval's middle, and the observed three-grid order with its Richardson limit) and the
rule's verdict (order >= 1.5 and both grid-to-grid differences above the alignment scatter).

    python -m benchmarks.flow_align [DIR]      # DIR default benchmarks/results/flow_align

DIR holds shift_<S>.jsonl (16/32/64 from rest) and c128_t2_<S>.jsonl (688x128, the figure: t 2.0 past the 344x64
state); c128_t1_<S>.jsonl (t 1.0) and c128_t3_<S>.jsonl (t 3.0, a drift check) give the continuation's drift
against the figure. Numpy only, no JAX.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

KEYS = ("cd", "cl", "dp", "cd_cv", "cl_cv")
NAMES = {"cd": "Cd", "cl": "Cl", "dp": "Delta p", "cd_cv": "Cd (m. b.)", "cl_cv": "Cl (m. b.)"}
PUBLISHED = {"cd": (5.57, 5.59), "cl": (0.0104, 0.0110), "dp": (0.1172, 0.1176),
             "cd_cv": (5.57, 5.59), "cl_cv": (0.0104, 0.0110)}


def load(folder: Path) -> tuple[list[dict], dict[str, list[dict]]]:
    """(rows of the figures: shift_*.jsonl and c128_t2_*.jsonl, {"1.0": c128_t1 rows, "3.0": c128_t3 rows}): each
    a flow_bodies row."""
    read = lambda pat: [json.loads(line) for f in sorted(folder.glob(pat))  # noqa: E731
                        for line in f.read_text().splitlines() if line.strip()]
    return read("shift_*.jsonl") + read("c128_t2_*.jsonl"), {"1.0": read("c128_t1_*.jsonl"),
                                                              "3.0": read("c128_t3_*.jsonl")}


def stats(rows: list[dict]) -> dict[int, dict]:
    """Per ny: {"shifts": sorted shifts, key: (mean, std (population), half range)} over that grid's rows."""
    out = {}
    for ny in sorted({r["ny"] for r in rows}):
        rs = [r for r in rows if r["ny"] == ny]
        out[ny] = {"shifts": sorted(r["shift_x"] for r in rs), "nx": rs[0]["nx"]}
        for k in KEYS:
            a = np.array([r[k] for r in rs])
            out[ny][k] = (float(a.mean()), float(a.std()), float(0.5 * (a.max() - a.min())))
    return out


def three_grid(f1: float, f2: float, f3: float) -> tuple[float | None, float | None]:
    """Observed order p = log2((f1 - f2) / (f2 - f3)) and Richardson limit f3 + (f3 - f2) / (2^p - 1); (None, None)
    where the differences differ in sign (or one is 0), (p, None) where p <= 0 (no limit)."""
    d1, d2 = f1 - f2, f2 - f3
    if d1 * d2 <= 0:
        return None, None
    p = math.log2(d1 / d2)
    return p, (f3 - d2 / (2 ** p - 1) if p > 0 else None)


def order_to_published(f1: float, f2: float, lo_hi: tuple) -> float:
    """log2(|f1 - mid| / |f2 - mid|), mid the published interval's middle (errors floored at 1e-12)."""
    mid = 0.5 * sum(lo_hi)
    return math.log2(max(abs(f1 - mid), 1e-12) / max(abs(f2 - mid), 1e-12))


def verdict(m: list[tuple[float, float]], p: float | None) -> str:
    """The rule's verdict for one quantity over three grids, m = [(mean, std)] * 3 coarse to fine, p its order."""
    diffs = [abs(m[i][0] - m[i + 1][0]) for i in range(2)]
    scatter = [max(m[i][1], m[i + 1][1]) for i in range(2)]
    if any(d <= s for d, s in zip(diffs, scatter)):
        return "no order at this scatter (" + ", ".join(f"difference {d:.4f} vs std {s:.4f}"
                                                          for d, s in zip(diffs, scatter)) + ")"
    if p is None:
        return "missed (differences change sign)"
    return f"met (p {p:.2f})" if p >= 1.5 else f"missed (p {p:.2f} < 1.5)"


def tables(rows: list[dict], legs: dict[str, list[dict]]) -> str:
    """The markdown tables: per grid (shifts, mean, std, half range), the continuation's drift, the orders."""
    st = stats(rows)
    head = "| grid | shift | " + " | ".join(NAMES[k] for k in KEYS) + " |\n|---|---|" + "---|" * len(KEYS)
    out = [head]
    for ny, s in st.items():
        for r in sorted((r for r in rows if r["ny"] == ny), key=lambda r: r["shift_x"]):
            out.append(f"| {s['nx']}x{ny} | {r['shift_x']:g} | " + " | ".join(f"{r[k]:.4f}" for k in KEYS) + " |")
        for i, lab in enumerate(("**mean**", "std", "half range")):
            out.append(f"| {s['nx']}x{ny} | {lab} | " + " | ".join(f"{s[k][i]:.4f}" for k in KEYS) + " |")
    for t, leg in legs.items():
        if not leg:
            continue
        out += ["", "688x128 continuation, " + ("t 2.0 (the figure) minus t 1.0:" if float(t) < 2 else
                                                 "t 3.0 (the drift check) minus t 2.0 (the figure):"), "",
                "| shift | " + " | ".join(NAMES[k] for k in KEYS) + " |", "|---|" + "---|" * len(KEYS)]
        for r1 in sorted(leg, key=lambda r: r["shift_x"]):
            r2 = [r for r in rows if r["ny"] == r1["ny"] and r["shift_x"] == r1["shift_x"]]
            if r2:
                sign = 1 if float(t) < 2 else -1
                out.append(f"| {r1['shift_x']:g} | " + " | ".join(f"{sign * (r2[0][k] - r1[k]):+.4f}" for k in KEYS)
                           + " |")
    nys = list(st)
    out += ["", "Orders of the means against the published interval's middle, log2(|e_k| / |e_k+1|):", "",
            "| grids | " + " | ".join(NAMES[k] for k in KEYS) + " |", "|---|" + "---|" * len(KEYS)]
    for a, b in zip(nys, nys[1:]):
        cells = [f"{order_to_published(st[a][k][0], st[b][k][0], PUBLISHED[k]):.2f}" for k in KEYS]
        out.append(f"| {a} -> {b} | " + " | ".join(cells) + " |")
    out += ["", "Observed three-grid order of the means p, Richardson limit, and the rule's verdict:", "",
            "| grids | quantity | p | limit | verdict |", "|---|---|---|---|---|"]
    for a, b, c in zip(nys, nys[1:], nys[2:]):
        for k in KEYS:
            m = [st[n][k][:2] for n in (a, b, c)]
            p, lim = three_grid(*(x[0] for x in m))
            out.append(f"| {a}/{b}/{c} | {NAMES[k]} | {'sign' if p is None else f'{p:.2f}'} | "
                       f"{'' if lim is None else f'{lim:.4f}'} | {verdict(m, p)} |")
    return "\n".join(out)


def main(argv=None):
    args = sys.argv[1:] if argv is None else argv
    folder = Path(args[0]) if args else Path("benchmarks/results/flow_align")
    if not folder.is_dir():
        raise SystemExit(f"no folder {folder}: give the folder of flow_bodies' shift_*.jsonl files")
    rows, legs = load(folder)
    if not rows:
        raise SystemExit(f"no shift_*.jsonl rows in {folder}")
    print(tables(rows, legs))


if __name__ == "__main__":
    main()
