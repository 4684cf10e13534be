"""How far one held-out split's coverage strays from the level: handcap's conformal intervals on
every held-out block of the real datasets in turn (not a test).

    cargo build --release
    target/peers-venv/bin/python scripts/bench_coverage.py [--history] [--model krr] [--only soft_trunk]

(any Python with numpy; target/peers-venv is the one scripts/bench-peers.sh makes)

The notes hold out one block of each dataset (the soft trunk's ramps 24-29, the tendon arm's last
220 rows). Conformal coverage is a promise over rows exchangeable with the held-out ones, averaged
over splits; one split of a time series is a few long runs of correlated rows, and its pooled
coverage varies from split to split. This holds out each block in turn, fits `handcap model` with
all defaults on the rest (`--history`: with the time column too), and prints each split's pooled
coverage at the model's 90 % and 95 % radii (each row's, as `handcap predict --interval` writes
it), their mean over the splits and their spread, the median 90 % radius over the median test
error, and the per-run band (radii calibrated on each held-out
run's worst error) with the share of whole test runs inside it.

Splits (from ../shared/realdata, never copied into the repository):
  soft_trunk  30 ramps in 5 windows of 6 (0-5, ..., 24-29); training every 4th row of the other
              ramps, as scripts/bench_peers.py
  tendon_arm  phase 1, 1000 rows in 5 blocks of 200; training the other 800 rows
"""

import argparse
import csv
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from bench_peers import (HANDCAP, SOFT_TRUNK, TENDON_ARM, fit_and_predict, soft_trunk_rows,  # noqa: E402
                         tendon_arm_rows, write)


def soft_trunk():
    header, body = soft_trunk_rows()
    for start in range(0, 30, 6):
        held = set(range(start, start + 6))
        train = [r for r in body if int(r[0]) not in held][::4]
        test = [r for r in body if int(r[0]) in held]
        yield f"ramps {start}-{start + 5}", header, train, test


def tendon_arm():
    header, body = tendon_arm_rows()
    for start in range(0, len(body), 200):
        yield f"rows {start}-{start + 199}", header, body[:start] + body[start + 200:], \
            body[start:start + 200]


DATASETS = {"soft_trunk": (soft_trunk, *SOFT_TRUNK[1:]), "tendon_arm": (tendon_arm, *TENDON_ARM[1:])}


def coverage(work, header, train, test, inputs, outputs, extra, run_column):
    """Pooled coverage of the test rows at the model's 90 % and 95 % radii, the radii, the
    median test error, and the per-run band: its radii and the share of whole test runs (rows
    grouped by `run_column`) inside them."""
    write(os.path.join(work, "train.csv"), header, train)
    write(os.path.join(work, "test.csv"), header, test)
    intervals = fit_and_predict(work, inputs, outputs, extra)["intervals"]
    radii = [r["radius"] for r in intervals["radii"]]
    band = [r["radius"] for r in intervals.get("runs", {}).get("radii", [])]
    truth = np.array([[float(r[header.index(c)]) for c in outputs] for r in test])
    # Each row's radius at each level, as `handcap predict --interval` writes it (wider where
    # the inputs are far from the training rows).
    per_row = []
    for r in intervals["radii"]:
        subprocess.run([HANDCAP, "predict", "model.json", "test.csv", "--out", "pred.csv",
                        "--interval", str(r["level"])], cwd=work, check=True,
                       stdout=subprocess.DEVNULL)
        with open(os.path.join(work, "pred.csv")) as f:
            pred = list(csv.DictReader(f))
        per_row.append(np.array([float(p["interval_radius"]) for p in pred]))
    predicted = np.array([[float(r[c]) for c in outputs] for r in pred])
    error = np.linalg.norm(truth - predicted, axis=1)
    runs = np.array([r[header.index(run_column)] for r in test]) if run_column else np.zeros(len(test))
    worst = np.array([error[runs == g].max() for g in np.unique(runs)])
    inside = [float((worst <= b).mean()) for b in band]
    return [float((error <= r).mean()) for r in per_row], \
        [float(np.median(r)) for r in per_row], float(np.median(error)), band, inside, len(worst)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--history", action="store_true", help="fit with the time column too")
    ap.add_argument("--only", default="", help="comma-separated dataset names")
    ap.add_argument("--model", default=None, help="handcap model's --model (default: its own)")
    a = ap.parse_args()
    family = ["--model", a.model] if a.model else []
    print("| data | held out | rows | coverage at 90 % / 95 % | radii | radius 90 % / median error "
          "| per-run band 90 % / 95 % | whole test runs inside |")
    print("|---|---|---|---|---|---|---|---|")
    for name, (splits, inputs, outputs, time_args) in DATASETS.items():
        if a.only and name not in a.only.split(","):
            continue
        seen, ratios, insides = [], [], []
        run_column = RUN_COLUMN[name]
        with tempfile.TemporaryDirectory() as work:
            for label, header, train, test in splits():
                cov, radii, median, band, inside, runs = coverage(
                    work, header, train, test, inputs, outputs,
                    (time_args if a.history else []) + family, run_column)
                seen.append(cov)
                ratios.append(radii[0] / median)
                insides.append(inside)
                print(f"| {name} | {label} | {len(test)} | "
                      f"{' / '.join(f'{100 * c:.1f}' for c in cov)} | "
                      f"{' / '.join(f'{r:.2f}' for r in radii)} | {radii[0] / median:.2f} | "
                      f"{' / '.join(f'{b:.2f}' for b in band) or 'none'} | "
                      f"{' / '.join(f'{100 * i:.0f} %' for i in inside) or '-'} of {runs} |",
                      flush=True)
        seen = np.array(seen)
        mean, sd = 100 * seen.mean(0), 100 * seen.std(0, ddof=1)
        pooled_inside = [np.mean([i[k] for i in insides if len(i) > k]) for k in range(2)
                         if any(len(i) > k for i in insides)]
        print(f"| {name} | mean over {len(seen)} splits (sd) | | "
              f"{' / '.join(f'{m:.1f} ({s:.1f})' for m, s in zip(mean, sd))} | | "
              f"{np.mean(ratios):.2f} | | "
              f"{' / '.join(f'{100 * i:.0f} %' for i in pooled_inside) or '-'} |", flush=True)


# The column naming the held-out rows' runs (the tendon arm's block is one run).
RUN_COLUMN = {"soft_trunk": "iteration", "tendon_arm": None}


if __name__ == "__main__":
    sys.exit(main())
