#!/usr/bin/env python3
"""The camera channel's still scene on rendered sessions (docs/monitor.md, "The still scene").

For each seed and fault: a rendered dynamic session of 60 s (the virtual lab's webcams: JPEG,
a cluttered wall, flicker), its calibration, and `handcap monitor SESSION` against the
data-level model `tests/it/monitor.rs` fits, with a 20 s baseline. Prints, per session, how far
each camera's view of the still scene wandered while it had not moved (the largest and the
99th percentile of `scene_*_px`), and each camera alarm's delay after the fault, named by
channel (the beads' residual, or a camera's still scene).

    python3 scripts/bench_scene.py [--seeds 11,12,13,14] [--keep DIR]

About a minute a session on 2 cores; sessions are kept in DIR (default
target/bench-scene) and not made again.
"""

import argparse
import csv
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HANDCAP = os.path.join(ROOT, "target", "release", "handcap")
FAULT_S = 30.0
FAULTS = [None, "camera@30=0.1", "pan@30=0.1", "pan@30=0.5"]


def run(args, cwd):
    done = subprocess.run([HANDCAP, *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"handcap {' '.join(args)}: {done.stderr.strip()}")
    return done.stdout


def model(keep):
    if not os.path.exists(os.path.join(keep, "model.json")):
        run(["synth", "--dynamic", "--no-images", "--out", "train", "--duration-s", "40",
             "--trials", "3", "--seed", "1"], keep)
        run(["model", "train/session.csv", "--inputs", "P1_kpa,P2_kpa,P3_kpa",
             "--outputs", "x_mm,y_mm,z_mm", "--time", "time_s", "--group-by", "phase",
             "--history", "ema:0.0167,0.0667,0.267", "--search", "none", "--c", "156.67",
             "--epsilon", "0.0301", "--sigma", "1.364", "--intervals", "--folds", "3",
             "--out", "model.json"], keep)
    return os.path.join(keep, "model.json")


def session(keep, seed, fault):
    name = f"s{seed}_{(fault or 'none').replace('@', '_').replace('=', '_')}"
    d = os.path.join(keep, name)
    if not os.path.exists(os.path.join(d, "calib.yml")):
        args = ["synth", "--out", name, "--dynamic", "--views", "8", "--duration-s", "60",
                "--trials", "1", "--seed", str(seed)]
        run(args + (["--fault", fault] if fault else []), keep)
        run(["calibrate", f"{name}/calib", "--out", f"{name}/calib.yml"], keep)
    return d


def percentile(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))] if values else float("nan")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", default="11,12,13,14")
    parser.add_argument("--keep", default=os.path.join(ROOT, "target", "bench-scene"))
    a = parser.parse_args()
    os.makedirs(a.keep, exist_ok=True)
    m = model(a.keep)
    print("| seed | fault | still: left max / p99 (px) | still: right max / p99 | measured rows | alarms after the fault (s) |")
    print("|---|---|---|---|---|---|")
    for seed in [int(s) for s in a.seeds.split(",")]:
        for fault in FAULTS:
            d = session(a.keep, seed, fault)
            out = os.path.join(d, "watch")
            run(["monitor", d, "--calib", os.path.join(d, "calib.yml"), "--model", m,
                 "--baseline-s", "20", "--out", out], a.keep)
            rows = list(csv.DictReader(open(os.path.join(out, "rows.csv"))))
            moved_at = FAULT_S if fault else float("inf")
            still = {}
            for camera in ["left", "right"]:
                until = moved_at if camera == "right" else float("inf")
                still[camera] = [float(r[f"scene_{camera}_px"]) for r in rows
                                 if r[f"scene_{camera}_px"] and float(r["time_s"]) < until]
            measured = sum(1 for r in rows if r["scene_left_px"])
            alarms = json.load(open(os.path.join(out, "monitor.json")))["alarms"]
            said = [f"{a.get('camera', 'residual') if a['channel'] == 'camera' else 'finger'} "
                    f"{a['time_s'] - FAULT_S:+.1f}" for a in alarms]
            cells = [f"{max(still[c]):.2f} / {percentile(still[c], 0.99):.2f}" if still[c] else "none"
                     for c in ["left", "right"]]
            print(f"| {seed} | {fault or 'none'} | {cells[0]} | {cells[1]} | "
                  f"{measured} of {len(rows)} | {', '.join(said) or 'none'} |", flush=True)


if __name__ == "__main__":
    main()
