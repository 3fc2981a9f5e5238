"""The vortex-street anchors' Strouhal number (benchmarks/flow_anchors.py): known signals, no solver needed."""

import numpy as np
import pytest

from benchmarks.flow_anchors import VortexCase, strouhal


@pytest.mark.parametrize("freq", [0.9, 1.5, 3.0])
def test_strouhal_of_a_sine(freq):
    case = VortexCase()  # D = 0.2, u_in = 1: St = 0.2 f
    dt = 0.01
    t = np.arange(4000) * dt
    st = strouhal(np.sin(2 * np.pi * freq * t + 0.3) + 0.5, dt, case)
    assert st == pytest.approx(freq * 2 * case.radius / case.u_in, rel=0.01)


def test_strouhal_of_a_flat_or_noisy_signal_is_nan():
    case = VortexCase()
    rng = np.random.default_rng(0)
    assert np.isnan(strouhal(np.full(400, 0.3), 0.1, case))
    assert np.isnan(strouhal(1e-6 * rng.standard_normal(400), 0.1, case))  # rounding noise is not shedding


def test_case_viscosity_and_probe():
    case = VortexCase(re=200.0, u_in=2.0, radius=0.05, centre=(0.4, 0.5))
    assert case.nu == pytest.approx(2.0 * 0.1 / 200.0)
    assert case.probe == pytest.approx((0.6, 0.5))
