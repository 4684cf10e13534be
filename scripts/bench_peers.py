"""handcap's model search against what a user would set up instead, on the same splits.

Run through `bash scripts/bench-peers.sh` (which makes the venv and builds handcap). For each
dataset: handcap with all defaults, with the dataset's time column (input history), and with each
search asked for; then the peers, each set up as its own documentation shows and a user would:

  * targets as given (mm; no target scaling around the estimator), the inputs scaled by a
    StandardScaler in a pipeline (as the SVR and KernelRidge API pages' examples do);
  * the grids of scikit-learn's example "Comparison of kernel ridge regression and SVR":
      SVR x 3 (MultiOutputRegressor) + GridSearchCV: C in {1, 10, 100, 1000} x gamma in
        logspace(-2, 2, 5) (20 candidates); epsilon stays at SVR's default 0.1 (output units, mm),
        as in the example, which does not search it;
      KernelRidge (rbf) + GridSearchCV: alpha in {1, 0.1, 0.01, 0.001} x the same gammas (20);
  * a Gaussian process (constant x ARD RBF + white noise; normalize_y=True, the estimator's own
    option, its kernel bounds left at their defaults);
  * then the same at handcap's budget (the number of candidates handcap's default search scored,
    or --budget): RandomizedSearchCV and Optuna TPE over SVR x 3, RandomizedSearchCV over
    KernelRidge, all log-uniform over a box a decade beyond the grid on either side (SVR: C 0.1-1e4,
    gamma 1e-3-1e3, epsilon 0.01-10 mm; KernelRidge: alpha 1e-4-10, gamma 1e-3-1e3).

libsvm's iterations are bounded (max_iter = 10^6; its default is none): on targets in mm a corner
of the box (C 1000-10^4 with gamma 0.1-10) needs 10^6 iterations and more, 4-12 s for one output's
fit on the soft trunk, so an unbounded one could run for minutes. A fit stopped there has not
converged and is scored as it stands (the wrapper script silences libsvm's ConvergenceWarning; a
row whose chosen model's final fit stopped there says so).

The split (printed above each dataset's table): whole runs held out, never rows of a run on both
sides.
  soft_trunk  6 pressures -> tip; ramps 0-23 for training (every 4th row, file order), ramps 24-29
              held out (every row); a t_s column is added (0.05 s per logged row within each ramp,
              before decimation)
  tendon_arm  phase 1 (one random walk with 2 s settles), 3 offsets -> tip; the first 780 steps
              for training, the later block of the last 220 held out; `step` is its clock
  synthetic   handcap synth: the 50 kPa grid for training, the two sweeps held out
The peers' cross-validation (every grid, random search and TPE of a dataset scores the very same
5 folds, on the raw and on the filtered features alike) is the kind handcap's own folds choose:
GroupKFold on `iteration` for the soft trunk (whole ramps), unshuffled KFold (contiguous blocks)
for the tendon arm's single run, shuffled KFold (seeded) for the synthetic designed grid.

Where handcap's history kept filtered copies of the inputs, the peers (all but the Gaussian
process, whose ARD over four times the inputs is not what a user would try first) run again on the
same features, so the regressor alone differs. Prints held-out MAE (mean over rows and outputs of
|y - y_hat|, handcap's and the paper's measure), wall time, both as ratios to the matching handcap
run (the defaults; the history run for the peers given its features), then the best peer (lowest
mean held-out MAE) against handcap, and the whole benchmark's time.

The handcap run "history" is the defaults with the dataset's time column (--time, and
--group-by for the soft trunk's ramps): input history chosen by cross-validation.
"""

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SHARED = os.path.join(os.path.dirname(ROOT), "shared", "realdata")
BUILT = os.path.join(ROOT, "target", "release", "handcap")
HANDCAP = BUILT  # the copy in the work directory once main() has made it


def write(path, header, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


# The real robots: (file under SHARED, inputs, outputs, handcap's time arguments).
SOFT_TRUNK = (os.path.join("soft_trunk", "soft_trunk_taskspace_clean.csv"),
              [f"p{i}_kPa" for i in range(6)], ["x_mm", "y_mm", "z_mm"],
              ["--time", "t_s", "--group-by", "iteration"])
TENDON_ARM = (os.path.join("tendon_arm", "tendon_soft_arm_3000_joined.csv"),
              ["act_s0_m0", "act_s0_m1", "act_s0_m2"],
              ["SA-up-X_mm", "SA-up-Y_mm", "SA-up-Z_mm"], ["--time", "step"])


def soft_trunk_rows():
    """(header, rows) of the soft trunk, with a t_s column: 0.05 s per logged row within each
    ramp (`iteration`, the first column); None when ../shared is not there."""
    path = os.path.join(SHARED, SOFT_TRUNK[0])
    if not os.path.exists(path):
        return None
    rows = list(csv.reader(open(path)))
    body, logged = [], {}
    for r in rows[1:]:
        k = logged.get(r[0], 0)
        logged[r[0]] = k + 1
        body.append(r + [f"{0.05 * k:.2f}"])
    return rows[0] + ["t_s"], body


def tendon_arm_rows():
    """(header, rows) of the tendon arm's phase 1; None when ../shared is not there."""
    path = os.path.join(SHARED, TENDON_ARM[0])
    if not os.path.exists(path):
        return None
    rows = list(csv.reader(open(path)))
    return rows[0], [r for r in rows[1:] if r[1] == "1"]


def splits(work):
    """Writes the train/test files; returns (name, train, [tests], inputs, outputs, time args)."""
    out = []
    st = soft_trunk_rows()
    if st:
        header, body = st
        held = {24, 25, 26, 27, 28, 29}
        train = [r for r in body if int(r[0]) not in held][::4]
        test = [r for r in body if int(r[0]) in held]
        write(os.path.join(work, "st_train.csv"), header, train)
        write(os.path.join(work, "st_test.csv"), header, test)
        out.append(("soft_trunk", "st_train.csv", ["st_test.csv"], *SOFT_TRUNK[1:]))
    ta = tendon_arm_rows()
    if ta:
        header, body = ta
        write(os.path.join(work, "ta_train.csv"), header, body[:780])
        write(os.path.join(work, "ta_test.csv"), header, body[780:])
        out.append(("tendon_arm", "ta_train.csv", ["ta_test.csv"], *TENDON_ARM[1:]))
    subprocess.run([HANDCAP, "synth", "--out", os.path.join(work, "syn"), "--no-images"],
                   check=True, stdout=subprocess.DEVNULL)
    out.append(("synthetic", "syn/train.csv", ["syn/sweep_a.csv", "syn/sweep_b.csv"],
                ["P1_kpa", "P2_kpa", "P3_kpa"], ["x_mm", "y_mm", "z_mm"], None))
    return out


# Each dataset's split, said in the output, and the peers' cross-validation: (kind, column).
SPLIT = {
    "soft_trunk": ("whole ramps: ramps 0-23 for training (every 4th row, file order), ramps 24-29 "
                   "held out (every row)", ("groups", "iteration")),
    "tendon_arm": ("a later block of the one run (phase 1): steps 0-779 for training, steps "
                   "780-999 held out", ("blocks", None)),
    "synthetic": ("a designed grid for training (the 50 kPa grid), the two sweeps held out",
                  ("shuffle", None)),
}
FOLDS = 5


def cv_folds(path, kind, column, seed):
    """The peers' folds of the training file at `path`, as a list of (train, test) row indices,
    and their description: whole groups of `column` ("groups"), contiguous blocks in file order
    ("blocks", scikit-learn's unshuffled KFold) or shuffled rows ("shuffle")."""
    import pandas as pd
    from sklearn.model_selection import GroupKFold, KFold
    d = pd.read_csv(path)
    if kind == "groups":
        groups = d[column].values
        return (list(GroupKFold(n_splits=FOLDS).split(d, groups=groups)),
                f"GroupKFold({FOLDS}) on `{column}` ({len(np.unique(groups))} groups, whole groups "
                "held out)")
    if kind == "blocks":
        return (list(KFold(n_splits=FOLDS).split(d)),
                f"KFold({FOLDS}), unshuffled (contiguous blocks in file order)")
    return (list(KFold(n_splits=FOLDS, shuffle=True, random_state=seed).split(d)),
            f"KFold({FOLDS}, shuffle=True, random_state={seed})")


def load(path, inputs, outputs):
    import pandas as pd
    d = pd.read_csv(path)
    return d[inputs].values, d[outputs].values


def fit_and_predict(work, inputs, outputs, args):
    """In `work`: `handcap model train.csv` (the `inputs` to the `outputs`, with `args`) into
    model.json, then `handcap predict` of test.csv into pred.csv; the model file's contents."""
    subprocess.run([HANDCAP, "model", "train.csv", "--inputs", ",".join(inputs), "--outputs",
                    ",".join(outputs), "--out", "model.json", *args], cwd=work, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    subprocess.run([HANDCAP, "predict", "model.json", "test.csv", "--out", "pred.csv"], cwd=work,
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(os.path.join(work, "model.json")) as f:
        return json.load(f)


def mae(y, p):
    return float(np.abs(np.asarray(y) - np.asarray(p)).mean())


def run_handcap(work, name, train, tests, inputs, outputs, search, budget, time_args):
    """Held-out MAE per test, seconds, fold scheme and candidates scored; `search` "default"
    gives no --search (nor --budget), "history" the defaults with `time_args`."""
    model = os.path.join(work, f"{name}_{search}.json")
    args = [HANDCAP, "model", train, "--inputs", ",".join(inputs), "--outputs",
            ",".join(outputs), "--out", model]
    if search == "history":
        args += time_args
    elif search != "default":
        args += ["--search", search]
    if search in ("aco-r", "grid") and budget:
        args += ["--budget", str(budget)]
    for t in tests:
        args += ["--test", t]
    start = time.time()
    subprocess.run(args, cwd=work, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    seconds = time.time() - start
    errors = []
    for t in tests:
        pred = os.path.join(work, "pred.csv")
        subprocess.run([HANDCAP, "predict", model, t, "--out", pred], cwd=work, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _, y = load(os.path.join(work, t), inputs, outputs)
        _, p = load(pred, inputs, outputs)
        errors.append(mae(y, p))
    with open(model) as f:
        written = json.load(f)
    searched = written.get("search", {})
    used = (written.get("history") or {}).get("used")
    kept = used["memory"] if used else None
    return (errors, seconds, searched.get("folds", {}).get("scheme", "-"),
            searched.get("evaluations"), kept)


def ema(u, t, groups, taus):
    """The inputs `u` (rows x inputs) followed by one exponentially filtered copy per time
    constant, as handcap's history builds them: f <- f + (1 - exp(-dt/tau)) (u - f), restarting
    at each group's first row, in time order within the group."""
    out = [u]
    for tau in taus:
        f = np.empty_like(u)
        for g in np.unique(groups):
            rows = np.flatnonzero(groups == g)
            rows = rows[np.argsort(t[rows], kind="stable")]
            state = u[rows[0]].copy()
            for k, r in enumerate(rows):
                if k:
                    state += (1 - np.exp(-(t[r] - t[rows[k - 1]]) / tau)) * (u[r] - state)
                f[r] = state
        out.append(f)
    return np.hstack(out)


def ema_features(path, inputs, time_args, taus):
    """[`ema`] of a CSV's inputs, with the time (and group) column `time_args` names."""
    import pandas as pd
    d = pd.read_csv(path)
    time_col = time_args[time_args.index("--time") + 1]
    group_col = time_args[time_args.index("--group-by") + 1] if "--group-by" in time_args else None
    groups = d[group_col].values if group_col else np.zeros(len(d))
    return ema(d[inputs].values.astype(float), d[time_col].values.astype(float), groups, taus)


# libsvm's iteration bound (module docs): on targets in mm, C 1000-1e4 with gamma 0.1-10 needs
# 10^6 iterations and more (4-12 s per output's fit on the soft trunk).
MAX_ITER = 10**6
SVR_GRID = {"C": [1, 10, 100, 1000], "gamma": np.logspace(-2, 2, 5)}  # the example's grids
KR_GRID = {"alpha": [1, 0.1, 1e-2, 1e-3], "gamma": np.logspace(-2, 2, 5)}
# The box of the searches at handcap's budget: a decade beyond the grids on either side; epsilon
# in output units (mm) around SVR's default 0.1.
SVR_BOX = {"C": (0.1, 1e4), "gamma": (1e-3, 1e3), "epsilon": (1e-2, 10)}
KR_BOX = {"alpha": (1e-4, 10), "gamma": (1e-3, 1e3)}


def peers(x, y, tests, budget, seed, folds, gp=True, searched=True):
    """(name, [held-out MAE per test], seconds, what it chose) for each peer (module docs), all
    scored on the same `folds` (a list of (train, test) row indices of `x`); `gp` False leaves
    the Gaussian process out, `searched` False the searches at handcap's budget (the grids
    alone)."""
    from sklearn.base import clone
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, WhiteKernel, ConstantKernel
    from sklearn.kernel_ridge import KernelRidge
    from sklearn.model_selection import GridSearchCV, RandomizedSearchCV, cross_val_score
    from sklearn.multioutput import MultiOutputRegressor
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVR
    from scipy.stats import loguniform

    results = []
    key = "multioutputregressor__estimator__"
    svr = make_pipeline(StandardScaler(),
                        MultiOutputRegressor(SVR(cache_size=500, max_iter=MAX_ITER)))
    kr = make_pipeline(StandardScaler(), KernelRidge(kernel="rbf"))

    def chose(model):
        """What a search picked (and whether the final SVR fits hit libsvm's bound)."""
        picked = getattr(model, "best_params_", None)
        if picked is None:
            return ""
        text = ", ".join(f"{k.split('__')[-1]} {v:.3g}" for k, v in sorted(picked.items()))
        final = model.best_estimator_[-1]
        if isinstance(final, MultiOutputRegressor):
            stopped = sum(int(getattr(e, "fit_status_", 0)) for e in final.estimators_)
            if stopped:
                text += f"; {stopped} of {len(final.estimators_)} final fits stopped at max_iter"
        return text

    def timed(name, fit):
        start = time.time()
        model = fit()
        seconds = time.time() - start
        results.append((name, [mae(ty, model.predict(tx)) for tx, ty in tests], seconds,
                        chose(model)))

    def grid(model, space, prefix):
        return GridSearchCV(model, {prefix + k: list(v) for k, v in space.items()},
                            scoring="neg_mean_absolute_error", cv=folds, n_jobs=2)

    def randomized(model, box, prefix):
        return RandomizedSearchCV(
            model, {prefix + k: loguniform(*b) for k, b in box.items()}, n_iter=budget,
            scoring="neg_mean_absolute_error", cv=folds, n_jobs=2, random_state=seed)

    n_svr = len(SVR_GRID["C"]) * len(SVR_GRID["gamma"])
    n_kr = len(KR_GRID["alpha"]) * len(KR_GRID["gamma"])
    timed(f"scikit-learn SVR x3 + GridSearchCV (docs grid, {n_svr}; epsilon 0.1)",
          lambda: grid(svr, SVR_GRID, key).fit(x, y))
    timed(f"scikit-learn KernelRidge + GridSearchCV (docs grid, {n_kr})",
          lambda: grid(kr, KR_GRID, "kernelridge__").fit(x, y))
    if gp:
        model = make_pipeline(StandardScaler(), GaussianProcessRegressor(
            ConstantKernel() * RBF(length_scale=np.ones(x.shape[1])) + WhiteKernel(),
            normalize_y=True, random_state=seed))
        timed("scikit-learn GaussianProcess (ARD RBF + white)", lambda: model.fit(x, y))
    if not searched:
        return results
    timed(f"scikit-learn SVR x3 + RandomizedSearchCV ({budget})",
          lambda: randomized(svr, SVR_BOX, key).fit(x, y))
    timed(f"scikit-learn KernelRidge + RandomizedSearchCV ({budget})",
          lambda: randomized(kr, KR_BOX, "kernelridge__").fit(x, y))
    try:
        import optuna
    except ImportError:
        return results
    optuna.logging.set_verbosity(optuna.logging.WARNING)

    class Tuned:
        """The TPE study's best SVR x 3, refitted on all rows (what `chose` reads)."""

        def fit(self):
            def objective(trial):
                params = {key + k: trial.suggest_float(k, *b, log=True) for k, b in SVR_BOX.items()}
                return -cross_val_score(clone(svr).set_params(**params), x, y, cv=folds,
                                        scoring="neg_mean_absolute_error", n_jobs=2).mean()
            study = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=seed))
            study.optimize(objective, n_trials=budget)
            self.best_params_ = {key + k: v for k, v in study.best_params.items()}
            self.best_estimator_ = clone(svr).set_params(**self.best_params_).fit(x, y)
            return self

        def predict(self, tx):
            return self.best_estimator_.predict(tx)

    timed(f"Optuna TPE over SVR x3 ({budget})", lambda: Tuned().fit())
    return results


def best(rows):
    """The row (name, errors, ...) with the lowest mean held-out MAE."""
    return min(rows, key=lambda r: float(np.mean(r[1])))


def errors_text(errors):
    return " / ".join(f"{e:.3f}" for e in errors)


def versus(what, peer, handcap_label, handcap_errors):
    """The line comparing a handcap run with the best peer."""
    ratio = float(np.mean(handcap_errors)) / float(np.mean(peer[1]))
    return (f"{what}: {peer[0]} MAE {errors_text(peer[1])}, {handcap_label} MAE "
            f"{errors_text(handcap_errors)} (handcap / best peer {ratio:.2f}; "
            f"{'handcap ahead' if ratio < 1 else 'the peer ahead' if ratio > 1 else 'level'})")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--work", required=True)
    ap.add_argument("--searches", default="default,history",
                    help="handcap runs: default (no --search), history (defaults with the time "
                         "column), aco-r, grid, aco-paper")
    ap.add_argument("--budget", type=int, default=None,
                    help="for aco-r and grid runs and the peers' searches at handcap's budget "
                         "(default: what handcap's default search scored, else 120)")
    ap.add_argument("--seed", type=int, default=2020)
    ap.add_argument("--only", default="", help="comma-separated dataset names")
    a = ap.parse_args()
    a.work = os.path.abspath(a.work)
    os.makedirs(a.work, exist_ok=True)
    global HANDCAP
    HANDCAP = os.path.join(a.work, "handcap")  # rebuilding during a run changes nothing
    shutil.copy2(BUILT, HANDCAP)
    # handcap hands synth (and the other camera commands) to handcap-cameras beside it.
    cameras = os.path.join(os.path.dirname(BUILT), "handcap-cameras")
    if os.path.exists(cameras):
        shutil.copy2(cameras, os.path.join(a.work, "handcap-cameras"))
    started = time.time()
    summary = []

    def row(name, label, errors, seconds, reference):
        """One line; `reference` is the handcap run (errors, seconds) the ratios compare with."""
        ratios = ("-", "-")
        if reference:
            ratios = (" / ".join(f"{e / r:.2f}" for e, r in zip(errors, reference[0])),
                      f"{seconds / reference[1]:.2f}")
        print(f"| {name} | {label} | {errors_text(errors)} | {seconds:.1f} "
              f"| {ratios[0]} | {ratios[1]} |", flush=True)

    for name, train, tests, inputs, outputs, time_args in splits(a.work):
        if a.only and name not in a.only.split(","):
            continue
        x, y = load(os.path.join(a.work, train), inputs, outputs)
        held = [load(os.path.join(a.work, t), inputs, outputs) for t in tests]
        split, (kind, column) = SPLIT[name]
        folds, folds_text = cv_folds(os.path.join(a.work, train), kind, column, a.seed)
        print(f"\n### {name}\n\nsplit: {split}; {len(x)} training rows, "
              f"{' + '.join(str(len(ty)) for _, ty in held)} held out ({', '.join(tests)})  ")
        print(f"peers' cross-validation (the same folds for every peer): {folds_text}\n",
              flush=True)
        print("| data | method | held-out MAE | time (s) | MAE / handcap's | time / handcap's |")
        print("|---|---|---|---|---|---|")
        budget = a.budget
        static = history = None
        for search in a.searches.split(","):
            if search == "history" and not time_args:
                continue
            errors, seconds, scheme, scored, kept = run_handcap(
                a.work, name, train, tests, inputs, outputs, search, a.budget, time_args)
            if search == "history":
                memory = "none kept" if kept is None else (
                    f"{kept['kind']} {kept.get('tau', kept.get('rows'))}")
                label = f"handcap, defaults + {' '.join(time_args)} (history: {memory})"
                history = (errors, seconds, kept)
            elif search == "default":
                label = f"handcap, defaults ({scored} candidates, folds: {scheme})"
                budget = budget or scored
                static = (errors, seconds)
            else:
                label = f"handcap --search {search} ({scored} candidates, folds: {scheme})"
            row(name, label, errors, seconds, static if search != "default" else None)
        budget = budget or 120
        found = peers(x, y, held, budget, a.seed, folds)
        for peer, errors, seconds, picked in found:
            row(name, f"{peer}{f' (chose {picked})' if picked else ''}", errors, seconds, static)
        lines = []
        top = best(found)
        if static:
            lines.append(versus("best peer", top, "handcap defaults", static[0]))
        else:
            lines.append(f"best peer: {top[0]} MAE {errors_text(top[1])} (no handcap defaults run)")
        if history and history[2] and history[2]["kind"] == "ema":
            # The peers on the features handcap's history kept: the same inputs, the regressor
            # alone differs.
            taus = history[2]["tau"]
            xh = ema_features(os.path.join(a.work, train), inputs, time_args, taus)
            heldh = [(ema_features(os.path.join(a.work, t), inputs, time_args, taus), ty)
                     for t, (_, ty) in zip(tests, held)]
            filtered = peers(xh, y, heldh, budget, a.seed, folds, gp=False)
            for peer, errors, seconds, picked in filtered:
                row(name, f"{peer} on the inputs + handcap's filtered copies"
                    f"{f' (chose {picked})' if picked else ''}", errors, seconds, history[:2])
            lines.append(versus("best peer on handcap's filtered features", best(filtered),
                                f"handcap defaults + {' '.join(time_args)}", history[0]))
            lines.append(versus("best peer of all", best(found + filtered),
                                f"handcap defaults + {' '.join(time_args)}", history[0]))
        elif history:
            # No filtered copies to hand the peers (none kept, or lags): the static peers.
            kept = "none" if history[2] is None else history[2]["kind"]
            lines.append(versus(f"best peer (static features; handcap's history kept {kept})",
                                top, f"handcap defaults + {' '.join(time_args)}", history[0]))
        print()
        for line in lines:
            print(f"{line}  ", flush=True)
        summary += [f"{name}, {line}" for line in lines]
    print("\n### handcap against the best peer\n")
    for line in summary:
        print(f"- {line}")
    print(f"\nwhole benchmark: {time.time() - started:.0f} s")


if __name__ == "__main__":
    sys.exit(main())
