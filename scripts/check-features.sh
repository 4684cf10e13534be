#!/usr/bin/env bash
# Fails when a dependency shared by the command's build (`cargo test`: the default members, i.e.
# the command, the core and the benchmarks, with their dev-dependencies) and the wheel's (maturin:
# the Python binding and the core) gets different features in the two, which compiles it and
# everything above it twice; names the crate and the features to add to workspace-hack/Cargo.toml.
set -euo pipefail
cd "$(dirname "$0")/.."
features() { cargo tree "$@" -f '{p} {f}' --prefix none | sed 's/ (\*)$//; s/ (proc-macro)//'; }
# One after the other (two at once wait for each other's lock), and a failing `cargo tree` stops
# the script rather than passing an empty list.
command_build=$(features -p handcap -p handcap-core -p handcap-model -p handcap-benches -e normal,build,dev)
wheel_build=$(features -p handcap-python -e normal,build)
awk '
    FNR == 1 { side++ }
    NF >= 2 && $3 !~ /^\(/ {
        key = $1 " " $2
        seen[side, key] = 1
        n = split($3, list, ",")
        for (i = 1; i <= n; i++) has[side, key, list[i]] = 1
        all[key] = all[key] "," $3
    }
    END {
        for (key in all) {
            if (!((1, key) in seen) || !((2, key) in seen)) continue
            n = split(all[key], list, ",")
            delete told
            for (i = 1; i <= n; i++) {
                f = list[i]
                if (f == "" || f in told) continue
                told[f] = 1
                if (((1, key, f) in has) != ((2, key, f) in has)) {
                    printf "%s: feature %s is enabled only in the %s build; add it to workspace-hack/Cargo.toml\n", key, f, ((1, key, f) in has) ? "command'"'"'s" : "wheel'"'"'s"
                    bad = 1
                }
            }
        }
        exit bad
    }' <(printf '%s\n' "$command_build") <(printf '%s\n' "$wheel_build")
