"""The monitor's false alarms and its time to each fault, on data-level virtual sessions (not a
test; the figures of docs/monitor.md).

    cargo build --release
    python3 scripts/bench_monitor.py [--out target/bench-monitor] [--clean 100-243]
                                     [--trials 100-147] [--faults 21-25]

Two models of the same training session (three 40 s trials of seed 1, `--intervals --folds
3`): `handcap model`'s defaults (`--model auto`) and `--model msvr`. Each watches, with the
monitor's defaults:
- clean sessions, one 600 s run each (`--clean` seeds), and clean sessions of 15 trials of
  40 s, as the models were trained (`--trials` seeds): every alarm there is false;
- 300 s sessions with a fault at 150 s (`--faults` seeds): seconds from the fault to each
  channel's alarm, and which test of the finger's raised it (`exceed`: the errors against the
  baseline's reference; `resp`: the finger's response); and the share of the 60 rows after the
  fault that the online band held, beside the model file's fixed radius (split conformal).
Prints markdown tables. Sessions and models are kept in `--out` and reused.
"""

import argparse
import csv
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HANDCAP = os.path.join(ROOT, "target", "release", "handcap")
FAULTS = ["camera@150=0.5", "stiffness@150=-0.1", "stiffness@150=-0.2", "leak@150=0.05",
          "leak@150=0.3", "payload@150=0.2", "payload@150=1"]
COLUMNS = ["--inputs", "P1_kpa,P2_kpa,P3_kpa", "--outputs", "x_mm,y_mm,z_mm"]


def run(args):
    subprocess.run([HANDCAP, *args], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)


def seeds(text):
    lo, _, hi = text.partition("-")
    return range(int(lo), int(hi or lo) + 1)


def session(out, name, synth_args):
    """A data-level session (made once): its rows' path."""
    path = os.path.join(out, "sessions", name)
    if not os.path.exists(os.path.join(path, "session.csv")):
        run(["synth", "--dynamic", "--no-images", *synth_args, "--out", path])
    return os.path.join(path, "session.csv")


def watch(out, model, name, rows):
    """What `handcap monitor` wrote of `rows` with `model`: its summary, and its rows (time,
    error, band and whether it held) from `monitor.csv`."""
    where = os.path.join(out, "watched", model, name)
    run(["monitor", rows, "--model", os.path.join(out, f"{model}.json"), "--out", where])
    with open(os.path.join(where, "monitor.json")) as f:
        summary = json.load(f)
    with open(os.path.join(where, "monitor.csv")) as f:
        watched = [(float(r["time_s"]), float(r["error"]), int(r["covered"]))
                   for r in csv.DictReader(f)]
    return summary, watched


def held_after(watched, radius, at=150.0, rows=60):
    """The shares of the `rows` rows from `at` on the band held, and `radius` would have."""
    after = [w for w in watched if w[0] >= at][:rows]
    return (sum(c for _, _, c in after) / len(after),
            sum(e <= radius for _, e, _ in after) / len(after))


def fitted(out, model, extra):
    path = os.path.join(out, f"{model}.json")
    if not os.path.exists(path):
        train = session(out, "train", ["--trials", "3", "--duration-s", "40", "--seed", "1"])
        run(["model", train, *COLUMNS, "--time", "time_s", "--group-by", "phase", "--folds", "3",
             "--intervals", *extra, "--out", path])
    with open(path) as f:
        m = json.load(f)
    return m["family"]["used"] if isinstance(m.get("family"), dict) else model


def said(alarm):
    """The finger test that raised an alarm, from its advice (after a camera's: the camera
    moved first, whichever test it was)."""
    if alarm["channel"] != "finger":
        return ""
    if "camera" in alarm["advice"]:
        return " (the camera first)"
    return " (resp)" if "modelled" in alarm["advice"] else " (exceed)"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", default=os.path.join(ROOT, "target", "bench-monitor"))
    ap.add_argument("--clean", default="100-243")
    ap.add_argument("--trials", default="100-147")
    ap.add_argument("--faults", default="21-25")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    models = {"auto": [], "msvr": ["--model", "msvr"]}
    print("| model | sessions | hours watched | finger alarms | camera alarms "
          "| band coverage (mean) |")
    print("|---|---|---|---|---|---|")
    for model, extra in models.items():
        family = fitted(a.out, model, extra)
        for kind, synth_args in (("600 s runs", ["--trials", "1", "--duration-s", "600"]),
                                 ("15 × 40 s trials", ["--trials", "15", "--duration-s", "40"])):
            chosen = seeds(a.clean if kind == "600 s runs" else a.trials)
            alarms = {"finger": [], "camera": []}
            hours, coverage = 0.0, []
            for s in chosen:
                name = f"{'run' if kind == '600 s runs' else 'trials'}_{s}"
                rows = session(a.out, name, [*synth_args, "--seed", str(s)])
                w, _ = watch(a.out, model, name, rows)
                with open(rows) as f:
                    last = f.readlines()[-1]
                # Watched: the rows after the baseline, where an alarm can fire.
                hours += (float(last.split(",")[0]) - w["settings"]["baseline_s"]) / 3600
                coverage.append(w["coverage"])
                for alarm in w["alarms"]:
                    alarms[alarm["channel"]].append(f"{s} at {alarm['time_s']:.0f} s")
            print(f"| {model} ({family}) | {len(chosen)} × {kind}, seeds {chosen.start}-"
                  f"{chosen.stop - 1} | {hours:.1f} | {len(alarms['finger'])} "
                  f"{', '.join(alarms['finger'])} | {len(alarms['camera'])} | "
                  f"{sum(coverage) / len(coverage):.3f} |", flush=True)
    print()
    print("| fault at 150 s | model | camera alarm (s after) | finger alarm (s after) "
          "| first 60 rows after: band held, file's radius held |")
    print("|---|---|---|---|---|")
    for fault in FAULTS:
        kind, amount = fault.split("@")[0], fault.split("=")[1]
        for model in models:
            after = {"camera": [], "finger": []}
            band, fixed = [], []
            for s in seeds(a.faults):
                name = f"{kind}_{amount}_{s}"
                rows = session(a.out, name, ["--trials", "1", "--duration-s", "300", "--seed",
                                             str(s), "--fault", fault])
                summary, watched = watch(a.out, model, name, rows)
                got = {x["channel"]: x for x in summary["alarms"]}
                held = held_after(watched, summary["start_radius"])
                band.append(held[0])
                fixed.append(held[1])
                for channel in after:
                    x = got.get(channel)
                    after[channel].append("-" if x is None else
                                          f"{x['time_s'] - 150:.0f}{said(x)}")
            print(f"| {kind} {amount} | {model} | {', '.join(after['camera'])} | "
                  f"{', '.join(after['finger'])} | {sum(band) / len(band):.2f} "
                  f"({min(band):.2f}-{max(band):.2f}), {sum(fixed) / len(fixed):.2f} |",
                  flush=True)


if __name__ == "__main__":
    sys.exit(main())
