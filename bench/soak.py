#!/usr/bin/env python3
"""Soak benchmark of issue 15 (not a CI test): a long `touch` session and a long
`explore --device sim --hidden` session, each driven by a random level, pan and parameter
command every 100 ms, run side by side.

Reported (JSON on stdout, and --out FILE if given):
  - resident memory (VmRSS from /proc/PID/status, sampled every --sample-s seconds): after the
    warm-up (the first --warmup-fraction of the run, while the LoD cache of built levels and
    windows fills up to lod.memory_budget_mb), the first and last sample, the growth between
    them and the slope of a least-squares line through the samples [MiB/min]. touch --realtime
    locks its memory (mlockall), so its RSS counts every mapped page;
  - commands: the touch session's LoD switches recorded against the zoom-path actions written,
    and explore's timed script steps run against the steps written (a step waits while the
    session is busy; none may be lost), plus the servo's rejected commands and dropped events;
  - surfaces: published and freed (SharedState's accounting) at the end of explore; what is
    still held must be at most the current, the pending and the retire ring (2 + 8).

Usage (from the repository root, after a release build):
  python3 bench/soak.py --minutes 30 [--config configs/happy_buddha.yaml] [--out soak.json]
Nothing is asserted here: the figures go into the issue's closing note.
"""
import argparse
import json
import os
import random
import shutil
import subprocess
import sys
import threading
import time

from soak_common import emit, hapticloud_exe, work_folder  # bench/soak_common.py, beside this file


def rss_kib(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def sampler(proc, period_s, samples, t0):
    while proc.poll() is None:
        v = rss_kib(proc.pid)
        if v is not None:
            samples.append((time.monotonic() - t0, v))
        time.sleep(period_s)


def memory_figures(samples, warmup_fraction):
    if not samples:
        return {"samples": 0}
    end = samples[-1][0]
    kept = [(t, v) for t, v in samples if t >= warmup_fraction * end] or samples[-1:]
    n = len(kept)
    mt = sum(t for t, _ in kept) / n
    mv = sum(v for _, v in kept) / n
    den = sum((t - mt) ** 2 for t, _ in kept)
    slope_kib_s = sum((t - mt) * (v - mv) for t, v in kept) / den if den > 0 else 0.0
    return {
        "samples": len(samples),
        "peak_mib": max(v for _, v in samples) / 1024.0,
        "after_warmup_first_mib": kept[0][1] / 1024.0,
        "last_mib": kept[-1][1] / 1024.0,
        "growth_after_warmup_mib": (kept[-1][1] - kept[0][1]) / 1024.0,
        "slope_mib_per_min": slope_kib_s * 60.0 / 1024.0,
        "warmup_s": kept[0][0],
    }


def touch_zoom_path(rng, seconds, period_s, path):
    """One action every period_s: zoom in or out around the proxy, a level, or a pan."""
    n = 0
    with open(path, "w") as f:
        t = period_s
        while t < seconds - period_s:
            r = rng.random()
            if r < 0.25:
                f.write(f"{t:.3f} in\n")
            elif r < 0.5:
                f.write(f"{t:.3f} out\n")
            elif r < 0.7:
                f.write(f"{t:.3f} level {rng.randint(0, 3)}\n")
            else:
                f.write(f"{t:.3f} pan {rng.randint(-40, 40)} {rng.randint(-40, 40)}\n")
            n += 1
            t += period_s
    return n


def explore_script(rng, seconds, period_s, path):
    """One timed step ("T s") every period_s: level, finer/coarser, pan, texture, mu_s, model."""
    n = 0
    with open(path, "w") as f:
        t = period_s
        while t < seconds - period_s:
            r = rng.random()
            if r < 0.15:
                step = "finer"
            elif r < 0.3:
                step = "coarser"
            elif r < 0.45:
                step = f"level {rng.randint(0, 3)}"
            elif r < 0.7:
                step = f"pan {rng.uniform(-0.5, 0.5):.3f} {rng.uniform(-0.5, 0.5):.3f}"
            elif r < 0.8:
                step = f"texture {rng.choice(['on', 'off'])}"
            elif r < 0.9:
                step = f"mu_s {rng.uniform(0.0, 1.0):.3f}"
            else:
                step = f"model {rng.choice(['paper', 'curvature'])}"
            f.write(f"{t:.3f}s {step}\n")
            n += 1
            t += period_s
    return n


def run_monitored(cmd, sample_s, log_path):
    t0 = time.monotonic()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        samples = []
        th = threading.Thread(target=sampler, args=(proc, sample_s, samples, t0), daemon=True)
        th.start()
        rc = proc.wait()
        th.join()
    return rc, samples, time.monotonic() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--config", default="configs/happy_buddha.yaml")
    ap.add_argument("--build", default="build/release")
    ap.add_argument("--period-s", type=float, default=0.1, help="time between commands [s]")
    ap.add_argument("--sample-s", type=float, default=5.0)
    ap.add_argument("--warmup-fraction", type=float, default=0.25,
                    help="part of the run left out of the growth figures: the LoD cache (lod.memory_budget_mb, "
                         "512 MiB by default) fills first")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", help="folder for the work files (default: a temporary folder, removed)")
    ap.add_argument("--out", help="also write the JSON figures here")
    a = ap.parse_args()
    exe = hapticloud_exe(a.build, "soak")
    seconds = a.minutes * 60.0
    rng = random.Random(a.seed)
    work, tmp_obj = work_folder(a.keep, "hc-soak-")

    scene_run = os.path.join(work, "scene-run")
    subprocess.run([exe, "-q", "run", a.config, "--out", scene_run], check=True)
    scene = os.path.join(scene_run, "scene")

    zoom = os.path.join(work, "touch.zoom")
    n_zoom = touch_zoom_path(rng, seconds, a.period_s, zoom)
    script = os.path.join(work, "explore.script")
    n_steps = explore_script(rng, seconds, a.period_s, script)

    touch_cmd = [exe, "touch", scene, "--realtime", "--seconds", str(seconds), "--zoom-path", zoom,
                 "--out", os.path.join(work, "touch-out"), "--force"]
    explore_summary = os.path.join(work, "explore-summary.json")
    explore_cmd = [exe, "explore", scene, "--device", "sim", "--hidden", "--no-audio", "--seconds", str(seconds),
                   "--script", "@" + script, "--summary", explore_summary,
                   "--out", os.path.join(work, "explore-out")]
    if not os.environ.get("DISPLAY"):
        # A hidden window still needs an X server: a virtual one (Xvfb), as the tests use.
        xvfb = shutil.which("xvfb-run")
        if xvfb is None:
            sys.exit("soak: explore needs a display: set DISPLAY or install xvfb (scripts/install-deps)")
        explore_cmd = [xvfb, "-a", "-s", "-screen 0 1280x800x24"] + explore_cmd

    results = {}

    def go(name, cmd):
        rc, samples, wall = run_monitored(cmd, a.sample_s, os.path.join(work, name + ".log"))
        results[name] = {"exit": rc, "wall_s": wall, "memory": memory_figures(samples, a.warmup_fraction),
                         "rss_series_mib": [[round(t, 1), round(v / 1024.0, 1)] for t, v in samples[::max(1, len(samples) // 60)]]}

    threads = [threading.Thread(target=go, args=("touch", touch_cmd)),
               threading.Thread(target=go, args=("explore", explore_cmd))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()

    touch_summary = os.path.join(work, "touch-out", "summary.json")
    if os.path.exists(touch_summary):
        with open(touch_summary) as f:
            ts = json.load(f)
        switches = len(ts.get("lod", {}).get("switches", [])) - 1  # the first is the start window
        results["touch"].update({"zoom_actions_written": n_zoom, "zoom_actions_applied": switches,
                                 "ticks": ts.get("ticks"), "events_dropped": ts.get("events", {}).get("dropped"),
                                 "overruns": ts.get("overruns")})
    if os.path.exists(explore_summary):
        with open(explore_summary) as f:
            es = json.load(f)
        held = es.get("surfaces_published", 0) - es.get("surfaces_freed", 0)
        results["explore"].update({
            "script_steps_written": n_steps, "script_steps": es.get("script_steps"),
            "script_steps_run": es.get("script_steps_run"), "frames": es.get("frames"),
            "commands_applied": es.get("commands_applied"), "commands_rejected": es.get("commands_rejected"),
            "events_dropped": es.get("events_dropped"), "surfaces_published": es.get("surfaces_published"),
            "surfaces_freed": es.get("surfaces_freed"), "surfaces_held_at_end": held,
            "surfaces_held_limit": 10, "status": es.get("status")})
    results["settings"] = {"minutes": a.minutes, "config": a.config, "period_s": a.period_s,
                           "seed": a.seed,
                           "load_avg_at_end": os.getloadavg()}
    emit(results, a.out)
    if tmp_obj:
        tmp_obj.cleanup()


if __name__ == "__main__":
    main()
