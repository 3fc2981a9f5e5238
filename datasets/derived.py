"""Fields derived from a flow's stored ones (MAC grid: u on each cell's left face, v on its bottom face).

``vorticity(u, v, h)`` works on numpy arrays and torch tensors alike (a batch from the stream, a cache's arrays);
``flow_vorticity(ds)`` on an opened cache (xarray), as a variable like ``u``::

    ds = xr.open_zarr("karman.zarr"); w = datasets.flow_vorticity(ds)   # [sample, time, x, y], 1/s
    w = datasets.vorticity(batch["x"][:, 0, 0], batch["x"][:, 0, 1], h)  # u, v channels of a flow's frames
"""

from __future__ import annotations


def vorticity(u, v, h: float):
    """dv/dx - du/dy (1/s) at the interior cell corners: u, v [..., nx, ny] (left / bottom face values, m/s),
    h the cell size (m) -> [..., nx-1, ny-1] (corner (i, j) is the lower-left corner of cell (i, j), i, j >= 1)."""
    dvdx = v[..., 1:, 1:] - v[..., :-1, 1:]
    dudy = u[..., 1:, 1:] - u[..., 1:, :-1]
    return (dvdx - dudy) / h


def flow_vorticity(ds):
    """Vorticity dv/dx - du/dy [1/s] of a MAC-grid flow's cache (u on cells' left faces, v on bottom faces),
    at the cells' lower-left corners, as a DataArray like u (the first row and column repeat their neighbours)."""
    h = float(ds["x"][1] - ds["x"][0])
    u, v = ds["u"], ds["v"]
    dvdx = v.diff("x", label="upper").reindex(x=ds["x"], method="bfill")  # plain numpy fills (no bottleneck)
    dudy = u.diff("y", label="upper").reindex(y=ds["y"], method="bfill")
    return ((dvdx - dudy) / h).assign_attrs(long_name="vorticity", units="1/s")
