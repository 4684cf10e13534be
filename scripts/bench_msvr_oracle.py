"""The lowest held-out MAE any (C, epsilon, sigma) gives MSVR on the peer benchmark's splits: the
parameters chosen on the held-out rows themselves, a bound no honest search can beat (not a
test). Where a peer scores below this bound, no choice of MSVR's parameters reaches it; where it
scores above, the gap is the search's.

    bash python/test.sh            # builds and installs the wheel into target/py-venv
    target/py-venv/bin/python scripts/bench_msvr_oracle.py [--only tendon_arm] [--history]

A log grid: C 10^0..10^6 (7), epsilon 10^-3..10^-0.5 of the outputs' RMS spread (6), sigma from
0.1 to 2 sqrt(d) in scaled inputs (8): 336 exact fits per dataset on the splits of
scripts/bench_peers.py (whole runs held out). `--history` adds the filtered copies of the inputs
that handcap's history run keeps (`--time`, its time constants: give them with --taus).
`--blocks` holds out each block of scripts/bench_splits.py in turn instead (static inputs), and
gives each family's bound: MSVR's grid above, and kernel ridge's (C and sigma, epsilon 0).
"""

import argparse
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import bench_peers as peers  # noqa: E402

import handcap  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--only", default="", help="comma-separated dataset names")
    ap.add_argument("--history", default="",
                    help="ema time constants (the time column's units) to fit on, e.g. 0.5,2,8")
    ap.add_argument("--blocks", action="store_true",
                    help="every block of scripts/bench_splits.py held out in turn, both families")
    a = ap.parse_args()
    if a.blocks:
        return blocks(a.only)
    print("| data | inputs | best held-out MAE | at (C, epsilon, sigma) | fits | time (s) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as work:
        for name, train, tests, inputs, outputs, time_args in peers.splits(work):
            if a.only and name not in a.only.split(","):
                continue
            x, y = peers.load(os.path.join(work, train), inputs, outputs)
            tx, ty = peers.load(os.path.join(work, tests[0]), inputs, outputs)
            fit_kw, predict_kw, label = {}, {}, "present"
            if a.history:
                if not time_args:
                    continue
                column = time_args[1]
                group = time_args[3] if len(time_args) > 3 else None
                t, g = column_of(work, train, column), column_of(work, train, group)
                tt, tg = column_of(work, tests[0], column), column_of(work, tests[0], group)
                fit_kw = dict(time=t, groups=g)
                predict_kw = dict(time=tt, groups=tg)
                label = f"+ ema {a.history}"
            d = x.shape[1] * (1 + (len(a.history.split(",")) if a.history else 0))
            start = time.time()
            best, fits = bound(x, y, tx, ty, "msvr", d, a.history, fit_kw, predict_kw)
            c, e, s = best[1]
            print(f"| {name} | {label} | {best[0]:.3f} | ({c:.3g}, {e:.3g}, {s:.3g}) | {fits} "
                  f"| {time.time() - start:.0f} |", flush=True)


def grid(y, d, family):
    """The (C, epsilon, sigma) the bound tries for `family` on outputs `y` and `d` inputs."""
    spread = np.sqrt(((y - y.mean(0)) ** 2).sum(1).mean())
    tubes = [0.0] if family == "krr" else spread * np.logspace(-3, -0.5, 6)
    return [(c, e, s) for c in np.logspace(0, 6, 7) for e in tubes
            for s in np.geomspace(0.1, 2 * np.sqrt(d), 8)]


def bound(x, y, tx, ty, family, d=None, history="", fit_kw=None, predict_kw=None):
    """The lowest held-out MAE of `family` over its grid and where, and the fits made (`d`: the
    inputs the model sees, the filtered copies of `history` included)."""
    best, fits = (np.inf, None), 0
    for c, e, s in grid(y, d or x.shape[1], family):
        model = handcap.MSVRRegressor(model=family, search="none", C=c, sigma=s,
                                      epsilon=None if family == "krr" else e,
                                      history=f"ema:{history}" if history else "none")
        try:
            model.fit(x, y, **(fit_kw or {}))
        except ValueError:
            continue
        fits += 1
        err = np.abs(model.predict(tx, **(predict_kw or {})) - ty).mean()
        if err < best[0]:
            best = (err, (c, e, s))
    return best, fits


def blocks(only):
    """Each family's bound on every block of scripts/bench_splits.py held out in turn."""
    from bench_coverage import DATASETS
    print("| data | held out | MSVR bound | at (C, epsilon, sigma) | kernel ridge bound | at (C, sigma) |")
    print("|---|---|---|---|---|---|")
    for name, (splits, inputs, outputs, _) in DATASETS.items():
        if only and name not in only.split(","):
            continue
        rows = []
        with tempfile.TemporaryDirectory() as work:
            for label, header, train, test in splits():
                paths = [os.path.join(work, f) for f in ("train.csv", "test.csv")]
                for path, body in zip(paths, (train, test)):
                    peers.write(path, header, body)
                (x, y), (tx, ty) = (peers.load(p, inputs, outputs) for p in paths)
                msvr, krr = (bound(x, y, tx, ty, f)[0] for f in ("msvr", "krr"))
                rows.append((msvr[0], krr[0]))
                (c, e, s), (kc, _, ks) = msvr[1], krr[1]
                print(f"| {name} | {label} | {msvr[0]:.3f} | ({c:.3g}, {e:.3g}, {s:.3g}) "
                      f"| {krr[0]:.3f} | ({kc:.3g}, {ks:.3g}) |", flush=True)
        m = np.mean(rows, axis=0)
        print(f"| {name} | mean | {m[0]:.3f} | | {m[1]:.3f} | |", flush=True)


def column_of(work, path, column):
    """One column of a split's file as floats, or None."""
    if column is None:
        return None
    import csv
    with open(os.path.join(work, path)) as f:
        return np.array([float(r[column]) for r in csv.DictReader(f)])


if __name__ == "__main__":
    sys.exit(main())
