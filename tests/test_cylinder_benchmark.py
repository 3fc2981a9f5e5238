"""The Schaefer-Turek 2D-2 benchmark's own arithmetic (benchmarks/flow_validation.py): the unsteady control-volume
force against an exact unsteady flow with no body in the box (its force is zero), and the convergence table's
orders and Richardson limit on a known sequence. Small arrays only (no rollout)."""

import math

import numpy as np

from benchmarks.flow_validation import box_momentum, cylinder_table
from pdestream.generator.flow import Geometry

NU = 0.5  # large, so the momentum inside the box decays fast: dM/dt = -2 nu M is as large as the fluxes


def _taylor_green_box(n, t=0.3, cx=2.3, cy=3.4):
    """(S, dM/dt) of box_momentum on the exact decaying Taylor-Green vortex u = sin x cos y F, v = -cos x sin y F,
    p = (cos 2x + cos 2y) F^2 / 4, F = exp(-2 nu t), sampled on the MAC grid of n x n cells over [0, 2 pi)^2;
    the box 2 x 0.7 wide about (cx, cy), off every symmetry line, so its momentum is not zero."""
    h = 2 * math.pi / n
    f = math.exp(-2 * NU * t)
    xf, xc = np.arange(n + 1) * h, (np.arange(n) + 0.5) * h
    u = np.sin(xf)[None, :] * np.cos(xc)[:, None] * f
    v = -np.cos(xc)[None, :] * np.sin(xf)[:, None] * f
    p = (np.cos(2 * xc)[None, :] + np.cos(2 * xc)[:, None]) * f * f / 4
    geom = Geometry(n, n, 2 * math.pi, 2 * math.pi)
    m, s = box_momentum(geom, u, v, p, NU, cx, cy, 1e-9, int(round(0.35 / h)))  # r ~ 0: no body, nothing left out
    return np.asarray(s, np.float64), -2 * NU * np.asarray(m, np.float64)  # the exact dM/dt of M ~ F


def test_unsteady_control_volume_force_of_a_body_free_box_vanishes_at_second_order():
    errs = []
    for n in (64, 128):
        s, dmdt = _taylor_green_box(n)
        assert np.all(np.abs(dmdt) > 0.05)  # the d/dt term matters: S alone is not the force here
        errs.append(np.max(np.abs(s - dmdt)) / np.max(np.abs(dmdt)))
    assert errs[0] < 0.005  # 2.3e-3 at 64 cells, 6.3e-4 at 128 (float32 sums)
    assert math.log2(errs[0] / errs[1]) > 1.5


def test_convergence_table_recovers_order_and_limit_and_flags_sign_changes():
    rows = [{"ny": ny, "nx": 86 * ny // 16, "advection": "maccormack", "cfl": 0.4, "tol": 1e-5,
             "cd_max": 3.2 + 0.4 * (16 / ny) ** 2, "cl_max": [0.9, 1.05, 0.98][k], "st": 0.3 - 0.08 * 16 / ny}
            for k, ny in enumerate((16, 32, 64))]
    table = cylinder_table(rows)
    line = table.splitlines()[-1]
    assert line.startswith("| 16/32/64 |") and "| 2.00, 3.2000 | sign | 1.00, 0.3000 |" in line
    assert "| 344x64 | 15.6 | maccormack | 0.4 | 3.2250 (-0.0050) |" in table
