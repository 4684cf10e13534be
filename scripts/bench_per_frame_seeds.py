#!/usr/bin/env python3
"""The per-frame tip in motion on ten seeds, and what its error is made of (docs/motion.md).

For each seed: a dynamic session of the demo's design (3 trials of 8 s, 30 Hz, the lab's
webcams unless --format/--jpeg-quality/--chroma say otherwise), rendered by `handcap synth
--dynamic`, and `handcap triangulate --per-frame` on it with the rig's true calibration
(`truth/rig.yml`: what the detector and the triangulation do, without a calibration's error; on
the demo's own session of seed 2 its calibration gave 0.0893 mm and the true one 0.0892). Prints, per seed, the
tip's RMS error against the truth over the unflagged rows, the mean error (what every row
shares), and the error's least-squares slope on the tip's height z in the hand frame (mm per
mm): the share of the error that grows with the bend.

    python3 scripts/bench_per_frame_seeds.py [--seeds 1,2,...] [--jpeg-quality 85] [--chroma 420]
                                             [--format jpeg|png] [--keep DIR]

About 25 s a seed on 2 cores; sessions are kept in DIR (default target/bench-per-frame) and not
rendered again.
"""

import argparse
import csv
import math
import os
import statistics
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HANDCAP = os.path.join(ROOT, "target", "release", "handcap")
AXES = ("x_mm", "y_mm", "z_mm")


def run(args):
    done = subprocess.run([HANDCAP, *args], capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"handcap {' '.join(args)}: {done.stderr.strip()}")


def tips(path, unflagged):
    with open(path) as f:
        return {int(r["frame"]): [float(r[a]) for a in AXES] for r in csv.DictReader(f)
                if not unflagged or (r["flag"] == "" and r["x_mm"] != "")}


def figures(measured, truth):
    """RMS error, mean error and the slope of each axis' error on the true z."""
    frames = [f for f in measured if f in truth]
    if not frames:
        sys.exit("no unflagged row has a truth to compare with")
    errors = [[m - t for m, t in zip(measured[f], truth[f])] for f in frames]
    z = [truth[f][2] for f in frames]
    n = len(frames)
    rms = math.sqrt(sum(sum(e * e for e in row) for row in errors) / n)
    mean = [sum(row[a] for row in errors) / n for a in range(3)]
    # Least squares through the origin (the rest position is z = 0).
    zz = sum(v * v for v in z)
    slope = [sum(row[a] * v for row, v in zip(errors, z)) / zz for a in range(3)]
    return n, rms, mean, slope


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", default="1,2,3,4,5,6,7,8,9,2020")
    ap.add_argument("--format", default="jpeg", choices=["jpeg", "png"])
    ap.add_argument("--jpeg-quality", type=int, default=85)
    ap.add_argument("--chroma", default="420", choices=["420", "444"])
    ap.add_argument("--keep", default=os.path.join(ROOT, "target", "bench-per-frame"))
    a = ap.parse_args()
    look = ["--format", a.format] + (["--jpeg-quality", str(a.jpeg_quality), "--chroma", a.chroma]
                                     if a.format == "jpeg" else [])
    tag = "png" if a.format == "png" else f"q{a.jpeg_quality}_{a.chroma}"
    print(f"per-frame tip against the truth, {tag}, true calibration")
    print("| seed | rows | RMS (mm) | mean error x, y, z (mm) | slope on z (mm/mm) |")
    print("|---|---|---|---|---|")
    worst = []
    for seed in a.seeds.split(","):
        session = os.path.join(a.keep, f"{tag}_{seed}")
        if not os.path.exists(os.path.join(session, "truth", "per_frame.csv")):
            run(["synth", "--dynamic", "--seed", seed, "--duration-s", "8", "--trials", "3",
                 "--out", session, *look])
        rows = os.path.join(session, "per_frame.csv")
        run(["triangulate", os.path.join(session, "frames"), "--calib",
             os.path.join(session, "truth", "rig.yml"), "--pressures",
             os.path.join(session, "pressures.csv"), "--per-frame", "--out", rows])
        n, rms, mean, slope = figures(tips(rows, True),
                                      tips(os.path.join(session, "truth", "per_frame.csv"), False))
        worst.append(rms)
        print(f"| {seed} | {n} | {rms:.4f} | {', '.join(f'{v:+.4f}' for v in mean)} | "
              f"{', '.join(f'{v:+.4f}' for v in slope)} |")
    print(f"largest {max(worst):.4f} mm, median {statistics.median(worst):.4f} mm")


if __name__ == "__main__":
    main()
