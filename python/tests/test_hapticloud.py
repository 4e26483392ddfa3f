"""Tests of the Python API against oracles computed here with numpy: the analytic sinusoid the
scene was sampled from, the bilinear formula, the device's force cap, halving levels."""

import math
import os
import pathlib

import numpy as np
import pytest

import hapticloud

SOURCE = pathlib.Path(os.environ["HC_SOURCE_DIR"])

# configs/sinusoid.yaml: z = A sin(2 pi x / L) sin(2 pi y / L), A = 5 mm, L = 40 mm, noise 0.02 mm.
A, L, NOISE = 0.005, 0.04, 0.00002


@pytest.fixture(scope="module")
def sinusoid():
    return hapticloud.run(SOURCE / "configs" / "sinusoid.yaml", sets=["lod.report=false"])


def grid_xy(scene):
    x = scene.x0_m + scene.cell_size_m * np.arange(scene.cols)
    y = scene.y0_m + scene.cell_size_m * np.arange(scene.rows)
    return np.meshgrid(x, y)  # (rows, cols) each


def test_the_depth_layer_is_the_analytic_surface(sinusoid):
    s = sinusoid
    depth = s.layers["depth"]
    assert depth.dtype == np.float32 and depth.shape == (s.rows, s.cols) == (200, 200)
    assert {"depth", "envelope", "texture", "mu_d", "mu_s"} <= set(s.layers)
    x, y = grid_xy(s)
    # Grid frame -> the surface's own frame through the inverse of model_to_grid (recentring).
    inv = np.linalg.inv(s.model_to_grid)
    pts = np.stack([x.ravel(), y.ravel(), depth.astype(np.float64).ravel(), np.ones(x.size)])
    mx, my, mz, _ = inv @ pts
    err = mz - A * np.sin(2 * math.pi * mx / L) * np.sin(2 * math.pi * my / L)
    valid = np.isfinite(err)
    assert valid.mean() > 0.9
    # A node takes the front-most sample of its cell: within the half-diagonal of the node, on a
    # surface of slope at most 2 pi A / L, plus 5 sigma of noise.
    bound = 2 * math.pi * A / L * math.sqrt(0.5) * s.cell_size_m + 5 * NOISE
    assert np.abs(err[valid]).max() <= bound


def test_layers_are_read_only_views_that_outlive_their_scene():
    s = hapticloud.run(SOURCE / "configs" / "sinusoid.yaml", sets=["lod.report=false", "grid.n=50"])
    d = s.layers["depth"]
    assert not d.flags.owndata and not d.flags.writeable
    with pytest.raises(ValueError):
        d[0, 0] = 1.0
    assert d.base is not None  # the capsule that owns the scene
    copy = d.copy()
    del s
    # Allocate and fill another scene where the first one's memory would be reused if the view
    # did not keep it alive.
    other = hapticloud.run(SOURCE / "configs" / "sinusoid.yaml", sets=["lod.report=false", "grid.n=50",
                                                                      "input.synthetic.amplitude_m=0.001"])
    assert not np.array_equal(other.layers["depth"], copy, equal_nan=True)
    assert np.array_equal(d, copy, equal_nan=True)  # the view kept its scene alive


def test_sample_is_the_bilinear_interpolant_of_the_depth(sinusoid):
    s = sinusoid
    z = s.layers["depth"].astype(np.float64)
    rng = np.random.default_rng(3)
    u = rng.uniform(10, s.cols - 11, 200)
    v = rng.uniform(10, s.rows - 11, 200)
    x = s.x0_m + u * s.cell_size_m
    y = s.y0_m + v * s.cell_size_m
    h, gx, gy, normal = hapticloud.sample(s, x, y)
    c, r = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = u - c, v - r
    expect = (1 - a) * (1 - b) * z[r, c] + a * (1 - b) * z[r, c + 1] + (1 - a) * b * z[r + 1, c] + a * b * z[r + 1, c + 1]
    expect_gx = ((1 - b) * (z[r, c + 1] - z[r, c]) + b * (z[r + 1, c + 1] - z[r + 1, c])) / s.cell_size_m
    ok = np.isfinite(expect)
    assert ok.sum() > 150
    np.testing.assert_allclose(h[ok], expect[ok], atol=1e-9)
    np.testing.assert_allclose(gx[ok], expect_gx[ok], atol=1e-6)
    assert h.shape == gy.shape == (200,)
    # The normal is perpendicular to both tangents (1, 0, dz/dx) and (0, 1, dz/dy), unit, upward.
    assert normal.shape == (200, 3)
    n_ok = normal[ok]
    np.testing.assert_allclose(np.linalg.norm(n_ok, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(n_ok[:, 0] + n_ok[:, 2] * gx[ok], 0.0, atol=1e-12)
    np.testing.assert_allclose(n_ok[:, 1] + n_ok[:, 2] * gy[ok], 0.0, atol=1e-12)
    assert np.all(n_ok[:, 2] > 0)


def test_touch_returns_the_trace_of_a_session_that_touched_the_surface(sinusoid):
    t = hapticloud.touch(sinusoid, path="raster", seconds=2.0)
    n = 2000
    assert t["t_s"].shape == (n,)
    for key in ("hip_m", "proxy_m", "force_n"):
        assert t[key].shape == (n, 3)
    assert np.all(np.diff(t["t_s"]) > 0)
    force = np.linalg.norm(t["force_n"], axis=1)
    assert force.max() <= 8.0 + 1e-9  # touch's force cap
    assert t["in_contact"].mean() > 0.05
    # The proxy never sinks below the surface it rendered (the god-object constraint).
    assert np.all(t["proxy_m"][:, 2] >= t["surface_z_m"] - 1e-6)


def test_levels_halve_the_grid(sinusoid):
    table = hapticloud.levels(sinusoid, servo_ticks=0)
    assert [r["level"] for r in table] == list(range(len(table)))
    assert table[0]["rows"] == 200 and len(table) >= 2
    for fine, coarse in zip(table, table[1:]):
        assert coarse["rows"] == (fine["rows"] + 1) // 2
        assert coarse["cell_size_m"] == pytest.approx(2 * fine["cell_size_m"])
    # Without a config there is no cross-check; without servo ticks no timing.
    assert table[0]["rms_m"] is None and table[0]["tick_p50_s"] is None


def test_levels_with_the_config_give_the_cross_check_and_the_servo_columns(sinusoid):
    table = hapticloud.levels(sinusoid, config=SOURCE / "configs" / "sinusoid.yaml", servo_ticks=200)
    k = 2 * math.pi / L
    for r in table:
        # Points against the level's bilinear surface, bounded from the analytic sinusoid: a
        # node holds the front-most sample of its cell (disc splats), at most half a cell
        # diagonal away, so off by at most the largest slope A k times h / sqrt(2); the
        # bilinear interpolant adds at most A k^2 h^2 / 4 (curvature A k^2 along x and y,
        # h^2 / 8 each); plus 3 sigma of the noise. The coarser levels are smoothed before
        # decimation, which the doubled slope term covers.
        h = r["cell_size_m"]
        bound = 2 * A * k * h / math.sqrt(2) + A * k * k * h * h / 4 + 3 * NOISE
        assert 0.5 * NOISE <= r["rms_m"] <= bound, (r["level"], r["rms_m"], bound)
        assert r["p95_m"] <= r["max_m"]
        assert r["points_checked"] > 0
        assert 0.0 < r["supported_fraction"] <= 1.0
        # Timing columns are measured (positive), never compared with fixed numbers.
        assert r["tick_p50_s"] > 0 and r["tick_p99_s"] >= r["tick_p50_s"] and r["switch_s"] > 0
    for bad in (-1, 5, 9.9, "100"):
        with pytest.raises(hapticloud.Error, match="servo_ticks"):
            hapticloud.levels(sinusoid, servo_ticks=bad)


def test_run_from_a_dict_writes_the_output_when_asked(tmp_path):
    cfg = {
        "name": "plane",
        "input": {"synthetic": {"surface": "tilted_plane", "half_extent_m": 0.01, "density_per_m2": 4e6,
                                "slope_x": 0.2, "slope_y": 0.1}},
        "filters": {"outliers": {"enabled": False}},
        "grid": {"n": 40},
        "lod": {"report": False},
    }
    out = tmp_path / "run"
    s = hapticloud.run(cfg, out=out)
    assert (out / "scene" / "scene.yaml").is_file() and (out / "report.md").is_file()
    again = hapticloud.load_scene(out / "scene")
    np.testing.assert_array_equal(again.layers["depth"], s.layers["depth"])
    # A tilted plane z = 0.2 x + 0.1 y: the depth's slopes, by finite differences.
    d = s.layers["depth"].astype(np.float64)
    gx = np.nanmedian(np.diff(d, axis=1)) / s.cell_size_m
    gy = np.nanmedian(np.diff(d, axis=0)) / s.cell_size_m
    assert gx == pytest.approx(0.2, abs=0.01) and gy == pytest.approx(0.1, abs=0.01)


def test_bad_input_raises_hapticloud_error_naming_it(tmp_path):
    with pytest.raises(hapticloud.Error, match="no-such-scene"):
        hapticloud.load_scene(tmp_path / "no-such-scene")
    with pytest.raises(hapticloud.Error, match="grid.n"):
        hapticloud.run(SOURCE / "configs" / "sinusoid.yaml", sets=["grid.n=-3"])


def test_open_levels_reads_windows_of_a_tiled_scene_as_slices_of_the_whole_scene(tmp_path):
    out = tmp_path / "run"
    whole = hapticloud.run(SOURCE / "configs" / "sinusoid.yaml", out=out,
                           sets=["lod.report=false", "scale.scene_tiles=on", "scale.scene_tile_cells=64",
                                 "lod.min_cells=20"])
    lv = hapticloud.open_levels(out / "scene")
    assert lv.level_count >= 3
    assert lv.tiles_read == 0
    g0 = lv.geometry(0)
    assert (g0["rows"], g0["cols"]) == (whole.rows, whole.cols)
    # Level 0: every window equals the numpy slice of the scene loaded whole, bit for bit.
    for (r0, c0, n, m) in [(0, 0, 50, 70), (37, 101, 64, 64), (150, 150, 50, 50)]:
        w = lv.window(0, r0, c0, n, m)
        assert (w["row0"], w["col0"]) == (r0, c0)
        for name in ("depth", "envelope", "texture", "mu_d", "mu_s"):
            a, b = w["layers"][name], whole.layers[name][r0:r0 + n, c0:c0 + m]
            assert a.shape == (n, m) and not a.flags.writeable
            assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), name
        assert w["x0_m"] == pytest.approx(whole.x0_m + c0 * whole.cell_size_m, abs=1e-12)
    # Coarser levels halve the grid, cell sizes double, and windows are clamped into the level.
    for level in range(1, lv.level_count):
        g = lv.geometry(level)
        assert g["rows"] == -(-lv.geometry(level - 1)["rows"] // 2)
        assert g["cell_size_m"] == pytest.approx(2 ** level * whole.cell_size_m)
        w = lv.window(level, 10 ** 6, 10 ** 6, 16, 16)
        assert (w["row0"], w["col0"]) == (g["rows"] - 16, g["cols"] - 16)
        assert np.isfinite(w["layers"]["depth"]).any()
    assert lv.tiles_read > 0
    with pytest.raises(hapticloud.Error, match="scale.scene_tiles"):
        hapticloud.open_levels(hapticloud_run_untiled(tmp_path))


def test_levels_of_a_tiled_scene_read_as_stored_equal_the_table_of_the_scene_loaded_whole(tmp_path):
    # The oracle: levels() of the same scene loaded whole (its pyramid built in memory, whose
    # levels the stored ones equal bit for bit). This scene's levels are below 1024² samples, so
    # they are read whole from the files; the windowed reading is checked in C++
    # (TiledScene.TheLevelsTableOfAStoredPyramidReadsWindowsAndEqualsTheInMemoryTable).
    out = tmp_path / "run"
    config = SOURCE / "configs" / "sinusoid.yaml"
    sets = ["lod.report=false", "scale.scene_tiles=on", "scale.scene_tile_cells=64", "lod.min_cells=20"]
    hapticloud.run(config, out=out, sets=sets)
    whole = hapticloud.levels(hapticloud.load_scene(out / "scene"), config=config, servo_ticks=0)
    stored = hapticloud.levels(hapticloud.open_levels(out / "scene"), config=config, servo_ticks=0)
    assert len(stored) == len(whole) >= 3
    for a, b in zip(stored, whole):
        assert a["stored"] and not b["stored"]
        assert a["build_s"] == 0.0
        for k in ("level", "rows", "cols", "cell_size_m", "valid_cells", "rms_m", "p95_m", "max_m", "points_checked",
                  "points_sampled", "points_total", "supported_fraction", "mu_d_at_min_fraction", "mu_d_at_max_fraction"):
            assert a[k] == b[k], (a["level"], k)
        assert a["rms_m"] is not None
        assert a["points_from"] == b["points_from"] == "scan"
    # Without a config the Levels take the filtered points the scene stores (points_sample.bin):
    # every 2nd of this scan's 400 000 (lod.report_sample_points 200 000), which are the points
    # the table from the scan read again evaluates, so the RMS, p95 and max are equal; the
    # support needs every point and is not measured from the sample.
    sample = hapticloud.levels(hapticloud.open_levels(out / "scene"), servo_ticks=0)
    for a, b in zip(sample, whole):
        assert a["points_from"] == "points_sample.bin"
        assert (a["points_sampled"], a["points_total"]) == (200000, 400000) and a["sampled"]
        for k in ("rms_m", "p95_m", "max_m", "points_checked", "points_sampled", "points_total"):
            assert a[k] == b[k], (a["level"], k)
        assert a["supported_fraction"] is None and b["supported_fraction"] is not None
    # The scene loaded whole takes the sample its folder stores too (Scene::loaded_from): its
    # levels built in memory, the same figures as the stored levels' against the same sample.
    loaded = hapticloud.levels(hapticloud.load_scene(out / "scene"), servo_ticks=0)
    for a, b in zip(loaded, sample):
        assert a["points_from"] == "points_sample.bin" and not a["stored"]
        for k in ("rms_m", "p95_m", "max_m", "points_checked", "points_sampled", "points_total", "supported_fraction"):
            assert a[k] == b[k], (a["level"], k)
    # A scene without the sample, cross_check=False, and a config given with it.
    (out / "scene" / "points_sample.bin").unlink()
    for rows in (hapticloud.levels(hapticloud.open_levels(out / "scene"), servo_ticks=0),
                 hapticloud.levels(hapticloud.load_scene(out / "scene"), servo_ticks=0),
                 hapticloud.levels(hapticloud.open_levels(out / "scene"), servo_ticks=0, cross_check=False)):
        assert all(r["points_from"] is None and r["rms_m"] is None for r in rows)
    with pytest.raises(hapticloud.Error, match="cross_check=False"):
        hapticloud.levels(hapticloud.open_levels(out / "scene"), config=config, cross_check=False)
    with pytest.raises(hapticloud.Error, match="cross_check=False"):  # refused before the config is read
        hapticloud.levels(hapticloud.open_levels(out / "scene"), config=tmp_path / "no-such.yaml", cross_check=False)
    with pytest.raises(hapticloud.Error, match="cross_check"):
        hapticloud.levels(hapticloud.open_levels(out / "scene"), cross_check="no")


def hapticloud_run_untiled(tmp_path):
    out = tmp_path / "untiled"
    hapticloud.run(SOURCE / "configs" / "sinusoid.yaml", out=out, sets=["lod.report=false", "grid.n=40"])
    return out / "scene"
