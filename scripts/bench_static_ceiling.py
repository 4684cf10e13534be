"""How far can a static model (one that sees only the present inputs) go on the real robots?

The peer benchmark's static models share one RBF width across inputs. This script gives the
width a factor per input (ARD, automatic relevance determination), chosen by the same honest
folds (whole ramps on the soft trunk, unshuffled blocks on the tendon arm), and prints the
held-out MAE beside the isotropic model's: a ceiling for what widths alone can buy a static
model on the splits of bench_peers.py (whose splits, loaders and MAE it uses).

  KRR iso     KernelRidge (RBF) on min-max inputs and standardised targets, 8 x 16 grid
  KRR ARD     the same with a width per input: Optuna TPE, then Nelder-Mead from the TPE best
              and from the isotropic optimum; the lower cross-validated MAE is kept
  GP ARD      a Gaussian process (ARD RBF + white noise, noise >= 0.1 of the standardised
              targets: below that it fits the logs' near-copies as signal)
  SVR x3 ARD  the tube loss with a width per input (--svr-trials; about 6 minutes on the
              tendon arm, where every squared loss stays near 33 mm)

Run: target/peers-venv/bin/python scripts/bench_static_ceiling.py [--trials 300]
     [--svr-trials 150] [--only soft_trunk]  (the venv is made by scripts/bench-peers.sh)
"""

import argparse
import os
import sys
import tempfile
import time
import warnings

import numpy as np
import optuna
from scipy.optimize import minimize
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from sklearn.kernel_ridge import KernelRidge
from sklearn.model_selection import GridSearchCV, GroupKFold, KFold
from sklearn.preprocessing import MinMaxScaler, StandardScaler
from sklearn.svm import SVR

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_peers as bp  # noqa: E402

warnings.filterwarnings("ignore", category=ConvergenceWarning)
optuna.logging.set_verbosity(optuna.logging.WARNING)


class Ard(BaseEstimator, RegressorMixin):
    """Min-max inputs times a factor per input, standardised targets, then `kind`: KernelRidge
    (alpha) or one SVR per output (C, epsilon), RBF exp(-gamma |s * (x - x')|^2)."""

    def __init__(self, kind="krr", alpha=1e-2, C=1.0, epsilon=0.1, gamma=1.0, scales=None):
        self.kind, self.alpha, self.C, self.epsilon = kind, alpha, C, epsilon
        self.gamma, self.scales = gamma, scales

    def _x(self, x):
        return self.mx_.transform(x) * self.s_

    def fit(self, x, y):
        self.mx_ = MinMaxScaler().fit(x)
        self.sy_ = StandardScaler().fit(y)
        self.s_ = np.ones(x.shape[1]) if self.scales is None else np.asarray(self.scales)
        xs, ys = self._x(x), self.sy_.transform(y)
        if self.kind == "krr":
            self.m_ = [KernelRidge(kernel="rbf", alpha=self.alpha, gamma=self.gamma).fit(xs, ys)]
        else:
            self.m_ = [SVR(C=self.C, epsilon=self.epsilon, gamma=self.gamma, cache_size=500,
                           max_iter=10**6).fit(xs, ys[:, j]) for j in range(ys.shape[1])]
        return self

    def predict(self, x):
        xs = self._x(x)
        p = self.m_[0].predict(xs) if self.kind == "krr" else \
            np.column_stack([m.predict(xs) for m in self.m_])
        return self.sy_.inverse_transform(p)


def widths(v, d):
    """log10 of one gamma per input -> (their geometric mean, each input's factor)."""
    g = 10 ** np.asarray(v[-d:])
    gm = float(np.exp(np.log(g).mean()))
    return gm, np.sqrt(g / gm)


def cv_mae(model, x, y, folds):
    return float(np.mean([bp.mae(y[va], model.fit(x[tr], y[tr]).predict(x[va]))
                          for tr, va in folds]))


def ard_search(make, suggest, start, x, y, folds, trials, seed):
    """TPE over the log parameters, then Nelder-Mead from the TPE best and from `start`; returns
    (cross-validated MAE, parameters) of the lower."""
    score = lambda v: cv_mae(make(v), x, y, folds)  # noqa: E731
    study = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=seed))
    study.optimize(lambda t: score(suggest(t)), n_trials=trials)
    best = (study.best_value, list(study.best_params.values()))
    for v0 in (best[1], start):
        v0 = np.asarray(v0, float)
        simplex = v0 + np.vstack([np.zeros(len(v0)), 0.3 * np.eye(len(v0))])
        r = minimize(score, v0, method="Nelder-Mead",
                     options={"maxfev": 250, "xatol": 1e-2, "fatol": 1e-3,
                              "initial_simplex": simplex})
        if r.fun < best[0]:
            best = (r.fun, list(r.x))
    return best


def run(x, y, tx, ty, folds, trials, svr_trials, seed):
    """Rows (model, CV MAE, held-out MAE, seconds, chosen widths)."""
    d, rows = x.shape[1], []

    def row(name, cv, model, started, note=""):
        rows.append((name, cv, bp.mae(ty, model.fit(x, y).predict(tx)), time.time() - started,
                     note))
        print(f"  {name}: CV {cv:.3f}, held out {rows[-1][2]:.3f} ({rows[-1][3]:.0f} s) {note}",
              flush=True)

    t = time.time()
    grid = {"alpha": list(np.logspace(-6, 1, 8)), "gamma": list(np.logspace(-1, 3, 16))}
    gs = GridSearchCV(Ard(), grid, scoring="neg_mean_absolute_error", cv=folds).fit(x, y)
    row("KRR iso, grid 8 x 16", -gs.best_score_, gs.best_estimator_, t)

    def krr(v):
        gamma, s = widths(v, d)
        return Ard(alpha=10 ** v[0], gamma=gamma, scales=s)

    t = time.time()
    start = [np.log10(gs.best_params_["alpha"])] + [np.log10(gs.best_params_["gamma"])] * d
    cv, v = ard_search(krr, lambda tr: [tr.suggest_float("log_alpha", -6, 1)]
                       + [tr.suggest_float(f"log_g{i}", -2, 3) for i in range(d)],
                       start, x, y, folds, trials, seed)
    row("KRR ARD", cv, krr(v), t, f"factors {np.round(widths(v, d)[1], 2).tolist()}")

    t = time.time()
    mx = MinMaxScaler().fit(x)
    kernel = (ConstantKernel() * RBF(np.ones(d), (1e-3, 1e3))
              + WhiteKernel(0.1, noise_level_bounds=(1e-1, 1e1)))

    class Gp(BaseEstimator, RegressorMixin):
        def fit(self, a, b):
            self.m_ = MinMaxScaler().fit(a)
            self.g_ = GaussianProcessRegressor(kernel, normalize_y=True, random_state=seed)
            self.g_.fit(self.m_.transform(a), b)
            return self

        def predict(self, a):
            return self.g_.predict(self.m_.transform(a))

    row("GP ARD, noise >= 0.1", cv_mae(Gp(), x, y, folds), Gp(), t)

    if svr_trials:
        t = time.time()
        grid = {"C": [0.1, 1, 10, 100], "epsilon": [0.01, 0.1, 0.5], "gamma": [0.1, 1, 10, 100]}
        gs = GridSearchCV(Ard(kind="svr"), grid, scoring="neg_mean_absolute_error",
                          cv=folds).fit(x, y)
        row("SVR x3 iso, grid 48", -gs.best_score_, gs.best_estimator_, t)

        def svr(v):
            gamma, s = widths(v, d)
            return Ard(kind="svr", C=10 ** v[0], epsilon=10 ** v[1], gamma=gamma, scales=s)

        t = time.time()
        p = gs.best_params_
        start = [np.log10(p["C"]), np.log10(p["epsilon"])] + [np.log10(p["gamma"])] * d
        cv, v = ard_search(svr, lambda tr: [tr.suggest_float("log_C", -2, 3),
                                            tr.suggest_float("log_eps", -3, 0)]
                           + [tr.suggest_float(f"log_g{i}", -2, 3) for i in range(d)],
                           start, x, y, folds, svr_trials, seed)
        row("SVR x3 ARD", cv, svr(v), t, f"factors {np.round(widths(v, d)[1], 2).tolist()}")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=300, help="TPE trials of each ARD search")
    ap.add_argument("--svr-trials", type=int, default=0,
                    help="TPE trials of the ARD SVR x 3 on the tendon arm (0: not run)")
    ap.add_argument("--only", default="", help="soft_trunk or tendon_arm")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    table = []
    with tempfile.TemporaryDirectory() as work:
        for name, train, tests, inputs, outputs, _ in bp.splits(work):
            if name == "synthetic" or (a.only and name != a.only):
                continue
            x, y = bp.load(os.path.join(work, train), inputs, outputs)
            tx, ty = bp.load(os.path.join(work, tests[0]), inputs, outputs)
            if name == "soft_trunk":
                ramps = bp.load(os.path.join(work, train), ["iteration"], outputs)[0].ravel()
                folds = list(GroupKFold(n_splits=5).split(x, y, ramps))
            else:
                folds = list(KFold(n_splits=5).split(x))
            print(f"{name}: {len(x)} rows for training, {len(tx)} held out", flush=True)
            svr_trials = a.svr_trials if name == "tendon_arm" else 0
            table += [(name, *r) for r in run(x, y, tx, ty, folds, a.trials, svr_trials, a.seed)]
    print("\n| data | static model | CV MAE | held-out MAE | time (s) | widths |")
    print("|---|---|---|---|---|---|")
    for name, model, cv, held, secs, note in table:
        print(f"| {name} | {model} | {cv:.3f} | {held:.3f} | {secs:.0f} | {note} |")


if __name__ == "__main__":
    main()
