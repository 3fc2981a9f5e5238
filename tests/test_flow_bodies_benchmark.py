"""The grid study's own arithmetic (benchmarks/flow_bodies.py): the control-volume forces against a pressure field
whose force is known in closed form, and the three-grid observed order / Richardson limit on a known sequence.
Small numpy arrays only (no rollout)."""

import math
from types import SimpleNamespace

import numpy as np

from benchmarks.flow_bodies import _box_balance, _prolong, momentum_balance, richardson, weighted_force


def _linear_pressure(a=0.7, n=80, h=0.01):
    """Fluid at rest under p = a x on an n x n grid of spacing h (MAC layout)."""
    p = a * (np.arange(n)[None, :] + 0.5) * h * np.ones((n, 1))
    return np.zeros((n, n + 1)), np.zeros((n + 1, n)), p


def test_momentum_balance_is_minus_the_pressure_gradient_times_the_area():
    a, h = 0.7, 0.01
    u, v, p = _linear_pressure(a, h=h)
    fx, fy = momentum_balance(u, v, p, h, (20, 50, 25, 45))  # 30 x 20 cells
    assert math.isclose(fx, -a * (30 * h) * (20 * h), rel_tol=1e-12)
    assert abs(fy) < 1e-14


def test_a_box_past_the_grid_gives_none_not_a_crash():
    u, v, p = _linear_pressure(0.7, n=16, h=0.025625)
    s = SimpleNamespace(u=u, v=v, p=p)
    # 86x16's 7-radii square around a body shifted upstream to cell 7 reaches cell 0 (its differences cell -1)
    assert _box_balance(s, 0.025625, 7, 8, 16, 16, 3.5, 1.0) == (None, None)
    assert _box_balance(s, 0.025625, 8, 8, 16, 16, 2.5, 1.0)[0] is not None


def test_weighted_force_is_minus_the_gradient_times_the_weight_integral():
    a, h, r1, r2 = 0.7, 0.01, 0.1, 0.2
    u, v, p = _linear_pressure(a, h=h)
    rho = np.linspace(r1, r2, 20001)
    ring = np.trapezoid(2 * np.pi * rho * 0.5 * (1 + np.cos(np.pi * (rho - r1) / (r2 - r1))), rho)
    fx, fy = weighted_force(u, v, p, h, 0.4, 0.4, r1, r2)
    assert math.isclose(fx, -a * (np.pi * r1 ** 2 + ring), rel_tol=2e-3)
    assert abs(fy) < 1e-3 * abs(fx)


def test_richardson_recovers_order_and_limit_and_flags_sign_changes():
    rows = [{"body": "sharp", "ny": ny, "cd": 5.0 + 0.3 * (16 / ny) ** 2, "cl": [0.1, -0.1, 0.05][k]}
            for k, ny in enumerate((16, 32, 64))]
    line = richardson(rows).splitlines()[-1]
    assert "| 2.00, 5.0000 |" in line and "| sign |" in line


def test_prolong_is_exact_for_linear_fields_on_the_doubled_grid():
    h = 0.1
    coarse = 2.0 + 3.0 * np.arange(9)[None, :] * h + 0.5 * (np.arange(4)[:, None] + 0.5) * h  # u-like: faces in x
    fine = _prolong(coarse, (8, 17), 0.0, 0.5)
    x, y = np.arange(17)[None, :] * h / 2, (np.arange(8)[:, None] + 0.5) * h / 2
    interior = (slice(1, -1), slice(None))  # the edge rows lie beyond the coarse centres (extended, not linear)
    assert np.allclose(fine[interior], (2.0 + 3.0 * x + 0.5 * y)[interior])
