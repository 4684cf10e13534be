#!/usr/bin/env bash
# Property-based fuzzing of every reader of a user's file (tests/it/fuzz.rs): the CSV reader,
# the pressure log, the frame index, the model file (damaged bytes, and tampered values used
# as predict and inverse use them), and the OpenCV YAML readers (board and
# calibration). Arbitrary bytes and damaged real files; a panic fails and proptest prints the
# smallest input that causes it.
#
#   bash scripts/fuzz.sh [CASES]      (default 20000 per reader; CI runs 256)
set -euo pipefail
cd "$(dirname "$0")/.."
cases="${1:-20000}"
start=$(date +%s)
PROPTEST_CASES="$cases" cargo test --release --test it fuzz:: -- --test-threads 2
echo "fuzz: $cases cases per reader, 7 targets (6 readers and the tampered model file), $(( $(date +%s) - start )) s, no panic"
