"""Pictures a person can read: a cache's 2D fields plot x across and y up with plain xarray, coordinates carry
labels, and ``pdestream inspect --plot`` draws labelled colourbars over one colour range per field."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
import xarray as xr  # noqa: E402

from pdestream import (
    datasets,  # noqa: E402
    generator,  # noqa: E402
)
from pdestream.datasets import (
    inspect,
    schema,  # noqa: E402
)
from pdestream.datasets.cache import open_cache  # noqa: E402

N = 3
# Kolmogorov forcing depends on y only (f = -A k cos(k y)): started (nearly) from rest, the vorticity stays a function
# of y alone (up to the 1e-6 IC), so the picture's orientation is fixed by the physics, not by the solver's array order.
NS = {"n": 16, "n_frames": 3, "t_end": 1.0, "ic.sigma": 1e-6}


def _plain_open(path):
    return xr.open_zarr(path) if str(path).endswith(".zarr") else xr.open_dataset(path, engine="h5netcdf")


@pytest.fixture(scope="module", params=["zarr", "h5"])
def ns_cache(request, tmp_path_factory):
    pde = generator.get_pde("ns2d", **NS)
    path = tmp_path_factory.mktemp("pictures") / f"ns.{request.param}"
    datasets.write_cache(pde, path, N, seed=0, progress=False)
    return pde, path


@pytest.fixture(scope="module")
def gs_cache(tmp_path_factory):
    pde = generator.get_pde("grayscott2d", n=16, n_frames=3, t_end=200.0)
    path = tmp_path_factory.mktemp("pictures") / "gs.zarr"
    datasets.write_cache(pde, path, 2, seed=1, progress=False)
    return pde, path


@pytest.fixture(scope="module")
def burgers_cache(tmp_path_factory):
    pde = generator.get_pde("burgers1d", n=32, n_frames=5, t_end=0.2)
    path = tmp_path_factory.mktemp("pictures") / "b.h5"
    datasets.write_cache(pde, path, 3, seed=0, progress=False)
    return pde, path


def test_a_2d_cache_is_stored_y_then_x(ns_cache):
    pde, path = ns_cache
    ds = _plain_open(path)
    assert ds["vorticity"].dims == ("sample", "time", "y", "x")
    w = ds["vorticity"].isel(sample=0, time=-1)
    # forced from rest: varies along y only (an (x, y) store would show it varying along the plot's x)
    assert float(w.std("x").max()) < 1e-4 * float(w.std("y").max()) and float(w.std("y").max()) > 1e-3
    # one point, by name: the cache at (x_i, y_j) is the generator's u[..., i, j]
    traj = generator.sample(pde, [1], 0)
    i, j = 3, 11
    assert float(ds["vorticity"].isel(sample=1, time=-1, x=i, y=j)) == float(traj.u[0, -1, 0, i, j])


def test_the_cache_dim_named_x_is_the_pdes_x(tmp_path):
    # advection by c = (0.25, 0) for t = 1 on [0, 1)^2, n = 16: an exact shift by 4 cells along x, none along y
    pde = generator.get_pde("advection2d", n=16, c_x=0.25, c_y=0.0, t_end=1.0, n_frames=2)
    datasets.write_cache(pde, tmp_path / "adv.h5", 1, progress=False)
    u = _plain_open(tmp_path / "adv.h5")["u"].isel(sample=0)
    assert u.dims == ("time", "y", "x")
    assert float(abs(u.isel(time=-1) - u.isel(time=0).roll(x=4)).max()) < 1e-5
    assert float(abs(u.isel(time=-1) - u.isel(time=0).roll(y=4)).max()) > 0.1


def test_readers_get_the_generators_tensors_bit_for_bit(ns_cache):
    pde, path = ns_cache
    u = torch.from_numpy(np.array(generator.sample(pde, range(N), 0).u))  # [N, T, C, x, y]
    for in_memory in (True, False):
        whole = datasets.CachedTrajectories(path, view="whole", in_memory=in_memory)
        for k in range(N):
            assert torch.equal(whole[k]["u"], u[k])
        pairs = datasets.CachedTrajectories(path, view="next_step", in_memory=in_memory)
        assert torch.equal(pairs[1]["x"], u[0, 1:2]) and torch.equal(pairs[1]["y"], u[0, 2:3])
    norm = datasets.CachedTrajectories(path, view="whole").normalization()
    assert norm.mean.shape[0] == 1 and torch.isfinite(norm.std).all()


def test_plain_xarray_plot_puts_x_across_and_y_up(ns_cache):
    _, path = ns_cache
    ds = _plain_open(path)
    fig = plt.figure()
    try:
        ds["vorticity"].isel(sample=0, time=-1).plot()
        ax = fig.axes[0]
        assert ax.get_xlabel().startswith("x [length]") and ax.get_ylabel().startswith("y [length]")
        assert fig.axes[1].get_ylabel() == "vorticity [1/time]"  # the colourbar: the field's name and units
    finally:
        plt.close(fig)


def test_plain_xarray_plot_of_a_1d_sample_is_space_time(burgers_cache):
    _, path = burgers_cache
    fig = plt.figure()
    try:
        _plain_open(path)["u"].isel(sample=0).plot()
        ax = fig.axes[0]
        assert ax.get_xlabel() == "x [length]" and ax.get_ylabel() == "t [time]"
    finally:
        plt.close(fig)


def test_coordinates_carry_labels(ns_cache):
    pde, path = ns_cache
    ds = _plain_open(path)
    for d in ("x", "y"):
        assert (ds[d].attrs["long_name"], ds[d].attrs["units"]) == (d, "length")
    assert (ds["time"].attrs["long_name"], ds["time"].attrs["units"]) == ("t", "time")
    assert ds["nu"].attrs["long_name"] == pde.PARAMS["nu"].description
    assert ds["nu"].attrs["units"] == pde.PARAMS["nu"].units
    assert ds["vorticity"].attrs["long_name"] == "vorticity" and ds["vorticity"].attrs["units"] == "1/time"
    assert ds.attrs["pdestream_schema"] == schema.SCHEMA_VERSION == 2


def _images(fig):
    return [im for ax in fig.axes for im in ax.get_images()]


def _frame(im) -> str:
    """'t=0.5' of a panel titled 'vorticity #1 t=0.5' (its first line)."""
    return im.axes.get_title().split("\n")[0].split()[2]


def test_inspect_1d_shared_zero_centred_colour_range(burgers_cache):
    _, path = burgers_cache
    fig = inspect.figure(path, n_show=3)
    try:
        ims = _images(fig)
        assert len(ims) == 3 and len(fig.axes) > len(ims)  # panels plus a colourbar
        lo, hi = ims[0].get_clim()
        assert all(im.get_clim() == (lo, hi) for im in ims)  # one range over every panel
        u = open_cache(path)["u"].values[:3]
        assert lo == -hi == -np.abs(u).max()  # signed field: centred on zero, covering the data
        assert ims[0].get_cmap().name == "RdBu_r"
        panel = ims[0].axes
        assert panel.get_xlabel() == "x [length]" and panel.get_ylabel() == "t [time]"
        bars = [ax for ax in fig.axes if not ax.get_images()]
        assert [ax.get_ylabel() for ax in bars] == ["u [length/time]"]
    finally:
        plt.close(fig)


def test_inspect_2d_panels_have_axes_and_colourbars(ns_cache, gs_cache):
    for path, n_fields in ((ns_cache[1], 1), (gs_cache[1], 2)):
        fig = inspect.figure(path, n_show=2)
        try:
            ims = _images(fig)
            assert len(ims) == 2 * 3 * n_fields and len(fig.axes) == len(ims) + 3 * n_fields  # a bar per column
            for im in ims:
                ax = im.axes
                assert im.origin == "lower" and ax.get_aspect() == 1.0 and " t=" in ax.get_title()
            assert ims[-1].axes.get_xlabel() == "x [length]" and ims[0].axes.get_ylabel() == "y [length]"
            ds = open_cache(path)
            for _c, name in enumerate(ds.attrs["pdestream_fields"].split()):
                mine = [im for im in ims if im.axes.get_title().startswith(f"{name} #")]
                assert len(mine) == 6
                columns = {_frame(im) for im in mine}
                assert len(columns) == 3  # one range per frame column, shared by its samples
                assert all(len({im.get_clim() for im in mine if _frame(im) == t}) == 1 for t in columns)
                # the image is the stored (y, x) frame itself: row = y, column = x
                first = next(im for im in mine if im.axes.get_title().startswith(f"{name} #0 t=0"))
                np.testing.assert_array_equal(first.get_array(), ds[name].values[0, 0])
        finally:
            plt.close(fig)


def test_inspect_puts_at_most_three_fields_across(ns_cache):
    """A flow's vorticity, u, v, p and scalar made 15 panels in one row: five fields now take two bands of rows."""
    ds = open_cache(ns_cache[1])
    names = ["a", "b", "c", "d", "e"]
    ds = ds.assign({k: ds["vorticity"] * (i + 1) for i, k in enumerate(names)})
    ds.attrs["pdestream_fields"] = " ".join(names)
    fig = inspect.draw(ds, n_show=2)
    try:
        ims = _images(fig)
        assert len(ims) == 5 * 3 * 2
        rows = {im.axes.get_subplotspec().rowspan.start for im in ims}
        cols = {im.axes.get_subplotspec().colspan.start for im in ims}
        assert rows == {0, 1, 2, 3} and cols == set(range(9))  # 2 samples x 2 bands, 3 fields x 3 frames across
        for i, name in enumerate(names):  # a field's panels share one band: its samples' rows, its own columns
            mine = [im.axes.get_subplotspec() for im in ims if im.axes.get_title().startswith(f"{name} #")]
            assert {sp.rowspan.start for sp in mine} == ({0, 1} if i < 3 else {2, 3})
            assert {sp.colspan.start for sp in mine} == set(range(3 * (i % 3), 3 * (i % 3) + 3))
        assert sum(1 for ax in fig.axes if not ax.axison) == 2 * 3  # the second band's empty slot, switched off
    finally:
        plt.close(fig)
        ds.close()


def test_inspect_one_signed_field_gets_a_sequential_map(gs_cache):
    _, path = gs_cache
    fig = inspect.figure(path, n_show=2)
    try:
        for name in ("u", "v"):  # concentrations (v: its Gibbs undershoot stays small)
            ims = [im for im in _images(fig) if im.axes.get_title().startswith(f"{name} #")]
            assert {im.get_cmap().name for im in ims} == {"viridis"}
        assert ims[0].get_clim()[1] > 10 * -ims[0].get_clim()[0]
    finally:
        plt.close(fig)


def test_colour_scale():
    assert inspect.colour_scale(np.array([-1.0, 3.0])) == {"cmap": "RdBu_r", "vmin": -3.0, "vmax": 3.0}
    assert inspect.colour_scale(np.array([0.2, 0.9])) == {"cmap": "viridis", "vmin": 0.2, "vmax": 0.9}
    ringing = inspect.colour_scale(np.array([-0.05, 0.66]))  # Gibbs undershoot of a concentration
    assert ringing["cmap"] == "viridis" and ringing["vmin"] == -0.05
    assert inspect.colour_scale(np.array([np.nan, 1.0, 1.0]))["vmax"] > 1.0  # constant: a non-empty range
    # a karman vorticity: a wake of +-3 and a few body-corner cells at +-100 (the range was +-100: a blank picture)
    wake = np.sin(np.linspace(0, 20, 4000)) * 3.0
    wake[:8] = [100, -100, 90, -95, 100, -100, 80, -85]
    scale = inspect.colour_scale(wake)
    assert scale["cmap"] == "RdBu_r" and 2.9 < scale["vmax"] < 3.01 and scale["vmin"] == -scale["vmax"]
    spread = np.linspace(-3.0, 3.0, 1000)  # no outliers: the full range, as before
    assert inspect.colour_scale(spread)["vmax"] == 3.0


def test_3d_fields_round_trip_and_plot_the_three_mid_slices():
    # adv50: only the middle z slice was drawn (x-y planes); now x-y, x-z and y-z through the centre, last frame
    u = np.arange(2 * 3 * 4 * 4 * 4, dtype=np.float32).reshape(2, 3, 4, 4, 4) - 100  # [S, T, x, y, z]
    disk = schema.to_disk(u, 3)
    assert disk[1, 2, 3, 1, 0] == u[1, 2, 0, 1, 3]  # stored (z, y, x)
    assert np.array_equal(schema.from_disk(np.ascontiguousarray(disk), 3), u)
    grid = np.arange(4, dtype=np.float32)
    coords = {d: (d, grid, {"long_name": d, "units": "length"}) for d in "xyz"}
    ds = xr.Dataset({"u": (("sample", "time", "z", "y", "x"), disk)},
                    coords={**coords, "time": ("time", np.arange(3.0), {"long_name": "t", "units": "time"}),
                            "sample": ("sample", np.arange(2))},
                    attrs={"pdestream_fields": "u", "pdestream_params": "", "pde": "fake3d", "equation": "-"})
    fig = inspect.draw(ds, n_show=2)
    try:
        ims = _images(fig)
        assert len(ims) == 6 and all("t=2" in im.axes.get_title() for im in ims)
        for im, plane in zip(ims[:3], ("z=2", "y=2", "x=2")):
            assert plane in im.axes.get_title(), im.axes.get_title()
        np.testing.assert_array_equal(ims[0].get_array(), u[0, 2, :, :, 2].T)  # row y, column x at z = 2
        np.testing.assert_array_equal(ims[1].get_array(), u[0, 2, :, 2, :].T)  # row z, column x at y = 2
        np.testing.assert_array_equal(ims[2].get_array(), u[0, 2, 2, :, :].T)  # row z, column y at x = 2
        assert [im.axes.get_ylabel() for im in ims[3:]] == ["y [length]", "z [length]", "z [length]"]
        assert "mid-slices x=2, y=2, z=2 at the last frame t=2" in fig._suptitle.get_text()
    finally:
        plt.close(fig)


def test_inspect_plot_of_a_3d_cache_shows_three_planes(tmp_path, capsys):
    from pdestream import cli

    cache, png = tmp_path / "a.h5", tmp_path / "a.png"
    assert cli.main(["generate", "advection3d", "--n", "1", "--set", "n=16", "--set", "n_frames=2", "--out",
                     str(cache)]) == 0
    fig = inspect.figure(cache, n_show=1)
    try:
        titles = [im.axes.get_title().splitlines()[0] for im in _images(fig)]
        assert len(titles) == 3 and [t.split()[-1][0] for t in titles] == ["z", "y", "x"], titles
        assert "mid-slices" in fig._suptitle.get_text()
    finally:
        plt.close(fig)
    assert cli.main(["inspect", str(cache), "--plot", str(png)]) == 0 and png.stat().st_size > 0


def test_a_3d_flows_vorticity_panels_say_they_are_its_z_component():
    """adv51: plume3d's figure drew dv/dx - du/dy (the z component) titled "vorticity", in its x-z and y-z planes
    too, as if it were the vorticity of the 3D flow."""
    grid = np.arange(4, dtype=np.float32)
    dims = ("sample", "time", "z", "y", "x")
    u = np.random.default_rng(0).standard_normal((1, 2, 4, 4, 4)).astype(np.float32)
    units = {"long_name": "u", "units": "m/s"}
    ds = xr.Dataset({k: (dims, u * (i + 1), {**units, "long_name": k}) for i, k in enumerate("uvwp")},
                    coords={**{d: (d, grid, {"long_name": d, "units": "m"}) for d in "xyz"},
                            "time": ("time", np.arange(2.0), {"long_name": "t", "units": "s"}),
                            "sample": ("sample", np.arange(1))},
                    attrs={"pdestream_fields": "u v w p", "pdestream_params": "", "pde": "fake_flow3d",
                           "equation": "-", "sides": "left=wall"})
    fig = inspect.draw(ds, n_show=1)
    try:
        first = [im.axes.get_title().split()[0] for im in _images(fig)[:3]]
        assert first == ["vorticity_z"] * 3, first
        labels = {ax.get_xlabel() for ax in fig.axes if ax.get_label() == "<colorbar>"}
        assert "z-vorticity dv/dx - du/dy [1/s]" in labels, labels
    finally:
        plt.close(fig)


def test_a_schema_1_2d_cache_is_refused_in_one_line(tmp_path, ns_cache, capsys):
    import h5py

    from pdestream import cli

    pde, _ = ns_cache
    old = tmp_path / "old.h5"
    datasets.write_cache(pde, old, 1, progress=False)
    with h5py.File(old, "r+") as f:
        f.attrs["pdestream_schema"] = np.int64(1)  # as written by schema 1 (then stored (x, y))
    with pytest.raises(ValueError, match=r"older pdestream \(cache schema 1.*regenerate"):
        datasets.CachedTrajectories(old)
    code = cli.main(["inspect", str(old)])
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and "schema 1" in err and "Traceback" not in err


def test_a_schema_1_1d_cache_still_reads(tmp_path):
    import h5py

    pde = generator.get_pde("burgers1d", n=16, n_frames=3, t_end=0.1)
    path = tmp_path / "old1d.h5"
    datasets.write_cache(pde, path, 2, progress=False)
    with h5py.File(path, "r+") as f:
        f.attrs["pdestream_schema"] = np.int64(1)  # 1D layout is the same in both schemas
    u = torch.from_numpy(np.array(generator.sample(pde, [1], 0).u[0]))
    assert torch.equal(datasets.CachedTrajectories(path)[1]["u"], u)


def test_a_frame_column_has_its_own_colour_range(ns_cache):
    # forced from rest (|w| ~ 1e-6 at t = 0, ~1 later): one range over all frames drew the t = 0 column blank
    _, path = ns_cache
    w = open_cache(path)["vorticity"].values[:2]  # [S, T, y, x]
    fig = inspect.figure(path, n_show=2)
    try:
        for f, t in enumerate(("t=0", "t=0.5", "t=1")):
            clims = {im.get_clim() for im in _images(fig) if _frame(im) == t}
            (lo, hi), peak = clims.pop(), np.abs(w[:, f]).max()
            assert hi == peak and lo == -peak  # the column's own data fills its range
        bars = [ax for ax in fig.axes if not ax.get_images()]
        assert {ax.get_xlabel() for ax in bars} == {"vorticity [1/time]"}  # the PDE's units on every bar
    finally:
        plt.close(fig)


@pytest.mark.parametrize("name, settings", [("darcy2d", {"n": 9}), ("ns2d", NS), ("burgers1d", {"n": 16, "t_end": 0.1})])
def test_no_label_or_title_is_clipped(tmp_path, name, settings):
    pde = generator.get_pde(name, **settings)
    datasets.write_cache(pde, tmp_path / "c.zarr", 4, seed=0, progress=False)
    fig = inspect.figure(tmp_path / "c.zarr", n_show=4)
    try:
        fig.canvas.draw()
        page = fig.bbox
        texts = [fig._suptitle] + [t for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label)]
        for text in texts:
            if text is not None and text.get_text():
                box = text.get_window_extent()
                assert page.x0 - 0.5 <= box.x0 and box.x1 <= page.x1 + 0.5, text.get_text()
                assert page.y0 - 0.5 <= box.y0 and box.y1 <= page.y1 + 0.5, text.get_text()
    finally:
        plt.close(fig)


def test_every_entry_declares_the_units_of_its_fields():
    for name in generator.PDES:
        pde = generator.get_pde(name)
        for f in (*pde.INPUTS, *pde.FIELDS):
            assert pde.FIELD_UNITS.get(f), (name, f)
    assert generator.get_pde("burgers2d").FIELD_UNITS["v"] == "length/time"
    assert generator.get_pde("ks2d").FIELD_UNITS["u"] == "length^2/time"  # the scalar form: |grad u|^2 ~ u_t


def test_list_name_shows_field_units(capsys):
    import json

    from pdestream import cli

    assert cli.main(["list", "ns2d"]) == 0
    assert "fields (units): vorticity [1/time]" in capsys.readouterr().out
    assert cli.main(["list", "darcy2d", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["fields"] == {"a": "1", "u": "1"}


def test_rollouts_figure_of_a_flow_draws_vorticity_with_the_body_and_a_1d_entry_as_space_time(tmp_path):
    """solver-in-the-loop's rollouts.png: a flow's rows are vorticity (not u), the body in grey; 1D: space-time."""
    from pdestream.experiments.rollout_figure import picture_of, plot_rollouts

    flow = generator.get_pde("karman2d")
    nx, ny = flow.grid.shape
    frames = torch.zeros(6, len(flow.FIELDS), nx, ny)
    frames[:, flow.FIELDS.index("u")] = torch.linspace(0, 1, ny)  # shear du/dy = 1/h per cell: vorticity -1/h...
    pic, what = picture_of(flow, frames, flow.h)
    assert what.startswith("vorticity") and pic.shape == (6, nx - 1, ny - 1)
    assert np.allclose(pic, -(1 / (ny - 1)) / flow.h, rtol=1e-4)  # ...times the profile's step 1/(ny-1)
    solid = torch.zeros(nx, ny)
    solid[10:14, 12:18] = 1
    plot_rollouts(tmp_path / "flow.png", flow, {"reference": frames, "coarse": frames * 0.5}, flow.h, 0.1,
                  solid=solid)
    burgers = generator.get_pde("burgers1d", n=32)
    plot_rollouts(tmp_path / "b.png", burgers, {"reference": torch.rand(5, 1, 32), "corrected": torch.rand(5, 1, 32)},
                  1 / 32, 0.1)
    for name in ("flow.png", "b.png"):
        assert plt.imread(tmp_path / name).shape[0] > 100
