#!/usr/bin/env bash
# handcap's model search against scikit-learn and Optuna on the same splits of the real datasets
# in ../shared/realdata (soft trunk, tendon arm; never copied here) and the synthetic grid:
# held-out MAE and wall time, one Markdown table (scripts/bench_peers.py says what runs).
# Makes its own Python venv (target/peers-venv) with scikit-learn, pandas and optuna; not part
# of the tests.
#
#   bash scripts/bench-peers.sh [--searches default,aco-r,grid,aco-paper] [--budget N] [--only soft_trunk]
set -euo pipefail
cd "$(dirname "$0")/.."
venv=target/peers-venv
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet scikit-learn pandas optuna
fi
cargo build --release --quiet
# libsvm's iteration bound (max_iter) warns on every fit it stops.
PYTHONWARNINGS=ignore::UserWarning "$venv/bin/python" scripts/bench_peers.py --work target/bench-peers "$@"
