#!/usr/bin/env bash
# handcap's ChArUco stereo calibration against OpenCV's own Python ChArUco calibration
# (CharucoDetector, calibrateCamera, stereoCalibrate as in OpenCV's tutorials) on the same
# synthetic renders (`handcap synth`, one per seed), both scored against the renders' ground
# truth: focal, principal point, baseline and rotation errors, RMS, pairs used and wall time,
# one Markdown table (scripts/bench_charuco.py says what runs).
# Makes its own Python venv (target/charuco-venv) with opencv-contrib-python-headless and
# numpy; builds handcap first; not part of the tests.
#
#   bash scripts/bench-charuco.sh [--seeds 2020,1,2] [--work target/bench-charuco] [--clean] [--reuse]
set -euo pipefail
cd "$(dirname "$0")/.."
venv=target/charuco-venv
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet opencv-contrib-python-headless==4.10.0.84 numpy
fi
cargo build --release --quiet
"$venv/bin/python" scripts/bench_charuco.py "$@"
