"""The finite-volume family's 2D entries: ``shallow_water2d`` (flat-bed shallow water with wet/dry fronts) and
``euler2d`` (compressible Euler of an ideal gas), ``generator.problem.Problem``s on n x n square cells of
[0, length]^2 (the schemes: ``generator.finite_volume.shallow_water`` and ``euler``).

A sample is u [T, C, n, n] float32 at ``times()``, index [.., i, j] the cell centre (x_i, y_j): shallow_water2d
stores the conserved h, hu, hv (depth and momenta: no division by a vanishing depth at a dry cell), euler2d the
primitive rho, u, v, p. Boundaries per axis (``bc``): outflow (zero gradient), periodic or wall (reflective);
one word for both axes, or "x=wall,y=periodic" (``bc.x`` / ``bc.y`` set one axis).

Time, failures and identity as euler1d's (``problem.FiniteVolume``): one fixed step per configuration, dt =
cfl h / (2 s0) with s0 the largest speed the IC distribution allows (the 2D CFL number dt (max(|u| + c) +
max(|v| + c)) / h sums both axes); a sample that outruns its step (MAX_CFL), loses positivity or goes non-finite
fails with its cause; samples run in fixed chunks (bit-identical alone and in a batch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import numpy as np

from pdestream.generator.lazy_jax import jax, jnp

from ..domains import Fixed
from ..problem import Param
from .problem import (
    EULER_2D,
    GAMMA_MAX,
    NAVIER_STOKES_2D,
    SHALLOW_WATER,
    FiniteVolume,
    FVGrid,
    ViscousGas,
    check_gamma,
    ic_domains,
)
from .scheme import SIDE_KINDS

SW_MAX_CFL = 0.5  # the positivity bound of MUSCL-HLL with SSP-RK3 (shallow_water's docstring)


# --- the ICs' shared pieces -----------------------------------------------------------------------------------------
def _draw(doms: dict, key: jax.Array) -> list:
    return [d.sample(jax.random.fold_in(key, j)) for j, d in enumerate(doms.values())]


def _centres(grid):
    """Cell-centre coordinates (x [n, 1], y [1, n]) float32."""
    c = jnp.asarray(grid.coords())
    return c[:, None], c[None, :]


def _fourier(key: jax.Array, grid, count: int, max_mode: int) -> jax.Array:
    """``count`` random smooth periodic fields [count, n, n] on [0, length)^2, each a Fourier series of the modes
    (kx, ky) in [-max_mode, max_mode]^2 but (0, 0) with N(0, 1 / |k|^2) coefficients, scaled to max |f| = 1."""
    x, y = _centres(grid)
    k = np.arange(-max_mode, max_mode + 1)
    kx, ky = (a.ravel() for a in np.meshgrid(k, k, indexing="ij"))
    keep = (kx != 0) | (ky != 0)
    kx, ky = jnp.asarray(kx[keep], jnp.float32), jnp.asarray(ky[keep], jnp.float32)
    phase = (2 * np.pi / grid.length) * (kx[:, None, None] * x + ky[:, None, None] * y)  # [modes, n, n]
    a, b = jax.random.normal(key, (2, count, kx.shape[0]), jnp.float32) / jnp.sqrt(kx**2 + ky**2)
    f = jnp.tensordot(a, jnp.cos(phase), 1) + jnp.tensordot(b, jnp.sin(phase), 1)
    return f / jnp.max(jnp.abs(f), axis=(1, 2), keepdims=True)


def _check_smooth(ic, grid) -> None:
    if not 0 < ic.amplitude < 1:
        raise ValueError(f"ic.amplitude={ic.amplitude:g} not allowed: must be in (0, 1) (the base state stays "
                         "positive)")
    if not 1 <= ic.max_mode <= grid.n // 8:
        raise ValueError(f"ic.max_mode={ic.max_mode} not allowed on n={grid.n}: need 1 <= max_mode <= n//8 = "
                         f"{grid.n // 8}")


def _check_inside(name: str, dom, grid) -> None:
    lo, hi = dom.bounds
    if not 0 < lo <= hi < grid.length:
        raise ValueError(f"ic.{name}={dom} not allowed: must lie in (0, {grid.length:g})")


# --- shallow water ICs: stored (h, hu, hv) [3, n, n] --------------------------------------------------------------
@dataclass(frozen=True)
class RadialDamBreak:
    """PDEBench's 2D shallow-water set-up (Takamoto et al. 2022, radial_dam_break.yaml): depth h_in inside a
    circle of radius ``radius`` centred at (cx, cy), h_out outside, at rest; each a domain. PDEBench's own:
    radius uniform(0.3, 0.7), centre the middle of [-2.5, 2.5]^2 (here ic.cx=2.5 ic.cy=2.5 on length 5)."""

    h_in: str = "2"
    h_out: str = "1"
    radius: str = "uniform(0.3, 0.7)"
    cx: str = "uniform(2, 3)"
    cy: str = "uniform(2, 3)"
    kind = "radial"
    field_count = 3
    NAMES: ClassVar[tuple] = ("h_in", "h_out", "radius", "cx", "cy")

    def sample(self, key: jax.Array, grid, n_fields: int = 3) -> jax.Array:
        h_in, h_out, radius, cx, cy = _draw(ic_domains(self, self.NAMES), key)
        x, y = _centres(grid)
        h = jnp.where((x - cx) ** 2 + (y - cy) ** 2 <= radius**2, h_in, h_out)
        return jnp.stack([h, jnp.zeros_like(h), jnp.zeros_like(h)]).astype(jnp.float32)

    def check(self, grid) -> None:
        doms = ic_domains(self, self.NAMES)
        if not min(doms["h_in"].bounds) > 0 or not min(doms["h_out"].bounds) >= 0:
            raise ValueError(f"ic.h_in={doms['h_in']}, ic.h_out={doms['h_out']} not allowed: need h_in > 0, h_out >= 0")
        if not min(doms["radius"].bounds) > 0:
            raise ValueError(f"ic.radius={doms['radius']} not allowed: must be > 0")
        _check_inside("cx", doms["cx"], grid)
        _check_inside("cy", doms["cy"], grid)

    def bound(self, grid) -> float:
        d = ic_domains(self, ("h_in", "h_out"))
        return max(max(abs(b) for b in v.bounds) for v in d.values())

    def speed(self, g: float) -> float:
        """Largest c = sqrt(g h) of the initial depths (the water is at rest)."""
        return math.sqrt(g * self.bound(None))

    def __str__(self) -> str:
        return (f"radial dam break: depth {self.h_in} inside a circle of radius {self.radius} at ({self.cx}, "
                f"{self.cy}), {self.h_out} outside, at rest")


@dataclass(frozen=True)
class DamBreak:
    """A straight dam at x = x0: depth h_l to its left, h_r to its right (0: a dry bed, Ritter's problem; > 0:
    Stoker's), at rest, uniform in y (nothing random)."""

    h_l: float = 1.0
    h_r: float = 0.0
    x0: float = 2.5
    kind = "dam"
    field_count = 3

    def sample(self, key: jax.Array, grid, n_fields: int = 3) -> jax.Array:
        x, y = _centres(grid)
        h = jnp.broadcast_to(jnp.where(x < self.x0, jnp.float32(self.h_l), jnp.float32(self.h_r)), (grid.n, grid.n))
        return jnp.stack([h, jnp.zeros_like(h), jnp.zeros_like(h)]).astype(jnp.float32)

    def check(self, grid) -> None:
        if not (self.h_l > 0 and self.h_r >= 0):
            raise ValueError(f"ic.h_l={self.h_l:g}, ic.h_r={self.h_r:g} not allowed: need h_l > 0, h_r >= 0")
        if not 0 < self.x0 < grid.length:
            raise ValueError(f"ic.x0={self.x0:g} not allowed: the dam must lie in (0, {grid.length:g})")

    def bound(self, grid) -> float:
        return max(self.h_l, self.h_r)

    def speed(self, g: float) -> float:
        return math.sqrt(g * max(self.h_l, self.h_r))

    def __str__(self) -> str:
        return f"dam break at x = {self.x0:g}: depth {self.h_l:g} left, {self.h_r:g} right, at rest"


@dataclass(frozen=True)
class SmoothWater:
    """A random smooth periodic state: h = 1 + amplitude f1, u = amplitude f2, v = amplitude f3 (stored h, hu,
    hv), each f a random Fourier series of modes |k_x|, |k_y| <= max_mode scaled to max |f| = 1."""

    amplitude: float = 0.2
    max_mode: int = 3
    kind = "smooth"
    field_count = 3

    def sample(self, key: jax.Array, grid, n_fields: int = 3) -> jax.Array:
        f = self.amplitude * _fourier(key, grid, 3, self.max_mode)
        h = 1 + f[0]
        return jnp.stack([h, h * f[1], h * f[2]])

    def check(self, grid) -> None:
        _check_smooth(self, grid)

    def bound(self, grid) -> float:
        return (1 + self.amplitude) * (1 + self.amplitude)

    def speed(self, g: float) -> float:
        return self.amplitude + math.sqrt(g * (1 + self.amplitude))

    def __str__(self) -> str:
        return f"smooth periodic state, amplitude {self.amplitude:g} about (h, u, v) = (1, 0, 0), modes <= {self.max_mode}"


SW_IC_KINDS: dict[str, type] = {c.kind: c for c in (RadialDamBreak, DamBreak, SmoothWater)}


# --- Euler ICs: primitive (rho, u, v, p) [4, n, n] --------------------------------------------------------------------
def _quadrants(grid, states, x0, y0):
    """[4, n, n]: Lax-Liu's quadrants 1 (x > x0, y > y0), 2 (x < x0, y > y0), 3 (both below), 4 (x > x0, y < y0),
    each state 4 scalars (rho, u, v, p)."""
    x, y = _centres(grid)
    right, top = x > x0, y > y0
    s = [jnp.stack([jnp.float32(v) for v in st])[:, None, None] for st in states]
    return jnp.where(top, jnp.where(right, s[0], s[1]), jnp.where(right, s[3], s[2])).astype(jnp.float32)


@dataclass(frozen=True)
class Riemann2D:
    """A random 2D Riemann problem (Lax & Liu 1998's four-quadrant set-up): a state (rho, u, v, p) drawn for
    each quadrant around the corner (x0, y0), quadrants numbered 1..4 anticlockwise from x > x0, y > y0; every
    setting a domain (rho1 .. p4, x0, y0)."""

    rho: str = "uniform(0.2, 1)"
    u: str = "uniform(-0.5, 0.5)"
    v: str = "uniform(-0.5, 0.5)"
    p: str = "loguniform(0.1, 1)"
    x0: str = "uniform(0.3, 0.7)"
    y0: str = "uniform(0.3, 0.7)"
    kind = "riemann"
    field_count = 4
    NAMES: ClassVar[tuple] = ("rho", "u", "v", "p", "x0", "y0")

    def sample(self, key: jax.Array, grid, n_fields: int = 4) -> jax.Array:
        doms = ic_domains(self, self.NAMES)
        states = [[doms[n].sample(jax.random.fold_in(key, 4 * q + j)) for j, n in enumerate(("rho", "u", "v", "p"))]
                  for q in range(4)]
        x0 = doms["x0"].sample(jax.random.fold_in(key, 16))
        y0 = doms["y0"].sample(jax.random.fold_in(key, 17))
        return _quadrants(grid, states, x0, y0)

    def check(self, grid) -> None:
        doms = ic_domains(self, self.NAMES)
        for name in ("rho", "p"):
            if not min(doms[name].bounds) > 0:
                raise ValueError(f"ic.{name}={doms[name]} not allowed: densities and pressures must be > 0")
        _check_inside("x0", doms["x0"], grid)
        _check_inside("y0", doms["y0"], grid)

    def bound(self, grid) -> float:
        return max(max(abs(b) for b in d.bounds) for d in ic_domains(self, self.NAMES).values())

    def speed(self, gamma: float) -> float:
        """Largest max(|u|, |v|) + c of the quadrant states over the domains."""
        d = ic_domains(self, self.NAMES)
        vel = max(abs(b) for n in ("u", "v") for b in d[n].bounds)
        return vel + math.sqrt(gamma * max(d["p"].bounds) / min(d["rho"].bounds))

    def __str__(self) -> str:
        return (f"2D Riemann problem: four quadrants around ({self.x0}, {self.y0}), each (rho, u, v, p) drawn from "
                f"({self.rho}, {self.u}, {self.v}, {self.p})")


@dataclass(frozen=True)
class _Classic2D:
    """Fixed quadrant states (nothing random) around (x0, y0)."""

    x0: float = 0.5
    y0: float = 0.5
    field_count = 4
    STATES: ClassVar[tuple] = ()
    TITLE: ClassVar[str] = ""

    def states(self) -> tuple:
        return self.STATES

    def sample(self, key: jax.Array, grid, n_fields: int = 4) -> jax.Array:
        return _quadrants(grid, self.states(), jnp.float32(self.x0), jnp.float32(self.y0))

    def check(self, grid) -> None:
        for name in ("x0", "y0"):
            if not 0 < getattr(self, name) < grid.length:
                raise ValueError(f"ic.{name}={getattr(self, name):g} not allowed: must lie in (0, {grid.length:g})")

    def bound(self, grid) -> float:
        return max(abs(v) for st in self.states() for v in st)

    def speed(self, gamma: float) -> float:
        return max(max(abs(u), abs(v)) + math.sqrt(gamma * p / r) for r, u, v, p in self.states())

    def __str__(self) -> str:
        return f"{self.TITLE}: quadrant states (rho, u, v, p) 1..4 = {self.states()} around ({self.x0:g}, {self.y0:g})"


@dataclass(frozen=True)
class LaxLiu3(_Classic2D):
    kind = "config3"
    STATES: ClassVar[tuple] = ((1.5, 0.0, 0.0, 1.5), (0.5323, 1.206, 0.0, 0.3), (0.138, 1.206, 1.206, 0.029),
                               (0.5323, 0.0, 1.206, 0.3))
    TITLE: ClassVar[str] = "Lax-Liu configuration 3 (four shocks; Kurganov & Tadmor 2002 compare at t = 0.3)"


@dataclass(frozen=True)
class Sod2D(_Classic2D):
    """Sod's shock tube along ``axis`` (x: the jump at x0, uniform in y; y: at y0, uniform in x)."""

    axis: str = "x"
    kind = "sod"
    TITLE: ClassVar[str] = "Sod's shock tube (compare at t = 0.2)"

    def states(self) -> tuple:
        left, right = (1.0, 0.0, 0.0, 1.0), (0.125, 0.0, 0.0, 0.1)
        return (right, left, left, right) if self.axis == "x" else (right, right, left, left)

    def check(self, grid) -> None:
        if self.axis not in ("x", "y"):
            raise ValueError(f"ic.axis={self.axis!r} not allowed; allowed: x, y")
        super().check(grid)

    def __str__(self) -> str:
        return f"Sod's shock tube along {self.axis} (left (1, 0, 1), right (0.125, 0, 0.1), compare at t = 0.2)"


@dataclass(frozen=True)
class SmoothGas:
    """A random smooth periodic state: rho = 1 + amplitude f1, u = amplitude f2, v = amplitude f3, p = 1 +
    amplitude f4, each f a random Fourier series of modes |k_x|, |k_y| <= max_mode scaled to max |f| = 1."""

    amplitude: float = 0.2
    max_mode: int = 3
    kind = "smooth"
    field_count = 4

    def sample(self, key: jax.Array, grid, n_fields: int = 4) -> jax.Array:
        base = jnp.array([1.0, 0.0, 0.0, 1.0], jnp.float32)[:, None, None]
        return base + self.amplitude * _fourier(key, grid, 4, self.max_mode)

    def check(self, grid) -> None:
        _check_smooth(self, grid)

    def bound(self, grid) -> float:
        return 1 + self.amplitude

    def speed(self, gamma: float) -> float:
        return self.amplitude + math.sqrt(gamma * (1 + self.amplitude) / (1 - self.amplitude))

    def __str__(self) -> str:
        return (f"smooth periodic state, amplitude {self.amplitude:g} about (rho, u, v, p) = (1, 0, 0, 1), modes <= "
                f"{self.max_mode}")


@dataclass(frozen=True)
class RandomGas2D:
    """PDEBench's random 2D gas state (``init_multi_HD_2DRand``, mode 2D_rand): with rho0 ~ rho0, T0 ~ T0,
    d_rho ~ d_rho, d_p ~ d_p per sample, four fields f = sum over modes (i, j) in [-max_mode, max_mode]^2 with
    i j != 0 of |k|^(-1/2) sin(k . x + phi), phi ~ U(0, 2 pi) each, k = 2 pi (i, j) / length; the velocity (f1, f2)
    scaled so that its mean magnitude is mach sqrt(gamma T0), rho = rho0 (1 + d_rho f4 / mean|f4|), p = rho0 T0
    (1 + d_p f3 / mean|f3|); then with probability window_prob the product of tanh windows along x and y (ends
    x_l ~ window_left, x_r ~ window_right, width window_width, fractions of the length) blends the state into rest
    at rho0, p = rho0 T0 outside."""

    mach: float = 0.1
    rho0: str = "uniform(0.1, 10)"
    T0: str = "uniform(0.1, 10)"
    d_rho: str = "uniform(0.01, 0.2)"
    d_p: str = "uniform(0.01, 0.2)"
    max_mode: int = 4
    gamma: float = 5.0 / 3.0  # the ratio of specific heats the Mach number is measured with
    window_prob: float = 0.5
    window_left: str = "uniform(0.1, 0.45)"
    window_right: str = "uniform(0.55, 0.9)"
    window_width: float = 0.01
    kind = "rand"
    field_count = 4
    DRAWN: ClassVar[tuple] = ("rho0", "T0", "d_rho", "d_p", "window_left", "window_right")
    PEAK_SOUND: ClassVar[float] = 2.0  # sqrt(max(1 + d_p f) / min(1 + d_rho f)) at |f| <= 3 mean|f|, d <= 0.2
    PEAK_FLOW: ClassVar[float] = 4.0  # max |u| / mean |u| of the random velocity (3.0-3.6 over 64 draws at 128^2)

    def sample(self, key: jax.Array, grid, n_fields: int = 4) -> jax.Array:
        d = ic_domains(self, self.DRAWN)
        k_draw, k_phase, k_win, k_wx, k_wy = jax.random.split(key, 5)
        rho0, t0, d_rho, d_p, _, _ = _draw(d, k_draw)
        x, y = _centres(grid)
        k0 = 2 * np.pi / grid.length
        f = [jnp.zeros((grid.n, grid.n), jnp.float32) for _ in range(4)]
        m = 0
        for j in range(-self.max_mode, self.max_mode + 1):
            for i in range(-self.max_mode, self.max_mode + 1):
                if i * j == 0:  # PDEBench skips every mode on an axis
                    continue
                phase = 2 * jnp.pi * jax.random.uniform(jax.random.fold_in(k_phase, m), (4,), jnp.float32)
                arg = k0 * (i * x + j * y)
                size = float((k0 * k0 * (i * i + j * j)) ** -0.25)
                f = [f[c] + size * jnp.sin(arg + phase[c]) for c in range(4)]
                m += 1
        speed = jnp.mean(jnp.sqrt(f[0] ** 2 + f[1] ** 2))
        scale = self.mach * jnp.sqrt(self.gamma * t0) / speed
        rho = rho0 * (1 + d_rho * f[3] / jnp.mean(jnp.abs(f[3])))
        p = rho0 * t0 * (1 + d_p * f[2] / jnp.mean(jnp.abs(f[2])))
        w = self.window_width * grid.length
        ends = [grid.length * d[n].sample(jax.random.fold_in(k, 0)) for k in (k_wx, k_wy)
                for n in ("window_left", "window_right")]
        wx = 0.5 * (jnp.tanh((x - ends[0]) / w) - jnp.tanh((x - ends[1]) / w))
        wy = 0.5 * (jnp.tanh((y - ends[2]) / w) - jnp.tanh((y - ends[3]) / w))
        mask = jnp.where(jax.random.uniform(k_win) < self.window_prob, wx * wy, jnp.ones_like(wx * wy))
        state = jnp.stack([rho * mask + rho0 * (1 - mask), scale * f[0] * mask, scale * f[1] * mask,
                           p * mask + rho0 * t0 * (1 - mask)])
        return state.astype(jnp.float32)

    def check(self, grid) -> None:
        d = ic_domains(self, self.DRAWN)
        for name in ("rho0", "T0"):
            if not min(d[name].bounds) > 0:
                raise ValueError(f"ic.{name}={d[name]} not allowed: must be > 0")
        for name in ("d_rho", "d_p"):
            lo, hi = d[name].bounds
            if not 0 <= lo <= hi <= 0.25:
                raise ValueError(f"ic.{name}={d[name]} not allowed: a relative amplitude in [0, 0.25] (density and "
                                 "pressure stay positive)")
        for name in ("window_left", "window_right"):
            lo, hi = d[name].bounds
            if not 0 <= lo <= hi <= 1:
                raise ValueError(f"ic.{name}={d[name]} not allowed: a fraction of the length, in [0, 1]")
        if not (math.isfinite(self.mach) and self.mach >= 0):
            raise ValueError(f"ic.mach={self.mach} not allowed: must be a finite number >= 0")
        if not 1 <= self.max_mode <= grid.n // 8:
            raise ValueError(f"ic.max_mode={self.max_mode} not allowed on n={grid.n}: need 1 <= max_mode <= n//8 = "
                             f"{grid.n // 8}")
        if not (self.window_width > 0 and 0 <= self.window_prob <= 1):
            raise ValueError(f"ic.window_width={self.window_width}, ic.window_prob={self.window_prob} not allowed: "
                             "need a width > 0 and a probability in [0, 1]")
        if not 1 < self.gamma <= GAMMA_MAX:  # (ic.gamma=5 was accepted, 1e300 refused as t_end's step count)
            raise ValueError(f"ic.gamma={float(self.gamma)} not allowed: the ratio of specific heats the Mach number is "
                             f"measured with lies in (1, {GAMMA_MAX:g}], as the gas's own gamma (air 1.4, a monatomic "
                             "gas 5/3)")

    def bound(self, grid) -> float:
        d = ic_domains(self, self.DRAWN)
        return 1.5 * max(d["rho0"].bounds) * max(d["T0"].bounds)

    def speed(self, gamma: float) -> float:
        """An estimate of the largest |u| + c (PEAK_SOUND, PEAK_FLOW); a sample beyond it that outruns its step
        fails with that cause (MAX_CFL), never silently."""
        c = math.sqrt(max(gamma, self.gamma) * max(ic_domains(self, ("T0",))["T0"].bounds))
        return c * (self.PEAK_SOUND + self.PEAK_FLOW * self.mach)

    def __str__(self) -> str:
        return (f"PDEBench's random 2D gas: Mach {self.mach:g} velocity of modes |i|, |j| <= {self.max_mode}, rho0 "
                f"{self.rho0}, T0 {self.T0}, d_rho {self.d_rho}, d_p {self.d_p}, window p={self.window_prob:g}")


EULER_IC_KINDS: dict[str, type] = {c.kind: c for c in (Riemann2D, LaxLiu3, Sod2D, SmoothGas, RandomGas2D)}


# --- the entries ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FiniteVolume2D(FiniteVolume):
    """The 2D entries' boundaries: ``bc`` one of SIDE_KINDS for every side, or per axis "x=K,y=K" (an axis not
    named: outflow); ``bc.x`` / ``bc.y`` change one axis."""

    NDIM: ClassVar[int] = 2
    BOUNDARIES: ClassVar[tuple] = SIDE_KINDS

    def replace(self, overrides: Mapping[str, Any] | None = None, **kwargs) -> "FiniteVolume2D":
        """``ProblemBase.replace``; ``bc.x`` / ``bc.y`` set one axis of ``bc``."""
        changes = {**(overrides or {}), **kwargs}
        axes = {k[3:]: v for k, v in changes.items() if k in ("bc.x", "bc.y")}
        if axes:
            kx, ky = _axes(self.NAME, changes.get("bc", self.bc))
            axes = {"x": kx, "y": ky, **{a: str(v).strip().lower() for a, v in axes.items()}}
            changes = {k: v for k, v in changes.items() if k not in ("bc.x", "bc.y")}
            changes["bc"] = axes["x"] if axes["x"] == axes["y"] else f"x={axes['x']},y={axes['y']}"
        return super().replace(changes)

    @property
    def axes(self) -> tuple[str, str]:
        """The side kind of (x, y)."""
        return _axes(self.NAME, self.bc)

    @property
    def sides(self) -> tuple[str, str, str, str]:
        kx, ky = self.axes
        return (kx, kx, ky, ky)

    @property
    def grid(self) -> FVGrid:
        return FVGrid(2, self.n, self.length, self.sides)

    def speed_bound(self) -> float:
        """Largest speed the IC distribution allows at t = 0, at the physical parameter's largest value."""
        return self.ic.speed(max(getattr(self, self.PHYS[0]).bounds))


def _axes(name: str, bc: Any) -> tuple[str, str]:
    """(x kind, y kind) of a bc setting, or a one-line refusal."""
    words = [w.strip().lower() for w in str(bc).split(",")]
    bad = ValueError(f"{name}: bc={bc!r} not allowed; allowed: {', '.join(SIDE_KINDS)} for every side, or per "
                     "axis x=KIND,y=KIND (e.g. x=periodic,y=wall)")
    if len(words) == 1 and "=" not in words[0]:
        if words[0] not in SIDE_KINDS:
            raise bad
        return words[0], words[0]
    kinds = {"x": "outflow", "y": "outflow"}
    named = [w.partition("=")[0].strip() for w in words]
    twice = sorted({a for a in named if named.count(a) > 1})
    if twice:  # the last one would win, silently
        raise ValueError(f"{name}: bc={bc!r} not allowed: axis {', '.join(twice)} given twice; give each axis once, "
                         "e.g. 'x=periodic,y=wall'")
    for w in words:
        axis, _, kind = (s.strip() for s in w.partition("="))
        if axis not in kinds or kind not in SIDE_KINDS:
            raise bad
        kinds[axis] = kind
    return kinds["x"], kinds["y"]


@dataclass(frozen=True)
class ShallowWater2D(FiniteVolume2D):
    """2D shallow water on a flat bed (wet/dry fronts allowed); length, time and depth units of the IC."""

    NAME: ClassVar[str] = "shallow_water2d"
    # `pdestream generate shallow_water2d --n 4` on 2 CPU cores shared with other work, no compilation cache
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 6.5, "unit_s": 2.5}
    EQUATION: ClassVar[str] = ("h_t + (hu)_x + (hv)_y = 0, (hu)_t + (hu^2 + g h^2 / 2)_x + (huv)_y = 0, "
                               "(hv)_t + (huv)_x + (hv^2 + g h^2 / 2)_y = 0, h >= 0; stored: conserved h, hu, hv")
    FIELDS: ClassVar[tuple] = ("h", "hu", "hv")
    FIELD_UNITS: ClassVar[dict] = {"h": "length", "hu": "length^2/time", "hv": "length^2/time"}
    PARAMS: ClassVar[dict] = {"g": Param("gravitational acceleration", "length/time^2", positive=True)}
    IC_KINDS: ClassVar[Mapping[str, type]] = SW_IC_KINDS
    SCHEME: ClassVar = SHALLOW_WATER
    PHYS: ClassVar[tuple] = ("g",)
    MAX_CFL: ClassVar[float] = SW_MAX_CFL
    FAILURE_WORDS: ClassVar[str] = "a negative depth, a NaN/Inf"

    n: int = 128  # cells per side (PDEBench's 128^2)
    length: float = 5.0  # PDEBench's [-2.5, 2.5]^2, here [0, 5]^2
    ic: Any = RadialDamBreak()
    t_end: float = 1.0
    n_frames: int = 21  # PDEBench stores 101 (every 0.01)
    bc: str = "outflow"  # PDEBench's (extrapolation)
    cfl: float = 0.3  # 2 s0 dt / h at the initial largest speed s0: room below SW_MAX_CFL for waves to speed up
    limiter: str = "mc"  # PDEBench's (PyClaw's MC)
    g: Any = Fixed(1.0)

    def validate(self) -> None:
        self._validate_common(16)
        _axes(self.NAME, self.bc)
        self._validate_size()

    def describe_setup(self) -> str:
        return (f"  fields: {', '.join(self.FIELDS)} (conserved)   grid: {self.grid.describe()}\n"
                f"  {self._step_words()}; finite volumes: MUSCL ({self.limiter}) on (h, u, v), HLL with wet/dry "
                "speeds, SSP-RK3")


@dataclass(frozen=True)
class Euler2D(FiniteVolume2D):
    """2D compressible Euler of an ideal gas; dimensionless (length, time and density units of the IC)."""

    NAME: ClassVar[str] = "euler2d"
    # `pdestream generate euler2d --n 4` on 2 CPU cores shared with other work, no compilation cache
    TYPICAL_TIMES: ClassVar[dict] = {"startup_s": 13.5, "unit_s": 1.0}
    EQUATION: ClassVar[str] = ("rho_t + div(rho u) = 0, (rho u)_t + div(rho u u + p I) = 0, E_t + div((E + p) u) = "
                               "0, E = p / (gamma - 1) + rho |u|^2 / 2; stored: primitive rho, u, v, p")
    FIELDS: ClassVar[tuple] = ("rho", "u", "v", "p")
    FIELD_UNITS: ClassVar[dict] = {"rho": "mass/length^3", "u": "length/time", "v": "length/time",
                                   "p": "mass/(length time^2)"}
    PARAMS: ClassVar[dict] = {"gamma": Param("ratio of specific heats (ideal gas)", "1", positive=True)}
    IC_KINDS: ClassVar[Mapping[str, type]] = EULER_IC_KINDS
    SCHEME: ClassVar = EULER_2D
    PHYS: ClassVar[tuple] = ("gamma",)

    n: int = 64  # cells per side
    length: float = 1.0
    ic: Any = Riemann2D()
    t_end: float = 0.2
    n_frames: int = 11
    bc: str = "outflow"
    cfl: float = 0.4  # 2 s0 dt / h at the initial largest speed s0
    limiter: str = "minmod"
    gamma: Any = Fixed(1.4)

    def validate(self) -> None:
        self._validate_common(16)
        _axes(self.NAME, self.bc)
        check_gamma(self.NAME, self.gamma)
        self._validate_size()

    def describe_setup(self) -> str:
        return (f"  fields: {', '.join(self.FIELDS)} (primitive)   grid: {self.grid.describe()}\n"
                f"  {self._step_words()}; finite volumes: MUSCL ({self.limiter}) on (rho, u, v, p), HLLC by axis, "
                "SSP-RK3 (unsplit)")


@dataclass(frozen=True)
class CompressibleNS2D(ViscousGas, Euler2D):
    """2D compressible Navier-Stokes, PDEBench's 2D CFD model: euler2d's scheme plus its stress, axis by axis
    (``navier_stokes.viscous_rate_2d``), kinematic viscosities eta and zeta; no heat conduction. Dimensionless."""

    NAME: ClassVar[str] = "compressible_ns2d"
    EQUATION: ClassVar[str] = ("euler2d's equations plus viscous fluxes per axis n (t the other): rho (4/3 eta + zeta) "
                               "(u_n)_n on the normal momentum, rho eta (u_t)_n on the transverse one, and their "
                               "work on E (PDEBench's stress); stored: primitive rho, u, v, p")
    SCHEME: ClassVar = NAVIER_STOKES_2D
    NU_L: ClassVar[str] = "7/3 eta + zeta"  # nu_max's words

    n: int = 64
    ic: Any = RandomGas2D()
    t_end: float = 0.2
    n_frames: int = 5

    def nu_max(self) -> float:
        """The largest 4/3 eta + zeta plus eta (u's diffusion along x and y) the domains allow (length^2 / time)."""
        return 7.0 / 3.0 * max(self.eta.bounds) + max(self.zeta.bounds)

    def describe_setup(self) -> str:
        return (f"  fields: {', '.join(self.FIELDS)} (primitive)   grid: {self.grid.describe()}\n"
                f"  {self._step_words()} with the viscous limit (nu_l + eta <= {self.nu_max():.3g}); finite volumes: "
                f"MUSCL ({self.limiter}) on (rho, u, v, p), HLLC by axis, central viscous fluxes, SSP-RK3 (unsplit)")


__all__ = ["CompressibleNS2D", "EULER_IC_KINDS", "Euler2D", "SW_IC_KINDS", "ShallowWater2D"]
