"""handcap against the peers' grids on every held-out block in turn (not a test): is the one
split of `scripts/bench-peers.sh` representative?

    bash scripts/bench-peers.sh --only synthetic    # makes target/peers-venv, builds handcap
    target/peers-venv/bin/python scripts/bench_splits.py [--only soft_trunk,tendon_arm]

One held-out block of a time series is a few long runs of correlated rows; which method is
ahead on it can be the block's doing. This holds out each block of `scripts/bench_coverage.py`
in turn (the soft trunk's 30 ramps in 5 windows of 6, the tendon arm's 1000 steps in 5 blocks
of 200), fits `handcap model` with its defaults on the rest, static and with the time column,
and beside it the scikit-learn grids of `scripts/bench_peers.py` (SVR x 3 and KernelRidge, the
docs' grids, on the same folds as there), on the raw inputs and, where handcap kept filtered
copies of them, on those. Prints each split's held-out MAE (mean over rows and outputs of
|y - y_hat|) and, per dataset, the means over the splits and handcap's ratio to the better grid's
mean (a method picked before seeing the held-out rows, not the better of the two on each split).
The searches at handcap's budget (RandomizedSearchCV, Optuna) are left out: a minute a split.
"""

import argparse
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from bench_coverage import DATASETS  # noqa: E402
from bench_peers import (SPLIT, cv_folds, ema_features, fit_and_predict, load, mae,  # noqa: E402
                         peers, write)


def handcap(work, inputs, outputs, extra):
    """Held-out MAE of `handcap model` with its defaults (and `extra`) fitted on train.csv, and
    the filtered copies' time constants its history kept (None: none)."""
    written = fit_and_predict(work, inputs, outputs, extra)
    _, y = load(os.path.join(work, "test.csv"), inputs, outputs)
    _, p = load(os.path.join(work, "pred.csv"), inputs, outputs)
    used = (written.get("history") or {}).get("used")
    taus = used["memory"]["tau"] if used and used["memory"]["kind"] == "ema" else None
    return mae(y, p), taus


def grids(x, y, test, folds):
    """Held-out MAE of the two grids: SVR x 3, KernelRidge."""
    return [errors[0] for _, errors, _, _ in peers(x, y, [test], 0, 0, folds, gp=False,
                                                    searched=False)]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--only", default="", help="comma-separated dataset names")
    a = ap.parse_args()
    print("| data | held out | handcap | SVR x 3 grid | KernelRidge grid | handcap + time "
          "| SVR x 3 grid, handcap's features | KernelRidge grid, handcap's features |")
    print("|---|---|---|---|---|---|---|---|")
    summary = []
    for name, (splits, inputs, outputs, time_args) in DATASETS.items():
        if a.only and name not in a.only.split(","):
            continue
        kind, column = SPLIT[name][1]
        table = []
        with tempfile.TemporaryDirectory() as work:
            for label, header, train, test in splits():
                write(os.path.join(work, "train.csv"), header, train)
                write(os.path.join(work, "test.csv"), header, test)
                folds, _ = cv_folds(os.path.join(work, "train.csv"), kind, column, 2020)
                x, y = load(os.path.join(work, "train.csv"), inputs, outputs)
                held = load(os.path.join(work, "test.csv"), inputs, outputs)
                static, _ = handcap(work, inputs, outputs, [])
                peer = grids(x, y, held, folds)
                timed, taus = handcap(work, inputs, outputs, time_args)
                # Where no filtered copies were kept (none, or lags), the peers' static figures.
                filtered = peer
                if taus:
                    paths = [os.path.join(work, f) for f in ("train.csv", "test.csv")]
                    xh, xt = (ema_features(p, inputs, time_args, taus) for p in paths)
                    filtered = grids(xh, y, (xt, held[1]), folds)
                table.append([static, *peer, timed, *filtered])
                row = " | ".join(f"{v:.3f}" for v in table[-1])
                print(f"| {name} | {label}{'' if taus else ' (no history kept)'} | {row} |",
                      flush=True)
        m = np.mean(table, axis=0)
        print(f"| {name} | mean over {len(table)} splits | {' | '.join(f'{v:.3f}' for v in m)} |",
              flush=True)
        summary.append(f"{name}: handcap / the better grid's mean {m[0] / min(m[1:3]):.2f} static, "
                       f"{m[3] / min(m[4:6]):.2f} with the time column ({len(table)} splits)")
    print()
    for line in summary:
        print(f"- {line}")


if __name__ == "__main__":
    sys.exit(main())
