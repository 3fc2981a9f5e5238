"""Forces on the bodies of a flow, its signed distance to them, and vortex-shedding detection (JAX).

- ``body_force``: the force on the masked body per unit depth and density, a surface integral over the staircase
  of fluid-solid cell faces: the pressure of each fluid cell next to the body on that face (h wide) plus the wall
  shear nu du_t/dn over the half cell between the fluid cell's centre velocity and the no-slip face. First order in
  h (the staircase); Schaefer-Turek 2D-1/2D-2 figures in benchmarks/flow_validation.py.
- ``force_coefficients``: C = 2 F / (U^2 D) (F per unit depth and density, U the reference speed, D the
  reference length), the Schaefer & Turek (1996) normalisation with U their mean inflow speed and D the diameter.
- ``circle_distance``: the exact signed distance of cell centres to a circle (negative inside).
- ``shedding``: the Strouhal number of a lift series and whether its oscillation is developed (rules there).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

# Shedding rules (``shedding``): a lift oscillation of fitted amplitude below MIN_LIFT_AMPLITUDE (in C_l) is
# "no shedding" (karman2d's non-shedding sample of issue 28 had 0.004, the shedding ones 0.3-0.9); "developed"
# means the amplitude drifts by less than MAX_DRIFT over DRIFT_PERIODS periods, and the window holds that many.
MIN_LIFT_AMPLITUDE = 0.01
MAX_DRIFT = 0.02
DRIFT_PERIODS = 3


def body_force(geom, solid, state, nu):
    """Force on the masked body per unit depth and density (Fx, Fy) [m^3/s^2]: pressure on each fluid-solid
    cell face (the fluid cell's p, h wide) plus wall shear nu du/dn over the half cell between the fluid cell's
    centre velocity and the no-slip face. A staircase surface: first order in h.

    geom: a Geometry; solid [ny, nx] bool (all bodies); state: anything with u [ny, nx+1], v [ny+1, nx] and
    p [ny, nx] (pressure over density) of the solver's layout; nu: kinematic viscosity (m^2/s)."""
    f = 1.0 - solid.astype(state.p.dtype)
    sol = 1.0 - f
    p, h = state.p, geom.h
    uc = 0.5 * (state.u[:, 1:] + state.u[:, :-1])
    vc = 0.5 * (state.v[1:] + state.v[:-1])
    left = f[:, :-1] * sol[:, 1:]   # fluid cell (i) left of solid (i+1): pushes the body in +x
    right = sol[:, :-1] * f[:, 1:]
    below = f[:-1] * sol[1:]
    above = sol[:-1] * f[1:]
    fx = h * (jnp.sum(left * p[:, :-1]) - jnp.sum(right * p[:, 1:]))
    fy = h * (jnp.sum(below * p[:-1]) - jnp.sum(above * p[1:]))
    fx = fx + 2 * nu * (jnp.sum(below * uc[:-1]) + jnp.sum(above * uc[1:]))
    fy = fy + 2 * nu * (jnp.sum(left * vc[:, :-1]) + jnp.sum(right * vc[:, 1:]))
    return fx, fy


def force_coefficients(fx, fy, speed, length):
    """(C_d, C_l) = 2 (Fx, Fy) / (U^2 D): F per unit depth and density (``body_force``), U = ``speed`` (m/s),
    D = ``length`` (m)."""
    scale = 2.0 / (speed * speed * length)
    return fx * scale, fy * scale


def circle_distance(geom, cx, cy, r, dtype=jnp.float32):
    """Signed distance [ny, nx] (m) of the cell centres to the circle (cx, cy, r): |x - c| - r, negative inside
    (exact for a circle; the solver's mask is the cells with a negative value, ``grid.circle_solid``)."""
    h = geom.h
    x = (jnp.arange(geom.nx, dtype=dtype) + 0.5) * h
    y = (jnp.arange(geom.ny, dtype=dtype) + 0.5) * h
    x, y = jnp.meshgrid(x, y)
    return jnp.sqrt((x - cx) ** 2 + (y - cy) ** 2) - r


def shedding(lift, t, length, speed, min_amplitude=MIN_LIFT_AMPLITUDE, max_drift=MAX_DRIFT,
             periods=DRIFT_PERIODS):
    """Vortex shedding in a lift series: (St, sheds, developed, amplitude, drift) (float32, bool, bool, float32,
    float32 scalars); lift [T] (C_l at the frame times t [T], s), length D (m) and speed U (m/s) of St = f D / U.

    Frequency: the crossings of the series' mean (linearly interpolated between frames), f = (n - 1) / (2 (t_last
    - t_first)) over the n crossings, then corrected once by the turn of the fitted phase below (refit at the
    corrected f: within 0.1% on a sine of 4 to 6 frames per period). Amplitude and drift: a least-squares fit over
    the window of
    C_l(t) ~ c0 + c1 s + (a0 + a1 s) cos(2 pi f t) + (b0 + b1 s) sin(2 pi f t), s = (t - t_mid) f (periods
    from the window's middle): amplitude A = hypot(a0, b0) at the middle, drift = ``periods`` * dA/ds / A (the
    relative change of the amplitude over ``periods`` periods; a pure phase drift from an inexact f adds nothing
    to first order). ``sheds``: at least 3 crossings (a whole period) and A >= ``min_amplitude``; ``developed``:
    sheds, the window spans >= ``periods`` periods and |drift| < ``max_drift``. Where it does not shed, St,
    amplitude and drift are 0 (never NaN: ``sheds`` says which)."""
    dtype = lift.dtype
    t = t.astype(dtype)
    c = lift - jnp.mean(lift)
    c0, c1 = c[:-1], c[1:]
    cross = (c0 < 0) != (c1 < 0)
    frac = jnp.where(cross, c0 / jnp.where(cross, c0 - c1, 1), 0)
    tc = t[:-1] + frac * (t[1:] - t[:-1])
    n = jnp.sum(cross)
    first = jnp.min(jnp.where(cross, tc, jnp.inf))
    last = jnp.max(jnp.where(cross, tc, -jnp.inf))
    enough = n >= 3
    freq = jnp.where(enough, (n - 1) / jnp.where(enough, 2 * (last - first), 1), 0).astype(dtype)
    mid = 0.5 * (t[0] + t[-1])

    def fit(freq):
        s = (t - mid) * freq
        cos, sin = jnp.cos(2 * math.pi * freq * t), jnp.sin(2 * math.pi * freq * t)
        design = jnp.stack([jnp.ones_like(t), s, cos, sin, s * cos, s * sin], 1)
        return jnp.linalg.lstsq(design, lift)[0]

    coef = fit(freq)  # the phase of (a, b) turns at -2 pi (f_true - f) / f per period: correct f once, refit
    amp2 = coef[2] ** 2 + coef[3] ** 2
    turn = (coef[2] * coef[5] - coef[3] * coef[4]) / jnp.where(amp2 > 0, amp2, 1)
    freq = jnp.where(enough, freq * (1 - turn / (2 * math.pi)), freq)
    coef = fit(freq)
    amp = jnp.hypot(coef[2], coef[3])
    slope = (coef[2] * coef[4] + coef[3] * coef[5]) / jnp.where(amp > 0, amp, 1)
    drift = periods * slope / jnp.where(amp > 0, amp, 1)
    sheds = enough & (amp >= min_amplitude)
    developed = sheds & ((t[-1] - t[0]) * freq >= periods) & (jnp.abs(drift) < max_drift)
    zero = jnp.zeros((), dtype)
    st = jnp.where(sheds, freq * length / speed, zero)
    return st, sheds, developed, jnp.where(sheds, amp, zero), jnp.where(sheds, drift, zero)


__all__ = ["DRIFT_PERIODS", "MAX_DRIFT", "MIN_LIFT_AMPLITUDE", "body_force", "circle_distance",
           "force_coefficients", "shedding"]
