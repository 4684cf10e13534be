"""How far one held-out split's coverage strays from the level: handcap's conformal intervals on
every held-out block of the real datasets in turn (not a test).

    cargo build --release
    target/peers-venv/bin/python scripts/bench_coverage.py [--history] [--only soft_trunk]

(any Python with numpy; target/peers-venv is the one scripts/bench-peers.sh makes)

The notes hold out one block of each dataset (the soft trunk's ramps 24-29, the tendon arm's last
220 rows). Conformal coverage is a promise over rows exchangeable with the held-out ones, averaged
over splits; one split of a time series is a few long runs of correlated rows, and its pooled
coverage varies from split to split. This holds out each block in turn, fits `handcap model` with
all defaults on the rest (`--history`: with the time column too), and prints each split's pooled
coverage at the model's 90 % and 95 % radii, their mean over the splits and their spread.

Splits (from ../shared/realdata, never copied into the repository):
  soft_trunk  30 ramps in 5 windows of 6 (0-5, ..., 24-29); training every 4th row of the other
              ramps, as scripts/bench_peers.py
  tendon_arm  phase 1, 1000 rows in 5 blocks of 200; training the other 800 rows
"""

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SHARED = os.path.join(os.path.dirname(ROOT), "shared", "realdata")
HANDCAP = os.path.join(ROOT, "target", "release", "handcap")


def write(path, header, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


def soft_trunk():
    rows = list(csv.reader(open(os.path.join(SHARED, "soft_trunk",
                                             "soft_trunk_taskspace_clean.csv"))))
    header, body, logged = rows[0] + ["t_s"], [], {}
    for r in rows[1:]:
        k = logged.get(r[0], 0)
        logged[r[0]] = k + 1
        body.append(r + [f"{0.05 * k:.2f}"])
    for start in range(0, 30, 6):
        held = set(range(start, start + 6))
        train = [r for r in body if int(r[0]) not in held][::4]
        test = [r for r in body if int(r[0]) in held]
        yield f"ramps {start}-{start + 5}", header, train, test


def tendon_arm():
    rows = list(csv.reader(open(os.path.join(SHARED, "tendon_arm",
                                             "tendon_soft_arm_3000_joined.csv"))))
    header, body = rows[0], [r for r in rows[1:] if r[1] == "1"]
    for start in range(0, len(body), 200):
        yield f"rows {start}-{start + 199}", header, body[:start] + body[start + 200:], \
            body[start:start + 200]


DATASETS = {
    "soft_trunk": (soft_trunk, [f"p{i}_kPa" for i in range(6)], ["x_mm", "y_mm", "z_mm"],
                   ["--time", "t_s", "--group-by", "iteration"]),
    "tendon_arm": (tendon_arm, ["act_s0_m0", "act_s0_m1", "act_s0_m2"],
                   ["SA-up-X_mm", "SA-up-Y_mm", "SA-up-Z_mm"], ["--time", "step"]),
}


def coverage(work, header, train, test, inputs, outputs, extra):
    """Pooled coverage of the test rows at the model's 90 % and 95 % radii."""
    write(os.path.join(work, "train.csv"), header, train)
    write(os.path.join(work, "test.csv"), header, test)
    subprocess.run([HANDCAP, "model", "train.csv", "--inputs", ",".join(inputs), "--outputs",
                    ",".join(outputs), "--out", "model.json", *extra], cwd=work, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    subprocess.run([HANDCAP, "predict", "model.json", "test.csv", "--out", "pred.csv"], cwd=work,
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(os.path.join(work, "model.json")) as f:
        radii = [r["radius"] for r in json.load(f)["intervals"]["radii"]]
    truth = np.array([[float(r[header.index(c)]) for c in outputs] for r in test])
    with open(os.path.join(work, "pred.csv")) as f:
        pred = list(csv.DictReader(f))
    predicted = np.array([[float(r[c]) for c in outputs] for r in pred])
    error = np.linalg.norm(truth - predicted, axis=1)
    return [float((error <= r).mean()) for r in radii], radii


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--history", action="store_true", help="fit with the time column too")
    ap.add_argument("--only", default="", help="comma-separated dataset names")
    a = ap.parse_args()
    print("| data | held out | rows | coverage at 90 % / 95 % | radii |")
    print("|---|---|---|---|---|")
    for name, (splits, inputs, outputs, time_args) in DATASETS.items():
        if a.only and name not in a.only.split(","):
            continue
        seen = []
        with tempfile.TemporaryDirectory() as work:
            for label, header, train, test in splits():
                cov, radii = coverage(work, header, train, test, inputs, outputs,
                                      time_args if a.history else [])
                seen.append(cov)
                print(f"| {name} | {label} | {len(test)} | "
                      f"{' / '.join(f'{100 * c:.1f}' for c in cov)} | "
                      f"{' / '.join(f'{r:.2f}' for r in radii)} |", flush=True)
        seen = np.array(seen)
        mean, sd = 100 * seen.mean(0), 100 * seen.std(0, ddof=1)
        print(f"| {name} | mean over {len(seen)} splits (sd) | | "
              f"{' / '.join(f'{m:.1f} ({s:.1f})' for m, s in zip(mean, sd))} | |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
