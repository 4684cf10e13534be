#!/usr/bin/env bash
# The tests (README's second command): the system packages, the Rust tests on the release profile,
# then the Python package's wheel and tests (python/test.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# The tests that run the virtual lab in real time (its cameras rendering at 30 fps, a capture
# triangulating them as they come, a browser on the page) need the cores to themselves: beside
# other tests on a slower machine their frames came late and their tracks and alarms missed
# (a CI run: the page's track 0.19 mm from the truth, the live camera alarm 10 s late). They
# run last, one at a time; every other test first, with one test thread more than the cores
# (a dozen of them spend most of their time waiting on paced streams or a protocol's holds, and
# the spare thread keeps the cores busy meanwhile). RUST_TEST_THREADS set by the caller wins.
lab=(lab:: view::) # substrings of the names: the N-view unit tests (nview::) run here too
skip=()
for name in "${lab[@]}"; do skip+=(--skip "$name"); done
RUST_TEST_THREADS="${RUST_TEST_THREADS:-$(($(nproc) + 1))}" cargo test --release -- "${skip[@]}"
RUST_TEST_THREADS=1 cargo test --release -- "${lab[@]}"
bash python/test.sh
