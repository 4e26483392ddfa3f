"""hapticloud from Python: scenes as numpy arrays, runs, bilinear samples, scripted touch
sessions and the levels of detail (issue 17). Units are SI; grids are (rows, cols) arrays with
row 0 at the smallest y, in the grid frame (metres, larger z nearer the viewer).

    import hapticloud
    scene = hapticloud.run("configs/sinusoid.yaml")           # or a dict, or load_scene(DIR/scene)
    z = scene.layers["depth"]                                  # float32 (rows, cols) view, NaN = no data
    h, dzdx, dzdy, normal = hapticloud.sample(scene, [0.0], [0.01])   # bilinear, grid frame [m]
    trace = hapticloud.touch(scene, path="raster", seconds=2)  # dict of per-tick numpy arrays
    table = hapticloud.levels(scene)                           # one dict per level of detail
    lv = hapticloud.open_levels("runs/big/scene")              # a tiled scene, read window by window
    w = lv.window(level=2, row0=100, col0=300, rows=200, cols=200)   # dict of numpy views
"""

import json as _json
import os as _os

from ._hapticloud import Error, Levels, Scene, load_scene, open_levels, sample, touch  # noqa: F401
from . import _hapticloud as _native

__all__ = ["Error", "Levels", "Scene", "levels", "load_scene", "open_levels", "run", "sample", "touch"]


def run(config, out=None, sets=()):
    """Runs the pipeline of a run config and returns the Scene.

    config: a path to a YAML run config (docs/config.md), or a dict of the same structure
        (relative input paths are then taken from the current folder).
    out: None (nothing written) or a folder to write as `hapticloud run --out` does (scene,
        previews, report; refused if it is a folder hapticloud did not write); the Scene is then
        the one read back from OUT/scene.
    sets: "key=value" overrides, as `--set`.
    Raises hapticloud.Error (naming the file, key or value) on bad input.
    """
    out = None if out is None else _os.fspath(out)
    if isinstance(sets, str):
        sets = [sets]
    if isinstance(config, dict):
        # JSON is YAML: the same parser reads it. Messages name the config "<dict config>".
        origin = _os.path.join(_os.getcwd(), "<dict config>")
        return _native._run_text(_json.dumps(config), origin, out, list(sets))
    return _native._run_file(_os.fspath(config), out, list(sets))


def levels(scene, config=None, servo_ticks=3000, cross_check=True):
    """The speed-against-error table of the scene's levels of detail, as `hapticloud levels`.

    scene: a Scene (its own lod options and layer options are used), or the Levels of a tiled
        scene (open_levels): its stored levels as they are, nothing built (build_s 0, stored
        True), a level of more than 1024² samples read a window at a time (supported_fraction
        None there), so that a scene larger than memory gets its table.
    config: None, or the run config the scene was made from (a path or a dict, as for run()):
        its scan is read whole and filtered, and each level is cross-checked against its points.
        Without a config, the Levels of a tiled scene written with the cross-check on are
        cross-checked against the sample of filtered points the scene stores
        (points_sample.bin: at most lod.report_sample_points of them, in the grid frame, as
        `hapticloud levels` takes them; supported_fraction None, as it needs every point), and
        so is a Scene loaded from such a folder (load_scene, or run() with out); a Scene built
        in memory (run() without out) is not cross-checked without a config.
    servo_ticks: servo ticks timed per level (>= 10; 0 or None leaves the timing columns None).
    cross_check: False skips the cross-check (as `hapticloud levels --no-cross-check`); a config
        given with it is an error.
    Returns a list of dicts, one per level from 0 (finest), SI units: level, rows, cols,
    cell_size_m [m], valid_cells, build_s [s] (smoothing + decimation + layers), stored (read
    from a tiled scene's files, not built), points_from ("scan": the config's;
    "points_sample.bin": the scene's stored sample; None: no cross-check); with a cross-check,
    rms_m, p95_m, max_m [m] (vertical distance of the points to the level's bilinear surface),
    points_checked (points on the surface among those evaluated), supported_fraction (samples
    with a point within 0.5 mm, over every point), points_sampled and points_total (the RMS,
    p95 and max come from every ⌈points_total / lod.report_sample_points⌉-th point: the scene's
    option, 200 000 by default; with the stored sample, its points of the points_total it
    stands for) and sampled (points_sampled < points_total), else None;
    mu_d_at_min_fraction and mu_d_at_max_fraction (cells at the friction clamps); with
    servo_ticks, tick_p50_s and tick_p99_s [s] (servo tick compute on a window of the level)
    and switch_s [s] (request to the first tick on a new window). Times are wall-clock on
    this machine: compare them within one run, never against fixed numbers.
    Raises hapticloud.Error naming the file, key or value on bad input.
    """
    if not isinstance(cross_check, bool):
        raise Error(f"levels: cross_check {cross_check!r} (expected True or False)")
    if config is not None and not cross_check:
        raise Error("levels: a config was given with cross_check=False (the config only supplies the "
                    "cross-check's points: leave it out, or leave cross_check True)")
    if isinstance(config, dict):
        origin = _os.path.join(_os.getcwd(), "<dict config>")
        return _native._levels_text(scene, _json.dumps(config), origin, _ticks(servo_ticks), cross_check)
    servo_ticks = _ticks(servo_ticks)
    path = None if config is None else _os.fspath(config)
    return _native._levels_file(scene, path, servo_ticks, cross_check)


def _ticks(servo_ticks):
    """servo_ticks as an int: None -> 0; anything not an integer in [0, 10**9] -> hapticloud.Error."""
    if servo_ticks is None:
        return 0
    if isinstance(servo_ticks, bool) or not isinstance(servo_ticks, int) or not 0 <= servo_ticks <= 10**9:
        raise Error(f"levels: servo_ticks {servo_ticks!r} (expected an integer: 0 or None for no timing, or 10..1e9)")
    return servo_ticks
