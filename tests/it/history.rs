//! Input history (issue 27): a plant that lags is modelled from its inputs' past, a plant that
//! does not keeps its static model, the steady state's Jacobian, and bad time columns.

use std::fmt::Write as _;
use std::path::Path;

use handcap::data::{Columns, Dataset};
use handcap::model::history::{History, Memory, Series, SteadyState, AUTO_LADDERS};
use handcap::model::msvr::{Loss, MsvrParams};
use handcap::model::{Differentiable, ModelSpec, Predict};

use crate::common::{
    csv_rows, handcap, handcap_err, handcap_ok, handcap_usage, lowest_fitness, read_json, tempdir,
    write, Lcg,
};

/// Time step of the lagging plant's log (s) and its lag's time constant (s).
const DT: f64 = 0.1;
const LAG_S: f64 = 0.4;

/// The settled outputs of the lagging plant at its internal state `s` (2 → 2, smooth).
fn settled(s: [f64; 2]) -> [f64; 2] {
    [
        0.1 * s[0] + 3.0 * (s[1] / 60.0).sin(),
        0.08 * s[1] - 2.0 * (s[0] / 70.0).cos(),
    ]
}

/// `trials` runs of `rows` rows each, logged every [`DT`] s: two pressures held for 3-12 rows at
/// random levels in [0, 200] kPa, and outputs that follow them through a first-order lag of
/// [`LAG_S`]. Columns: trial, t_s, P1_kpa, P2_kpa, x_mm, y_mm.
pub(crate) fn lagging_plant(seed: u64, trials: usize, rows: usize) -> String {
    lagging_plant_of(LAG_S, seed, trials, rows)
}

/// [`lagging_plant`] with a lag of `lag_s`.
fn lagging_plant_of(lag_s: f64, seed: u64, trials: usize, rows: usize) -> String {
    let mut rng = Lcg(seed);
    let mut csv = String::from("trial,t_s,P1_kpa,P2_kpa,x_mm,y_mm\n");
    for trial in 0..trials {
        let mut u = [200.0 * rng.next(), 200.0 * rng.next()];
        let mut s = u;
        let mut hold = 0;
        for k in 0..rows {
            if hold == 0 {
                u = [200.0 * rng.next(), 200.0 * rng.next()];
                hold = 3 + (10.0 * rng.next()) as usize;
            }
            hold -= 1;
            let gain = 1.0 - (-DT / lag_s).exp();
            for j in 0..2 {
                s[j] += gain * (u[j] - s[j]);
            }
            let y = settled(s);
            let _ = writeln!(
                csv,
                "{trial},{:.2},{:.4},{:.4},{:.6},{:.6}",
                k as f64 * DT,
                u[0],
                u[1],
                y[0],
                y[1]
            );
        }
    }
    csv
}

fn mae_of(predicted: &Path, truth: &Path) -> f64 {
    let (p, t) = (csv_rows(predicted), csv_rows(truth));
    assert_eq!(p.len(), t.len());
    let mut sum = 0.0;
    for (a, b) in p.iter().zip(&t) {
        for c in ["x_mm", "y_mm"] {
            sum += (a[c].parse::<f64>().unwrap() - b[c].parse::<f64>().unwrap()).abs();
        }
    }
    sum / (2 * p.len()) as f64
}

/// Fits `train.csv` in `d` (a [`lagging_plant`]) with `history` and fixed hyper-parameters
/// (no search) into `out`.
pub(crate) fn fit_lagging(d: &Path, history: &str, out: &str) {
    fit_lagging_with(d, history, out, &[]);
}

/// [`fit_lagging`] with the options `more` besides.
pub(crate) fn fit_lagging_with(d: &Path, history: &str, out: &str, more: &[&str]) {
    let mut args = vec!["model", "train.csv"];
    args.extend(COLUMNS);
    args.extend(["--time", "t_s", "--group-by", "trial", "--history", history]);
    args.extend(["--c", "100", "--epsilon", "0.01", "--sigma", "2"]);
    args.extend(more);
    handcap_ok(d, &[&args[..], &["--out", out]].concat());
}

pub(crate) const COLUMNS: [&str; 4] = ["--inputs", "P1_kpa,P2_kpa", "--outputs", "x_mm,y_mm"];

#[test]
fn a_lagging_plant_is_modelled_from_its_inputs_history() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &lagging_plant(1, 6, 100));
    write(d, "test.csv", &lagging_plant(2, 2, 100));
    let fit = |history: &str, out: &str| {
        let report = format!("rep_{history}");
        let mut args = vec!["model", "train.csv"];
        args.extend(COLUMNS);
        args.extend([
            "--time",
            "t_s",
            "--group-by",
            "trial",
            "--history",
            history,
            "--budget",
            "40",
            "--test",
            "test.csv",
            "--out",
            out,
            "--report",
            &report,
        ]);
        handcap_ok(d, &args);
        handcap_ok(d, &["predict", out, "test.csv", "--out", "pred.csv"]);
        mae_of(&d.join("pred.csv"), &d.join("test.csv"))
    };
    let history = fit("auto", "model.json");
    let file = read_json(&d.join("model.json"));
    let decision = &file["history"];
    assert_eq!(decision["used"]["memory"]["kind"], "ema", "{decision}");
    assert_eq!(decision["used"]["group"], "trial");
    let tried = decision["tried"].as_array().unwrap();
    assert_eq!(tried.len(), 2, "{decision}");
    assert!(tried[0]["memory"].is_null());
    assert!(tried[1]["fitness"].as_f64() < tried[0]["fitness"].as_f64());
    // Every ladder fits in the 9.9 s trials (the longest starts at 8 steps, 0.8 s).
    assert_eq!(decision["screened"].as_array().unwrap().len(), AUTO_LADDERS);
    // The model's inputs are the features: 2 present inputs and 2 per time constant.
    let inputs = file["model"]["inputs"].as_array().unwrap().len();
    let taus = decision["used"]["memory"]["tau"].as_array().unwrap().len();
    assert_eq!(inputs, 2 * (1 + taus));
    let stat = fit("none", "static.json");
    let static_file = read_json(&d.join("static.json"));
    assert!(static_file["history"]["used"].is_null());
    // `auto` keeps what its present-input search chose: the static model's own parameters
    // (the demo fits its static model from them rather than searching twice).
    assert_eq!(tried[0]["params"], static_file["model"]["params"]);
    assert!(
        history <= 0.5 * stat,
        "held-out MAE with history {history:.4}, static {stat:.4}"
    );

    // `model --test` scored the test file as `predict` then did.
    let metrics = csv_rows(&d.join("rep_auto/metrics.csv"));
    let reported: f64 = metrics[0]["mae_mm"].parse().unwrap();
    assert!(
        (reported - history).abs() < 1e-9 * history.max(1.0),
        "report {reported}, predict {history}"
    );
    let report = std::fs::read_to_string(d.join("rep_auto/report.md")).unwrap();
    assert!(report.contains("Input history: ema:"), "{report}");
    assert!(report.contains("| present only |"), "{report}");

    // A file without the time column cannot be predicted; one without the group neither.
    let no_time = write(d, "no_time.csv", "P1_kpa,P2_kpa\n1,2\n3,4\n");
    let e = handcap_err(
        d,
        &[
            "predict",
            "model.json",
            no_time.to_str().unwrap(),
            "--out",
            "p.csv",
        ],
    );
    assert!(
        e.contains("no column `t_s`, which the model's input history needs as its time"),
        "{e}"
    );
    write(d, "no_group.csv", "t_s,P1_kpa,P2_kpa\n0,1,2\n0.1,3,4\n");
    let e = handcap_err(
        d,
        &["predict", "model.json", "no_group.csv", "--out", "p.csv"],
    );
    assert!(e.contains("no column `trial`"), "{e}");
    assert!(!d.join("p.csv").exists());

    // The inverse plans on the steady state, and says so; the target is the plant's settled
    // tip at (120, 80) kPa.
    let target = settled([120.0, 80.0]);
    let out = handcap(
        d,
        &[
            "inverse",
            "model.json",
            "--target",
            &format!("{},{}", target[0], target[1]),
            "--reach",
            "0.05",
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("once settled"));
}

/// The screen of `auto`'s ladders ranks them by the plant's lag: of the same log's pressures
/// through a lag of 0.15 s and one of 1.5 s, the slow plant's best-screened ladder starts at a
/// longer time constant than the fast one's, and each plant's best ladder scores better than
/// its present inputs.
#[test]
fn the_ladder_screen_follows_the_plants_lag() {
    let dir = tempdir();
    let d = dir.path();
    let screened = |lag_s: f64| -> (f64, f64, f64) {
        let name = format!("lag_{lag_s}");
        write(
            d,
            &format!("{name}.csv"),
            &lagging_plant_of(lag_s, 3, 4, 100),
        );
        let mut args = vec!["model".to_string(), format!("{name}.csv")];
        args.extend(COLUMNS.map(String::from));
        args.extend(
            [
                "--time",
                "t_s",
                "--group-by",
                "trial",
                "--budget",
                "30",
                "--model",
                "msvr",
            ]
            .map(String::from),
        );
        args.extend(["--out".to_string(), format!("{name}.json")]);
        handcap_ok(d, &args.iter().map(String::as_str).collect::<Vec<_>>());
        let decision = &read_json(&d.join(format!("{name}.json")))["history"];
        let best = lowest_fitness(&decision["screened"]);
        let first_tau = best["memory"]["tau"][0].as_f64().unwrap();
        let present = decision["tried"][0]["fitness"].as_f64().unwrap();
        eprintln!(
            "ladder screen, lag {lag_s} s: best ladder {} ({}), present inputs {present}",
            best["memory"]["tau"], best["fitness"]
        );
        (first_tau, best["fitness"].as_f64().unwrap(), present)
    };
    let (fast_tau, fast_best, fast_present) = screened(0.15);
    let (slow_tau, slow_best, slow_present) = screened(1.5);
    assert!(
        slow_tau > fast_tau,
        "slow plant's ladder from {slow_tau} s, fast's from {fast_tau} s"
    );
    assert!(fast_best < fast_present && slow_best < slow_present);
}

#[test]
fn a_plant_without_lag_keeps_its_static_model() {
    // The virtual micro-hand's designed grid, visited in order and settled at every step.
    let dir = tempdir();
    let d = dir.path();
    handcap_ok(d, &["synth", "--out", "syn", "--no-images"]);
    let grid = std::fs::read_to_string(d.join("syn/train.csv")).unwrap();
    let mut lines = grid.lines();
    let mut timed = format!("step,{}\n", lines.next().unwrap());
    for (k, line) in lines.enumerate() {
        let _ = writeln!(timed, "{k},{line}");
    }
    write(d, "timed.csv", &timed);
    // The default budget: the present inputs' reference search has half of it.
    let said = handcap_ok(
        d,
        &["model", "timed.csv", "--time", "step", "--out", "m.json"],
    );
    let with_time = read_json(&d.join("m.json"));
    let decision = &with_time["history"];
    assert!(decision["used"].is_null(), "{decision}");
    assert!(
        decision["reason"]
            .as_str()
            .unwrap()
            .contains("the present inputs alone"),
        "{decision}"
    );
    // Kept, they are searched again with the whole budget: the model `model` gives without
    // the time column, to the bit.
    assert!(
        said.contains("searched again with the whole budget"),
        "{said}"
    );
    handcap_ok(d, &["model", "timed.csv", "--out", "s.json"]);
    let alone = read_json(&d.join("s.json"));
    for key in ["params", "support_vectors", "coefficients", "bias"] {
        assert_eq!(with_time["model"][key], alone["model"][key], "{key}");
    }
    assert_eq!(
        with_time["search"]["evaluations"],
        alone["search"]["evaluations"]
    );
}

#[test]
fn the_steady_state_jacobian_sums_the_copies() {
    let history = History {
        time: "t".into(),
        group: None,
        inputs: vec!["a".into(), "b".into()],
        memory: Memory::Ema {
            tau: vec![0.5, 2.0],
        },
    };
    let mut rng = Lcg(9);
    let n = 120;
    let raw = Columns::new(history.inputs.clone(), rng.vec(2 * n));
    let series = Series {
        time: (0..n).map(|i| i as f64 * 0.3).collect(),
        group: None,
    };
    let features = history.features(&raw, &series).unwrap();
    let y: Vec<f64> = features
        .iter_rows()
        .flat_map(|r| [r[0] + (2.0 * r[3]).sin(), r[1] * r[4] - r[5]])
        .collect();
    let data = Dataset {
        source: "lag".into(),
        inputs: features,
        outputs: Columns::new(vec!["y1".into(), "y2".into()], y),
        weights: None,
    };
    let fitted = ModelSpec::Msvr(MsvrParams::new(100.0, 0.01, 0.8).loss(Loss::Robust))
        .fit(&data)
        .unwrap();
    let steady = SteadyState::new(fitted.differentiable(), Some(&history));
    assert_eq!(steady.inputs(), ["a", "b"]);
    let x = [0.4, 0.7];
    let (mut out, mut jac) = ([0.0; 2], [0.0; 4]);
    steady.predict_with_jacobian(&x, &mut out, &mut jac);
    let mut direct = [0.0; 2];
    fitted
        .predictor()
        .predict_row(&[0.4, 0.7, 0.4, 0.7, 0.4, 0.7], &mut direct);
    for (a, b) in out.iter().zip(direct) {
        assert!(
            (a - b).abs() < 1e-12 * (1.0 + b.abs()),
            "{out:?} {direct:?}"
        );
    }
    let h = 1e-6;
    for j in 0..2 {
        let (mut up, mut down) = (x, x);
        up[j] += h;
        down[j] -= h;
        let (mut yu, mut yd) = ([0.0; 2], [0.0; 2]);
        steady.predict_row(&up, &mut yu);
        steady.predict_row(&down, &mut yd);
        for i in 0..2 {
            let fd = (yu[i] - yd[i]) / (2.0 * h);
            assert!(
                (fd - jac[i * 2 + j]).abs() < 1e-5 * (1.0 + fd.abs()),
                "∂y{i}/∂x{j}: analytic {}, central difference {fd}",
                jac[i * 2 + j]
            );
        }
    }
}

#[test]
fn bad_time_columns_get_one_line_naming_the_row() {
    let dir = tempdir();
    let d = dir.path();
    let mut rows = String::from("trial,t_s,P1_kpa,P2_kpa,x_mm,y_mm\n");
    for k in 0..30 {
        let _ = writeln!(
            rows,
            "{},{:.1},{},{},{},{}",
            k / 15,
            (k % 15) as f64 * 0.1,
            k,
            30 - k,
            k,
            2 * k
        );
    }
    let args = |file: &str, extra: &[&'static str]| -> Vec<String> {
        let mut a: Vec<String> = ["model", file].map(String::from).to_vec();
        a.extend(COLUMNS.map(String::from));
        a.extend(["--search", "none", "--out", "m.json"].map(String::from));
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let run_err = |file: &str, extra: &[&'static str]| {
        let a = args(file, extra);
        handcap_err(d, &a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    // Time repeats in trial 1 at its 4th row (file line 20).
    write(d, "repeat.csv", &rows.replacen("1,0.3,18", "1,0.2,18", 1));
    let e = run_err("repeat.csv", &["--time", "t_s", "--group-by", "trial"]);
    assert!(
        e.contains("repeat.csv line 20: time 0.2 repeats the previous row's 0.2 in group 1"),
        "{e}"
    );
    // Without the group, the second trial's clock goes back.
    let e = run_err("repeat.csv", &["--time", "t_s"]);
    assert!(
        e.contains("line 17: time 0 goes back from the previous row's 1.4"),
        "{e}"
    );
    // An empty time cell.
    write(d, "empty.csv", &rows.replacen("0,0.5,5", "0,,5", 1));
    let e = run_err("empty.csv", &["--time", "t_s", "--group-by", "trial"]);
    assert!(e.contains("line 7, column `t_s`"), "{e}");
    // More lags than a trial has rows.
    write(d, "ok.csv", &rows);
    let e = run_err(
        "ok.csv",
        &[
            "--time",
            "t_s",
            "--group-by",
            "trial",
            "--history",
            "lags:20",
        ],
    );
    assert!(
        e.contains("group 0: 15 rows, but lags:20 needs at least 21 per group"),
        "{e}"
    );
    // A history without a time column is a usage error.
    let a = args("ok.csv", &["--history", "ema:1"]);
    let e = handcap_usage(d, &a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(e.contains("give --time COLUMN"), "{e}");
    assert!(!d.join("m.json").exists());
}
