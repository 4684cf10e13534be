#!/usr/bin/env bash
# handcap's model search against scikit-learn and Optuna on the same splits of the real datasets
# in ../shared/realdata (soft trunk, tendon arm; never copied here) and the synthetic grid:
# held-out MAE and wall time, one Markdown table per dataset, then handcap against the best peer.
# The split holds out whole runs (the soft trunk's ramps 24-29; the tendon arm's later block,
# steps 780-999); the peers are set up as scikit-learn's docs show (targets as given, inputs
# scaled in a pipeline, the grids of its kernel ridge vs SVR example), then searched at handcap's
# budget, all on the same folds (whole ramps, contiguous blocks, shuffled for the designed grid).
# scripts/bench_peers.py says what runs. Makes its own Python venv (target/peers-venv) with
# scikit-learn, pandas and optuna; not part of the tests.
#
#   bash scripts/bench-peers.sh [--searches default,history,aco-r,grid,aco-paper] [--budget N]
#                               [--only soft_trunk,tendon_arm,synthetic] [--seed N]
set -euo pipefail
cd "$(dirname "$0")/.."
venv=target/peers-venv
if ! "$venv/bin/python" -c 'import sklearn, pandas, optuna' 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet scikit-learn pandas optuna
fi
cargo build --release --quiet
# libsvm's iteration bound (max_iter, bench_peers.py's MAX_ITER) raises a ConvergenceWarning (a
# UserWarning) on every fit it stops; the rows say when a chosen model's final fit stopped there.
PYTHONWARNINGS=ignore::UserWarning "$venv/bin/python" scripts/bench_peers.py --work target/bench-peers "$@"
