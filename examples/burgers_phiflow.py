"""2D viscous Burgers flow simulated by PhiFlow (semi-Lagrangian advection, explicit diffusion), as an entry.

    v_t + (v . grad) v = nu lap v   on the periodic square [0, length)^2,   v = (u, w)

Random per sample: the viscosity nu and (from the seed) a smooth random initial velocity. PhiFlow runs on its
NumPy backend in the solver's worker processes (``pip install phiflow``). Use it as any entry:

    PYTHONPATH=. pdestream train --pde examples.burgers_phiflow:PhiBurgers --reservoir --view next_step --steps 500 --out runs/phi
"""

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pdestream.generator import ExternalSolver, Param


@dataclass(frozen=True)
class PhiBurgers(ExternalSolver):
    NAME: ClassVar[str] = "phi_burgers2d"
    EQUATION: ClassVar[str] = "v_t + (v . grad) v = nu lap v (PhiFlow)"
    FIELDS: ClassVar[tuple] = ("u", "w")
    FIELD_UNITS: ClassVar[dict] = {"u": "length/time", "w": "length/time"}
    NDIM: ClassVar[int] = 2
    PARAMS: ClassVar[dict] = {"nu": Param("viscosity", "length^2/time", positive=True)}
    VERSION: ClassVar[str] = "1"

    n: int = 32
    length: float = 1.0
    t_end: float = 0.5
    n_frames: int = 11
    steps_per_frame: int = 5
    amplitude: float = 0.3  # rms of the initial velocity, length/time
    nu: Any = "loguniform(1e-3, 1e-2)"

    def solve(self, params, seed):
        from phi.flow import Box, CenteredGrid, Noise, advect, diffuse, extrapolation, math

        math.seed(seed)  # PhiFlow's random initial field comes from the sample's seed: reproducible
        v = CenteredGrid(Noise(vector="x,y", scale=0.3 * self.length, smoothness=1.5), extrapolation.PERIODIC,
                         x=self.n, y=self.n, bounds=Box(x=self.length, y=self.length))
        v = v * (self.amplitude / float(math.std(v.values)))
        dt = self.t_end / max(1, self.n_frames - 1) / self.steps_per_frame
        frames = [v.values.numpy("vector,x,y")]
        for _ in range(self.n_frames - 1):
            for _ in range(self.steps_per_frame):
                v = diffuse.explicit(advect.semi_lagrangian(v, v, dt), params["nu"], dt)
            frames.append(v.values.numpy("vector,x,y"))
        return np.stack(frames)  # [T, 2, n, n]
