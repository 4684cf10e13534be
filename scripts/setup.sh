#!/usr/bin/env bash
# Installs what a fresh Debian machine lacks to build, test and run handcap.
# Safe to run twice: it installs only what is missing. Needs root or sudo for apt.
set -euo pipefail

# OpenCV 4.6 (calibration, triangulation; its contrib modules for ChArUco boards), what the
# `opencv` crate needs to generate its bindings, and the font the figures are labelled with.
APT_PACKAGES=(libopencv-dev libopencv-contrib-dev clang libclang-dev pkg-config fonts-dejavu-core)
# The tests open `capture --view`'s page in a headless browser.
APT_PACKAGES+=(chromium)

# The Python package's tests (python/test.sh) make a venv: Python 3.9 or newer with venv.
if ! python3 -c 'import sys, venv, ensurepip; sys.exit(sys.version_info < (3, 9))' 2>/dev/null; then
    APT_PACKAGES+=(python3 python3-venv)
fi

missing=()
for pkg in "${APT_PACKAGES[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$pkg")
    fi
done

if [ "${#missing[@]}" -gt 0 ]; then
    if [ "$(id -u)" -eq 0 ]; then
        sudo=()
    elif command -v sudo >/dev/null 2>&1; then
        sudo=(sudo)
    else
        echo "setup.sh: missing packages ${missing[*]}, and neither root nor sudo is available to install them" >&2
        exit 1
    fi
    echo "setup.sh: installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    "${sudo[@]}" apt-get update -qq
    "${sudo[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
    echo "setup.sh: cargo not found; install Rust with rustup (https://rustup.rs) and rerun" >&2
    exit 1
fi

if command -v rustup >/dev/null 2>&1; then
    for component in rustfmt clippy; do
        if ! rustup component list --installed 2>/dev/null | grep -q "^${component}"; then
            rustup component add "$component"
        fi
    done
fi

echo "setup.sh: ok"
