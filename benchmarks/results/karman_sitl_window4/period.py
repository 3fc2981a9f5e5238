"""The shedding period of karman_sitl --small: v at a probe 1.5 D behind the cylinder, one fine sample per Re.

    nice -n 5 python benchmarks/results/karman_sitl_window4/period.py
"""
import numpy as np
import torch

from pdestream import datasets, generator

torch.set_num_threads(1)
for re in (40, 60, 80, 88):
    pde = generator.get_pde("karman2d", n=32, radius="0.145", re=f"{re}", cx="0.5", cy="0.44", plug="0.15",
                            t_start=2.0, t_end=10.0, n_frames=81)
    d = datasets.sample_tensors(pde, np.arange(1), 0)
    u = d["u"][0].numpy()  # [T, C, nx, ny]
    v = u[:, pde.FIELDS.index("v")]
    nx, ny = v.shape[1:]
    h = 1.0 / 32
    i, j = int((0.5 + 0.145 * 3) / h), int(0.44 / h)   # ~1.5 D behind the centre, on its line
    s = v[:, i, j]
    t = 2.0 + 0.1 * np.arange(len(s))
    # zero crossings (upward) of the probe's v, from t = 2
    x = s - s.mean()
    up = [t[k] - x[k] * 0.1 / (x[k + 1] - x[k]) for k in range(len(x) - 1) if x[k] < 0 <= x[k + 1]]
    amp = [np.ptp(s[(t >= a) & (t < a + 2)]) for a in (2, 4, 6, 8)]
    print(f"Re {re}: upward crossings {np.round(up, 2).tolist()}, periods {np.round(np.diff(up), 2).tolist()}, "
          f"v ptp per 2 s {np.round(amp, 3).tolist()}", flush=True)
