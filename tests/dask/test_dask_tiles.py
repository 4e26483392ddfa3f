"""The Dask driver (tools/dask/hapticloud-dask, issue 14) against the single-process tiled run.

A dask-scheduler and two dask-worker processes are started on 127.0.0.1; the Buddha (N = 400,
tiles of 64 cells, the robust outlier filter on) goes through them, and its scene folder must be
byte for byte the one `hapticloud run` writes for the same config in one process (the oracle).
A second run kills the worker that runs the first tile job (SIGKILL to the worker process,
mid-job) and must still give the same scene. Needs Debian's python3-distributed
(scripts/install-deps); its absence fails the test, it is not skipped.
"""

import filecmp
import json
import os
import signal
import stat
import subprocess
import sys
import time

import pytest

SRC = os.environ["HC_SOURCE_DIR"]
HAPTICLOUD = os.environ["HAPTICLOUD_BIN"]
DRIVER = os.path.join(SRC, "tools", "dask", "hapticloud-dask")
CONFIG = os.path.join(SRC, "configs", "happy_buddha.yaml")
SETS = ["grid.n=400", "scale.tiled=on", "scale.tile_cells=64"]
SCAN = os.path.join(SRC, "data", "scans", "happy_buddha", "happy_stand_merged_1099005pts.ply.gz")


def sets():
    out = []
    for s in SETS:
        out += ["--set", s]
    return out


def same_folder(a, b):
    """Lists of files that differ or exist on one side only, recursively."""
    cmp = filecmp.dircmp(a, b)
    bad = cmp.left_only + cmp.right_only + cmp.funny_files
    _, mismatch, errors = filecmp.cmpfiles(a, b, cmp.common_files, shallow=False)
    bad += mismatch + errors
    for d in cmp.common_dirs:
        bad += [os.path.join(d, x) for x in same_folder(os.path.join(a, d), os.path.join(b, d))]
    return bad


def write_ascii_ply(path, pts):
    """Points (x, y, z) [m] as an ASCII PLY of double vertices, every digit kept."""
    with open(path, "w") as f:
        f.write("ply\nformat ascii 1.0\nelement vertex %d\nproperty double x\nproperty double y\nproperty double z\n"
                "end_header\n" % len(pts))
        f.writelines("%.17g %.17g %.17g\n" % p for p in pts)


def run_quietly(config, out, *sets, code=0):
    """`hapticloud run CONFIG --out OUT [--set S ...]` in one process: the oracle's scene; it must
    exit with `code` (4: written, the verdict fail)."""
    cmd = [HAPTICLOUD, "run", str(config), "--out", str(out)]
    for s in sets:
        cmd += ["--set", s]
    assert subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode == code


def drive_local(config, out, scratch, *extra):
    """The driver on a LocalCluster of two workers, its work folder under `scratch`; its output."""
    return subprocess.run([sys.executable, DRIVER, str(config), "--out", str(out), "--workers", "2", "--scratch",
                           str(scratch), "--hapticloud", HAPTICLOUD] + list(extra),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A scheduler and two workers (one thread each) on 127.0.0.1; yields the address and the
    cluster's log file."""
    base = tmp_path_factory.mktemp("cluster")
    sched_file = base / "scheduler.json"
    procs = []
    log = open(base / "cluster.log", "w", buffering=1)
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
             "--no-dashboard", "--scheduler-file", str(sched_file)], stdout=log, stderr=log))
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert sched_file.exists(), "the scheduler did not start within 60 s (see %s)" % (base / "cluster.log")
        address = json.loads(sched_file.read_text())["address"]
        for _ in range(2):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1", "--nworkers", "1",
                 "--host", "127.0.0.1", "--no-dashboard", "--local-directory", str(base)], stdout=log, stderr=log))
        from dask.distributed import Client
        with Client(address, timeout=60) as c:
            c.wait_for_workers(2, timeout=60)
        yield address, base / "cluster.log"
    finally:
        for p in procs:
            p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
        log.close()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The oracle: `hapticloud run` of the same config in one process."""
    assert os.path.exists(SCAN), "missing %s: run data/get-data" % SCAN
    base = tmp_path_factory.mktemp("reference")
    subprocess.run([HAPTICLOUD, "run", CONFIG, "--out", str(base / "run")] + sets(), check=True,
                   stdout=subprocess.DEVNULL)
    return base / "run"


def drive(tmp, address, hapticloud=HAPTICLOUD, extra=()):
    out = tmp / "run"
    p = subprocess.run([sys.executable, DRIVER, CONFIG, "--out", str(out), "--scheduler", address,
                        "--scratch", str(tmp), "--hapticloud", hapticloud] + sets() + list(extra),
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 0, p.stdout[-3000:]
    return out, p.stdout


def test_two_workers_give_the_single_process_scene(cluster, reference, tmp_path):
    out, log = drive(tmp_path, cluster[0])
    assert "tiles in" in log
    assert same_folder(reference / "scene", out / "scene") == []
    ref = json.loads((reference / "report.json").read_text())
    got = json.loads((out / "report.json").read_text())
    assert got["cross_check"] == ref["cross_check"]
    # The work folder the driver made under --scratch is gone.
    assert sorted(os.listdir(tmp_path)) == ["run"]


def test_a_worker_killed_mid_job_still_gives_the_same_scene(cluster, reference, tmp_path):
    # A stand-in for hapticloud: the first tile job starts the real one, then SIGKILLs the worker
    # process that runs it (its parent) and its own job, as a crashed node would. The scheduler
    # moves the task to a worker that lives; the leftovers of the killed attempt stay behind.
    marker = tmp_path / "killed"
    wrapper = tmp_path / "hapticloud-killing-its-worker"
    wrapper.write_text(
        "#!/bin/sh\n"
        'if [ "$1" = tile-job ] && mkdir "%s" 2>/dev/null; then\n'
        '  "%s" "$@" & job=$!\n'
        "  sleep 0.3\n"
        "  kill -9 $PPID\n"
        "  kill -9 $job\n"
        "  exit 1\n"
        "fi\n"
        'exec "%s" "$@"\n' % (marker, HAPTICLOUD, HAPTICLOUD))
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IXUSR)
    out, log = drive(tmp_path, cluster[0], hapticloud=str(wrapper), extra=["--retries", "0"])
    assert marker.is_dir(), "no tile job ran through the killing wrapper"
    # The worker did die (the nanny says so); with --retries 0 only the scheduler's move of the
    # lost task to a live worker lets the run finish.
    assert "was killed by signal 9" in cluster[1].read_text()
    assert same_folder(reference / "scene", out / "scene") == []
    ref = json.loads((reference / "report.json").read_text())
    got = json.loads((out / "report.json").read_text())
    assert got["cross_check"] == ref["cross_check"]


def test_the_merge_refuses_a_plan_with_a_tile_missing(tmp_path):
    # Without the cluster: a plan, all tiles but one, then the merge.
    plan_dir = tmp_path / "plan"
    subprocess.run([HAPTICLOUD, "tile-plan", os.path.join(SRC, "configs", "bunny.yaml"), "--work", str(plan_dir),
                    "--set", "scale.tile_cells=64"], check=True, stdout=subprocess.DEVNULL)
    count = json.loads((plan_dir / "plan.json").read_text())["tiles"]["count"]
    assert count > 2
    subprocess.run([HAPTICLOUD, "tile-job", str(plan_dir / "plan.json"), "--tiles",
                    ",".join(str(t) for t in range(count) if t != 1)], check=True)
    p = subprocess.run([HAPTICLOUD, "tile-merge", str(plan_dir / "plan.json"), "--out", str(tmp_path / "run")],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode != 0
    assert "1 of %d tiles have no result (1)" % count in p.stdout
    assert not (tmp_path / "run").exists()


def test_a_local_cluster_gives_the_single_process_scene_and_a_failing_tile_stops_the_run(tmp_path):
    # The driver's default: a LocalCluster here (the bunny, small and quick).
    config = os.path.join(SRC, "configs", "bunny.yaml")
    ref = tmp_path / "ref"
    subprocess.run([HAPTICLOUD, "run", config, "--out", str(ref), "--set", "scale.tiled=on", "--set", "scale.tile_cells=64"], check=True,
                   stdout=subprocess.DEVNULL)
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, DRIVER, config, "--out", str(out), "--workers", "2", "--scratch", str(tmp_path),
                        "--hapticloud", HAPTICLOUD, "--set", "scale.tiled=on", "--set", "scale.tile_cells=64",
                        "--tiles-per-job", "3"],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 0, p.stdout[-3000:]
    assert "LocalCluster" in p.stdout
    assert same_folder(ref / "scene", out / "scene") == []
    # A tile job that always fails: the driver stops before the merge, names the tiles, writes
    # no run folder and removes the work folder it made.
    failing = tmp_path / "hapticloud-failing"
    failing.write_text('#!/bin/sh\nif [ "$1" = tile-job ]; then echo "error: disk on fire" >&2; exit 2; fi\n'
                       'exec "%s" "$@"\n' % HAPTICLOUD)
    failing.chmod(failing.stat().st_mode | stat.S_IXUSR)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    p = subprocess.run([sys.executable, DRIVER, config, "--out", str(tmp_path / "failed"), "--workers", "1",
                        "--scratch", str(scratch), "--hapticloud", str(failing), "--retries", "1",
                        "--set", "scale.tile_cells=64"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 1, p.stdout[-3000:]
    assert "failed after 1 retries" in p.stdout and "disk on fire" in p.stdout, p.stdout[-3000:]
    assert not (tmp_path / "failed").exists()
    assert os.listdir(scratch) == []
    # --scheduler without shared storage named is refused before anything runs.
    p = subprocess.run([sys.executable, DRIVER, config, "--out", str(tmp_path / "x"), "--scheduler", "tcp://127.0.0.1:1"],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 2 and "--work" in p.stdout


def test_an_island_the_plans_halo_cannot_decide_is_planned_again_with_the_wider_halo(tmp_path):
    # The scene of TiledRun.AnIslandRunningPastTheCellsATileDecides... (tests/pipeline/
    # tiled_run_test.cpp): a 1 m plane of points 1 cm apart, a strip at x 2.9 to 2.99 m, and three
    # points 3 cm apart at x 1.21 to 1.27 m whose discs make a 15-cell group reaching the edge of
    # the cells the window of the tile right of col 128 has as the whole grid's. Under
    # scale.island_halo: auto a tile job exits 5 there; the driver plans again with the key true
    # and its scene is byte for byte the single-process run's with the key true (the oracle).
    # With the key false the driver stops naming it. A LocalCluster (about 10 s).
    pts = [(0.01 * i, 0.01 * j, 0.0) for i in range(100) for j in range(100)]
    pts += [(2.9 + 0.01 * i, 0.01 * j, 0.0) for i in range(10) for j in range(100)]
    pts += [(1.21, 0.45, 0.002), (1.24, 0.45, 0.002), (1.27, 0.45, 0.002)]
    write_ascii_ply(tmp_path / "plane.ply", pts)
    config = tmp_path / "plane.yaml"
    config.write_text(
        "input: {files: [plane.ply], units: m}\n"
        "grid: {n: 300, splat_radius_cells: 1.2, splat_mode: plane, see_through_depth_m: 0.002, see_through_window_cells: 3}\n"
        "filters: {outliers: {local_ratio: 100, mad_multiplier: 100, off_surface_ratio: 0, far_clusters: {enabled: false}}}\n"
        "cross_check: {isolation_min_neighbours: 2}\nscale: {filter_halo_cells: 12, tiled: on, tile_cells: 32}\n")
    ref = tmp_path / "ref"
    run_quietly(config, ref, "scale.island_halo=true")
    out = tmp_path / "run"
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    p = drive_local(config, out, scratch)
    assert p.returncode == 0, p.stdout[-3000:]
    assert "planning again with --set scale.island_halo=true" in p.stdout, p.stdout[-3000:]
    assert "stage despike" in p.stdout, p.stdout[-3000:]
    assert same_folder(ref / "scene", out / "scene") == []
    assert json.loads((out / "report.json").read_text())["cross_check"] == json.loads((ref / "report.json").read_text())["cross_check"]
    assert os.listdir(scratch) == []
    # The key false: the tile job's error, named, after the retries; no run folder.
    p = subprocess.run([sys.executable, DRIVER, str(config), "--out", str(tmp_path / "failed"), "--workers", "1",
                        "--scratch", str(scratch), "--hapticloud", HAPTICLOUD, "--retries", "0",
                        "--set", "scale.island_halo=false"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 1, p.stdout[-3000:]
    assert "set scale.island_halo: true" in p.stdout and "planning again" not in p.stdout, p.stdout[-3000:]
    assert not (tmp_path / "failed").exists()
    assert os.listdir(scratch) == []


def test_a_grid_the_filters_changed_is_planned_again_on_the_kept_points_box(tmp_path):
    # The patch of TiledRun.AStrayThatSetsTheBoxIsRemovedAndTheGridLaidAgainOnTheKeptPoints
    # (tests/pipeline/tiled_run_test.cpp): 100 x 100 points 1 cm apart and a stray 7 cm past the
    # edge that sets the plan's x-y box and that the outlier filters remove. The in-core run lays
    # its grid on the kept points; tile-merge exits 6 and writes their box, and the driver plans
    # again with --grid-box. Its scene is byte for byte the single-process run's (the oracle,
    # which starts again in process), and the run's grid is the in-core one; the first plan's
    # folder is gone and its box kept (--keep-work shows the work folder). A LocalCluster.
    pts = [(0.01 * i, 0.01 * j, 0.001 * ((i * 7 + j * 3) % 5)) for i in range(100) for j in range(100)]
    pts += [(1.06, 0.5, 0.002)]
    write_ascii_ply(tmp_path / "patch.ply", pts)
    config = tmp_path / "patch.yaml"
    config.write_text(
        "input: {files: [patch.ply], units: m}\n"
        "grid: {n: 200, splat_radius_cells: 1.2, see_through_depth_m: 0.01, hole_fill_max_cells: 16}\n"
        "cross_check: {tolerance_m: 0.002}\nscale: {tiled: on, tile_cells: 32}\n")
    ref = tmp_path / "ref"
    run_quietly(config, ref)
    core = tmp_path / "core"
    run_quietly(config, core, "scale.tiled=off")
    out = tmp_path / "run"
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    p = drive_local(config, out, scratch, "--tiles-per-job", "8", "--keep-work")
    assert p.returncode == 0, p.stdout[-3000:]
    assert "planning again with --grid-box" in p.stdout, p.stdout[-3000:]
    assert sum(line.startswith("hapticloud tile-plan ") for line in p.stdout.splitlines()) == 2, p.stdout[-3000:]
    assert same_folder(ref / "scene", out / "scene") == []
    grid = json.loads((out / "report.json").read_text())["grid"]
    assert grid == json.loads((core / "report.json").read_text())["grid"]
    # The first plan (its spill as large as the scan) went once its box was copied out.
    (work,) = os.listdir(scratch)
    assert sorted(os.listdir(scratch / work)) == ["grid_box-1.json", "plan-2"]


def test_a_run_whose_verdict_fails_is_written_and_the_driver_exits_4(tmp_path):
    # PDAL's autzen_trim_7.las (data/get-data) at N = 300: the honest check confirms grid spikes,
    # so `hapticloud run` writes its folder and exits 4. The driver writes the same scene and
    # exits 4 too, not 1 (which says no run folder was made). A LocalCluster.
    scan = os.path.join(SRC, "data", "scans", "scanner_samples", "las", "pdal-autzen_trim_7.las")
    config = tmp_path / "autzen.yaml"
    config.write_text(
        "input: {files: [%s], units: ft}\n"
        "grid: {n: 300, splat_radius_cells: 1.2, see_through_depth_m: 1, hole_fill_max_cells: 32}\n"
        "cross_check: {tolerance_m: 0.3}\nscale: {tiled: on, tile_cells: 48}\n" % scan)
    ref = tmp_path / "ref"
    run_quietly(config, ref, code=4)
    out = tmp_path / "run"
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    p = drive_local(config, out, scratch, "--tiles-per-job", "8")
    assert p.returncode == 4, p.stdout[-3000:]
    assert "the cross-check's verdict is fail" in p.stdout, p.stdout[-3000:]
    assert json.loads((out / "report.json").read_text())["verdict"]["status"] == "fail"
    assert same_folder(ref / "scene", out / "scene") == []
    assert os.listdir(scratch) == []
