"""The linear family against closed forms (Fourier-mode solutions written here, in float64), 1D to 3D.

Each PDE is solved from an initial condition made of a few Fourier modes whose exact evolution is known;
the float32 solver must match it within 1e-5 relative L2 at every frame. The wave equation also conserves
its energy on random samples.
"""

import numpy as np
import pytest

from pdestream import generator as g

TOL = 1e-5


def rel_err(a, b):
    return float(np.linalg.norm(np.asarray(a, np.float64) - b) / np.linalg.norm(b))


def mesh(pde):
    """Coordinates, float64 [ndim, *shape]."""
    x = pde.grid.coords().astype(np.float64)
    return np.stack(np.meshgrid(*([x] * pde.NDIM), indexing="ij"))


# A few modes per dimension, m = integer wavevector (cycles per box), with amplitude and phase.
MODES = {1: [((3,), 1.0, 0.0), ((7,), 0.5, 1.0)],
         2: [((1, 2), 1.0, 0.3), ((-3, 1), 0.6, 0.0), ((0, 4), 0.3, 2.0)],
         3: [((1, 0, 2), 1.0, 0.0), ((-2, 1, 1), 0.5, 0.7)]}


def modes_at(pde, symbol, t):
    """sum_m a_m Re(exp(i (2 pi m.x / L + phase) + symbol(k) t)): the exact solution of u_t = L u, L = symbol(k)."""
    X = mesh(pde)
    out = 0.0
    for m, a, phase in MODES[pde.NDIM]:
        k = 2 * np.pi * np.asarray(m, np.float64) / pde.length
        theta = sum(ki * xi for ki, xi in zip(k, X)) + phase
        out = out + a * np.real(np.exp(1j * theta + symbol(k) * t))
    return out


CASES = [  # (entry, settings, parameters, symbol of L for a wavevector k)
    ("advection1d", {"n": 32}, {"c": 0.37}, lambda p, k: -1j * p["c"] * k[0]),
    ("advection2d", {"n": 16}, {"c_x": 0.37, "c_y": -0.8}, lambda p, k: -1j * (p["c_x"] * k[0] + p["c_y"] * k[1])),
    ("advection3d", {"n": 16}, {"c_x": 0.3, "c_y": -0.5, "c_z": 0.9},
     lambda p, k: -1j * (p["c_x"] * k[0] + p["c_y"] * k[1] + p["c_z"] * k[2])),
    ("diffusion2d", {"n": 16}, {"nu": 4e-3}, lambda p, k: -p["nu"] * k @ k),
    ("diffusion3d", {"n": 16}, {"nu": 2e-3}, lambda p, k: -p["nu"] * k @ k),
    ("advection_diffusion1d", {"n": 32}, {"c": -0.6, "nu": 3e-3}, lambda p, k: -1j * p["c"] * k[0] - p["nu"] * k @ k),
    ("advection_diffusion2d", {"n": 16}, {"c_x": 0.5, "c_y": 0.25, "nu": 3e-3},
     lambda p, k: -1j * (p["c_x"] * k[0] + p["c_y"] * k[1]) - p["nu"] * k @ k),
    ("dispersion1d", {"n": 32}, {"beta": 5e-4}, lambda p, k: 1j * p["beta"] * k[0] ** 3),
    ("hyper_diffusion1d", {"n": 32}, {"nu": 5e-6}, lambda p, k: -p["nu"] * (k @ k) ** 2),
    ("hyper_diffusion2d", {"n": 16}, {"nu": 5e-6}, lambda p, k: -p["nu"] * (k @ k) ** 2),
]


@pytest.mark.parametrize("name, settings, params, symbol", CASES, ids=[c[0] for c in CASES])
def test_fourier_modes_evolve_as_the_closed_form(name, settings, params, symbol):
    pde = g.get_pde(name, n_frames=6, **settings)
    traj = g.solve(pde, modes_at(pde, lambda k: 0.0, 0.0), params)
    for j, t in enumerate(pde.times().astype(np.float64)):
        exact = modes_at(pde, lambda k: symbol(params, k), t)
        assert rel_err(traj.u[0, j, 0], exact) < TOL, (name, t, rel_err(traj.u[0, j, 0], exact))


def wave_exact(pde, c, t):
    """u = sum_m Re(a_m e^{i theta}) cos(w t) + Re(b_m e^{i theta}) sin(w t) / w and v = u_t, w = c |k|, for
    u0 = sum Re(a_m e^{i theta}), v0 = sum Re(b_m e^{i theta}) with b_m = a_m * (1 + i) (a velocity of its own)."""
    X = mesh(pde)
    u, v = 0.0, 0.0
    for m, a, phase in MODES[pde.NDIM]:
        k = 2 * np.pi * np.asarray(m, np.float64) / pde.length
        w = c * np.sqrt(k @ k)
        e = np.exp(1j * (sum(ki * xi for ki, xi in zip(k, X)) + phase))
        a_e, b_e = np.real(a * e), np.real(a * (1 + 1j) * e)
        u = u + a_e * np.cos(w * t) + b_e * np.sin(w * t) / w
        v = v - a_e * w * np.sin(w * t) + b_e * np.cos(w * t)
    return np.stack([u, v])


@pytest.mark.parametrize("name, n", [("wave1d", 32), ("wave2d", 16)])
def test_wave_modes_evolve_as_the_closed_form(name, n):
    c = 0.8
    pde = g.get_pde(name, n=n, n_frames=6)
    traj = g.solve(pde, wave_exact(pde, c, 0.0), {"c": c})
    for j, t in enumerate(pde.times().astype(np.float64)):
        exact = wave_exact(pde, c, t)
        for f in range(2):
            assert rel_err(traj.u[0, j, f], exact[f]) < TOL, (name, t, f)


def wave_energy(pde, u, c):
    """(1/2) integral of v^2 + c^2 |grad u|^2 over the box, float64 [...] from frames [..., 2, *space]."""
    axes = tuple(range(-pde.NDIM, 0))
    u_hat = np.fft.fftn(np.asarray(u[..., 0, *([slice(None)] * pde.NDIM)], np.float64), axes=axes)
    m = np.fft.fftfreq(pde.n, 1.0 / pde.n)
    k2 = (2 * np.pi / pde.length) ** 2 * sum(x**2 for x in np.meshgrid(*([m] * pde.NDIM), indexing="ij"))
    cell = (pde.length / pde.n) ** pde.NDIM
    grad2 = (k2 * np.abs(u_hat) ** 2).sum(axis=axes) / pde.n**pde.NDIM  # Parseval: sum_x |grad u|^2
    v2 = (np.asarray(u[..., 1, *([slice(None)] * pde.NDIM)], np.float64) ** 2).sum(axis=axes)
    return 0.5 * cell * (v2 + c[..., None] ** 2 * grad2)


@pytest.mark.parametrize("name", ["wave1d", "wave2d"])
def test_wave_energy_is_conserved_on_random_samples(name):
    pde = g.get_pde(name, n=32, n_frames=11)
    traj = g.sample(pde, range(3), seed=4)
    energy = wave_energy(pde, np.asarray(traj.u), np.asarray(traj.params["c"], np.float64))  # [B, T]
    assert np.abs(energy / energy[:, :1] - 1).max() < TOL
    assert np.abs(np.asarray(traj.u[:, -1, 0]) - np.asarray(traj.u[:, 0, 0])).max() > 0.1  # it moved


def test_wave_refuses_initial_conditions_with_a_mean():
    with pytest.raises(ValueError) as err:
        g.get_pde("wave1d", **{"ic.offset": 0.5})
    assert str(err.value).startswith("wave1d: ic.offset=0.5 not allowed") and "\n" not in str(err.value)
    with pytest.raises(ValueError, match="wave2d: ic.zero_mean=False not allowed"):
        g.get_pde("wave2d", ic={"kind": "grf", "zero_mean": False})


@pytest.mark.parametrize("name", ["advection3d", "diffusion3d"])
def test_default_3d_grid_fits_and_streams_in_chunks(name):
    # the default 3D grid solves in memory-sized rollout chunks (several per batch) to the same bits as alone
    from pdestream.generator.spectral.rollout import evolve_chunk

    pde = g.get_pde(name)
    assert pde.n == 32 and 1 < evolve_chunk(pde) < 8
    batch = g.sample(pde, range(8), seed=1)
    alone = g.sample(pde, [5], seed=1)
    assert np.array_equal(np.asarray(batch.u[5]), np.asarray(alone.u[0]))
    assert batch.u.shape == (8, pde.n_frames, 1, 32, 32, 32) and bool(np.isfinite(np.asarray(batch.u)).all())
