"""The developed street of karman_sitl --small --re 60,100: v at a probe 1.5 D behind the cylinder, one fine sample
per Re (60, 80, 100 and the beyond set's 108), t = 2..14 s; stop 48's period.py extended in Re and time, plus the
rule of stop 49 applied to its peak-to-peak per 2-s window.

    nice -n 5 python benchmarks/results/karman_sitl_developed/period.py
"""
import numpy as np
import torch

from pdestream import datasets, generator

torch.set_num_threads(1)
T0, T1, DT = 2.0, 14.0, 0.1
WINDOWS = np.arange(2, 14, 2)  # 2-s windows [a, a + 2) from t = 2 to 14
RULE_RE, STARTS, TOL = (60, 80, 100), (4, 6, 8, 10), 0.05
ptp = {}
for re in (60, 80, 100, 108):
    pde = generator.get_pde("karman2d", n=32, radius="0.145", re=f"{re}", cx="0.5", cy="0.44", plug="0.15",
                            t_start=T0, t_end=T1, n_frames=round((T1 - T0) / DT) + 1)
    d = datasets.sample_tensors(pde, np.arange(1), 0)
    u = d["u"][0].numpy()  # [T, C, nx, ny]
    finite = bool(np.isfinite(u).all())
    v = u[:, pde.FIELDS.index("v")]
    h = 1.0 / 32
    i, j = int((0.5 + 0.145 * 3) / h), int(0.44 / h)   # ~1.5 D behind the centre, on its line
    s = v[:, i, j]
    t = T0 + DT * np.arange(len(s))
    x = s - s.mean()
    up = [t[k] - x[k] * DT / (x[k + 1] - x[k]) for k in range(len(x) - 1) if x[k] < 0 <= x[k + 1]]
    per = round(2 / DT)  # frames per 2-s window
    amp = [float(np.ptp(s[round((a - T0) / DT):round((a - T0) / DT) + per])) for a in WINDOWS]
    ptp[re] = dict(zip(WINDOWS.tolist(), amp))
    print(f"Re {re}: finite {finite}, max |u| {np.abs(u).max():.3f}, upward crossings {np.round(up, 2).tolist()}, "
          f"periods {np.round(np.diff(up), 2).tolist()}, v ptp per 2 s from t = 2 {np.round(amp, 3).tolist()}",
          flush=True)

# the rule: the smallest t_start of STARTS at which, at every Re of RULE_RE, the ptp of [t_start, t_start + 2) and
# of [t_start + 2, t_start + 4) differ by < TOL relative to the first
for ts in STARTS:
    ch = {re: abs(ptp[re][ts + 2] / ptp[re][ts] - 1) for re in RULE_RE}
    ok = all(c < TOL for c in ch.values())
    print(f"t_start {ts}: relative ptp change, window {ts}-{ts + 2} -> {ts + 2}-{ts + 4}: "
          + ", ".join(f"Re {re} {c:.3f}" for re, c in ch.items()) + f" -> {'developed' if ok else 'not yet'}")
    if ok:
        print(f"rule: t_start = {ts}")
        break
else:
    print("rule: no t_start of 4, 6, 8, 10 settles by t = 14")
