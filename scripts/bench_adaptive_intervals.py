#!/usr/bin/env python3
"""Conformal intervals that widen where the inputs are far from the training rows, measured
beside the constant radius handcap writes (docs/benchmarks.md, "intervals"); not in handcap.

Every block of ../shared/realdata held out in turn, as scripts/bench_coverage.py holds them
(the tendon arm's 1000 steps in blocks of 200, contiguous folds; the soft trunk's ramps in
windows of six, every 4th row of the others for training, folds of whole ramps). A
scikit-learn model (KernelRidge, or SVR per axis) is chosen by the documentation's grid on those
folds, and its held-out fold errors ‖y − ŷ‖ give the radius:

  constant   the ⌈(n + 1)(1 − α)⌉-th smallest error, the same radius everywhere (handcap's);
  gpmaxP     each error divided by d(x) = max(1, s(x) / s_P), where s(x) is the posterior
             standard deviation of a Gaussian process with the model's kernel and
             regularisation (KernelRidge's α; 1/C for SVR) given the fold's training rows and
             s_P the P-th percentile of s over the held-out rows; the radius at x is the
             quantile of the ratios times d(x): constant where the inputs are as well covered
             as usual, growing where they are not.

With `--history` the inputs are followed by exponentially filtered copies of themselves, the
time constants handcap's history kept on the single splits (the tendon arm: 0.5, 2, 8 steps;
the soft trunk: 0.1, 0.4, 1.6 s within each ramp), filtered within each file as
bench_splits.py filters them (a held-out block's filters start at its first row).

Prints each split's pooled coverage at 90 % and 95 %, their means over the splits, and the
median radius over the constant one.

    target/peers-venv/bin/python scripts/bench_adaptive_intervals.py krr|svr [--history]
"""

import os
import sys
import tempfile

import numpy as np
from sklearn.kernel_ridge import KernelRidge
from sklearn.metrics.pairwise import rbf_kernel
from sklearn.model_selection import GridSearchCV
from sklearn.multioutput import MultiOutputRegressor
from sklearn.preprocessing import MinMaxScaler
from sklearn.svm import SVR

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_coverage import DATASETS  # noqa: E402
from bench_peers import SPLIT, cv_folds, ema_features, load, write  # noqa: E402

GAMMAS = list(np.logspace(-1, 2, 7))
VARIANTS = [("constant", None), ("gpmax75", 0.75), ("gpmax90", 0.9), ("gpmax95", 0.95)]
# The time constants of the filtered copies with `--history`: those handcap's history kept on
# each dataset's single split (docs/benchmarks.md), in its time column's units.
TAUS = {"soft_trunk": [0.1, 0.4, 1.6], "tendon_arm": [0.5, 2, 8]}


def posterior_sd(x_train, x, gamma, alpha):
    k = rbf_kernel(x_train, x_train, gamma=gamma)
    kx = rbf_kernel(x, x_train, gamma=gamma)
    solved = np.linalg.solve(k + alpha * np.eye(len(x_train)), kx.T)
    return np.sqrt(np.maximum(1.0 - np.sum(kx.T * solved, axis=0), 1e-12))


def conformal(scores, level):
    k = int(np.ceil((len(scores) + 1) * level))
    return np.sort(scores)[min(k, len(scores)) - 1]


def splits(history):
    """(dataset, block, x, y, held-out x, held-out y, folds): bench_coverage.py's blocks and
    bench_peers.py's folds, the inputs filtered per file with `history` as bench_splits.py
    filters them."""
    for name, (blocks, inputs, outputs, time_args) in DATASETS.items():
        kind, column = SPLIT[name][1]
        with tempfile.TemporaryDirectory() as work:
            for label, header, train, test in blocks():
                paths = [os.path.join(work, f) for f in ("train.csv", "test.csv")]
                for path, rows in zip(paths, (train, test)):
                    write(path, header, rows)
                (x, y), (tx, ty) = (load(p, inputs, outputs) for p in paths)
                if history:
                    x, tx = (ema_features(p, inputs, time_args, TAUS[name]) for p in paths)
                folds, _ = cv_folds(paths[0], kind, column, 2020)
                yield name, label, x, y, tx, ty, folds


def chosen(family, x, y, folds):
    """(make a model, γ, the GP's regularisation) chosen by the documentation's grid."""
    if family == "krr":
        grid = {"alpha": [1, 0.1, 0.01, 0.001], "gamma": GAMMAS}
        best = GridSearchCV(KernelRidge(kernel="rbf"), grid, cv=folds,
                            scoring="neg_mean_absolute_error").fit(x, y).best_params_
        return (lambda: KernelRidge(kernel="rbf", **best)), best["gamma"], best["alpha"]
    grid = {"estimator__C": [1, 10, 100, 1000], "estimator__gamma": GAMMAS}
    best = GridSearchCV(MultiOutputRegressor(SVR()), grid, cv=folds,
                        scoring="neg_mean_absolute_error").fit(x, y).best_params_
    c, gamma = best["estimator__C"], best["estimator__gamma"]
    return (lambda: MultiOutputRegressor(SVR(C=c, gamma=gamma))), gamma, 1.0 / c


def main():
    args = sys.argv[1:]
    history = "--history" in args
    family = next((a for a in args if a != "--history"), "krr")
    if family not in ("krr", "svr"):
        sys.exit("usage: bench_adaptive_intervals.py krr|svr [--history]")
    results = {}
    print(f"{family}{' with history' if history else ''}: held-out coverage at 90 % / 95 %")
    for data, block, x, y, tx, ty, folds in splits(history):
        scale = MinMaxScaler().fit(x)
        x, tx = scale.transform(x), scale.transform(tx)
        make, gamma, alpha = chosen(family, x, y, folds)
        errors, sd = np.zeros(len(x)), np.zeros(len(x))
        for train, held in folds:
            model = make().fit(x[train], y[train])
            errors[held] = np.linalg.norm(model.predict(x[held]) - y[held], axis=1)
            sd[held] = posterior_sd(x[train], x[held], gamma, alpha)
        model = make().fit(x, y)
        test_errors = np.linalg.norm(model.predict(tx) - ty, axis=1)
        test_sd = posterior_sd(x, tx, gamma, alpha)
        line = [f"{data}, {block}:"]
        for name, p in VARIANTS:
            ref = np.quantile(sd, p) if p else np.inf
            d, test_d = np.maximum(1, sd / ref), np.maximum(1, test_sd / ref)
            covered = []
            for level in (0.9, 0.95):
                q = conformal(errors / d, level)
                covered.append(100 * np.mean(test_errors <= q * test_d))
                results.setdefault((data, name), []).append((level, covered[-1]))
            width = np.median(conformal(errors / d, 0.9) * test_d) / conformal(errors, 0.9)
            results.setdefault((data, name, "width"), []).append(width)
            line.append(f"{name} {covered[0]:.1f}/{covered[1]:.1f}")
        print("  ".join(line), flush=True)
    print("| data | radius | coverage at 90 % / 95 %, mean over the splits | median radius / constant |")
    print("|---|---|---|---|")
    for data in DATASETS:
        for name, _ in VARIANTS:
            cov = results[(data, name)]
            at = [np.mean([c for lv, c in cov if lv == level]) for level in (0.9, 0.95)]
            width = np.mean(results[(data, name, "width")])
            print(f"| {data} | {name} | {at[0]:.1f} / {at[1]:.1f} | {width:.2f} |")


if __name__ == "__main__":
    main()
