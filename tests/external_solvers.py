"""External solvers for tests/test_external_solver.py (a module of their own: worker processes import it)."""

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from pdestream.generator import ExternalSolver, Param


@dataclass(frozen=True)
class Decay(ExternalSolver):
    """u(t, x) = exp(-k t) u0(x), u0 white noise from the seed: deterministic, known in closed form."""

    NAME: ClassVar[str] = "decay_ext1d"
    EQUATION: ClassVar[str] = "u_t = -k u"
    FIELDS: ClassVar[tuple] = ("u",)
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict] = {"k": Param("decay rate", "1/time", positive=True)}

    n: int = 16
    n_frames: int = 5
    k: Any = "uniform(0.5, 2.0)"
    delay: float = 0.0  # seconds each solve sleeps (timeouts, the benchmark)

    def solve(self, params, seed):
        if self.delay:
            time.sleep(self.delay)
        u0 = np.random.default_rng(seed).standard_normal(self.n)
        return np.exp(-params["k"] * self.times())[:, None, None] * u0[None, None, :]


@dataclass(frozen=True)
class Faulty(ExternalSolver):
    """Fails, in the way ``fail`` names, on the samples whose q < threshold; solves as Decay otherwise."""

    NAME: ClassVar[str] = "faulty_ext1d"
    FIELDS: ClassVar[tuple] = ("u",)
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict] = {"q": Param("which samples fail")}

    n: int = 16
    n_frames: int = 5
    q: Any = "uniform(0, 1)"
    fail: str = "raise"  # raise | nan | shape | complex | hang | crash | none
    threshold: float = 0.3

    def solve(self, params, seed):
        out = np.full((self.n_frames, 1, self.n), params["q"] + seed % 7)
        if params["q"] >= self.threshold or self.fail == "none":
            return out
        if self.fail == "raise":
            raise RuntimeError("no convergence\nin the Newton loop")
        if self.fail == "nan":
            out[2, 0, 3] = np.nan
            return out
        if self.fail == "shape":
            return out[:, 0]
        if self.fail == "complex":  # was stored as its real part, cache complete, rc 0
            return out + 0.5j
        if self.fail == "hang":
            time.sleep(60)
        if self.fail == "crash":
            os._exit(3)
        raise ValueError(f"unknown fail={self.fail}")


@dataclass(frozen=True)
class Cmd(ExternalSolver):
    """Decay's solution written by a command line (tests/external_cmd.py)."""

    NAME: ClassVar[str] = "cmd_ext1d"
    FIELDS: ClassVar[tuple] = ("u",)
    NDIM: ClassVar[int] = 1
    PARAMS: ClassVar[dict] = {"k": Param("decay rate", "1/time", positive=True)}
    COMMAND: ClassVar[tuple] = (sys.executable, str(Path(__file__).with_name("external_cmd.py")), "{params}", "{out}")

    n: int = 16
    n_frames: int = 5
    k: Any = "uniform(0.5, 2.0)"
    exit_code: int = 0


@dataclass(frozen=True)
class CmdH5(Cmd):
    NAME: ClassVar[str] = "cmd_h5_ext1d"
    OUTPUT: ClassVar[str] = ".h5"


@dataclass(frozen=True)
class NoSolve(ExternalSolver):
    """Neither solve nor COMMAND: refused in one line."""

    NAME: ClassVar[str] = "nosolve_ext1d"
    FIELDS: ClassVar[tuple] = ("u",)
    NDIM: ClassVar[int] = 1


@dataclass(frozen=True)
class Noisy(Decay):
    """Decay plus noise from the operating system: not reproducible, and it says so."""

    NAME: ClassVar[str] = "noisy_ext1d"
    DETERMINISTIC: ClassVar[bool] = False

    def solve(self, params, seed):
        return super().solve(params, seed) + np.frombuffer(os.urandom(4), np.uint32)[0] * 1e-12


@dataclass(frozen=True)
class CoordinateNamedParam(Decay):
    """Decay whose rate is called "x", the name of the cache's space coordinate."""

    NAME: ClassVar[str] = "coordinate_param_ext1d"
    PARAMS: ClassVar[dict] = {"x": Param("decay rate", "1/time", positive=True)}
    k: Any = 1.0
    x: Any = "uniform(0.5, 2.0)"

    def solve(self, params, seed):
        return super().solve({"k": params["x"]}, seed)
