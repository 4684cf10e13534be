"""A pneumatic arm's size and dynamics, generated: handcap's model on 45 000 rows of a plant with
lag, beside scikit-learn's Nystroem + Ridge, static and with filtered inputs (not a test).

    cargo build --release
    target/peers-venv/bin/python scripts/bench_dynamic.py [--work DIR] [--seed 7] [--model krr]

(target/peers-venv is the venv scripts/bench-peers.sh makes, with scikit-learn.)

The plant: 45 trials of 1000 rows logged at 12 Hz; three pressures (0-250 kPa) each stepping to
a random level every 0.3-4 s; the tip (2 outputs, mm) a smooth nonlinear function of each
pressure passed through two first-order lags, 0.3 s and 2 s (a muscle that follows fast and
creeps slowly), with 0.05 mm of noise. Trials 0-40 train (41 000 rows), 41-44 are held out.
A static model of the present pressures cannot see where the lags stand; a model with the
inputs' history can.

Prints, for each run, the held-out MAE (mm, mean over rows and outputs), its wall time
(model, then predict) and handcap's choices (history, basis).
"""

import argparse
import csv
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from bench_peers import ema  # noqa: E402  (the filtered copies, as handcap builds them)
HANDCAP = os.path.join(ROOT, "target", "release", "handcap")
DT, TRIALS, ROWS, HELD = 1 / 12, 45, 1000, 4
FAST_S, SLOW_S = 0.3, 2.0


def plant(seed):
    """Rows (trial, t_s, P1, P2, P3, x, y), trial by trial."""
    rng = np.random.default_rng(seed)
    rows = []
    for trial in range(TRIALS):
        u = np.zeros((ROWS, 3))
        for j in range(3):
            k = 0
            while k < ROWS:
                hold = int(rng.uniform(0.3, 4.0) / DT) + 1
                u[k:k + hold, j] = rng.uniform(0, 250)
                k += hold
        fast, slow = u[0].copy(), u[0].copy()
        for k in range(ROWS):
            fast += (1 - np.exp(-DT / FAST_S)) * (u[k] - fast)
            slow += (1 - np.exp(-DT / SLOW_S)) * (u[k] - slow)
            a, b = np.tanh(fast / 120), np.tanh(slow / 150)
            x = 12 * a[0] - 6 * a[1] - 6 * a[2] + 3 * b[0] * b[1]
            y = 10 * (a[1] - a[2]) + 4 * b[2] - 2 * b[0]
            x, y = np.array([x, y]) + rng.normal(0, 0.05, 2)
            rows.append([trial, f"{k * DT:.4f}", *(f"{v:.3f}" for v in u[k]),
                         f"{x:.4f}", f"{y:.4f}"])
    return rows


def timed(args, cwd):
    start = time.time()
    subprocess.run(args, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.time() - start


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--work", default=os.path.join(ROOT, "target", "bench-dynamic"))
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--model", default=None, help="handcap model's --model (default: its own)")
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    header = ["trial", "t_s", "P1_kpa", "P2_kpa", "P3_kpa", "x_mm", "y_mm"]
    rows = plant(a.seed)
    split = {"train.csv": [r for r in rows if r[0] < TRIALS - HELD],
             "test.csv": [r for r in rows if r[0] >= TRIALS - HELD]}
    for name, part in split.items():
        with open(os.path.join(a.work, name), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(header)
            w.writerows(part)
    data = {n: np.array([[float(v) for v in r] for r in part]) for n, part in split.items()}
    train, test = data["train.csv"], data["test.csv"]
    print(f"| run | held-out MAE (mm) | model + predict (s) | kept |")
    print("|---|---|---|---|")
    kept_taus = []
    for label, extra in [("handcap, defaults", []),
                         ("handcap, defaults + --time t_s --group-by trial",
                          ["--time", "t_s", "--group-by", "trial"])]:
        model = os.path.join(a.work, "model.json")
        fit_s = timed([HANDCAP, "model", "train.csv", "--inputs", "P1_kpa,P2_kpa,P3_kpa",
                       "--outputs", "x_mm,y_mm", "--out", model, *extra,
                       *(["--model", a.model] if a.model else [])], a.work)
        predict_s = timed([HANDCAP, "predict", model, "test.csv", "--out", "pred.csv"], a.work)
        with open(os.path.join(a.work, "pred.csv")) as f:
            pred = np.array([[float(r["x_mm"]), float(r["y_mm"])] for r in csv.DictReader(f)])
        with open(model) as f:
            written = json.load(f)
        used = (written.get("history") or {}).get("used")
        if used:
            kept_taus = used["memory"].get("tau", [])
        basis = written["basis"]["basis"]
        family = (written.get("family") or {}).get("used", "msvr")
        kept = f"{family}, " + \
            (f"{used['memory']['kind']} {used['memory'].get('tau')}" if used else "static") + \
            f", basis {basis.get('centres', basis['kind'])}"
        print(f"| {label} | {np.abs(pred - test[:, 5:]).mean():.4f} | {fit_s:.1f} + {predict_s:.1f} "
              f"| {kept} |", flush=True)

    from sklearn.kernel_approximation import Nystroem
    from sklearn.linear_model import RidgeCV
    from sklearn.model_selection import GridSearchCV, GroupKFold
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import MinMaxScaler
    for label, taus in [("scikit-learn Nystroem (400) + RidgeCV, gamma by GroupKFold", []),
                        ("the same on the inputs + handcap's filtered copies", kept_taus),
                        ("the same on the inputs + filtered copies (0.25, 1, 4 s)", [0.25, 1, 4])]:
        start = time.time()
        x = ema(train[:, 2:5], train[:, 1], train[:, 0], taus)
        xt = ema(test[:, 2:5], test[:, 1], test[:, 0], taus)
        m = GridSearchCV(
            make_pipeline(MinMaxScaler(), Nystroem(n_components=400, random_state=a.seed),
                          RidgeCV(alphas=np.logspace(-6, 1, 8))),
            {"nystroem__gamma": [0.02, 0.1, 0.5, 2.0]}, cv=GroupKFold(5),
            scoring="neg_mean_absolute_error", n_jobs=2).fit(x, train[:, 5:], groups=train[:, 0])
        err = np.abs(m.predict(xt) - test[:, 5:]).mean()
        print(f"| {label} | {err:.4f} | {time.time() - start:.1f} | "
              f"gamma {m.best_params_['nystroem__gamma']} |", flush=True)

if __name__ == "__main__":
    sys.exit(main())
