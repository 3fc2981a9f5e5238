"""A body and a free stream in the 3D MAC solver (generator.flow.mac3d) by volume penalisation (JAX).

mac3d's projection is a direct FFT/DCT solve on the whole box, so a body cannot enter it as an internal boundary.
Instead (Brinkman penalisation, Angot, Bruneau & Fabrie 1999) the momentum equation gets -chi/eta (u - u_b) with
chi in [0, 1] the body's volume fraction on each velocity face and eta [s] a short relaxation time; treated
implicitly, u <- (u + a u_b) / (1 + a) with a = dt chi / eta, it is stable for any eta. The force the body takes
from the fluid (per unit density) is the momentum it removes per unit time, F = sum chi / eta (u - u_b) h^3 over
the faces (u after the relaxation: the implicit update's own balance). A free stream in a box periodic along the
stream uses the same relaxation toward (U, 0, 0) in a fringe near the box's ends (Spalart & Watmuff 1993), which
turns the periodic axis into an inflow/outflow pair; the lateral axes stay periodic (a periodic array of bodies:
the blockage is the lateral period).

The mask is smoothed over one cell (chi = clamp(1/2 + (R - r) / h, 0, 1), the volume fraction of a face's cell
cut by a plane at the surface), so the force varies smoothly as the body moves against the grid; the penalisation
error stays O(h) plus the Brinkman layer sqrt(nu eta) (benchmarks/sphere_drag.py measures it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from . import mac3d


class Relax(NamedTuple):
    """The implicit relaxations of one step: body (chi per component on its faces, [*face_shape(k)], 0..1) toward
    rest with time ``eta`` [s]; fringe (rate per component [1/s] on its faces) toward ``target`` (a velocity per
    component, m/s, scalars or face arrays). The body and the fringe should not overlap (the force counts the
    body's relaxation only)."""

    chi: tuple
    eta: float
    fringe: tuple
    target: tuple


def ball_fraction(box: mac3d.Box, centre, radius: float, k: int, dtype=np.float32, ramp: float = 1.0):
    """Smoothed volume fraction [*face_shape(k)] of the ball (centre per axis [m], radius [m]) on velocity
    component k's faces: clamp(1/2 + (radius - distance) / (ramp h), 0, 1) (a ramp ``ramp`` cells wide; 1: a
    face's cell cut by a plane at the surface; -> 0: the sharp indicator, a staircase)."""
    x = mac3d.points(box, box.face_shape(k), box.offsets(k), dtype)
    r = jnp.sqrt(sum((xi - c) ** 2 for xi, c in zip(x, centre)))
    return jnp.clip(0.5 + (radius - r) / (ramp * box.h), 0.0, 1.0)


def _smoothstep(s):
    s = jnp.clip(s, 0.0, 1.0)
    return s * s * (3 - 2 * s)


def fringe_rate(box: mac3d.Box, start: float, end: float, rise: float, rate: float, k: int, dtype=np.float32):
    """Fringe relaxation rate [1/s] on component k's faces [*face_shape(k)]: ``rate`` for start + rise <= x <=
    end - rise along axis 0 (m), smooth (C1) ramps of width ``rise`` up from start and down to end, 0 elsewhere."""
    x = mac3d.points(box, box.face_shape(k), box.offsets(k), dtype)[0]
    return rate * _smoothstep((x - start) / rise) * _smoothstep((end - x) / rise)


def relax(vel, r: Relax, dt):
    """The face velocities (one array per component, m/s) after the fringe's and the body's implicit relaxations
    over dt (s): u <- (u + a u_target) / (1 + a), a = dt rate, then u <- u / (1 + dt chi / eta)."""
    out = []
    for v, chi, lam, tgt in zip(vel, r.chi, r.fringe, r.target):
        v = (v + dt * lam * tgt) / (1 + dt * lam)
        out.append(v / (1 + dt * chi / r.eta))
    return tuple(out)


def _periodic_duplicates(box: mac3d.Box, k: int, dtype):
    """Weight [*face_shape(k)]: 0 on a periodic axis's last face along k (a copy of the first), else 1."""
    w = jnp.ones(box.face_shape(k), dtype)
    if box.periodic[k]:
        w = w.at[(slice(None),) * k + (-1,)].set(0)
    return w


def step(box: mac3d.Box, state: mac3d.State, params: mac3d.Params3, r: Relax, dt):
    """One mac3d step with the relaxations applied before the projection: (state, forces [2, 3] per unit density,
    m^4/s^2 = N per kg/m^3): row 0 the force on the body (the momentum its relaxation removes per unit time, drag
    along +x), row 1 the momentum the fringe adds per unit time. Steady, the two balance when the advection
    conserves momentum (the semi-Lagrangian advection does so only approximately: their gap measures it)."""
    vel, scalar = mac3d.predict(box, state, params, dt)
    new = mac3d.apply_bc(box, relax(vel, r, dt))
    # each distinct face once (a periodic axis's last face duplicates its first)
    w = [_periodic_duplicates(box, k, v.dtype) for k, v in enumerate(new)]
    body = [jnp.sum(wk * chi / r.eta * v) for wk, chi, v in zip(w, r.chi, new)]
    fringe = [jnp.sum(wk * (v - u)) / dt for wk, v, u in zip(w, _fringe_only(vel, r, dt), vel)]
    forces = jnp.stack([jnp.stack(body), jnp.stack(fringe)]) * box.h**box.ndim
    return mac3d.finish(box, state, new, scalar, dt), forces


def _fringe_only(vel, r: Relax, dt):
    return tuple((v + dt * lam * tgt) / (1 + dt * lam) for v, lam, tgt in zip(vel, r.fringe, r.target))


def run(box: mac3d.Box, state: mac3d.State, params: mac3d.Params3, r: Relax, dt, n_steps: int):
    """n_steps penalised steps in a lax.scan (jit with box and n_steps static): (state, ``step``'s forces per
    step [n, 2, 3])."""
    return jax.lax.scan(lambda s, _: step(box, s, params, r, dt), state, None, length=n_steps)


def stream_state(box: mac3d.Box, speed: float, dtype=np.float32) -> mac3d.State:
    """A uniform stream (speed, 0, 0) [m/s] on every face: an impulsively started body's initial state."""
    s = mac3d.initial_state(box, dtype)
    vel = (jnp.full(box.face_shape(0), speed, dtype),) + s.vel[1:]
    return s._replace(vel=mac3d.apply_bc(box, vel))
