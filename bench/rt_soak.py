#!/usr/bin/env python3
"""Real-time soak benchmark of issue 16 (not a CI test): one long session at 1 kHz on a real-time
servo thread, with the machine's own wake-up latency measured beside it.

Runs, one after the other (--sessions):
  - touch:   `hapticloud touch SCENE --realtime` (headless, the raster path);
  - explore: `hapticloud explore SCENE --device sim --realtime enforce --no-audio` with the viewer
             drawing (under `xvfb-run` when no DISPLAY is set: Mesa's llvmpipe renders on the CPU,
             so the viewer competes with the servo for both cores).
Beside each session runs the floor (on unless --no-floor): `cyclictest` (Debian's rt-tests) with
one SCHED_FIFO thread per CPU, pinned to it, at priority 70 (below the servo's 80), waking every
1000 us and doing nothing else. A wake-up it sees late by more than a period is the machine's
(the hypervisor stalling that virtual CPU, an interrupt storm), not the tick's: the servo's
overruns are to be read against it. The floor starts with the session's process, so its window
also covers the session's start-up (scene load, the X server) and ends that much before the
session's last tick.

Reported (JSON on stdout, and --out FILE if given), per session:
  - ticks, overruns (ServoStats: the tick ended after the next deadline), tick compute time
    (device read to snapshot) p50/p99/p99.9/max, wake-up lateness p99.9/max [ns];
  - the floor, per CPU: cycles, wake-up latency max [us], and how many wake-ups came later than
    500 us and than 1000 us (one period);
  - CPU steal time over the session (/proc/stat, as the guest kernel sees it; 0 when the
    hypervisor does not report it) and the load average at the end.
Usage (from the repository root, after a release build and as a user allowed SCHED_FIFO and
mlockall, e.g. root or with rtprio/memlock limits):
  python3 bench/rt_soak.py --minutes 10 [--sessions touch,explore] [--config configs/happy_buddha.yaml]
                           [--scene DIR] [--no-floor] [--out rt_soak.json]
Nothing is asserted here: the figures go into the issue's closing note and bench/README.md.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys

from soak_common import emit, hapticloud_exe, work_folder  # bench/soak_common.py, beside this file


def steal_ticks():
    """Total steal time of all CPUs [USER_HZ ticks] from /proc/stat (proc(5): the 8th field)."""
    with open("/proc/stat") as f:
        fields = f.readline().split()
    return int(fields[8]) if len(fields) > 8 else 0


def floor_command(seconds, json_path):
    """cyclictest's command line for `seconds` (at least 1: its -D 0 means "run forever")."""
    # -t -a: one thread per CPU, each pinned to its CPU (a stall of one virtual CPU shows on
    # that CPU's thread only, and the servo thread may run on either).
    return ["cyclictest", "-m", "-q", "-p", "70", "-i", "1000", "-t", "-a", "-D", f"{max(1, round(seconds))}s",
            "-h", "20000", f"--json={json_path}"]


def floor_figures(json_path):
    """cyclictest's JSON (rt-tests 2.x): per thread a histogram {latency_us: count}, min, max, avg."""
    try:
        with open(json_path) as f:
            d = json.load(f)
    except (OSError, ValueError) as e:
        return {"error": f"no floor figures in {json_path}: {e}"}
    per_cpu = []
    for t in d.get("thread", {}).values():
        f = {"cpu": t.get("cpu"), "cycles": t.get("cycles", 0), "max_us": t.get("max", 0), "late_500us": 0,
             "late_1000us": 0}
        for us, count in t.get("histogram", {}).items():
            # Bucket k holds latencies in [k, k + 1) us.
            if int(us) >= 500:
                f["late_500us"] += count
            if int(us) >= 1000:
                f["late_1000us"] += count
        # Samples beyond the histogram's 20 000 us: cycles minus the histogram's total.
        over = max(0, f["cycles"] - sum(t.get("histogram", {}).values()))
        f["late_500us"] += over
        f["late_1000us"] += over
        per_cpu.append(f)
    return {"per_cpu": per_cpu, "max_us": max((f["max_us"] for f in per_cpu), default=0),
            "late_1000us_all_cpus": sum(f["late_1000us"] for f in per_cpu)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=10.0, help="length of each session [min]")
    ap.add_argument("--sessions", default="touch,explore", help="comma-separated: touch, explore")
    ap.add_argument("--config", default="configs/happy_buddha.yaml", help="run config the scene is made from")
    ap.add_argument("--scene", help="an existing scene folder (skips the run)")
    ap.add_argument("--build", default="build/release")
    ap.add_argument("--no-floor", action="store_true", help="do not run cyclictest beside the sessions")
    ap.add_argument("--keep", help="folder for the work files (default: a temporary folder, removed)")
    ap.add_argument("--out", help="also write the JSON figures here")
    a = ap.parse_args()

    exe = hapticloud_exe(a.build, "rt_soak")
    sessions = [s for s in a.sessions.split(",") if s]
    for s in sessions:
        if s not in ("touch", "explore"):
            sys.exit(f"rt_soak: --sessions: '{s}' is not a session (expected touch or explore)")
    floor = not a.no_floor
    if floor and shutil.which("cyclictest") is None:
        sys.exit("rt_soak: cyclictest not found (Debian package rt-tests, scripts/install-deps); or pass --no-floor")
    xvfb = None
    if "explore" in sessions and not os.environ.get("DISPLAY"):
        xvfb = shutil.which("xvfb-run")
        if xvfb is None:
            sys.exit("rt_soak: explore needs a display: set DISPLAY or install xvfb (scripts/install-deps)")
    if not a.minutes > 0:
        sys.exit(f"rt_soak: --minutes {a.minutes}: expected a length above 0")
    seconds = a.minutes * 60.0

    work, tmp_obj = work_folder(a.keep, "hc-rt-soak-")
    scene = a.scene
    if not scene:
        run_dir = os.path.join(work, "scene-run")
        subprocess.run([exe, "-q", "run", a.config, "--out", run_dir, "--force"], check=True)
        scene = os.path.join(run_dir, "scene")

    results = {"settings": {"minutes": a.minutes, "scene": scene if a.scene else a.config, "floor": floor,
                            "viewer": "xvfb-run (Mesa llvmpipe)" if xvfb else os.environ.get("DISPLAY")}}
    for name in sessions:
        log_path = os.path.join(work, name + ".log")
        if name == "touch":
            out_dir = os.path.join(work, "touch-out")
            cmd = [exe, "touch", scene, "--realtime", "--seconds", str(seconds), "--out", out_dir, "--force"]
            summary = os.path.join(out_dir, "summary.json")
        else:
            summary = os.path.join(work, "explore-summary.json")
            cmd = [exe, "explore", scene, "--device", "sim", "--realtime", "enforce", "--no-audio",
                   "--seconds", str(seconds), "--summary", summary]
            if xvfb:
                cmd = [xvfb, "-a", "-s", "-screen 0 1280x800x24"] + cmd
        floor_json = os.path.join(work, name + "-floor.json")
        floor_log = os.path.join(work, name + "-floor.log")
        for stale in (summary, floor_json):  # left by an earlier run in a --keep folder
            if os.path.exists(stale):
                os.remove(stale)
        steal0 = steal_ticks()
        fl = None
        if floor:
            with open(floor_log, "w") as flog:
                fl = subprocess.Popen(floor_command(seconds, floor_json), stdout=flog, stderr=subprocess.STDOUT)
        with open(log_path, "w") as log:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
        if fl is not None:
            if rc != 0:
                fl.terminate()  # the session failed (e.g. no SCHED_FIFO): no floor to wait for
            fl.wait()
        r = {"exit": rc, "steal_s": (steal_ticks() - steal0) / os.sysconf("SC_CLK_TCK"),
             "load_avg_at_end": os.getloadavg()}
        if rc != 0:
            with open(log_path) as f:
                r["log_tail"] = f.read()[-2000:]
        if os.path.exists(summary):
            with open(summary) as f:
                s = json.load(f)
            r.update({k: s.get(k) for k in ("ticks", "overruns", "compute_ns", "lateness_ns")})
            rt = s.get("realtime") or {k: s.get(k) for k in ("fifo_granted", "memory_locked", "cpu_latency_pinned")}
            r["realtime"] = rt
            if name == "explore":
                r.update({k: s.get(k) for k in ("frames", "frame_mean_s", "display", "status")})
        if floor:
            r["floor"] = floor_figures(floor_json)
            r["floor"]["exit"] = fl.returncode
            if fl.returncode != 0:
                with open(floor_log) as f:
                    r["floor"]["log_tail"] = f.read()[-2000:]
        results[name] = r

    emit(results, a.out)
    if tmp_obj:
        tmp_obj.cleanup()


if __name__ == "__main__":
    main()
