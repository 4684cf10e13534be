"""handcap from Python against scikit-learn's SVR x 3, same data and model size (not a test).

    bash python/test.sh            # builds and installs the wheel into target/py-venv
    target/py-venv/bin/python scripts/bench_python.py

Prints fit time (C 10, epsilon 0.1, sigma 0.5 on inputs scaled to [0, 1]: gamma 2 for SVR; the
fit alone, the default without a search, and with intervals=True's held-out fits),
support vectors, and predict latency of one row (median of 2000 calls) and of 10 000 rows,
from Python and through the command line (one `handcap predict` process per call); the
Jacobian's likewise; a history model's prediction along a 10 000-row horizon; and the
exported C header's `handcap_step` and `handcap_jacobian` (ns per call, `cc -O2`).
"""

import os
import subprocess
import tempfile
import time

import numpy as np
from sklearn.multioutput import MultiOutputRegressor
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler
from sklearn.svm import SVR

import handcap

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HANDCAP = os.path.join(ROOT, "target", "release", "handcap")


def data(n, seed):
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 250, (n, 3))
    y = np.c_[10 * np.sin(x[:, 0] / 80), 5 * np.cos(x[:, 1] / 60) - x[:, 0] / 50,
              0.03 * x.sum(1) + 2 * np.sin(x[:, 2] / 40)]
    return x, y + rng.normal(0, 0.3, y.shape)


def median_call(f, calls=2000):
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main():
    for n in (1000, 2000):
        x, y = data(n, 1)
        start = time.perf_counter()
        ours = handcap.MSVRRegressor(search="none", C=10.0, epsilon=0.1, sigma=0.5,
                                     intervals=False).fit(x, y)
        fit_ours = time.perf_counter() - start
        start = time.perf_counter()
        handcap.MSVRRegressor(search="none", C=10.0, epsilon=0.1, sigma=0.5, intervals=True).fit(x, y)
        fit_intervals = time.perf_counter() - start
        svr = make_pipeline(MinMaxScaler(), MultiOutputRegressor(SVR(C=10.0, epsilon=0.1, gamma=2.0)))
        start = time.perf_counter()
        svr.fit(x, y)
        fit_svr = time.perf_counter() - start
        sv_svr = [e.support_.size for e in svr[-1].estimators_]
        print(f"n = {n}: fit handcap {fit_ours * 1e3:.0f} ms ({ours.support_vectors_.shape[0]} support vectors; "
              f"{fit_intervals * 1e3:.0f} ms with its intervals' held-out fits), "
              f"SVR x 3 {fit_svr * 1e3:.0f} ms ({sv_svr} support vectors)")
    # A model of 1000 support vectors (3 -> 3), as the issue asks.
    x, y = data(1000, 2)
    ours = handcap.MSVRRegressor(search="none", C=10.0, epsilon=0.001, sigma=0.5).fit(x, y)
    svr = make_pipeline(MinMaxScaler(), MultiOutputRegressor(SVR(C=10.0, epsilon=0.001, gamma=2.0))).fit(x, y)
    one = x[:1].copy()
    big = data(10000, 3)[0]
    raw = ours.model_
    rows = [
        ("handcap Model.predict (core)", lambda: raw.predict(one), lambda: raw.predict(big)),
        ("handcap MSVRRegressor.predict", lambda: ours.predict(one), lambda: ours.predict(big)),
        ("handcap Model.jacobian (core)", lambda: raw.jacobian(one), lambda: raw.jacobian(big)),
        ("handcap MSVRRegressor.jacobian", lambda: ours.jacobian(one), lambda: ours.jacobian(big)),
        ("scikit-learn SVR x 3 predict", lambda: svr.predict(one), lambda: svr.predict(big)),
    ]
    print(f"1 row / 10 000 rows, {ours.support_vectors_.shape[0]} support vectors "
          f"(SVR x 3: {[e.support_.size for e in svr[-1].estimators_]})")
    for name, single, many in rows:
        t1 = median_call(single)
        t = time.perf_counter()
        many()
        t2 = time.perf_counter() - t
        print(f"  {name}: {t1 * 1e6:.1f} us / {t2 * 1e3:.1f} ms")
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "m.json")
        ours.save(path)
        rows_csv = os.path.join(d, "x.csv")
        np.savetxt(rows_csv, one, delimiter=",", header="x0,x1,x2", comments="")
        out = os.path.join(d, "p.csv")
        times = []
        for _ in range(20):
            t = time.perf_counter()
            subprocess.run([HANDCAP, "predict", path, rows_csv, "--out", out], check=True,
                           stdout=subprocess.DEVNULL)
            times.append(time.perf_counter() - t)
        print(f"  handcap predict (the command line, one process per call): {np.median(times) * 1e3:.0f} ms")
    history_and_c()


C_TIMING = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "model.h"
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
int main(void) {
    double state[HANDCAP_STATE_LEN], u[HANDCAP_N_INPUTS], y[HANDCAP_N_OUTPUTS], sink = 0;
    double jac[HANDCAP_N_OUTPUTS * HANDCAP_N_INPUTS], t0;
    int k, j, calls = 20000;
    handcap_reset(state);
    t0 = now();
    for (k = 0; k < calls; k++) {
        for (j = 0; j < HANDCAP_N_INPUTS; j++) u[j] = 125.0 + 100.0 * ((k * (j + 3)) % 17) / 17.0;
        handcap_step(state, 1.0 / 30.0, u, y);
        sink += y[0];
    }
    printf("step %.0f ns", (now() - t0) / calls * 1e9);
    t0 = now();
    for (k = 0; k < calls; k++) {
        u[0] = 100.0 + k % 50;
        handcap_jacobian(u, jac);
        sink += jac[0];
    }
    printf(", jacobian %.0f ns (%g)\n", (now() - t0) / calls * 1e9, sink * 0.0);
    return 0;
}
"""


def history_and_c():
    """A history model of 1000 rows (3 -> 3): Python along a horizon, then its C header."""
    rng = np.random.default_rng(4)
    n = 1000
    t = np.arange(n) / 30.0
    u = np.repeat(rng.uniform(0, 250, (n // 10, 3)), 10, axis=0)
    _, y = data(n, 5)
    model = handcap.MSVRRegressor(search="none", C=10.0, epsilon=0.001, sigma=0.5,
                                  history="ema:0.1,0.4").fit(u, y, time=t)
    horizon = np.tile(u, (10, 1))
    th = np.arange(len(horizon)) / 30.0
    start = time.perf_counter()
    model.predict(horizon, time=th, groups=np.zeros(len(horizon)))
    print(f"history model ({model.support_vectors_.shape[0]} support vectors, "
          f"{len(model.model_.feature_names)} features): 10 000-row horizon "
          f"{(time.perf_counter() - start) * 1e3:.1f} ms")
    for name, m in (("static", None), ("history", model)):
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "m.json")
            if m is None:
                handcap.MSVRRegressor(search="none", C=10.0, epsilon=0.001, sigma=0.5).fit(*data(1000, 2)).save(path)
            else:
                m.save(path)
            subprocess.run([HANDCAP, "export", path, "--c", os.path.join(d, "model.h")], check=True,
                           stdout=subprocess.DEVNULL)
            with open(os.path.join(d, "t.c"), "w") as f:
                f.write(C_TIMING)
            exe = os.path.join(d, "t")
            subprocess.run(["cc", "-std=c99", "-O2", "-o", exe, os.path.join(d, "t.c"), "-lm"],
                           check=True, cwd=d)
            out = subprocess.run([exe], check=True, capture_output=True, text=True).stdout.strip()
            print(f"  C header, {name} model: {out}")


if __name__ == "__main__":
    main()
