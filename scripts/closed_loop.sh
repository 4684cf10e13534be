#!/usr/bin/env bash
# The whole control loop without hardware: the virtual finger, seen by the virtual webcams.
#
#   bash scripts/closed_loop.sh [OUT [REPETITIONS]]      (default: closed-loop, 6)
#
# 1. A dynamic session (6 trials of 20 s, with board pairs) → calibrate → triangulate per frame
#    → the history model (`handcap model --time time_s --group-by phase`).
# 2. A figure-eight of ±2.5 × ±1.5 mm, period 6.5 s, about the model's tip at 125 kPa each,
#    after a 1.5 s lead-in at its centre: `inverse --trajectory` plans the commands.
# 3. Each repetition: the commands played on the virtual finger between rest holds
#    (`synth --protocol`, same seed: the same rig), triangulated per frame, and the run's tip
#    (on the commands' clock) taught back (`inverse --previous --measured`).
# Prints the tracking RMS of every run against the target twice: from the triangulated frames
# the loop learns from (what a lab sees; the cameras' own error and bias are in it, and learning
# from them learns their bias too), and from the virtual finger's truth at every exposure (what
# the finger did: the figure to judge the loop by). Writes OUT/errors.csv with both. Needs
# target/release/handcap (built here when missing) and awk.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-closed-loop}
reps=${2:-6}
[ -x target/release/handcap ] || cargo build --release --quiet
h=target/release/handcap
seed=7
rest_s=2
mkdir -p "$out"

# 1. The session and the model.
$h synth --out "$out/session" --dynamic --duration-s 20 --trials 6 --seed $seed > /dev/null
$h calibrate "$out/session/calib" --out "$out/calib.yml" > /dev/null
$h triangulate "$out/session/frames" --calib "$out/calib.yml" --per-frame --out "$out/session.csv" > /dev/null
$h model "$out/session.csv" --time time_s --group-by phase --out "$out/model.json" > /dev/null

# 2. The target: the model's settled tip at 125 kPa each is the centre.
printf 'P1_kpa,P2_kpa,P3_kpa\n125,125,125\n' > "$out/centre_in.csv"
$h predict "$out/model.json" "$out/centre_in.csv" --out "$out/centre.csv" > /dev/null 2>&1 || {
    # A history model predicts from a series: the centre held for a second.
    printf 'time_s,phase,P1_kpa,P2_kpa,P3_kpa\n0,a,125,125,125\n1,a,125,125,125\n' > "$out/centre_in.csv"
    $h predict "$out/model.json" "$out/centre_in.csv" --out "$out/centre.csv" > /dev/null
}
read -r cx cy cz < <(awk -F, 'NR > 1 { x = $(NF - 2); y = $(NF - 1); z = $NF } END { print x, y, z }' "$out/centre.csv")
awk -v cx="$cx" -v cy="$cy" -v cz="$cz" 'BEGIN {
    print "time_s,x_mm,y_mm,z_mm"
    pi = 3.14159265358979; period = 6.5
    for (k = 0; k < 45 + 2 * period * 30; k++) {
        t = k / 30; ph = 2 * pi * (t > 1.5 ? t - 1.5 : 0) / period
        printf "%.6f,%.6f,%.6f,%.6f\n", t, cx + 2.5 * sin(ph), cy + 1.5 * sin(2 * ph), cz
    }
}' > "$out/target.csv"

# The tracking RMS after the lead-in of a run's rows (time_s,x_mm,y_mm,z_mm,flag on the
# commands' clock): each unflagged row against the target interpolated to its time.
tracking_rms() {
    awk -F, 'FNR == 1 { next }
        NR == FNR { t[++n] = $1; x[n] = $2; y[n] = $3; z[n] = $4; next }
        $5 == "" && $1 >= 1.5 && $1 <= t[n] {
            while (j < n - 1 && t[j + 1] < $1) j++
            if (j < 1) j = 1
            w = ($1 - t[j]) / (t[j + 1] - t[j])
            dx = $2 - (x[j] + w * (x[j + 1] - x[j])); dy = $3 - (y[j] + w * (y[j + 1] - y[j]))
            dz = $4 - (z[j] + w * (z[j + 1] - z[j])); s += dx * dx + dy * dy + dz * dz; m++ }
        END { printf "%.4f", sqrt(s / m) }' "$out/target.csv" "$1"
}

# 3. Plan, then play, measure and learn.
$h inverse "$out/model.json" --trajectory "$out/target.csv" --out "$out/commands_0.csv"
echo "repetition,tracking_rms_triangulated_mm,tracking_rms_truth_mm" > "$out/errors.csv"
for ((r = 0; r <= reps; r++)); do
    # The commands as a protocol: a rest hold (the hand frame's origin), the path, a rest.
    awk -F, -v rest="$rest_s" 'NR == 1 { print "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s"; print "0,rest,0,0,0," rest; next }
        { t[NR] = $1; p[NR] = $2 "," $3 "," $4; n = NR }
        END { for (k = 2; k <= n; k++) print k - 1 ",path," p[k] "," (k < n ? t[k + 1] - t[k] : 1 / 30)
              print n ",rest,0,0,0,1" }' "$out/commands_$r.csv" > "$out/protocol_$r.csv"
    rm -rf "$out/run_$r"
    $h synth --out "$out/run_$r" --protocol "$out/protocol_$r.csv" --seed $seed > /dev/null
    $h triangulate "$out/run_$r/frames" --calib "$out/calib.yml" --per-frame --out "$out/run_$r.csv" > /dev/null
    # The path's rows on the commands' clock.
    awk -F, -v rest="$rest_s" 'NR == 1 { for (i = 1; i <= NF; i++) c[$i] = i; print "time_s,x_mm,y_mm,z_mm,flag"; next }
        $c["phase"] == "path" { printf "%.6f,%s,%s,%s,%s\n", $c["time_s"] - rest, $c["x_mm"], $c["y_mm"], $c["z_mm"], $c["flag"] }' \
        "$out/run_$r.csv" > "$out/measured_$r.csv"
    $h inverse "$out/model.json" --trajectory "$out/target.csv" --previous "$out/commands_$r.csv" \
        --measured "$out/measured_$r.csv" --out "$out/commands_$((r + 1)).csv" > /dev/null
    # The finger's truth at each left exposure of the path, on the commands' clock.
    awk -F, -v rest="$rest_s" 'NR == 1 { for (i = 1; i <= NF; i++) c[$i] = i; print "time_s,x_mm,y_mm,z_mm,flag"; next }
        $c["phase"] == "path" { printf "%.6f,%s,%s,%s,\n", $c["exposure_s"] - rest, $c["x_mm"], $c["y_mm"], $c["z_mm"] }' \
        "$out/run_$r/truth/per_frame.csv" > "$out/truth_$r.csv"
    seen=$(tracking_rms "$out/measured_$r.csv")
    truth=$(tracking_rms "$out/truth_$r.csv")
    echo "repetition $r: tracking RMS after the lead-in $truth mm (the finger's truth), $seen mm (the triangulated frames it learned from)"
    echo "$r,$seen,$truth" >> "$out/errors.csv"
done
echo "wrote $out/errors.csv"
