#!/usr/bin/env bash
# The tests (README's second command): the system packages, the Rust tests on the release profile,
# then the Python package's wheel and tests (python/test.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# One test thread more than the cores: a dozen integration tests spend most of their time waiting
# on real time (cameras streaming at 30 fps, a stall, a protocol's holds), and the spare thread
# keeps the cores busy meanwhile (on 2 cores: 243 -> 222 s). RUST_TEST_THREADS set by the caller wins.
export RUST_TEST_THREADS="${RUST_TEST_THREADS:-$(($(nproc) + 1))}"
cargo test --release
bash python/test.sh
