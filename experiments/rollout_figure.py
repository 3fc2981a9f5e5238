"""A picture of rollouts a person reads at a glance: the reference, the coarse solver alone and the corrected coarse
solver side by side over time, for one held-out trajectory (solver-in-the-loop's figure).

For a flow (a problem whose FIELD_LOCATIONS put u and v on cell faces) the picture is the vorticity
dv/dx - du/dy at the cell corners, with the obstacle drawn in grey; for any other 2D problem it is the first
field; a 1D problem gets space-time images. Colours are shared across a row's reference and predictions (one
symmetric range per time column, the 99th percentile of the reference), so a wrong amplitude shows as a wrong colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pdestream.datasets.derived import vorticity


def frame_vorticity(frames: torch.Tensor, fields: tuple[str, ...], h: float) -> np.ndarray:
    """Vorticity [T, nx-1, ny-1] (1/s) of staggered frames [T, C, nx, ny] (u on left faces, v on bottom faces)."""
    return vorticity(frames[:, fields.index("u")], frames[:, fields.index("v")], h).numpy()


def picture_of(pde, frames: torch.Tensor, h: float) -> tuple[np.ndarray, str]:
    """What to draw of frames [T, C, *space]: (array [T, ...], its name)."""
    where = getattr(pde, "FIELD_LOCATIONS", {})
    if where.get("u") == "face_x" and where.get("v") == "face_y":
        return frame_vorticity(frames, tuple(pde.FIELDS), h), "vorticity [1/s]"
    return frames[:, 0].numpy(), pde.FIELDS[0]


def plot_rollouts(path: Path, pde, rows: dict[str, torch.Tensor], h: float, dt: float, columns: int = 5,
                  solid: torch.Tensor | None = None) -> None:
    """rows: {label: frames [T, C, nx, ny]} (the reference first), drawn at ``columns`` times from the first
    predicted frame to the last; h: the grid spacing of the frames (m), dt: the frame interval (s); solid: an
    obstacle mask [nx, ny] drawn in grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pics = {label: picture_of(pde, frames, h) for label, frames in rows.items()}
    if next(iter(pics.values()))[0].ndim == 2:  # 1D: one space-time image per row
        _space_time(plt, path, pde, pics, dt)
        return
    steps = next(iter(pics.values()))[0].shape[0]
    cols = np.unique(np.linspace(0, steps - 1, min(columns, steps)).round().astype(int))
    fig, axes = plt.subplots(len(pics), len(cols), figsize=(2.6 * len(cols), 1.6 * len(pics) + 0.6), squeeze=False)
    ref, what = next(iter(pics.values()))
    for j, t in enumerate(cols):
        lim = float(np.percentile(np.abs(ref[t]), 99)) or 1.0  # robust: a body corner spikes
        for i, (label, (pic, _)) in enumerate(pics.items()):
            ax = axes[i, j]
            ax.imshow(pic[t].T, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="equal")
            if solid is not None:
                s = solid.numpy()[-pic.shape[1]:, -pic.shape[2]:]  # vorticity corner (i, j): cell (i+1, j+1)'s
                ax.imshow(np.ma.masked_where(s.T < 0.5, s.T), origin="lower", cmap="Greys", vmin=0, vmax=1.5,
                          aspect="equal")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f"t = {(t + 1) * dt:.2f} s", fontsize=9)
            if j == 0:
                ax.set_ylabel(label, fontsize=8)
    fig.suptitle(f"{pde.NAME}: {what}, one held-out trajectory (colour range per column: the reference's)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _space_time(plt, path: Path, pde, pics: dict, dt: float) -> None:
    """1D rollouts: one image per row (x across, t up), the reference's colour range."""
    ref, what = next(iter(pics.values()))
    lim = float(np.percentile(np.abs(ref), 99)) or 1.0
    fig, axes = plt.subplots(1, len(pics), figsize=(2.8 * len(pics), 3.0), squeeze=False)
    for ax, (label, (pic, _)) in zip(axes[0], pics.items()):
        ax.imshow(pic, origin="lower", aspect="auto", cmap="RdBu_r", vmin=-lim, vmax=lim,
                  extent=(0, pic.shape[1], dt, dt * pic.shape[0]))
        ax.set_title(label, fontsize=8)
        ax.set_xlabel("x (cells)", fontsize=8)
    axes[0, 0].set_ylabel("t", fontsize=8)
    fig.suptitle(f"{pde.NAME}: {what}, one held-out trajectory", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
