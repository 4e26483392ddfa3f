#!/usr/bin/env python3
"""Scaling benchmark (issue 14): points per second and peak memory of `hapticloud run` on
generated carved-wall scans (tools/relief, hc-gen-relief) of growing size.

For every size and grid N it runs the program once as a child process and reads the child's own
resource usage (wait4: peak resident set size, user and system CPU), so no sampling can miss the
peak. The wall's scans are generated once into the scratch folder and reused by later runs (the
generator's files depend only on size and seed); each run's output folder is removed after its
report has been read.

    python3 bench/scale.py                          # 1e6 and 1e7 points, N = 800 and 4096
    python3 bench/scale.py --sizes 1e6,1e7,1e8 --json scale.json
    python3 bench/scale.py --build build/release --scratch /big/disk/scale
    python3 bench/scale.py --format las --sizes 1e7 --n 800   # LAS 1.2 instead of PLY
    python3 bench/scale.py --format ptx --sizes 3e6 --n 800   # PTX text (converted from the PLY)
    python3 bench/scale.py --format e57 --sizes 1e8 --n 4096 --modes tiled   # one E57 scan
    python3 bench/scale.py --order scan --sizes 1e8 --n 4096 --modes tiled   # a scanner's point order
    python3 bench/scale.py --order sorted --sizes 1e8 --n 4096 --modes tiled # the random wall's points, sorted
    python3 bench/scale.py --sizes 1e6,1e7,1e8 --json scale.json --plot docs/images/scale.png
    python3 bench/scale.py --plot-from a.json,b.json --plot docs/images/scale.png   # redraw, no run
    python3 bench/scale.py --compare old/hapticloud,build/release --sizes 1e8 --n 4096 --modes tiled \
        --tile-cells 512 --rounds 3                     # builds against each other, interleaved

Printed: a Markdown table (docs/scale.md keeps the measured one) with, per run, wall and CPU
seconds, peak RSS, bytes per point, M points per wall second and per CPU second, and the three
slowest stages (wall seconds, with their CPU seconds), and the glibc tunables the runs had.
Quote it with the machine's load (`uptime`): nothing else should run meanwhile.

--compare runs two or more builds (hapticloud executables, or build folders) on the first size,
N and mode, in interleaved rounds whose order rotates (on a shared VM the first run after a pause
is often slower, so no build may always go first), and prints each run, then per build the
median wall and CPU seconds, the CPU ratio to the first build (the median of the rounds' ratios,
each taken within one round), the median peak RSS, the median CPU seconds of every stage with
their ratios, and whether the scene (scene/ and previews/, byte for byte) equals the first
build's in every round. Speed claims between builds come from these ratios, never from runs on
different days. An entry may end in @in-core, @tiled or @as-is to run that build in that mode
instead of --modes' first; @as-is gives it no `--set scale.…` argument at all, for a build from
before the tiled run (issue 14's baseline, which knows no scale keys and always runs in core):

    python3 bench/scale.py --compare base/hapticloud@as-is,build/release --sizes 1e8 --n 800 \
        --modes tiled --tile-cells 512 --rounds 2      # the issue's baseline against today's build
"""

import argparse
import hashlib
import json
import os
import statistics
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# The same physical options at every size: 2 m x 1 m wall, 0.5 mm noise, 5 % back face,
# 0.1 % outliers (the generator's defaults), gridded with plane splats and the robust filter.
# The naive grid's cross-check and the levels table are off, as they are by default (since
# 2026-11-23 and 2026-11-24): said here so that a build from before then (whose defaults had them on)
# runs the same stages under --compare.
CONFIG = """name: relief_wall_{tag}
input: {{files: [{scan}], units: m}}
grid: {{n: {n}, splat_radius_cells: 1.2, splat_mode: plane, see_through_depth_m: 0.02,
        hole_fill_max_cells: 64, upsample: auto}}
cross_check: {{tolerance_m: 0.002, compare_naive: false}}
lod: {{report: false}}
layers: {{texture: {{sigma_space_cells: 3, sigma_range_m: 0.005}}}}
"""


def parse_count(text):
    value = float(text)
    if value < 1 or value != int(value):
        raise argparse.ArgumentTypeError(f"size {text!r}: expected an integer >= 1, e.g. 1e7")
    return int(value)


def run_child(cmd):
    """Runs cmd; returns (exit code, wall s, user s, sys s, peak RSS bytes, stderr text).
    The child's stderr (its progress lines) goes to a temporary file, not a pipe: a pipe read only
    after the child ends fills (64 KiB, about 700 progress lines) and stalls a long run's child in
    its next write, which then counts in its wall time."""
    import tempfile
    with tempfile.TemporaryFile() as err_file:
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err_file)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.monotonic() - t0
        err_file.seek(0)
        err = err_file.read().decode(errors="replace")
    proc.returncode = os.waitstatus_to_exitcode(status)
    # Linux reports ru_maxrss in kilobytes.
    return proc.returncode, wall, usage.ru_utime, usage.ru_stime, usage.ru_maxrss * 1024, err


def ply_to_ptx(ply, ptx):
    """One PTX scan (identity pose) of the float x y z of a binary little-endian PLY written by
    hc-gen-relief: 1000 rows, as many columns as needed, the rest of the grid no-return lines."""
    import array
    with open(ply, "rb") as f:
        header = b""
        while not header.endswith(b"end_header\n"):
            header += f.readline()
        n = int(header.split(b"element vertex ")[1].split(b"\n")[0])
        rows = 1000
        cols = (n + rows - 1) // rows
        tmp = ptx + ".partial"
        with open(tmp, "w") as out:
            out.write(f"{cols}\n{rows}\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
            left = n
            while left > 0:
                k = min(left, 1 << 20)
                a = array.array("f")
                a.fromfile(f, 3 * k)
                out.write("".join(f"{a[3*i]:.6f} {a[3*i+1]:.6f} {a[3*i+2]:.6f} 0.5\n" for i in range(k)))
                left -= k
            out.write("0 0 0 0\n" * (rows * cols - n))
        os.replace(tmp, ptx)


def plot_rows(rows, png, title):
    """Draws rows (as printed; failed rows left out) with gnuplot (Debian package gnuplot-nox, which
    the project's pipeline plots use too) into png: M input points per CPU second against the
    point count, and peak RSS against the point count, one line per mode and grid N, with issue
    14's aims (1 M points per CPU second; 1 GB at 10^8 points, N = 4096) drawn as dashed lines.
    Writes png.partial and renames it, so a failed plot leaves no half-written file."""
    import tempfile
    ok = [r for r in rows if "slowest" in r and r.get("cpu_s") == r.get("cpu_s")]
    series = {}
    for r in ok:
        series.setdefault((r["mode"], r["n"]), []).append(r)
    if not series:
        raise SystemExit("scale.py: --plot: no successful run to plot")
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "rows.dat")
        names = []
        with open(data, "w") as f:
            for (mode, n), rs in sorted(series.items()):
                names.append(f"{mode}, N = {n}")
                for r in sorted(rs, key=lambda r: r["points"]):
                    f.write(f"{r['points']} {r['points'] / r['cpu_s'] / 1e6:.6g} {r['peak_rss_bytes'] / 1e6:.6g}\n")
                f.write("\n\n")
        lo = min(r["points"] for r in ok) / 2
        hi = max(r["points"] for r in ok) * 2
        partial = png + ".partial"
        def plots(col):
            return ", ".join(f"'{data}' index {i} using 1:{col} with linespoints lw 2 pt {5 + 2 * (i % 4)} "
                             f"title '{name}'" for i, name in enumerate(names))
        script = f"""set terminal pngcairo size 1200,600 noenhanced font ',11'
set output '{partial}'
set multiplot layout 1,2 title '{title}'
set logscale x
set xrange [{lo}:{hi}]
set format x '10^%L'
set xlabel 'input points'
set grid
set key below maxrows 3
set title 'throughput'
set ylabel 'M input points per CPU second (user + system)'
set yrange [0:*]
set offsets graph 0, graph 0, graph 0.1, graph 0
plot {plots(2)}, 1 with lines dt 2 lc rgb 'black' title 'aim: 1 M per CPU second'
set title 'peak memory'
set ylabel 'peak RSS (MB)'
set logscale y
set yrange [*:*]
set offsets graph 0, graph 0, graph 0, graph 0
set format y '%g'
plot {plots(3)}, 1000 with lines dt 2 lc rgb 'black' title 'aim: 1 GB (10^8 points, N = 4096)'
unset multiplot
"""
        gp = os.path.join(tmp, "scale.gp")
        with open(gp, "w") as f:
            f.write(script)
        res = subprocess.run(["gnuplot", gp], capture_output=True, text=True)
        if res.returncode != 0 or not os.path.exists(partial):
            if os.path.exists(partial):
                os.remove(partial)
            raise SystemExit(f"scale.py: gnuplot failed drawing {png}: {res.stderr.strip()}")
        os.replace(partial, png)


def run_settings(mode, tile_cells, scratch, sets):
    """The `hapticloud run --set` arguments of a run in `mode` (in-core, tiled or dask; as-is: none
    of scale.*, for --compare's builds from before the tiled run): the same for the scaling table
    and for --compare. `sets` (--set) go to every mode."""
    out = [] if mode == "as-is" else ["--set", "scale.tiled=" + ("off" if mode == "in-core" else "on")]
    if mode == "tiled" or mode == "dask":
        out += ["--set", f"scale.tile_cells={tile_cells}", "--set", f"scale.scratch={scratch}"]
    for x in sets:
        out += ["--set", x]
    return out


def folder_digests(folder, parts=("scene", "previews")):
    """{relative path: sha256} of every file under folder/<part> for each part (missing: none)."""
    out = {}
    for part in parts:
        root = os.path.join(folder, part)
        for d, _, files in os.walk(root):
            for name in files:
                path = os.path.join(d, name)
                h = hashlib.sha256()
                with open(path, "rb") as f:
                    for block in iter(lambda: f.read(1 << 20), b""):
                        h.update(block)
                out[os.path.relpath(path, folder)] = h.hexdigest()
    return out


def resolve_program(text):
    """A hapticloud executable from --compare's entry: the file itself, or a build folder holding
    apps/hapticloud/hapticloud. Exits naming the entry when neither is executable."""
    for exe in (text, os.path.join(text, "apps", "hapticloud", "hapticloud")):
        if os.path.isfile(exe) and os.access(exe, os.X_OK):
            return os.path.abspath(exe)
    sys.exit(f"scale.py: --compare {text!r}: expected a hapticloud executable or a build folder holding "
             "apps/hapticloud/hapticloud")


def split_mode(entry):
    """(program text, mode or None) of a --compare entry: PATH, or PATH@in-core, PATH@tiled,
    PATH@as-is (see the module doc)."""
    for m in ("in-core", "tiled", "as-is"):
        if entry.endswith("@" + m):
            return entry[:-len(m) - 1], m
    return entry, None


def compare_builds(programs, labels, config, scratch, modes, tile_cells, sets, rounds, points):
    """Interleaved rounds of `hapticloud run config` for each program (see --compare in the module
    doc), programs[i] in modes[i], each named by its label in the tables; returns (rows, summary)
    for --json. `points`: the input's, for the M points per CPU second. Every run's output folder
    is removed once its round has been compared."""
    rows = []
    for r in range(rounds):
        order = [(i + r) % len(programs) for i in range(len(programs))]
        outs, this_round = {}, {}
        for i in order:
            out = os.path.join(scratch, f"compare_{i}")
            shutil.rmtree(out, ignore_errors=True)
            cmd = [programs[i], "run", config, "--out", out] + run_settings(modes[i], tile_cells, scratch, sets)
            code, wall, user, system, rss, err = run_child(cmd)
            row = {"round": r + 1, "build": labels[i], "program": programs[i], "mode": modes[i], "exit": code, "wall_s": wall,
                   "cpu_s": user + system, "peak_rss_bytes": rss, "stages_cpu_s": {}}
            report = os.path.join(out, "report.json")
            if os.path.exists(report):
                with open(report) as f:
                    doc = json.load(f)
                for st in doc["stages"]:
                    row["stages_cpu_s"][st["stage"]] = st.get("cpu_seconds", st["seconds"])
                    row["peak_rss_bytes"] = max(row["peak_rss_bytes"], st.get("peak_rss_mb", 0.0) * 1e6)
                outs[i] = folder_digests(out)
            else:
                row["error"] = err.strip().splitlines()[-1] if err.strip() else "no report"
            rows.append(row)
            this_round[i] = row
            print(f"round {r + 1}: {labels[i]}: wall {wall:.1f} s, CPU {row['cpu_s']:.1f} s, peak {row['peak_rss_bytes'] / 1e6:.0f} MB"
                  + (f", failed: {row['error']}" if "error" in row else ""), file=sys.stderr, flush=True)
        for i, row in this_round.items():
            row["scene_equal_to_first"] = i in outs and 0 in outs and outs[i] == outs[0] and bool(outs[0])
            if i in outs and 0 in outs and i != 0:
                # The files that differ from the first build's, or that only one of them wrote.
                row["scene_files_differing"] = sorted(k for k in set(outs[i]) | set(outs[0]) if outs[i].get(k) != outs[0].get(k))
        for i in order:
            shutil.rmtree(os.path.join(scratch, f"compare_{i}"), ignore_errors=True)
    ok = [x for x in rows if "error" not in x]
    if any("error" in x for x in rows):
        print("failed runs: " + ", ".join(f"round {x['round']} {x['build']}" for x in rows if "error" in x))
    print(f"load average after the last run: {os.getloadavg()[0]:.2f}; cores: {os.cpu_count()}; {rounds} rounds, order rotated")
    print("| build | mode | wall (s), median | CPU (s), median | M points per CPU s | CPU ratio to the first (rounds' median) | "
          "peak RSS (MB), median | scene equal to the first's |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    summary = []
    for i, lab in enumerate(labels):
        mine = [x for x in ok if x["build"] == lab]
        if not mine:
            print(f"| {lab} | {modes[i]} | failed | | | | | |")
            continue
        ratios = []
        for x in mine:
            base = [y for y in ok if y["round"] == x["round"] and y["build"] == labels[0]]
            if base:
                ratios.append(x["cpu_s"] / base[0]["cpu_s"])
        ratio = statistics.median(ratios) if ratios else float("nan")
        equal = all(x.get("scene_equal_to_first") for x in mine) if i > 0 else True
        srow = {"build": lab, "wall_s": statistics.median(x["wall_s"] for x in mine),
                "mode": modes[i], "cpu_s": statistics.median(x["cpu_s"] for x in mine), "cpu_ratio": ratio,
                "peak_rss_bytes": statistics.median(x["peak_rss_bytes"] for x in mine), "scene_equal": equal}
        differing = sorted({k for x in mine for k in x.get("scene_files_differing", [])})
        if i > 0:
            srow["scene_files_differing"] = differing
        summary.append(srow)
        named = ", ".join(differing[:3]) + (f" and {len(differing) - 3} more" if len(differing) > 3 else "")
        srow["m_points_per_cpu_s"] = points / srow["cpu_s"] / 1e6 if srow["cpu_s"] > 0 else float("nan")
        print(f"| {lab} | {modes[i]} | {srow['wall_s']:.1f} | {srow['cpu_s']:.1f} | {srow['m_points_per_cpu_s']:.3f} | {ratio:.3f} | "
              f"{srow['peak_rss_bytes'] / 1e6:.0f} | "
              + ("(the first)" if i == 0 else "yes" if equal else "**no**" + (f" ({named})" if named else "")) + " |")
    stages = []
    for x in ok:
        for name in x["stages_cpu_s"]:
            if name not in stages:
                stages.append(name)
    print()
    print("| stage | " + " | ".join(f"{lab} CPU (s)" for lab in labels) + " | " + " | ".join(f"{lab} / first" for lab in labels[1:]) + " |")
    print("|---|" + "---:|" * (2 * len(labels) - 1))
    for name in stages:
        med = []
        for lab in labels:
            v = [x["stages_cpu_s"][name] for x in ok if x["build"] == lab and name in x["stages_cpu_s"]]
            med.append(statistics.median(v) if v else float("nan"))
        rat = [m / med[0] if med[0] > 0 else float("nan") for m in med[1:]]
        print(f"| {name} | " + " | ".join(f"{m:.2f}" for m in med) + " | " + " | ".join(f"{q:.3f}" for q in rat) + " |")
    return rows, summary


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build", "release"), help="build folder (release preset)")
    ap.add_argument("--sizes", default="1e6,1e7", help="comma-separated point counts")
    ap.add_argument("--n", default="800,4096", help="comma-separated grid sizes (cells on the long side)")
    ap.add_argument("--scratch", default=None, help="folder for the generated scans and runs (default: BUILD/bench-scale)")
    ap.add_argument("--json", default=None, help="also write the rows as JSON to this file")
    ap.add_argument("--modes", default="in-core,tiled",
                    help="comma-separated: in-core, tiled (hapticloud run), dask (tools/dask/hapticloud-dask, LocalCluster)")
    ap.add_argument("--tile-cells", type=int, default=256, help="scale.tile_cells of the tiled runs")
    ap.add_argument("--dask-workers", type=int, default=2, help="LocalCluster workers of the dask mode")
    ap.add_argument("--set", action="append", default=[], help="extra `hapticloud run --set` overrides")
    ap.add_argument("--order", default="random", choices=["random", "scan", "sorted"],
                    help="the generated points' order: uniformly at random (the worst case for locality), a "
                         "scanner's vertical profiles from left to right on a raster (hc-gen-relief --scan-order), "
                         "or the random wall's own points sorted into that order (--sorted: the same points)")
    ap.add_argument("--format", default="ply", choices=["ply", "las", "ptx", "e57"],
                    help="the generated scans' format: binary float PLY, LAS 1.2 (point format 0), PTX "
                         "(one scan of 1000 rows, converted here from the generated PLY), or E57 (one data3D scan, "
                         "float coordinates, written by hc-gen-relief)")
    ap.add_argument("--keep-reports", default=None,
                    help="copy each run's report.json (every stage's figures and peak_rss_mb) into this folder as report_<tag>.json")
    ap.add_argument("--plot", default=None, help="also draw the rows with gnuplot into this PNG (throughput and peak RSS)")
    ap.add_argument("--plot-from", default=None,
                    help="draw --plot from these --json files (comma-separated) of earlier runs instead of running anything")
    ap.add_argument("--plot-title", default="hapticloud run on generated walls", help="the plot's title")
    ap.add_argument("--compare", default=None,
                    help="comma-separated builds (hapticloud executables or build folders), the first the baseline, each "
                         "optionally ending in @in-core, @tiled or @as-is (its mode; else --modes' first): interleaved "
                         "rounds on the first size and N (see the module doc)")
    ap.add_argument("--rounds", type=int, default=3, help="--compare's rounds (each runs every build once)")
    args = ap.parse_args()
    if args.plot_from:
        if not args.plot:
            sys.exit("scale.py: --plot-from needs --plot PNG")
        rows = []
        for name in args.plot_from.split(","):
            with open(name) as f:
                rows += json.load(f)
        plot_rows(rows, args.plot, args.plot_title)
        return 0

    sizes = [parse_count(s) for s in args.sizes.split(",")]
    grids = [int(n) for n in args.n.split(",")]
    modes = [m for m in args.modes.split(",") if m]
    for m in modes:
        if m not in ("in-core", "tiled", "dask"):
            sys.exit(f"scale.py: --modes {m!r}: expected in-core, tiled or dask")
    program = os.path.join(args.build, "apps", "hapticloud", "hapticloud")
    generator = os.path.join(args.build, "tools", "relief", "hc-gen-relief")
    for exe in (program, generator):
        if not os.access(exe, os.X_OK):
            sys.exit(f"scale.py: {exe} is missing: build the release preset first")
    # Absolute: the config written there names it (scale.scratch), and the program resolves a
    # relative path in a config against the config's own folder.
    scratch = os.path.abspath(args.scratch or os.path.join(args.build, "bench-scale"))
    os.makedirs(scratch, exist_ok=True)

    if args.compare:
        entries = [split_mode(x) for x in args.compare.split(",") if x]
        programs = [resolve_program(x) for x, _ in entries]
        # Each build named by its last path component (and its mode when given), or by the entry
        # as given where two share it.
        labels = [os.path.basename(os.path.normpath(x)) + (f"@{m}" if m else "") for x, m in entries]
        if len(set(labels)) < len(labels):
            labels = [x + (f"@{m}" if m else "") for x, m in entries]
        if len(programs) < 2:
            sys.exit("scale.py: --compare: expected two or more builds, comma-separated")
        if args.rounds < 1:
            sys.exit(f"scale.py: --rounds {args.rounds}: expected 1 or more")
        if modes[0] == "dask":
            sys.exit("scale.py: --compare runs `hapticloud run` (in-core or tiled), not the dask mode")
        sizes, grids, modes = sizes[:1], grids[:1], modes[:1]
        build_modes = [m or modes[0] for _, m in entries]

    rows = []
    for points in sizes:
        stem = f"wall_{points}" if args.order == "random" else f"wall_{args.order}_{points}"
        order_flag = {"random": [], "scan": ["--scan-order"], "sorted": ["--sorted"]}[args.order]
        scan = os.path.join(scratch, f"{stem}.{args.format}")
        if not os.path.exists(scan):
            print(f"generating {scan} ...", file=sys.stderr)
            if args.format == "ptx":
                ply = os.path.join(scratch, f"{stem}.ply")
                if not os.path.exists(ply):
                    subprocess.run([generator, ply, "--points", str(points), "--quiet"] + order_flag, check=True)
                ply_to_ptx(ply, scan)
            else:
                subprocess.run([generator, scan, "--points", str(points), "--quiet"] + order_flag, check=True)
        for n in grids:
          for mode in modes:
            tag = f"{points}_{args.format}_{n}_{mode}" + ("" if args.order == "random" else "_" + args.order)
            config = os.path.join(scratch, f"wall_{tag}.yaml")
            with open(config, "w") as f:
                f.write(CONFIG.format(tag=tag, scan=os.path.basename(scan), n=n))
            if args.compare:
                print(f"comparing {len(programs)} builds: {points} points, N = {n}, {', '.join(build_modes)}, {args.format.upper()}, "
                      f"{args.rounds} rounds")
                rows, summary = compare_builds(programs, labels, config, scratch, build_modes, args.tile_cells, args.set,
                                               args.rounds, points)
                if args.json:
                    with open(args.json, "w") as f:
                        json.dump({"runs": rows, "summary": summary}, f, indent=1)
                return 1 if any("error" in r for r in rows) else 0
            out = os.path.join(scratch, f"run_{tag}")
            shutil.rmtree(out, ignore_errors=True)
            if mode == "dask":
                # tools/dask/hapticloud-dask on a LocalCluster of --dask-workers processes: the
                # plan and the merge in the driver's hapticloud, the tile jobs on the workers.
                cmd = [sys.executable, os.path.join(ROOT, "tools", "dask", "hapticloud-dask"), config, "--out", out,
                       "--hapticloud", program, "--workers", str(args.dask_workers), "--scratch", scratch]
            else:
                cmd = [program, "run", config, "--out", out]
            cmd += run_settings(mode, args.tile_cells, scratch, args.set)
            print(f"running {points} points, N = {n}, {mode} ...", file=sys.stderr)
            code, wall, user, system, rss, err = run_child(cmd)
            row = {"points": points, "n": n, "mode": mode, "order": args.order, "exit": code, "wall_s": wall,
                   "cpu_s": user + system, "peak_rss_bytes": rss}
            if mode == "dask":
                # The workers are not this child's waited descendants: their CPU time and memory
                # are not in its rusage. Only the wall time and the merge's stages count.
                row["cpu_s"] = float("nan")
            report = os.path.join(out, "report.json")
            if os.path.exists(report):
                if args.keep_reports:
                    os.makedirs(args.keep_reports, exist_ok=True)
                    shutil.copyfile(report, os.path.join(args.keep_reports, f"report_{tag}.json"))
                with open(report) as f:
                    doc = json.load(f)
                stages = doc["stages"]
                row["glibc_tunables"] = doc.get("process", {}).get("glibc_tunables", "")
                slow = sorted(stages, key=lambda s: -s["seconds"])[:3]
                # Wall seconds, and the stage's CPU seconds where the report gives them (0 before).
                row["slowest"] = [(s["stage"], s["seconds"], s.get("cpu_seconds", 0.0)) for s in slow]
                # The program resets the high-water mark at every stage (per-stage peaks in the
                # report), so the child's ru_maxrss covers only the time since the last reset:
                # the run's peak is the larger of it and every stage's own.
                stage_peaks = [s.get("peak_rss_mb", 0.0) * 1e6 for s in stages]
                row["peak_rss_bytes"] = max([rss] + stage_peaks)
                peak_stage = max(stages, key=lambda s: s.get("peak_rss_mb", 0.0))
                row["peak_stage"] = peak_stage["stage"]
                for s in stages:
                    if s["stage"] == "tile_spill":
                        row["spill_mb"] = s.get("figures", {}).get("spill_bytes_peak_mb", 0.0)
            else:
                row["error"] = err.strip().splitlines()[-1] if err.strip() else "no report"
            shutil.rmtree(out, ignore_errors=True)
            rows.append(row)

    print(f"scans: generated walls, {args.format.upper()}, points in {args.order} order")
    print(f"load average before the last run: {os.getloadavg()[0]:.2f}; cores: {os.cpu_count()}")
    tunables = sorted({r.get("glibc_tunables", "") for r in rows if "slowest" in r})
    print("GLIBC_TUNABLES of the runs (hapticloud adds glibc.malloc.hugetlb=1 where it helps): " +
          (", ".join(f"'{t}'" for t in tunables) if tunables else "none reported"))
    print("| points | N | mode | wall (s) | CPU (s) | peak RSS (MB) | in stage | bytes/point | spill (MB) | Mpts/s (wall) | Mpts/s per CPU s | slowest stages (s) |")
    print("|---:|---:|---|---:|---:|---:|---|---:|---:|---:|---:|---|")
    for r in rows:
        if "slowest" not in r:
            print(f"| {r['points']:.0e} | {r['n']} | {r['mode']} | failed (exit {r['exit']}): {r.get('error', '')} |")
            continue
        slow = ", ".join(f"{name} {sec:.1f}" + (f" ({cpu:.1f} CPU)" if cpu > 0 else "")
                         for name, sec, cpu in r.get("slowest", []))
        print(f"| {r['points']:.0e} | {r['n']} | {r['mode']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
              f"{r['peak_rss_bytes'] / 1e6:.0f} | {r.get('peak_stage', '?')} | {r['peak_rss_bytes'] / r['points']:.0f} | "
              f"{r.get('spill_mb', 0.0):.0f} | "
              f"{r['points'] / r['wall_s'] / 1e6:.2f} | {r['points'] / r['cpu_s'] / 1e6:.2f} | {slow} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    if args.plot:
        plot_rows(rows, args.plot, args.plot_title)
    # A run that wrote its report counts even when its verdict failed (exit 3).
    return 1 if any("slowest" not in r for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
