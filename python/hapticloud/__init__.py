"""hapticloud from Python: scenes as numpy arrays, runs, bilinear samples, scripted touch
sessions and the levels of detail (issue 17). Units are SI; grids are (rows, cols) arrays with
row 0 at the smallest y, in the grid frame (metres, larger z nearer the viewer).

    import hapticloud
    scene = hapticloud.run("configs/sinusoid.yaml")           # or a dict, or load_scene(DIR/scene)
    z = scene.layers["depth"]                                  # float32 (rows, cols) view, NaN = no data
    h, dzdx, dzdy = hapticloud.sample(scene, [0.0], [0.01])   # bilinear, grid frame [m]
    trace = hapticloud.touch(scene, path="raster", seconds=2)  # dict of per-tick numpy arrays
    table = hapticloud.levels(scene)                           # one dict per level of detail
"""

import json as _json
import os as _os

from ._hapticloud import Error, Scene, levels, load_scene, sample, touch  # noqa: F401
from . import _hapticloud as _native

__all__ = ["Error", "Scene", "levels", "load_scene", "run", "sample", "touch"]


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
