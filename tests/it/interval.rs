//! Prediction intervals (issue 29): conformal radii from held-out residuals cover fresh rows at
//! their level, widen off the training rows (issue 62), `predict --interval` and `inverse`
//! carry them, and levels they cannot honour are refused.

use std::fmt::Write as _;

use crate::common::{csv_rows, handcap, handcap_err, handcap_ok, read_json, tempdir, write, Lcg};

/// Standard deviation of the plant's Gaussian noise on each output (mm).
const NOISE: f64 = 0.5;
/// ‖e‖'s 90 % and 95 % quantiles for e ~ N(0, NOISE² I₃): NOISE·√χ²₃(level).
const NOISE_QUANTILES: [(f64, f64); 2] = [(0.9, 2.5003 * NOISE), (0.95, 2.7955 * NOISE)];

/// `trials` runs of `rows` rows: two pressures at random in [0, 200] kPa, three smooth outputs
/// plus independent Gaussian noise of [`NOISE`]. Columns: trial, P1_kpa, P2_kpa, x_mm, y_mm, z_mm.
fn noisy_plant(seed: u64, first_trial: usize, trials: usize, rows: usize) -> String {
    let mut rng = Lcg(seed);
    let mut csv = String::from("trial,P1_kpa,P2_kpa,x_mm,y_mm,z_mm\n");
    for trial in first_trial..first_trial + trials {
        for _ in 0..rows {
            let p = [200.0 * rng.next(), 200.0 * rng.next()];
            let f = [
                5.0 * (p[0] / 80.0).sin() + 0.02 * p[1],
                4.0 * (p[1] / 90.0).cos() - 0.01 * p[0],
                0.0001 * p[0] * p[1],
            ];
            let _ = write!(csv, "{trial},{:.4},{:.4}", p[0], p[1]);
            for v in f {
                let _ = write!(csv, ",{:.6}", v + NOISE * normal(&mut rng));
            }
            csv.push('\n');
        }
    }
    csv
}

/// A standard normal draw (Box-Muller).
fn normal(rng: &mut Lcg) -> f64 {
    let (u, v) = (rng.next().max(1e-300), rng.next());
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

const COLUMNS: [&str; 4] = ["--inputs", "P1_kpa,P2_kpa", "--outputs", "x_mm,y_mm,z_mm"];

/// `handcap model train.csv` searching `budget` candidates on folds of whole trials, tested on
/// `test`: model.json and the report in rep/.
fn fit_by_trial<'a>(budget: &'a str, test: &'a str) -> Vec<&'a str> {
    let mut args = vec!["model", "train.csv"];
    args.extend(COLUMNS);
    args.extend([
        "--folds-by",
        "trial",
        "--budget",
        budget,
        "--test",
        test,
        "--out",
        "model.json",
        "--report",
        "rep",
    ]);
    args
}

/// The model file's radius at `level`.
fn radius(model: &serde_json::Value, level: f64) -> f64 {
    model["intervals"]["radii"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["level"].as_f64() == Some(level))
        .unwrap()["radius"]
        .as_f64()
        .unwrap()
}

#[test]
fn intervals_cover_fresh_rows_at_their_level_and_predict_writes_the_radius() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &noisy_plant(1, 0, 8, 60));
    write(d, "test.csv", &noisy_plant(2, 100, 6, 200));
    let log = handcap_ok(d, &fit_by_trial("40", "test.csv"));
    assert!(log.contains("prediction intervals: 90 %"), "{log}");
    let model = read_json(&d.join("model.json"));
    let intervals = &model["intervals"];
    assert_eq!(intervals["rows"], 480);
    assert_eq!(intervals["folds"]["scheme"], "groups");
    assert_eq!(intervals["scores"].as_array().unwrap().len(), 480);
    // Every held-out trial is listed with its coverage.
    assert_eq!(intervals["groups"].as_array().unwrap().len(), 8);
    // The radius is the noise's own quantile, widened a little by the model's error.
    for (level, noise_only) in NOISE_QUANTILES {
        let r = radius(&model, level);
        assert!(
            r > 0.95 * noise_only && r < 1.3 * noise_only,
            "{level}: radius {r}, the noise alone {noise_only}"
        );
    }

    // The test file: pooled coverage near each level, every trial listed.
    let report = read_json(&d.join("rep/fit.json"));
    let test = &report["intervals"]["tests"][0];
    assert_eq!(test["column"], "trial");
    for (k, (level, _)) in NOISE_QUANTILES.iter().enumerate() {
        let covered = test["pooled"][k][1].as_f64().unwrap();
        assert!(
            (covered - level).abs() < 0.04,
            "{level}: {covered} of the test rows covered"
        );
    }
    assert_eq!(test["groups"].as_array().unwrap().len(), 6);
    let md = std::fs::read_to_string(d.join("rep/report.md")).unwrap();
    assert!(md.contains("## Prediction intervals"), "{md}");
    assert!(md.contains("marginal"), "{md}");

    // `predict --interval` writes the radius beside each prediction; its coverage is the
    // report's.
    let out = handcap_ok(
        d,
        &[
            "predict",
            "model.json",
            "test.csv",
            "--out",
            "pred.csv",
            "--interval",
            "0.9",
        ],
    );
    assert!(out.contains("interval radius"), "{out}");
    let (pred, truth) = (csv_rows(&d.join("pred.csv")), csv_rows(&d.join("test.csv")));
    let r90 = radius(&model, 0.9);
    let (mut covered, mut at_r90) = (0, 0);
    for (p, t) in pred.iter().zip(&truth) {
        // The file's radius where the inputs are as near the training rows as most held-out
        // rows were; wider elsewhere.
        let r: f64 = p["interval_radius"].parse().unwrap();
        assert!(r >= r90 * (1.0 - 1e-12), "{r} against {r90}");
        at_r90 += usize::from(r <= r90 * (1.0 + 1e-12));
        let e: f64 = ["x_mm", "y_mm", "z_mm"]
            .iter()
            .map(|c| (p[*c].parse::<f64>().unwrap() - t[*c].parse::<f64>().unwrap()).powi(2))
            .sum::<f64>()
            .sqrt();
        covered += usize::from(e <= r);
    }
    assert!(
        at_r90 > pred.len() * 8 / 10,
        "{at_r90} of {} rows",
        pred.len()
    );
    let share = covered as f64 / pred.len() as f64;
    let reported = test["pooled"][0][1].as_f64().unwrap();
    assert!(
        (share - reported).abs() < 1e-9,
        "{share} against {reported}"
    );

    // Inputs beyond the training box: the radius widens, and the line says so.
    write(d, "far.csv", "P1_kpa,P2_kpa\n100,100\n320,100\n400,400\n");
    let out = handcap_ok(
        d,
        &[
            "predict",
            "model.json",
            "far.csv",
            "--out",
            "far_pred.csv",
            "--interval",
            "0.9",
        ],
    );
    assert!(out.contains("wider on 2 of 3 rows"), "{out}");
    let far: Vec<f64> = csv_rows(&d.join("far_pred.csv"))
        .iter()
        .map(|p| p["interval_radius"].parse().unwrap())
        .collect();
    assert_eq!(far[0], r90);
    assert!(
        far[1] > 1.5 * r90 && far[2] > far[1],
        "{far:?} against {r90}"
    );

    // A file written before the widening: the same radius for every row.
    let mut old = model.clone();
    old["intervals"].as_object_mut().unwrap().remove("widening");
    write(d, "old.json", &old.to_string());
    let out = handcap_ok(
        d,
        &[
            "predict",
            "old.json",
            "far.csv",
            "--out",
            "old_pred.csv",
            "--interval",
            "0.9",
        ],
    );
    assert!(out.contains("the same for every row"), "{out}");
    for p in csv_rows(&d.join("old_pred.csv")) {
        assert_eq!(p["interval_radius"].parse::<f64>().unwrap(), r90);
    }

    // Inverse: each planned tip carries the radius.
    write(d, "targets.csv", "x_mm,y_mm,z_mm\n2.0,3.0,1.0\n");
    handcap_ok(
        d,
        &[
            "inverse",
            "model.json",
            "--targets",
            "targets.csv",
            "--out",
            "plan.csv",
        ],
    );
    let plan = csv_rows(&d.join("plan.csv"));
    let r: f64 = plan[0]["interval_radius"].parse().unwrap();
    assert!(
        r >= r90 * (1.0 - 1e-12) && r < 2.0 * r90,
        "{r} against {r90}"
    );
}

#[test]
fn levels_an_interval_cannot_honour_are_refused_never_a_radius_of_zero() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "small.csv", &noisy_plant(3, 0, 1, 15));
    let mut args = vec!["model", "small.csv"];
    args.extend(COLUMNS);
    args.extend([
        "--folds-by",
        "shuffle",
        "--budget",
        "16",
        "--out",
        "small.json",
    ]);
    handcap_ok(d, &args);
    // 15 held-out rows: a 90 % radius (needs 9), not a 95 % one (needs 19).
    let base = ["predict", "small.json", "small.csv", "--out", "p.csv"];
    let with = |level: &'static str| [&base[..], &["--interval", level]].concat();
    handcap_ok(d, &with("0.9"));
    let err = handcap_err(d, &with("0.95"));
    assert!(err.contains("at least 19 held-out rows"), "{err}");
    assert!(err.contains("has 15"), "{err}");
    for bad in ["1.5", "0", "-0.1", "nan"] {
        let out = handcap(d, &with(bad));
        assert_eq!(out.status.code(), Some(2), "{bad}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--interval"), "{bad}: {err}");
    }
    // Scored on the training data: no held-out rows, no intervals.
    let mut args = vec!["model", "small.csv"];
    args.extend(COLUMNS);
    args.extend([
        "--fitness",
        "train",
        "--budget",
        "16",
        "--out",
        "train.json",
    ]);
    let log = handcap_ok(d, &args);
    assert!(log.contains("prediction intervals: none"), "{log}");
    let err = handcap_err(
        d,
        &[
            "predict",
            "train.json",
            "small.csv",
            "--out",
            "q.csv",
            "--interval",
            "0.9",
        ],
    );
    assert!(err.contains("no prediction intervals"), "{err}");
    assert!(!d.join("q.csv").exists());
}

/// Runs of a drifting actuator: `noisy_plant`'s map, shifted by 0.03 mm per run along x.
fn drifting_plant(seed: u64, first_trial: usize, trials: usize, rows: usize) -> String {
    let text = noisy_plant(seed, first_trial, trials, rows);
    let mut lines = text.lines();
    let mut csv = format!("{}\n", lines.next().unwrap());
    for line in lines {
        let mut cells: Vec<String> = line.split(',').map(String::from).collect();
        let trial: f64 = cells[0].parse().unwrap();
        let x: f64 = cells[3].parse().unwrap();
        cells[3] = format!("{:.6}", x + 0.03 * trial);
        csv += &(cells.join(",") + "\n");
    }
    csv
}

#[test]
fn runs_get_intervals_from_blocks_of_consecutive_runs_and_a_band_for_whole_runs() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &drifting_plant(3, 0, 20, 30));
    write(d, "later.csv", &drifting_plant(4, 20, 6, 40));
    handcap_ok(d, &fit_by_trial("30", "later.csv"));
    let model = read_json(&d.join("model.json"));
    let intervals = &model["intervals"];
    // The search dealt whole runs at random; the intervals' folds are blocks of runs.
    assert_eq!(model["search"]["folds"]["scheme"], "groups");
    let reason = intervals["folds"]["reason"].as_str().unwrap();
    assert!(
        reason.contains("each fold a block of consecutive runs"),
        "{reason}"
    );
    // The band: each of the 20 runs' worst error, ascending, at its conformal rank (the 19th
    // of 20 at 90 %, the 20th at 95 %).
    let worst: Vec<f64> = intervals["runs"]["worst"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(worst.len(), 20);
    assert!(worst.windows(2).all(|w| w[0] <= w[1]));
    let band = &intervals["runs"]["radii"];
    assert_eq!(band[0]["radius"].as_f64().unwrap(), worst[18]);
    assert_eq!(band[1]["radius"].as_f64().unwrap(), worst[19]);
    // A run's worst error exceeds most rows' error: the band is wider than the row radius.
    assert!(band[0]["radius"].as_f64().unwrap() > radius(&model, 0.9));

    // On the six later runs, the rows' coverage holds its level and whole runs stay in the band.
    let report = read_json(&d.join("rep/fit.json"));
    let test = &report["intervals"]["tests"][0];
    let covered = test["pooled"][0][1].as_f64().unwrap();
    assert!(
        covered > 0.85,
        "{covered} of the later runs' rows within the 90 % radius"
    );
    let runs = &test["runs"][0];
    assert_eq!(runs["runs"], 6);
    assert!(runs["inside"].as_u64().unwrap() >= 5, "{runs}");
    let md = std::fs::read_to_string(d.join("rep/report.md")).unwrap();
    assert!(
        md.contains("Per-run band, from the worst error of each of the 20 held-out runs"),
        "{md}"
    );
    assert!(md.contains("whole runs inside the 90.0 % band"), "{md}");
}
