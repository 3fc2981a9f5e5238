"""The 1D finite-volume solver's speed against a numpy reference of the same scheme: ``python -m
benchmarks.fv_speed [--n 1024] [--samples 8] [--t-end 0.02] [--eta 0.01] [--repeat 3]``.

The reference below is written from the scheme's description (MUSCL with the MC limiter on rho, u, p, HLLC
fluxes with Einfeldt's speeds, the central viscous stress rho (4/3 eta + zeta) u_x and its work, SSP-RK3, periodic
ends), in float64 numpy over the whole batch at once. Both solve the same initial states (``compressible_ns1d``'s
sines) with the same step count and dt; printed: cell updates per second (cells x steps x samples / wall time,
the compile excluded: the best of --repeat runs after one warm-up), their ratio, and the largest difference of
the final states relative to their range (the JAX solver is float32). A check of the JAX code by code written
apart from it, as well as a speed baseline: a ratio printed here is of one machine and load, never a test.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


# --- the numpy reference: primitive w [B, 3, n] (rho, u, p), periodic --------------------------------------------
def _mc(a, b):
    """MC-limited slope of backward and forward differences a, b: minmod(2a, 2b, (a + b) / 2)."""
    s = np.minimum(2 * np.minimum(np.abs(a), np.abs(b)), 0.5 * np.abs(a + b))
    return np.where(a * b > 0, np.sign(a) * s, 0.0)


def _hllc(wl, wr, gamma):
    """HLLC flux [B, 3, m] between primitive face states wl, wr [B, 3, m] (Einfeldt's signal speeds)."""
    (rl, ul, pl), (rr, ur, pr) = np.moveaxis(wl, 1, 0), np.moveaxis(wr, 1, 0)
    el, er = pl / (gamma - 1) + 0.5 * rl * ul ** 2, pr / (gamma - 1) + 0.5 * rr * ur ** 2
    cl, cr = np.sqrt(gamma * pl / rl), np.sqrt(gamma * pr / rr)
    wl_, wr_ = np.sqrt(rl), np.sqrt(rr)
    u_avg = (wl_ * ul + wr_ * ur) / (wl_ + wr_)
    h_avg = (wl_ * (el + pl) / rl + wr_ * (er + pr) / rr) / (wl_ + wr_)
    c_avg = np.sqrt(np.maximum((gamma - 1) * (h_avg - 0.5 * u_avg ** 2), 0.0))
    sl, sr = np.minimum(ul - cl, u_avg - c_avg), np.maximum(ur + cr, u_avg + c_avg)
    ml, mr = rl * (sl - ul), rr * (sr - ur)
    ss = (pr - pl + ul * ml - ur * mr) / (ml - mr)

    def flux(r, u, p, e):
        return np.stack([r * u, r * u * u + p, (e + p) * u], 1)

    def star_flux(r, u, p, e, s, m):
        k = m / (s - ss)
        star = np.stack([k, k * ss, k * (e / r + (ss - u) * (ss + p / m))], 1)
        return flux(r, u, p, e) + s[:, None] * (star - np.stack([r, r * u, e], 1))

    fl, fr = flux(rl, ul, pl, el), flux(rr, ur, pr, er)
    fsl, fsr = star_flux(rl, ul, pl, el, sl, ml), star_flux(rr, ur, pr, er, sr, mr)
    sl, ss, sr = sl[:, None], ss[:, None], sr[:, None]
    return np.where(sl >= 0, fl, np.where(ss >= 0, fsl, np.where(sr > 0, fsr, fr)))


def _rate(q, gamma, nu, h):
    """dq/dt [B, 3, n] of conserved q [B, 3, n] on a periodic grid of cell size h."""
    rho, m, e = q[:, 0], q[:, 1], q[:, 2]
    u = m / rho
    w = np.stack([rho, u, (gamma - 1) * (e - 0.5 * m * u)], 1)
    wp = np.concatenate([w[..., -2:], w, w[..., :2]], -1)  # two ghost cells a side
    d = np.diff(wp, axis=-1)
    s = _mc(d[..., :-1], d[..., 1:])  # slopes of padded cells 1 .. n + 2
    left, right = wp[..., 1:-2] + 0.5 * s[..., :-1], wp[..., 2:-1] - 0.5 * s[..., 1:]  # faces 0 .. n
    f = _hllc(left, right, gamma)
    up = np.concatenate([u[..., -1:], u, u[..., :1]], -1)
    rp = np.concatenate([rho[..., -1:], rho, rho[..., :1]], -1)
    tau = nu * 0.5 * (rp[..., 1:] + rp[..., :-1]) * np.diff(up, axis=-1) / h
    f[:, 1] -= tau
    f[:, 2] -= tau * 0.5 * (up[..., 1:] + up[..., :-1])
    return -np.diff(f, axis=-1) / h


def reference(w0: np.ndarray, gamma: float, nu: float, h: float, dt: float, steps: int) -> np.ndarray:
    """``steps`` SSP-RK3 steps of dt from primitive w0 [B, 3, n]: the primitive state [B, 3, n] (float64)."""
    rho, u, p = (w0[:, i].astype(np.float64) for i in range(3))
    q = np.stack([rho, rho * u, p / (gamma - 1) + 0.5 * rho * u * u], 1)
    for _ in range(steps):
        q1 = q + dt * _rate(q, gamma, nu, h)
        q2 = 0.75 * q + 0.25 * (q1 + dt * _rate(q1, gamma, nu, h))
        q = q / 3 + (2 / 3) * (q2 + dt * _rate(q2, gamma, nu, h))
    rho, m, e = q[:, 0], q[:, 1], q[:, 2]
    return np.stack([rho, m / rho, (gamma - 1) * (e - 0.5 * m * m / rho)], 1)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--t-end", type=float, default=0.02)
    ap.add_argument("--eta", type=float, default=0.01)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)

    from pdestream import generator as g

    pde = g.get_pde("compressible_ns1d", n=a.n, t_end=a.t_end, n_frames=2, eta=str(a.eta), zeta=str(a.eta))
    gamma, nu = float(pde.gamma.bounds[0]), 4 / 3 * a.eta + a.eta
    steps, dt = pde.steps_per_frame, pde.step_dt
    u0 = np.asarray(g.sample(pde.replace(t_end=pde.step_dt, n_frames=2), range(a.samples), seed=0).u[:, 0])
    params = {"gamma": gamma, "eta": a.eta, "zeta": a.eta}
    updates = a.n * steps * a.samples
    g.solve(pde, u0, params)  # the compile
    jax_s = min(_timed(lambda: g.solve(pde, u0, params).u) for _ in range(a.repeat))
    got = np.asarray(g.solve(pde, u0, params).u[:, -1], np.float64)
    t0 = time.perf_counter()
    want = reference(u0, gamma, nu, pde.h, dt, steps)
    np_s = time.perf_counter() - t0
    span = want.max(axis=(0, 2)) - want.min(axis=(0, 2))
    diff = (np.abs(got - want).max(axis=(0, 2)) / span).max()
    print(f"compressible_ns1d n={a.n}, {a.samples} samples, {steps} steps of {dt:.3g} (eta = zeta = {a.eta:g})")
    print(f"  jax (float32, this process): {jax_s:.2f} s  {updates / jax_s:.3g} cell updates/s")
    print(f"  numpy reference (float64):   {np_s:.2f} s  {updates / np_s:.3g} cell updates/s")
    print(f"  ratio jax / numpy: x{np_s / jax_s:.2f};  largest final-state difference / range: {diff:.2e}")


def _timed(fn) -> float:
    t0 = time.perf_counter()
    out = fn()
    np.asarray(out)
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
