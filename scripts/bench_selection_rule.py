"""Does a one-standard-error rule choose MSVR's parameters better than the lowest
cross-validated error? (not a test; a measurement for issue 62)

    bash python/test.sh            # builds and installs the wheel into target/py-venv
    target/py-venv/bin/python scripts/bench_selection_rule.py [soft_trunk] [tendon_arm]

On every block of scripts/bench_splits.py held out in turn: a log grid of (C, epsilon, sigma)
(7 x 5 x 7) scored by the peers' folds of the training rows (scripts/bench_peers.py), then the
held-out MAE of two picks: the lowest cross-validated MAE, and the smoothest candidate (the
largest sigma, then the smallest C, then the largest epsilon) whose paired fold difference above
the lowest is within one standard error. The held-out rows only report; they choose nothing.
"""

import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from bench_coverage import DATASETS  # noqa: E402
from bench_peers import SPLIT, cv_folds, load, write  # noqa: E402

import handcap  # noqa: E402


def held_out(x, y, tx, ty, c, e, s):
    """MAE on (tx, ty) of MSVR fitted on (x, y) at (C, epsilon, sigma); +inf if refused."""
    model = handcap.MSVRRegressor(model="msvr", search="none", C=c, epsilon=e, sigma=s,
                                  history="none")
    try:
        return np.abs(model.fit(x, y).predict(tx) - ty).mean()
    except ValueError:
        return np.inf


def picks(x, y, folds):
    """The grid, and the indices of its two picks: the lowest CV MAE, the one-SE rule's."""
    spread = np.sqrt(((y - y.mean(0)) ** 2).sum(1).mean())
    grid = [(c, e, s) for c in np.logspace(0, 6, 7)
            for e in spread * np.array([1e-3, 1e-2, 3e-2, 0.1, 0.3])
            for s in np.geomspace(0.1, 2 * np.sqrt(x.shape[1]), 7)]
    per_fold = np.array([[held_out(x[tr], y[tr], x[te], y[te], *h) for tr, te in folds]
                         for h in grid])
    best = int(np.argmin(per_fold.mean(1)))
    diff = per_fold - per_fold[best]
    se = diff.std(1, ddof=1) / np.sqrt(len(folds))
    within = [i for i in range(len(grid)) if diff[i].mean() <= se[i]]
    smoothest = max(within, key=lambda i: (grid[i][2], -grid[i][0], grid[i][1]))
    return grid, best, smoothest


def main():
    only = sys.argv[1:] or list(DATASETS)
    print("| data | held out | lowest CV: MAE (C, eps, sigma) | one-SE rule: MAE (C, eps, sigma) |")
    print("|---|---|---|---|")
    for name, (splits, inputs, outputs, _) in DATASETS.items():
        if name not in only:
            continue
        kind, column = SPLIT[name][1]
        rows = []
        with tempfile.TemporaryDirectory() as work:
            for label, header, train, test in splits():
                paths = [os.path.join(work, f) for f in ("train.csv", "test.csv")]
                for path, body in zip(paths, (train, test)):
                    write(path, header, body)
                folds, _ = cv_folds(paths[0], kind, column, 2020)
                (x, y), (tx, ty) = (load(p, inputs, outputs) for p in paths)
                grid, best, smoothest = picks(x, y, folds)
                rows.append([held_out(x, y, tx, ty, *grid[i]) for i in (best, smoothest)])
                said = [f"{e:.3f} ({', '.join(f'{v:.3g}' for v in grid[i])})"
                        for e, i in zip(rows[-1], (best, smoothest))]
                print(f"| {name} | {label} | {said[0]} | {said[1]} |", flush=True)
        m = np.mean(rows, axis=0)
        print(f"| {name} | mean | {m[0]:.3f} | {m[1]:.3f} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
