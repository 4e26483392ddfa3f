"""bench/scale.py --compare (issue 14's builds measured against each other): interleaved rounds in
rotated order, medians and ratios to the first build, and the scene compared byte for byte.

Oracles: a second copy of the same program must give the first's scene in every round; the same
program run with a wider splat radius (grid.splat_radius_cells, which changes every depth sample's
weights) must not; round r must start with build r mod B (the documented rotation), and the CPU
ratio of a build to itself within a round is 1 exactly.
"""

import json
import os
import subprocess
import sys

BUILD = os.environ.get("HC_BUILD_DIR")
SOURCE = os.environ.get("HC_SOURCE_DIR")


def wrapper(path, program, extra):
    with open(path, "w") as f:
        f.write("#!/bin/sh\nexec '" + program + "' \"$@\" " + extra + "\n")
    os.chmod(path, 0o755)
    return str(path)


def needs_build():
    assert BUILD and SOURCE, "set HC_BUILD_DIR (a build folder) and HC_SOURCE_DIR (the checkout): ctest does"


def test_compare_rotates_the_order_and_tells_an_equal_scene_from_a_changed_one(tmp_path):
    needs_build()
    program = os.path.join(BUILD, "apps", "hapticloud", "hapticloud")
    same = wrapper(tmp_path / "same", program, "")
    wider = wrapper(tmp_path / "wider", program, "--set grid.splat_radius_cells=1.6")
    out_json = tmp_path / "compare.json"
    scratch = tmp_path / "scratch"
    res = subprocess.run(
        [sys.executable, os.path.join(SOURCE, "bench", "scale.py"), "--build", BUILD, "--compare",
         ",".join([program, same, wider]), "--sizes", "2e5", "--n", "300", "--modes", "tiled",
         "--tile-cells", "128", "--rounds", "3", "--scratch", str(scratch), "--json", str(out_json)],
        capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    doc = json.loads(out_json.read_text())
    runs, summary = doc["runs"], doc["summary"]
    assert [r["build"] for r in runs] == ["hapticloud", "same", "wider", "same", "wider", "hapticloud",
                                          "wider", "hapticloud", "same"]
    assert all(r["exit"] == 0 for r in runs)
    by = {s["build"]: s for s in summary}
    assert by["hapticloud"]["cpu_ratio"] == 1.0
    assert by["same"]["scene_equal"] is True
    assert by["wider"]["scene_equal"] is False
    # Which files differ: none for the copy; for the wider splat, layers besides scene.yaml
    # (which records the --set value).
    assert by["same"]["scene_files_differing"] == []
    assert "scene/scene.yaml" in by["wider"]["scene_files_differing"]
    assert any(k.startswith("scene/") and k != "scene/scene.yaml" for k in by["wider"]["scene_files_differing"])
    assert all(r["scene_equal_to_first"] for r in runs if r["build"] == "same")
    assert not any(r["scene_equal_to_first"] for r in runs if r["build"] == "wider")
    # Every run's output folder is gone; the generated wall and its config stay for the next call.
    assert not [p for p in os.listdir(scratch) if p.startswith("compare_")]
    assert "| wider |" in res.stdout and "**no** (" in res.stdout


def test_compare_refuses_a_single_build_and_a_missing_program(tmp_path):
    needs_build()
    program = os.path.join(BUILD, "apps", "hapticloud", "hapticloud")
    script = os.path.join(SOURCE, "bench", "scale.py")
    one = subprocess.run([sys.executable, script, "--build", BUILD, "--compare", program, "--sizes", "1e3",
                          "--scratch", str(tmp_path)], capture_output=True, text=True)
    assert one.returncode != 0 and "two or more builds" in one.stderr
    missing = subprocess.run([sys.executable, script, "--build", BUILD, "--compare", program + "," + str(tmp_path / "nope"),
                              "--sizes", "1e3", "--scratch", str(tmp_path)], capture_output=True, text=True)
    assert missing.returncode != 0 and "nope" in missing.stderr and "build folder" in missing.stderr


def test_an_entry_runs_in_its_own_mode_and_as_is_passes_no_scale_key(tmp_path):
    """@in-core, @tiled and @as-is (a build from before the tiled run, issue 14's baseline).
    Oracles: a wrapper that refuses any `scale.` argument, as a build that knows no scale keys
    refuses an unknown key, runs under @as-is and fails without it; the runs' own reports show
    which path ran (stage tile_plan only in the tiled run)."""
    needs_build()
    program = os.path.join(BUILD, "apps", "hapticloud", "hapticloud")
    pre_scale = tmp_path / "pre_scale"
    pre_scale.write_text("#!/bin/sh\nfor a in \"$@\"; do case \"$a\" in scale.*) echo \"unknown key $a\" >&2; exit 2;; esac; done\n"
                         "exec '" + program + "' \"$@\"\n")
    os.chmod(pre_scale, 0o755)
    script = os.path.join(SOURCE, "bench", "scale.py")
    common = ["--sizes", "2e5", "--n", "300", "--modes", "tiled", "--tile-cells", "128", "--rounds", "1",
              "--scratch", str(tmp_path / "scratch")]
    out_json = tmp_path / "modes.json"
    res = subprocess.run([sys.executable, script, "--build", BUILD, "--compare",
                          ",".join([program + "@tiled", str(pre_scale) + "@as-is", program + "@in-core"]),
                          "--json", str(out_json)] + common, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    doc = json.loads(out_json.read_text())
    by = {r["build"]: r for r in doc["runs"]}
    assert set(by) == {"hapticloud@tiled", "pre_scale@as-is", "hapticloud@in-core"}
    assert all(r["exit"] == 0 for r in by.values())
    assert [by[b]["mode"] for b in ("hapticloud@tiled", "pre_scale@as-is", "hapticloud@in-core")] == ["tiled", "as-is", "in-core"]
    assert "tile_plan" in by["hapticloud@tiled"]["stages_cpu_s"]
    # 2·10^5 points are below scale.tiled_above_points: auto (as-is) stays in core, as off does.
    for b in ("pre_scale@as-is", "hapticloud@in-core"):
        assert "tile_plan" not in by[b]["stages_cpu_s"] and "outliers" in by[b]["stages_cpu_s"], b
    summary = {s["build"]: s for s in doc["summary"]}
    assert summary["pre_scale@as-is"]["m_points_per_cpu_s"] > 0.0
    assert "| pre_scale@as-is | as-is |" in res.stdout
    # The same wrapper given the mode's scale.* arguments fails, and the comparison says so.
    bad = subprocess.run([sys.executable, script, "--build", BUILD, "--compare", ",".join([program, str(pre_scale)])] + common,
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0 and "failed runs: round 1 pre_scale" in bad.stdout
