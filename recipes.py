"""Recipes: the field's published datasets as names, regenerated on the fly (``pdestream recipes``).

A recipe is one catalog entry with the settings of a published data set (its paper, the table or section, the
generator's file and line), the IC measure, grid and time sampling in words, train / valid / test splits fixed
by seed and size, and where our solver differs from the published one. A recipe name works wherever a PDE name
does (generator.catalog resolves it; the problem it makes records the recipe in its config). Declared once in
RECIPES; no JAX here, so the CLI lists and refuses names before importing a solver. Published sets that no
catalog entry can express are declared in NOT_EXPRESSIBLE with the reason, not faked.
"""

from __future__ import annotations

import difflib
import json
import shlex
from dataclasses import dataclass, field
from typing import Any, Mapping

SPLITS = ("train", "valid", "test")

# Where the published settings were read (commits of the public repositories).
PDEBENCH = "github.com/pdebench/PDEBench@9754b4c, pdebench/data_gen/data_gen_NLE/"
FNO = "github.com/neuraloperator/neuraloperator@11971af, data_generation/"
CFDBENCH = "github.com/luo-yining/CFDBench@6c30c62, "
# CFDBench's cell Reynolds numbers on our 64^2 grid: the subsets' largest speed U over their smallest kinematic
# viscosity mu / rho, with h = L / 64 for a box of side L (m) the public code does not state
_SUMMARY = ("a third-party summary of the paper (a CFDBench dataset card in the code index, not the paper, "
            "which could not be opened here)")
_CAVITY_WHY = ("CFDBench (Luo et al. 2023, arXiv 2310.05963) solved it in Fluent and interpolated to 64 x 64; "
               "its cases are a fixed list, not a distribution, split by random.seed(0) shuffling 80 / 10 / 10 "
               "(src/dataset/cavity.py:376-381), frames every 0.1 s (sample_cavity.txt:15, cavity.py:65) until "
               "the mean change of |u| between frames drops below 0.001 (cavity.py:250,320). ")


@dataclass(frozen=True)
class Split:
    """One split of a recipe: samples 0..n-1 under ``seed`` (sample i is a pure function of config, seed, i)."""

    seed: int
    n: int


@dataclass(frozen=True)
class Recipe:
    """A published data set as a catalog entry's settings.

    ``settings``: overrides on ``entry``'s defaults (the values --set takes; --set still overrides on top);
    ``ic``, ``grid``, ``time``: the IC measure, grid and time sampling in words; ``splits``: {split: Split};
    ``differs``: where our solver or measure differs from the published generator.
    """

    name: str
    entry: str
    paper: str
    where: str  # table / section of the paper
    url: str
    code: str  # the generator's files and lines the settings were read from
    settings: Mapping[str, Any]
    ic: str
    grid: str
    time: str
    splits: Mapping[str, Split]
    differs: str
    input_frames: int | None = None  # frames the published benchmark feeds its model (None: operator u0 -> u_T)
    notes: tuple[str, ...] = field(default=())

    @property
    def source(self) -> str:
        """The recipe's source in one line: paper, where in it, and the URL."""
        return f"{self.paper}, {self.where} ({self.url})"


def _splits(train: int, valid: int, test: int) -> dict[str, Split]:
    return {"train": Split(0, train), "valid": Split(1, valid), "test": Split(2, test)}


PDEBENCH_PAPER = "Takamoto et al. 2022, PDEBench (NeurIPS Datasets and Benchmarks)"
PDEBENCH_URL = "https://arxiv.org/abs/2210.07182"
FNO_PAPER = "Li et al. 2021, Fourier Neural Operator for Parametric PDEs (ICLR)"
FNO_URL = "https://arxiv.org/abs/2010.08895"
PDEBENCH_IC = ("PDEBench's init_multi (ic kind 'sines'): two wavenumbers drawn from 1..4, amplitudes U(0,1), "
               "phases U(0,2pi); |u| with p=0.1, a random sign, a tanh window with p=0.1")
PDEBENCH_IC_DIFF = ("our IC is on the cell-left points x_i = i/n of a periodic box; PDEBench's on cell centres with "
                    "wavenumbers 2 pi k / (1 - dx) (not exactly periodic) and draws that share PRNG keys")

_CFD = PDEBENCH + "CompressibleFluid/"
_CFD_CODE = (_CFD + "config/args/1D_Multi.yaml (nx 1024 on [-1, 1], dt_save 0.01, fin_time 1, gamma 5/3, CFL 0.3, "
             "eta, zeta, bc periodic), 1D_Multi_trans.yaml (bc trans, eta = zeta = 1e-8), 1D_Multi_shock.yaml "
             "(dt_save 0.005, fin_time 0.4, init_key 2020); CFD_multi_Hydra.py:657-681 (the ICs: rho from "
             "init_multi_HD with umin 1, umax 10, p with 10, 100, renormalised; u raw; shocks from "
             "init_multi_HD_shock), update_vis (the stress (eta + zeta + eta / 3) rho_face du / dx and its work), "
             "HLLC, limiting_HD (MC limiter on the primitive variables), a predictor-corrector step; utils.py:579-715 "
             "(init_multi_HD with k_tot 3, num_choise_k 2; init_multi_HD_shock); run_trainset_1D.sh (keys 2020..2029 "
             "of 1000 samples: 10000)")
_CFD_SOLVER = ("PDEBench's solver is a MUSCL (MC) HLLC scheme with Davis's wave speeds and a midpoint predictor-"
               "corrector step at an adaptive CFL 0.3, the viscous stress applied after it by sub-cycled forward-Euler "
               "steps (operator splitting), a pressure floor 1e-4, float32; ours MUSCL (MC), HLLC with Einfeldt's "
               "speeds, the stress in the same SSP-RK3 step (unsplit) at one fixed step per configuration (CFL 0.4 "
               "at the distribution's largest speed plus the viscous limit), a sample failing instead of a floor")
_CFD_IC = ("rho, u, p independent draws of PDEBench's init_multi_HD (ic kind 'sines': two wavenumbers drawn from "
           "1..3, amplitudes U(0,1), phases U(0,2pi), |s| with p=0.1, a random sign, a tanh window with p=0.5 on "
           "x_l in [0.1, 0.45], x_r in [0.55, 0.9] of PDEBench's [-1, 1]); rho rescaled to [b, b + m], m, b ~ "
           "loguniform(1, 10); p the same with loguniform(10, 100); u raw (|u| <= 3)")
_CFD_IC_DIFF = ("our IC is exactly periodic (wavenumbers 2 pi k / 2); PDEBench's uses 2 pi k / (x_last - x_first) "
                "= 2 pi k / (2 - dx), a seam of O(k dx) at the periodic end, and its draws share PRNG keys within a "
                "field (which modes and the amplitudes; |s| and the sign; the window's ends), ours are independent")
_CFD_SPLITS = ("PDEBench ships 10000 samples per file (its models test on a file's first 10%, models/fno/utils.py "
               "FNODatasetSingle: here 8000 / 1000 / 1000) "
               "and its models read 10 frames (config_1D_CFD initial_step 10); ")


def _cfd_rand(eta: str, bc: str, where: str) -> dict:
    """The settings of one of PDEBench's 1D CFD random-IC files."""
    return {"n": 1024, "length": 2.0, "t_end": 1.0, "n_frames": 101, "bc": bc, "limiter": "mc",
            "gamma": "1.6666666666666667", "eta": eta, "zeta": eta, "ic": {"kind": "sines"}}


RECIPES: dict[str, Recipe] = {r.name: r for r in (
    Recipe(
        name="fno_burgers1d", entry="burgers1d", paper=FNO_PAPER, where="section 5.1 (Burgers), Table 1", url=FNO_URL,
        code=FNO + "burgers/GRF1.m:18-40 (the GRF's eigenvalues); the paper's mu0 and nu (the public "
                   "gen_burgers1.m:5-13 shows other values: gamma 2.5, tau 7, nu 1e-3)",
        settings={"n": 1024, "nu": "0.1", "t_end": 1.0, "n_frames": 2,
                  "ic": {"kind": "grf", "sigma": 25.0, "tau": 5.0, "alpha": 2.0}},
        ic="u0 ~ N(0, 625 (-Laplacian + 25 I)^-2), periodic on [0, 1), zero mean",
        grid="1024 points on [0, 1) (the paper solves on 8192 and subsamples to 1024 and coarser)",
        time="u0 and u(t = 1): 2 frames", splits=_splits(1000, 100, 100),
        differs="the paper solves on 2^13 points with a split-step (spectral + heat) scheme in chebfun; we solve "
                "with ETDRK4 on the stated 1024 points (the 2/3 rule band-limits the IC to |k| <= 341)"),
    Recipe(
        name="fno_ns2d_nu1e-3", entry="ns2d", paper=FNO_PAPER, where="section 5.3 (Navier-Stokes), Table 1, nu = 1e-3",
        url=FNO_URL,
        code=FNO + "navier_stokes/ns_2d.py:113 (s = 256), :119 (GaussianRF alpha 2.5, tau 7), :126 (forcing), "
                   ":149 (nu 1e-3, T 50, dt 1e-4); random_fields.py:17,35 (sigma = tau^(alpha - 1))",
        settings={"n": 64, "length": 1.0, "nu": "0.001", "t_end": 50.0, "n_frames": 51, "forcing": "diagonal",
                  "forcing_amplitude": 0.1, "forcing_wavenumber": 1, "drag": 0.0,
                  "ic": {"kind": "grf", "sigma": 7.0**1.5, "tau": 7.0, "alpha": 2.5}},
        ic="w0 ~ N(0, 7^3 (-Laplacian + 49 I)^-2.5) on the unit torus, zero mean (the paper writes 7^(3/2): its "
           "code's sigma multiplies the square root of the covariance)",
        grid="64 x 64 on the unit torus (the paper solves on 256 x 256 and subsamples to 64 x 64)",
        time="t = 0, 1, ..., 50: 51 frames (the paper keeps w0 and t = 1..50; its model reads the first 10 "
             "frames and predicts the rest)",
        splits=_splits(1000, 100, 200), input_frames=10,
        differs="the paper: Crank-Nicolson (viscous) + explicit Euler (advection), dt = 1e-4 on 256^2, 2/3 "
                "dealiasing; we: ETDRK4 at the CFL step on 64^2 directly (2/3 rule), float32"),
    *(Recipe(
        name=f"fno_ns2d_nu1e-{e}", entry="ns2d", paper=FNO_PAPER,
        where=f"section 5.3 (Navier-Stokes), Table 1, nu = 1e-{e}", url=FNO_URL,
        code=FNO + "navier_stokes/ns_2d.py:113 (s = 256), :119 (GaussianRF alpha 2.5, tau 7), :126 (forcing); "
                   "random_fields.py:17,35 (sigma = tau^(alpha - 1)); the paper's section 5.3 for nu and T (the "
                   "script shows nu 1e-3, T 50)",
        settings={"n": 64, "refine": 4, "length": 1.0, "nu": f"1e-{e}", "t_end": t_end, "n_frames": int(t_end) + 1,
                  "forcing": "diagonal", "forcing_amplitude": 0.1, "forcing_wavenumber": 1, "drag": 0.0,
                  "ic": {"kind": "grf", "sigma": 7.0**1.5, "tau": 7.0, "alpha": 2.5}},
        ic="w0 ~ N(0, 7^3 (-Laplacian + 49 I)^-2.5) on the unit torus, zero mean, drawn on the 256 x 256 solve grid",
        grid="solved on 256 x 256 on the unit torus, every 4th point kept: 64 x 64 (the paper's subsampling)",
        time=f"t = 0, 1, ..., {t_end:g}: {int(t_end) + 1} frames (the paper keeps t = 1..{t_end:g}; its model reads "
             f"the first 10 and predicts the other {int(t_end) - 10})",
        splits=_splits(1000, 100, 200), input_frames=10,
        differs="the paper: Crank-Nicolson (viscous) + explicit Euler (advection), dt = 1e-4 on 256^2, 2/3 "
                "dealiasing, subsampled to 64^2; we: ETDRK4 at the CFL step on the same 256^2 (2/3 rule), float32, "
                "every 4th point kept (the paper does not say how it subsampled: we keep points, as its training "
                "scripts subsample)" + extra,
        notes=notes) for e, t_end, extra, notes in (
            (4, 30.0, "; the paper's N = 10000 column is the train split at --n 10000",
             ("a copy of ns_V1e-4_N10000_T30.mat described by a third party holds 50 frames, not the paper's 30 "
              "(not checked: the file is not reachable from here)",)),
            (5, 20.0, "", ()))),
    Recipe(
        name="fno_darcy2d", entry="darcy2d", paper=FNO_PAPER, where="section 5.2 (Darcy flow), Table 4",
        url=FNO_URL,
        code=FNO + "darcy/demo.m:13-14 (alpha 2, tau 3), :29-30 (f = 1), GRF.m:13-15 (Neumann cosine modes); "
                   "the paper's threshold 12 / 3 (demo.m:26-27 shows 12 / 4)",
        settings={"n": 85, "a_pos": "12", "a_neg": "3", "f": "1",
                  "ic": {"kind": "neumann_grf", "tau": 3.0, "alpha": 2.0}},
        ic="a = 12 where g >= 0, 3 where g < 0; g ~ N(0, (-Laplacian + 9 I)^-2) with zero Neumann boundaries",
        grid="85 x 85 nodes on [0, 1]^2 (the paper solves on 421 x 421 and subsamples by 5 to 85)",
        time="steady: one solve per sample", splits=_splits(1000, 100, 100),
        differs="the paper: second-order finite differences on 421^2 (MATLAB), subsampled; we solve the same "
                "scheme on 85^2 directly (Jacobi-preconditioned CG, float32)"),
    Recipe(
        name="pdebench_advection1d", entry="advection1d", paper=PDEBENCH_PAPER,
        where="Appendix D.1 (advection), Table 5", url=PDEBENCH_URL,
        code=PDEBENCH + "AdvectionEq/config/multi/beta1e0.yaml:2-8 (dt_save 0.01, T 2, nx 1024, beta), "
                        "advection_multi_solution_Hydra.py:279 (init_multi, k_tot 4), utils.py:40-124",
        settings={"n": 1024, "c": "choice(0.1, 0.4, 1.0, 4.0)", "t_end": 2.0, "n_frames": 201, "ic": "sines"},
        ic=PDEBENCH_IC, grid="1024 points on [0, 1), periodic",
        time="t = 0, 0.01, ..., 2: 201 frames", splits=_splits(9000, 500, 1000),
        differs="PDEBench ships one file per beta (--set c=0.4 makes one); its solver is a 2nd-order finite-volume "
                "upwind scheme with a limiter (diffusive), ours the exact spectral translation; " + PDEBENCH_IC_DIFF),
    Recipe(
        name="pdebench_burgers1d", entry="burgers1d", paper=PDEBENCH_PAPER, where="Appendix D.2 (Burgers), Table 5",
        url=PDEBENCH_URL,
        code=PDEBENCH + "BurgersEq/config/multi/1e-1.yaml:2-8 (dt_save 0.01, T 2, nx 1024, epsilon), "
                        "burgers_multi_solution_Hydra.py:177,241 (nu = epsilon / pi), :289 (init_multi, k_tot 4)",
        settings={"n": 1024, "nu": "choice(0.0003183, 0.003183, 0.03183, 0.3183)", "t_end": 2.0, "n_frames": 201,
                  "ic": "sines"},
        ic=PDEBENCH_IC, grid="1024 points on [0, 1), periodic",
        time="t = 0, 0.01, ..., 2: 201 frames", splits=_splits(9000, 500, 1000),
        differs="PDEBench's files are named by epsilon in {0.001, 0.01, 0.1, 1.0} and solve nu = epsilon / pi "
                "(here nu, --set nu=0.03183 makes one file's set); its solver is a 2nd-order finite-volume scheme, "
                "ours ETDRK4 pseudo-spectral: at nu = 3.2e-4 a shock (width ~2 nu / jump ~ 6e-4) is under one cell "
                "of 1024 points and the solution overshoots max|u0| by up to 0.4% (docs/results/recipes.md; "
                "--set n=4096 resolves it); " + PDEBENCH_IC_DIFF),
    Recipe(
        name="pdebench_reaction_diffusion1d", entry="fisher_kpp1d", paper=PDEBENCH_PAPER,
        where="Appendix D.3 (diffusion-reaction), Table 5", url=PDEBENCH_URL,
        code=PDEBENCH + "ReactionDiffusionEq/config/multi/Rho1e0_Nu1e0.yaml:2-9 (dt_save 0.01, T 1, nx 512, nu, "
                        "rho), reaction_diffusion_multi_solution_Hydra.py:272,277 (the equation), :279-284 "
                        "(init_multi, normalised)",
        settings={"n": 512, "D": "choice(0.5, 1.0, 2.0, 5.0)", "r": "choice(1.0, 2.0, 5.0, 10.0)", "t_end": 1.0,
                  "n_frames": 101, "ic": {"kind": "sines", "normalise": True}},
        ic=PDEBENCH_IC + ", rescaled to [0, 1]", grid="512 points on [0, 1), periodic",
        time="t = 0, 0.01, ..., 1: 101 frames", splits=_splits(9000, 500, 1000),
        differs="PDEBench ships one file per (nu, rho) (--set D=1 --set r=1 makes one); its solver splits the "
                "logistic reaction (exact) from a finite-volume diffusion step; ours ETDRK4; " + PDEBENCH_IC_DIFF),
    Recipe(
        name="pdebench_diffusion_sorption1d", entry="diffusion_sorption1d", paper=PDEBENCH_PAPER,
        where="Appendix D.8 (diffusion-sorption), Table 5", url=PDEBENCH_URL,
        code="github.com/pdebench/PDEBench@9754b4c, pdebench/data_gen/configs/diff-sorp.yaml:24-37 (D 5e-4, por "
             "0.29, rho_s 2880, k_f 3.5e-4, n_f 0.874, sol 1, t 500, xdim 1024 on [0, 1]), src/sim_diff_sorp.py:58-62 "
             "(cell centres), :74-76 (u0 constant ~ U(0, 0.2)), :109-122 (ghost values sol and D (u_{n-2} - u_{n-1}) "
             "/ dx, R with (u + 1e-6)), :94 (scipy solve_ivp, RK45 at its default rtol 1e-3, atol 1e-6); "
             "gen_diff_sorp.py:108-114 (seeds 0..9999); models/config/args/config_diff-sorp.yaml (t_train 101, "
             "initial_step 10)",
        settings={"n": 1024, "length": 1.0, "t_end": 500.0, "n_frames": 101, "dt": 0.25, "u_left": 1.0,
                  "eps": 1e-6, "D": "0.0005", "por": "0.29", "rho_s": "2880", "k_f": "0.00035", "n_f": "0.874",
                  "ic": {"kind": "constant", "low": 0.0, "high": 0.2}},
        ic="u0 = one value in every cell, ~ U(0, 0.2) per sample",
        grid="1024 cells on [0, 1], values at the cell centres; u = 1 at x = 0, u = -D u_x at x = 1",
        time="t = 0, 5, ..., 500: 101 frames", splits=_splits(9000, 500, 1000), input_frames=10,
        differs="the published file has 101 frames (its models' t_train 101; its DaRUS record: dt 5, t 500) while "
                "diff-sorp.yaml says tdim 501 (--set n_frames=501 makes that); PDEBench ships seeds 0..9999 (its "
                "scripts hold out the last 10%: here 9000 / 500 / 1000). Its solver: the same finite volumes with "
                "the boundary values in ghost cells a whole cell from the last centre (first order at both ends), "
                "time by scipy's adaptive RK45 at rtol 1e-3 (the record says 1e-6; the code passes none), whose error "
                "dominates its data: 0.4% (t = 5) to 1.7% (t = 500) relative L2 against a tight solve of its own "
                "scheme, beside its space error 1.0% to 0.12% at 1024 cells; ours: second order at both ends, "
                "TR-BDF2 at dt = 0.25 with Newton per stage, float32, within 1.3e-4 of its own finer runs (space 4e-5). "
                "The same IC in both: 0.3% to 1.6% apart, inside PDEBench's own error (docs/results/recipes.md); "
                "sample means agree, stds differ by its RK45 error (1.8% at t = 500). PDEBench's "
                "published set drew u0 with np.random.seed(seed) + uniform (2f71cb8, the pdebench 0.1.0 wheel), its "
                "current code default_rng(seed) (e4acf37): the same law, other draws, and ours others again"),
    Recipe(
        name="pdebench_diffusion_reaction2d", entry="diffusion_reaction2d", paper=PDEBENCH_PAPER,
        where="Appendix D (2D diffusion-reaction), Table 5", url=PDEBENCH_URL,
        code="github.com/pdebench/PDEBench@9754b4c, pdebench/data_gen/configs/diff-react.yaml:24-36 (Du 1e-3, Dv "
             "5e-3, k 5e-3, t 5, tdim 101, [-1, 1]^2, xdim = ydim = 128), src/sim_diff_react.py:60-67 (cell centres, "
             "dx = 2 / 128, frames linspace(0, 5, 101)), :80-83 (u0, v0 standard normal per cell), :93-123 (the "
             "5-point Laplacian with no-flux walls), :126 (scipy solve_ivp, RK45 at its default rtol 1e-3, atol "
             "1e-6), :150-156 (the equations); gen_diff_react.py:113-119 (seeds 0..999)",
        settings={"n": 128, "length": 2.0, "t_end": 5.0, "n_frames": 101, "bc": "neumann", "Du": "0.001",
                  "Dv": "0.005", "k": "0.005", "ic": {"kind": "white", "std": 1.0, "mean": 0.0}},
        ic="u0 and v0 standard normal, independent at every cell (white noise); PDEBench seeds numpy per sample",
        grid="128 x 128 cells on [0, 2]^2 (PDEBench's [-1, 1]^2 shifted by 1), values at the cell centres, "
             "no-flux (Neumann) walls",
        time="t = 0, 0.05, ..., 5: 101 frames", splits=_splits(800, 100, 100), input_frames=10,
        differs="PDEBench ships 1000 seeds (its scripts hold out the last 10%: here 800 / 100 / 100; its models read "
                "10 frames, config_diff-react.yaml initial_step 10); its solver is a second-order finite-volume "
                "Laplacian with scipy's adaptive RK45 at rtol 1e-3 (the dataset's metadata says 1e-6; the code "
                "passes no tolerance), ours a cosine (Neumann) spectral basis with ETDRK4 at dt = 1/60, float32. "
                "The white-noise IC is grid-scale: our solver starts from its 2/3-rule projection, so frame 0 keeps "
                "4/9 of the IC's variance (std 0.67, PDEBench's frame 0 std 1), and the first frames differ at the "
                "grid scale, where the two Laplacians differ most (spectral / finite volume: 1.46 at the 2/3 rule's "
                "last mode, 2.43 at the grid's). The same IC in both at 128^2: 4.3% apart at t = 5, the size of "
                "their own space errors (2.1%, 1.8%), 0.8% apart at 256^2 (docs/results/recipes.md). PDEBench's published set drew u0 with np.random.seed(seed) + randn "
                "(2f71cb8, the pdebench 0.1.0 wheel); its current code draws default_rng(seed) (e4acf37): the same "
                "distribution, other draws, and ours others again (jax keys)"),
    *(Recipe(
        name=f"pdebench_darcy2d_beta{tag}", entry="darcy2d", paper=PDEBENCH_PAPER,
        where=f"Appendix D (2D Darcy flow, beta = {beta})", url=PDEBENCH_URL,
        code=PDEBENCH + "ReactionDiffusionEq/config/multi/config_2D.yaml (nx = ny = 128 on [0, 1]^2, fin_time 2, "
                        "dt_save 0.25, CFL 0.25, numbers 200), reaction_diffusion_2D_multi_solution_Hydra.py (u_t = "
                        "div(nu grad u) + beta by a midpoint predictor-corrector step, face coefficient (nu_P + nu_Q) "
                        "/ 2, ghost cells u = 0 (bc_2D 'Neumann'), nu copied into them (bc_2D 'trans'); nu = 1 where "
                        "the sum of 5 bumps exp(-|x - x_m|^2 / w_m), x_m ~ U[0, 1]^2, w_m ~ 0.5 U(0, 1), exceeds its "
                        "batch mean, else 0.1), utils.py init_multi_2DRand (its pseudo-time start), run_DarcyFlow2D.sh "
                        "(keys from 2020); data_download/pdebench_data_urls.csv (the five beta files); "
                        "models/fno/utils.py FNODatasetSingle (test_ratio 0.1: the first 10% test)",
        settings={"n": 128, "length": 1.0, "points": "cells", "a_pos": "1", "a_neg": "0.1", "f": beta,
                  "ic": {"kind": "bumps", "count": 5, "w_max": 0.5}},
        ic="a = 1 where s(x) = sum of 5 bumps exp(-|x - x_m|^2 / w_m) (x_m uniform on [0, 1]^2, w_m ~ U(0, 0.5]) "
           "exceeds c = E[mean of s over the cells] = 1.852 (the measure's expectation), 0.1 elsewhere",
        grid="128 x 128 cell centres of (0, 1)^2, u = 0 at the ghost centres half a cell outside the walls "
             "(PDEBench's placement)",
        time="steady: one solve per sample (the steady state; PDEBench keeps u at pseudo-time t = 2)",
        splits=_splits(9000, 500, 1000),
        differs="PDEBench ships 10000 samples per beta (its models test on the first 10% and train on the rest: here "
                "9000 / 500 / 1000). It thresholds the bump sum at the mean over its whole batch of 200 samples, which "
                "ties a sample to its batch; we threshold at that mean's expectation c. Its u is the state at "
                "pseudo-time t = 2 of an explicit run from a random start (init_multi_2DRand: mean U(0.1, 10)), ours "
                "the steady state it approaches, solved directly: its transient decays independently of beta, so "
                "its small-beta files are not steady (its u(t = 2) against its own scheme's steady state, median / "
                "max over 32 samples: 6.5% / 535% at beta = 0.01, 2.1% / 54% at 0.1, 0.11% / 4.9% at 1, under 0.51% "
                "from 10 on; docs/results/recipes.md). Its face coefficient is the arithmetic mean of the two cells, "
                "ours the harmonic mean (exact across a layered jump); ours Jacobi-preconditioned CG to relative "
                "residual 1e-5, float32. On its coefficient fields ours is 0.81% (median; max 4.0%) from its "
                "steady state at 128^2, within the sum of the two space errors (1.8% ours, 1.5% its) in every "
                "sample, 0.44% at 256^2")
        for tag, beta in (("1e-2", "0.01"), ("1e-1", "0.1"), ("1e0", "1"), ("1e1", "10"), ("1e2", "100"))),
    *(Recipe(
        name=f"pdebench_cfd1d_rand_{tag}", entry="compressible_ns1d", paper=PDEBENCH_PAPER,
        where=f"Appendix D (1D compressible Navier-Stokes, Rand, eta = zeta = {eta}, {bc}), Table 5", url=PDEBENCH_URL,
        code=_CFD_CODE, settings=_cfd_rand(eta, bc, tag), ic=_CFD_IC,
        grid=f"1024 cells on [0, 2] (PDEBench's [-1, 1] shifted by 1), {ends}",
        time="t = 0, 0.01, ..., 1: 101 frames", splits=_splits(8000, 1000, 1000), input_frames=10,
        differs=_CFD_SPLITS + _CFD_SOLVER + "; " + _CFD_IC_DIFF + "; the viscous limit sets our step where eta >= "
                "1e-2: 27,300 steps per trajectory at 1e-8, 57,800 at 1e-2, 333,100 at 1e-1 (each a full flux "
                "evaluation; PDEBench sub-cycles the stress instead: ~40,800 and ~408,000 cheap viscous sub-steps)")
        for tag, eta, bc, ends in (("eta1e-8", "1e-8", "periodic", "periodic"), ("eta1e-2", "0.01", "periodic", "periodic"),
                                   ("eta1e-1", "0.1", "periodic", "periodic"),
                                   ("trans", "1e-8", "outflow", "zero-gradient (PDEBench trans) ends"))),
    Recipe(
        name="pdebench_cfd1d_shock", entry="compressible_ns1d", paper=PDEBENCH_PAPER,
        where="Appendix D (1D compressible Navier-Stokes, Shock, eta = zeta = 1e-8, trans), Table 5",
        url=PDEBENCH_URL, code=_CFD_CODE,
        settings={"n": 1024, "length": 2.0, "t_end": 0.4, "n_frames": 81, "bc": "outflow", "limiter": "mc",
                  "gamma": "1.6666666666666667", "eta": "1e-8", "zeta": "1e-8",
                  "ic": {"kind": "riemann", "rho_l": "loguniform(1, 10)", "rho_r": "loguniform(1, 10)",
                         "p_l": "loguniform(10, 100)", "p_r": "loguniform(10, 100)", "u_l": "uniform(-0.5, 0.5)",
                         "u_r": "uniform(-0.5, 0.5)", "x0": "uniform(0.5, 1.5)"}},
        ic="a random Riemann problem: rho left and right ~ loguniform(1, 10), p ~ loguniform(10, 100), u ~ "
           "uniform(-0.5, 0.5), the jump at x0 ~ uniform(0.5, 1.5) (PDEBench: at cell int(1024 U(0.25, 0.75)))",
        grid="1024 cells on [0, 2] (PDEBench's [-1, 1] shifted by 1), zero-gradient (PDEBench trans) ends",
        time="t = 0, 0.005, ..., 0.4: 81 frames", splits=_splits(8000, 1000, 1000), input_frames=10,
        differs=_CFD_SPLITS + _CFD_SOLVER + "; PDEBench draws the left and right states with shared PRNG keys "
                "(init_multi_HD_shock), ours independently; its jump sits on a face, ours between the cell centres "
                "either side of x0"),
    *(Recipe(
        name=f"pdebench_cfd2d_rand_m{mach}_{tag}", entry="compressible_ns2d", paper=PDEBENCH_PAPER,
        where=f"Appendix D (2D compressible Navier-Stokes, Rand, M = {mach}, eta = zeta = {eta}, 128^2), Table 5",
        url=PDEBENCH_URL,
        code=_CFD + "config/args/2D_Multi_Rand.yaml (128 x 128 on [0, 1]^2, dt_save 0.05, fin_time 1, gamma 5/3, "
                    "periodic, k_tot 4, M0), CFD_multi_Hydra.py:696-700 and utils.py:861-975 (init_multi_HD_2DRand: "
                    "d0, T0 ~ U(0.1, 10), delD, delP ~ U(0.01, 0.2), modes i j != 0 of |k|^-1/2, velocity scaled to "
                    "mean |v| = M0 sqrt(gamma T0), a window with p = 0.5), update_vis (the stress per axis)",
        settings={"n": 128, "length": 1.0, "t_end": 1.0, "n_frames": 21, "bc": "periodic", "limiter": "mc",
                  "gamma": "1.6666666666666667", "eta": eta, "zeta": eta, "ic": {"kind": "rand", "mach": float(mach)}},
        ic="PDEBench's init_multi_HD_2DRand (ic kind 'rand'): rho = rho0 (1 + d_rho f4 / mean|f4|), p = rho0 T0 (1 + "
           "d_p f3 / mean|f3|), velocity (f1, f2) scaled to mean magnitude M sqrt(gamma T0), each f a sum of sines "
           "of the modes (i, j) in [-4, 4]^2 with i j != 0, amplitude |k|^-1/2, random phases; rho0, T0 ~ U(0.1, "
           "10), d_rho, d_p ~ U(0.01, 0.2); with p = 0.5 a tanh window in x and y (ends in [0.1, 0.45] and [0.55, "
           "0.9]) with rest at rho0, p = rho0 T0 outside",
        grid="128 x 128 cells on [0, 1]^2, periodic", time="t = 0, 0.05, ..., 1: 21 frames",
        splits=_splits(8000, 1000, 1000), input_frames=10,
        differs=_CFD_SPLITS + _CFD_SOLVER.replace("MUSCL (MC), HLLC", "MUSCL (MC), HLLC by axis (unsplit)") + "; "
                "PDEBench draws the window's ends with the key of its on/off draw, ours independently; our step is "
                "fixed from an estimate of the largest speed (sqrt(gamma T0_max) (2 + 4 M): a sample outrunning it "
                "fails with its cause), 18,400 steps a trajectory at M = 1, eta = 1e-2 (~5 minutes a sample at euler2d's "
                "0.9e6 cell steps/s on 2 CPU cores; PDEBench generated its sets on GPUs)")
        for mach in ("0.1", "1") for tag, eta in (("eta1e-2", "0.01"), ("eta1e-1", "0.1"))),
    Recipe(
        name="pdebench_swe2d", entry="shallow_water2d", paper=PDEBENCH_PAPER,
        where="Appendix D (2D shallow-water equations: radial dam break), Table 5", url=PDEBENCH_URL,
        code="github.com/pdebench/PDEBench@2f71cb8, pdebench/data_gen/configs/radial_dam_break.yaml (T_end 1, "
             "n_time_steps 100, 128 x 128 on [-2.5, 2.5]^2, gravity 1, inner height 2), gen_radial_dam_break.py "
             "(dam_radius ~ uniform(0.3, 0.7) per seed), src/sim_radial_dam_break.py (h_out 1, centre (0, 0), "
             "PyClaw's Roe solver with entropy fix, MC limiter, extrapolation boundaries)",
        settings={"n": 128, "length": 5.0, "t_end": 1.0, "n_frames": 101, "bc": "outflow", "limiter": "mc",
                  "g": "1.0", "ic": {"kind": "radial", "h_in": "2", "h_out": "1", "radius": "uniform(0.3, 0.7)",
                                     "cx": "2.5", "cy": "2.5"}},
        ic="depth 2 inside a circle of radius ~ uniform(0.3, 0.7) at the domain's centre, 1 outside, at rest",
        grid="128 x 128 cells on [0, 5]^2 (PDEBench's [-2.5, 2.5]^2 shifted by 2.5), extrapolation (outflow) sides",
        time="t = 0, 0.01, ..., 1: 101 frames", splits=_splits(800, 100, 100),
        differs="PDEBench ships 1000 seeds (its scripts hold out the last 10%: here 800 / 100 / 100) and stores h "
                "alone (we store h, hu, hv: select h); its solver is PyClaw's dimensionally split Roe solver with an "
                "entropy fix and the MC limiter at CFL ~0.9, ours MUSCL (MC) with HLL fluxes, unsplit SSP-RK3 at "
                "CFL 0.3, float32; PyClaw needs a Fortran compiler, which this machine lacks, so the two were not run "
                "side by side (ours is checked against Ritter's and Stoker's exact dam breaks: "
                "docs/results/finite_volume.md)"),
)}

PDEARENA = ("github.com/pdearena/pdearena@78a8b03 (the generator unchanged since b633984), pdedatagen/navier_stokes.py, "
            "pdedatagen/configs/navierstokes2dsmoke.yaml, pdedatagen/scripts/navierstokes_jobs.sh")
RECIPES["pdearena_smoke2d"] = Recipe(
    name="pdearena_smoke2d", entry="smoke_box2d",
    paper="Gupta & Brandstetter 2022, Towards Multi-spatiotemporal-scale Generalized PDE Modeling (TMLR)",
    where="the 2D Navier-Stokes smoke experiments (buoyancy-driven, velocity form)",
    url="https://arxiv.org/abs/2209.15616",
    code=PDEARENA + ": a closed 32 x 32 box, 128^2 cells, zero velocity on every side, smoke |PhiFlow 2.1 "
                    "Noise(scale 11, smoothness 6)| with no source, buoyancy 0.5, nu 0.01, PhiFlow's "
                    "semi-Lagrangian step of dt 1.5, the states after steps 9, 13, ..., 61 kept (skip_nt 8, "
                    "sample_rate 4), 52 seeds x 100 / 25 / 25 trajectories",
    settings={"n": 128, "refine": 3, "length": 32.0, "buoyancy": "0.5", "nu": "0.01",
              "ic": {"kind": "noise", "scale": 11.0, "smoothness": 6.0},
              "t_start": 13.5, "t_end": 91.5, "n_frames": 14},
    ic="fluid at rest; smoke = |PhiFlow Noise(scale 11, smoothness 6)| on the 32 m box (PDEArena's law; nearly all "
       "its variance in the lowest modes), drawn on the solve grid",
    grid="solved on 384 x 384 cells of the 32 m closed box (cell Reynolds number u_max h / nu = 4 * 0.083 / 0.01 "
         "= 33, within the flow family's 40), each 3 x 3 block's means stored: 128 x 128 (PDEArena's grid; u, v the "
         "fluxes through the coarse faces, so the stored velocity stays divergence-free)",
    time="t = 13.5, 19.5, ..., 91.5 s: 14 frames 6 s apart (PDEArena's kept states; its files label them "
         "linspace(18, 102))",
    splits=_splits(5200, 1300, 1300),
    differs="PDEArena: PhiFlow 2.1's semi-Lagrangian step of dt 1.5 s directly on 128^2 (CFL up to ~24, cell "
            "Reynolds number ~100), which loses 8-16% of the closed box's smoke (docs/results/recipes.md); we: "
            "MacCormack advection at CFL 0.5 (step 0.0104 s, ~8,800 steps a trajectory) on 384^2, a resolved solve "
            "of the same PDE, stored as 128^2 block means: the recipe gives the PDE's statistics, not PhiFlow's step "
            "error (~10 min a trajectory on 2 CPU cores; the pressure p is stored too)")


# Published sets no catalog entry can express today: listed with the reason, never approximated.
NOT_EXPRESSIBLE: dict[str, str] = {
    "cfdbench_cavity_bc": (
        _CAVITY_WHY + CFDBENCH + "generation-code/fluent-scheme/create_scheme.py:58-67: lid speed 1, 2, ..., 50 m/s "
        "(50 cases) at density 1, viscosity 1e-5 Pa s (nu = 1e-5 m^2/s). On 64^2 the cell Reynolds number "
        "U h / nu = 50 (L / 64) / 1e-5 = 78125 L exceeds the flow family's limit 40 for any side L > 0.51 mm "
        "(cavity2d refuses it); " + _SUMMARY + " gives the paper's side L = 0.01 m: Re = U L / nu = 1,000-50,000, "
        "cell Reynolds number up to 781"),
    "cfdbench_cavity_prop": (
        _CAVITY_WHY + CFDBENCH + "create_scheme.py:58-78: lid 10 m/s, density {0.1, 0.5, 1, ..., 10} x viscosity "
        "{1e-5, 5e-5, 1e-4, 5e-4, 1e-3, 5e-3, 1e-2} (84 cases, nu = mu / rho from 1e-6 to 0.1 m^2/s). Its "
        "smallest nu puts the cell Reynolds number at 10 (L / 64) / 1e-6 = 156250 L, over 40 for any L > 0.26 mm; "
        "and density and viscosity enter our solver only through nu (Re), so cases of equal mu / rho coincide "
        "(at the summary's L = 0.01 m: Re 1 to 100,000, 28 of the 84 cases over the limit)"),
    "cfdbench_cavity_geo": (
        _CAVITY_WHY + CFDBENCH + "src/dataset/cavity.py:253-256 (25 cases) and case_params_keys (height, width): "
        "the cavity's height and width vary independently (a rectangle); cavity2d's box is aspect * n x n square "
        "cells with an integer aspect; " + _SUMMARY + " gives height and width each in {0.01, 0.02, ..., 0.05} m "
        "(all 25 pairs) at lid 10 m/s, nu = 1e-5: Re 10,000-50,000, beyond 64^2 even for the five squares"),
    "cfdbench_tube_bc, cfdbench_tube_prop, cfdbench_tube_geo": (
        CFDBENCH + "generation-code/fluent-scheme/sample_laminar.txt:1-12 (the tube's Fluent journal): a mixture "
        "(two-phase: air and water) model, the tube initialised full of air (line 8), the water volume fraction "
        "exported beside the velocity (line 12); create_scheme.py:31-55 (inlet 0.1-5 m/s, 50 cases; density "
        "10-1000 x viscosity 0.01-1, 100 cases) and src/dataset/tube.py:201-208 (diameter 0.05-0.15 m, length 0.5-1 m, "
        "inlet 0.05-0.15 m/s, density 900-1100, viscosity 0.005-0.015 Pa s) state different values. channel2d "
        "is one phase with a parabolic inflow and at least one obstacle: it cannot fill an air-filled tube with "
        "water (tube.py was laminar.py before 70d6c80; " + _SUMMARY + " confirms a VOF water-air model)"),
    "cfdbench_cylinder_bc, cfdbench_cylinder_prop, cfdbench_cylinder_geo": (
        CFDBENCH + "create_scheme.py:90-107 reads the cases' velocity, density and viscosity from karman_set.txt, "
        "not in the repository (defaults 1 m/s, density 10, viscosity 1e-3 Pa s: nu = 1e-4); Fluent steps 0.001 s "
        "(sample_karman.txt:14), uniform velocity inlet; " + _SUMMARY + " gives the paper's Table 5: a channel "
        "0.12 m high and 0.22 m long (x1 = y1 = y2 = 0.06 m, x2 = 0.16 m from the cylinder's centre), d = 0.02 m, "
        "bc: inlet 0.1, 0.2, ..., 5 m/s (Re = 20-1000), prop: density x viscosity pairs with Re = rho U d / mu in "
        "[20, 1000] (115 cases; its listed values give 105), geo: d, x1, y1, y2, x2 varied (20 cases), SST "
        "k-omega where Fluent needed it. karman2d cannot make them: its length is an integer multiple of the "
        "height (0.22 / 0.12 is not); 64 cells across the height resolve Re <= 284 (karman2d refuses 300 at cell "
        "Reynolds number 42.2; Re 1000 needs n = 256); bc couples Re = 200 U to the inlet speed, which karman2d "
        "draws independently; the case list is not reproducible from the summary; geo changes the box's ratio"),
}


def not_expressible(name) -> str | None:
    """The reason a published set ``name`` is not expressible (NOT_EXPRESSIBLE; a key may list several names
    separated by ', '), or None."""
    if not isinstance(name, str):
        return None
    return next((why for key, why in NOT_EXPRESSIBLE.items() if name in key.split(", ")), None)


def refuse_not_expressible(name) -> str | None:
    """The one-line refusal of a published set that no entry can express yet, or None if ``name`` is not one."""
    why = not_expressible(name)
    return None if why is None else f"recipe {name!r} is not expressible yet (skipped, not approximated): {why}"


def unknown_recipe(name) -> str:
    """The one-line refusal of recipe ``name``: why, if it is a published set not expressible yet; else a near
    name if any, and the allowed names."""
    refused = refuse_not_expressible(name)
    if refused:
        return refused
    near = difflib.get_close_matches(name, list(RECIPES), n=2) if isinstance(name, str) else []
    hint = f"; did you mean {' or '.join(near)}" if near else ""
    return f"unknown recipe {name!r}{hint}; allowed: {', '.join(RECIPES)}"


def get_recipe(name: str) -> Recipe:
    """The recipe ``name`` (one-line ValueError naming the allowed names)."""
    if not isinstance(name, str) or name not in RECIPES:
        raise ValueError(unknown_recipe(name))
    return RECIPES[name]


def split_of(name: str, split: str) -> Split:
    """The (seed, n) of ``split`` (train / valid / test) of recipe ``name`` (one-line ValueError if unknown)."""
    if split not in SPLITS:
        raise ValueError(f"split {split!r} not allowed; allowed: {', '.join(SPLITS)}")
    if not isinstance(name, str) or name not in RECIPES:
        raise ValueError(f"--split {split} needs a recipe (its seeds and sizes), not {name!r}; recipes: "
                         f"{', '.join(RECIPES)}")
    return RECIPES[name].splits[split]


def changed_from(name: str, config: Mapping[str, Any]) -> list[str]:
    """The settings of ``config`` (a problem's ``config()``, labelled as recipe ``name``) that differ from the
    recipe's own ([] when it is the recipe as published, or a recipe this version does not declare)."""
    if name not in RECIPES:
        return []
    from pdestream import generator

    own = generator.get_pde(name).config()
    return [k for k in sorted(set(own) | set(config)) if own.get(k) != config.get(k)]


def changed_note(name: str, config: Mapping[str, Any]) -> str:
    """' with n, c changed (not the published set)' for a problem made from recipe ``name`` with other settings
    ('' when it is the recipe's own)."""
    changed = changed_from(name, config)
    return f" with {', '.join(changed)} changed (not the published set)" if changed else ""


def listing() -> str:
    """`pdestream recipes`: every recipe with its entry and source, then the sets not expressible (and why)."""
    width, entry = max(len(n) for n in RECIPES), max(len(r.entry) for r in RECIPES.values())
    lines = [f"{r.name:<{width}}  {r.entry:<{entry}}  {r.paper}, {r.where}" for r in RECIPES.values()]
    lines += ["", "not expressible yet (skipped, not approximated):"]
    lines += [f"  {name}: {why}" for name, why in NOT_EXPRESSIBLE.items()]
    lines += ["", "pdestream recipes show NAME: its settings; a recipe name works wherever a PDE name does"]
    return "\n".join(lines)


def show(name: str, as_json: bool = False) -> str:
    """`pdestream recipes show NAME`: source, settings, IC, grid, time, splits and differences (or JSON)."""
    r = get_recipe(name)
    if as_json:
        return json.dumps({"name": r.name, "entry": r.entry, "source": r.source, "code": r.code,
                           "settings": dict(r.settings), "ic": r.ic, "grid": r.grid, "time": r.time,
                           "splits": {k: {"seed": s.seed, "n": s.n} for k, s in r.splits.items()},
                           "input_frames": r.input_frames, "differs": r.differs}, indent=2)
    sets = " ".join(_sets(k, v) for k, v in r.settings.items())
    lines = [f"{r.name}: {r.entry} with the settings of {r.paper}",
             f"  source:   {r.where} ({r.url})",
             f"  code:     {r.code}",
             f"  settings: {sets}",
             f"  ic:       {r.ic}",
             f"  grid:     {r.grid}",
             f"  time:     {r.time}",
             "  splits:   " + ", ".join(f"{k} seed {s.seed} n {s.n}" for k, s in r.splits.items())
             + f" (pdestream generate {r.name} --split train --out FILE)"]
    if r.input_frames:
        lines.append(f"  model:    the first {r.input_frames} frames in (train --k-in {r.input_frames})")
    lines.append(f"  differs:  {r.differs}")
    return "\n".join(lines)


def cli_command(args) -> None:
    """`pdestream recipes [show NAME]` (args.args: the words after `recipes`): prints the list or one recipe."""
    print(command(args.args))


def command(args: list[str], as_json: bool = False) -> str:
    """`pdestream recipes [show NAME]`'s output: the list, or one recipe (one-line ValueError otherwise)."""
    if not args:
        return listing()
    if args[0] == "show" and len(args) == 2:
        return show(args[1], as_json)
    if args[0] == "show":
        raise ValueError(f"give one recipe: pdestream recipes show NAME; allowed: {', '.join(RECIPES)}")
    raise ValueError(f"unknown recipes command {' '.join(args)!r}; allowed: `pdestream recipes` (the list) or "
                     "`pdestream recipes show NAME`")


def _sets(key: str, value) -> str:
    """A setting as --set arguments a shell takes as written: each KEY=VALUE quoted where it needs it (a domain's
    spaces and parentheses), numbers at full precision (the same config and bits as the recipe's), an ic dict as
    its kind plus one --set ic.FIELD per field."""
    if isinstance(value, Mapping):
        kind = value["kind"]
        return " ".join([_sets(key, kind), *(_sets(f"{key}.{k}", v) for k, v in value.items() if k != "kind")])
    return "--set " + shlex.quote(f"{key}={_number(value)}")


def _number(value) -> str:
    """A value as --set reads it back exactly: a float by its shortest round-trip form (7.0 as 7), else str."""
    if isinstance(value, float):
        text = repr(value)
        return text[:-2] if text.endswith(".0") else text
    return str(value)
