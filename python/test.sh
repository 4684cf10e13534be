#!/usr/bin/env bash
# The Python package's tests: builds the wheel (maturin, abi3 for CPython >= 3.9) into a venv
# it creates (TARGET/py-venv), installs it, and runs pytest. The command-line tests in it use
# TARGET/release/handcap (built by `cargo test --release`, or built here when missing). TARGET is
# where cargo builds: target/, or CARGO_TARGET_DIR (or build.target-dir) when set.
set -euo pipefail
cd "$(dirname "$0")/.."
target=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
export HANDCAP_BIN="$target/release/handcap"
venv="$target/py-venv"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/pip" install --quiet --upgrade pip
"$venv/bin/pip" install --quiet "maturin>=1.5,<2" pytest pandas scikit-learn numpy
[ -x "$HANDCAP_BIN" ] || cargo build --release --quiet
rm -rf "$target/wheels"
"$venv/bin/maturin" build --release --quiet -m python/Cargo.toml -i "$venv/bin/python" -o "$target/wheels"
"$venv/bin/pip" install --quiet --force-reinstall --no-deps "$target"/wheels/handcap-*.whl
# From the repository's root, so `import handcap` finds the installed wheel, not python/handcap.
"$venv/bin/python" -m pytest -q -p no:cacheprovider --import-mode=importlib python/tests
