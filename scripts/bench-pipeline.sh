#!/usr/bin/env bash
# Times the whole pipeline: runs `handcap demo` (default size unless arguments are given, e.g.
# --quick or --format png) and prints each stage's time and the key numbers from summary.json.
# Usage: bash scripts/bench-pipeline.sh [OUT_DIR] [demo options]   (needs: cargo build --release)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/bench-pipeline}
shift || true
rm -rf "$out"
target/release/handcap demo --out "$out" "$@" > "$out.log"
python3 - "$out/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
print("stage timings (s):", ", ".join(f"{k} {v:.1f}" for k, v in s["timings_s"]))
c = s["calibration"]
print(f"calibrate: RMS {c['rms_px']:.3f} px, intrinsics {c['intrinsics_error_pct']:.3f} %, baseline {c['baseline_error_pct']:.3f} %")
for t in s["triangulation"]:
    print(f"triangulate {t['phase']}: tip RMS {t['rms_mm']:.4f} mm over {t['rows']} steps")
for x in s["scores"]:
    if x["model"] == "msvr":
        print(f"msvr trained on {x['trained_on']}, {x['test']}: MAE {x['errors']['mae']:.4f} mm")
for i in s["inverse"]:
    print(f"inverse, {i['model']}: mean {i['mean_mm']:.4f} mm over {i['targets']} targets")
PY
