#!/usr/bin/env bash
# Times the hyper-parameter searches on the default synthetic training grid and reports the
# held-out MAE each reaches on the two sweeps.
# Usage: bash scripts/bench-search.sh [OUT_DIR]   (needs a release build: cargo build --release)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/bench-search}
bin=target/release/handcap
mkdir -p "$out"
"$bin" synth --out "$out/data" --no-images --seed 2020 >/dev/null

run() {
    local name=$1; shift
    local start end
    start=$(date +%s.%N)
    "$bin" model "$out/data/train.csv" --test "$out/data/sweep_a.csv" --test "$out/data/sweep_b.csv" \
        --out "$out/$name.json" --report "$out/$name" "$@" > "$out/$name.log"
    end=$(date +%s.%N)
    local search mae_a mae_b
    search=$(grep -E "candidates scored" "$out/$name.log" | sed 's/^ *//' || true)
    mae_a=$(awk -F, '$2=="sweep_a.csv"{print $3}' "$out/$name/metrics.csv")
    mae_b=$(awk -F, '$2=="sweep_b.csv"{print $3}' "$out/$name/metrics.csv")
    printf '| %s | %s | %.1f | %.4f | %.4f | %s |\n' "$name" "$*" "$(echo "$end - $start" | bc)" "$mae_a" "$mae_b" "$search"
}

echo "| run | options | wall s | MAE sweep A mm | MAE sweep B mm | search work |"
echo "|---|---|---|---|---|---|"
run paper-table2 --search none
run aco-paper-cv --search aco-paper
run aco-paper-train --search aco-paper --fitness train
run aco-r-cv-1600 --search aco-r --budget 1600
run grid-cv-1600 --search grid --budget 1600
run aco-paper-cv-400 --search aco-paper --max-iter 20
run aco-r-cv-400 --search aco-r --budget 400
run grid-cv-400 --search grid --budget 400
run aco-r-train-400 --search aco-r --budget 400 --fitness train
