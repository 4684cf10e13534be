//! The inverse model from the command line, and the demo end to end at reduced size, its
//! numbers checked against the virtual plant's truth.

use std::path::Path;

use handcap::synth::plant::Plant;

use crate::common::{
    csv_rows, every_core, handcap_err, handcap_ok, handcap_usage, read_json, tempdir,
    tip_rms_against_truth, write,
};

#[test]
fn inverse_finds_pressures_for_reachable_targets_and_says_what_is_out_of_reach() {
    let dir = tempdir();
    let d = dir.path();
    handcap_ok(d, &["synth", "--out", "data", "--no-images", "--seed", "4"]);
    handcap_ok(
        d,
        &[
            "model",
            "data/train.csv",
            "--search",
            "aco-paper",
            "--ants",
            "6",
            "--max-iter",
            "3",
        ],
    );
    // A measured tip of the training data is reachable: the model's tip lands on it.
    let row = &csv_rows(&d.join("data/train.csv"))[86]; // P = 100, 100, 100 kPa
    let target = format!("{},{},{}", row["x_mm"], row["y_mm"], row["z_mm"]);
    let out = handcap_ok(d, &["inverse", "model.json", "--target", &target]);
    assert!(out.starts_with("P1_kpa "), "{out}");
    let error: f64 = out
        .split("(error ")
        .nth(1)
        .and_then(|s| s.split(')').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no error in {out}"));
    assert!(error <= 0.01, "{out}");
    // With the model's 90 % interval around the planned tip.
    assert!(
        out.contains("within") && out.contains("90 % of the time"),
        "{out}"
    );
    // 60 mm sideways is out of reach: one line with the nearest point.
    let msg = handcap_err(d, &["inverse", "model.json", "--target", "60,0,0"]);
    assert!(
        msg.contains("out of reach") && msg.contains("nearest reachable point"),
        "{msg}"
    );
    // A file of targets: each row answered, the unreachable one marked.
    write(
        d,
        "targets.csv",
        &format!("x_mm,y_mm,z_mm\n{target}\n60,0,0\n0,0,0\n"),
    );
    let out = handcap_ok(
        d,
        &[
            "inverse",
            "model.json",
            "--targets",
            "targets.csv",
            "--out",
            "planned.csv",
            "--max-kpa",
            "200",
        ],
    );
    assert!(out.contains("3 targets: 2 reached"), "{out}");
    let planned = csv_rows(&d.join("planned.csv"));
    let reached: Vec<&str> = planned.iter().map(|r| r["reached"].as_str()).collect();
    assert_eq!(reached, ["1", "0", "1"]);
    for r in &planned {
        for p in ["P1_kpa", "P2_kpa", "P3_kpa"] {
            let v: f64 = r[p].parse().unwrap();
            assert!((0.0..=200.0).contains(&v), "{p} {v} outside --max-kpa 200");
        }
    }
    let msg = handcap_usage(
        d,
        &[
            "inverse",
            "model.json",
            "--target",
            "1,2,3",
            "--max-kpa",
            "400",
        ],
    );
    assert!(msg.contains("300"), "{msg}");
    let msg = handcap_err(d, &["inverse", "model.json", "--target", "1,2"]);
    assert!(msg.contains("3 outputs"), "{msg}");
}

/// What a demo's numbers must reach against its truth.
struct Bars {
    /// MSVR's MAE on each test sweep at least this many times lower than the previous model's
    /// with default constants.
    over_default: f64,
    /// MSVR's MAE on each test sweep at most this times the calibrated previous model's.
    over_calibrated: f64,
    /// The mean distance of the planned pressures' tips (through the plant) from their
    /// targets (mm).
    inverse_mean_mm: f64,
    /// The share of each sweep's rows within the 90 % interval, at least.
    sweep_coverage: f64,
}

/// Checks the demo in `demo` against the virtual capture's truth: no pressure step lost but
/// to an occlusion the truth records (a step is lost only when one of its frames is hidden),
/// the model against the previous one on the sweeps (the paper's claim), the 90 % interval on
/// the sweeps, and the inverse's plant error.
fn demo_holds_against_truth(demo: &Path, bars: &Bars) {
    let truth = csv_rows(&demo.join("capture/truth/frames.csv"));
    let occluded: std::collections::HashSet<&str> = truth
        .iter()
        .filter(|r| r["occluded"] == "1")
        .map(|r| r["step"].as_str())
        .collect();
    let logged = csv_rows(&demo.join("capture/pressures.csv"));
    let rows = csv_rows(&demo.join("triangulated/dataset.csv"));
    let kept: std::collections::HashSet<&str> = rows
        .iter()
        .filter(|r| r["flag"].is_empty())
        .map(|r| r["step"].as_str())
        .collect();
    let lost: Vec<&str> = logged
        .iter()
        .map(|r| r["step"].as_str())
        .filter(|s| !kept.contains(s))
        .collect();
    let unexplained: Vec<&&str> = lost.iter().filter(|s| !occluded.contains(**s)).collect();
    assert!(
        unexplained.is_empty(),
        "{} of {} steps lost, {} of them with no frame hidden: {unexplained:?}",
        lost.len(),
        logged.len(),
        unexplained.len()
    );
    assert!(
        lost.len() * 20 <= logged.len(),
        "{} of {} steps lost",
        lost.len(),
        logged.len()
    );
    for sweep in ["sweep_a", "sweep_b"] {
        let [msvr, auto, default, calibrated] = sweep_errors_against_truth(demo, sweep);
        // The paper's MSVR, and beside it `handcap model`'s default pick, each against the
        // previous model.
        for (name, mae) in [("MSVR", msvr), ("auto's pick", auto)] {
            assert!(
                mae * bars.over_default <= default && mae <= bars.over_calibrated * calibrated,
                "{sweep} against the truth: {name} {mae}, previous model {default}, calibrated {calibrated}"
            );
        }
    }
    let summary: serde_json::Value = read_json(&demo.join("summary.json"));
    let tests = summary["intervals"][0]["tests"].as_array().unwrap();
    for t in tests {
        let covered = t["pooled"][0][1].as_f64().unwrap();
        assert!(covered >= bars.sweep_coverage, "{t}");
    }
    let planned = csv_rows(&demo.join("inverse_check.csv"));
    let inverse_mean = mean(&planned, "plant_error_mm");
    assert!(
        inverse_mean <= bars.inverse_mean_mm,
        "the inverse's plant error {inverse_mean} mm"
    );
}

/// The mean absolute error (mm, over the rows and x, y, z) on the demo's `sweep` against the
/// plant's truth at the sweep's pressures (`capture/truth/tips.csv`), of MSVR (`model.json`)
/// and of `auto`'s pick (`model_auto.json`), each through `handcap predict`, and of the
/// previous model with the default and the calibrated constants `model/fit.json` records:
/// recomputed here, not read from the pipeline's summary (issue 61).
fn sweep_errors_against_truth(demo: &Path, sweep: &str) -> [f64; 4] {
    use handcap::model::previous::PreviousParams;
    let truth: Vec<_> = csv_rows(&demo.join("capture/truth/tips.csv"))
        .into_iter()
        .filter(|r| r["phase"] == sweep)
        .collect();
    assert!(!truth.is_empty(), "no {sweep} in the truth");
    let columns = ["P1_kpa", "P2_kpa", "P3_kpa", "x_mm", "y_mm", "z_mm"];
    let value =
        |r: &std::collections::HashMap<String, String>, k: &str| -> f64 { r[k].parse().unwrap() };
    let mut csv = columns.join(",") + "\n";
    for r in &truth {
        let row: Vec<String> = columns.iter().map(|k| r[*k].clone()).collect();
        csv += &(row.join(",") + "\n");
    }
    let dir = demo.parent().unwrap();
    let at = format!("truth_{sweep}.csv");
    write(dir, &at, &csv);
    let predict = |model: &str| -> Vec<[f64; 3]> {
        let (model, predicted) = (demo.join(model), format!("predicted_{sweep}.csv"));
        handcap_ok(
            dir,
            &["predict", model.to_str().unwrap(), &at, "--out", &predicted],
        );
        csv_rows(&dir.join(&predicted))
            .iter()
            .map(|r| ["x_mm", "y_mm", "z_mm"].map(|k| value(r, k)))
            .collect()
    };
    let fit: serde_json::Value = read_json(&demo.join("model/fit.json"));
    let previous = |which: &str| -> Vec<[f64; 3]> {
        let params: PreviousParams =
            serde_json::from_value(fit["previous"][which].clone()).unwrap();
        truth
            .iter()
            .map(|r| params.tip(["P1_kpa", "P2_kpa", "P3_kpa"].map(|k| value(r, k))))
            .collect()
    };
    let mae = |tips: &[[f64; 3]]| -> f64 {
        assert_eq!(tips.len(), truth.len());
        let sum: f64 = tips
            .iter()
            .zip(&truth)
            .map(|(tip, r)| {
                (0..3)
                    .map(|o| (tip[o] - value(r, columns[3 + o])).abs())
                    .sum::<f64>()
            })
            .sum();
        sum / (3 * truth.len()) as f64
    };
    [
        mae(&predict("model.json")),
        mae(&predict("model_auto.json")),
        mae(&previous("default")),
        mae(&previous("calibrated")),
    ]
}

/// The demo as a user runs it, all defaults: a 25 kPa grid of 1331 steps filmed with one or
/// two frames per camera and step. Its numbers hold against the truth: every step triangulated
/// but those an occlusion hid, MSVR ten times better than the previous model and no worse than
/// it calibrated, the 90 % interval holding on the sweeps and feed-forward within 0.1 mm.
#[test]
fn the_default_demo_loses_no_step_and_its_numbers_hold_against_the_truth() {
    let _cores = every_core();
    let dir = tempdir();
    let d = dir.path();
    handcap_ok(d, &["demo", "--out", "demo"]);
    demo_holds_against_truth(
        &d.join("demo"),
        &Bars {
            over_default: 10.0,
            over_calibrated: 1.0,
            inverse_mean_mm: 0.1,
            sweep_coverage: 0.7,
        },
    );
    // The finger in motion, on webcam (JPEG 4:2:0) frames: the bars (the per-frame tip
    // measured 0.0466 mm).
    dynamic_holds_against_truth(
        &d.join("demo"),
        &DynamicBars {
            tip_rms_mm: 0.05,
            history_over_static: 2.0,
            history_over_truth: 1.5,
        },
    );
}

/// What the demo's dynamic part must reach.
struct DynamicBars {
    /// RMS of the unflagged per-frame tips against the truth at their instants (mm).
    tip_rms_mm: f64,
    /// The history model's held-out error at least this many times lower than the static one's.
    history_over_static: f64,
    /// The history model from the triangulated rows at most this times the one from the truth.
    history_over_truth: f64,
}

/// The dynamic part's summary against its files and the truth: the per-frame tips recomputed
/// from `dynamic/dataset.csv` and `truth/per_frame.csv` by frame, at least 95 % of the frames
/// giving an unflagged row; the clock offset (the second camera's) against the one the
/// capture's stamps hold; the
/// models' held-out errors against `bars`.
fn dynamic_holds_against_truth(demo: &Path, bars: &DynamicBars) {
    let summary: serde_json::Value = read_json(&demo.join("summary.json"));
    let dy = &summary["dynamic"];
    let dir = demo.join("dynamic");
    let truth: std::collections::HashMap<String, std::collections::HashMap<String, String>> =
        csv_rows(&dir.join("capture/truth/per_frame.csv"))
            .into_iter()
            .map(|r| (r["frame"].clone(), r))
            .collect();
    let rows = csv_rows(&dir.join("dataset.csv"));
    let mut squares = Vec::new();
    for r in rows.iter().filter(|r| r["flag"].is_empty()) {
        let t = &truth[&r["frame"]];
        let d2: f64 = ["x_mm", "y_mm", "z_mm"]
            .iter()
            .map(|k| (r[*k].parse::<f64>().unwrap() - t[*k].parse::<f64>().unwrap()).powi(2))
            .sum();
        squares.push(d2);
    }
    let rms = (squares.iter().sum::<f64>() / squares.len() as f64).sqrt();
    assert_eq!(rows.len(), dy["rows"].as_u64().unwrap() as usize);
    assert_eq!(squares.len(), dy["unflagged"].as_u64().unwrap() as usize);
    assert!(
        squares.len() as f64 >= 0.95 * rows.len() as f64,
        "{} of {}",
        squares.len(),
        rows.len()
    );
    assert!(
        (rms - dy["tip_rms_mm"].as_f64().unwrap()).abs() < 1e-9,
        "{rms} vs {dy}"
    );
    assert!(rms <= bars.tip_rms_mm, "per-frame tip RMS {rms} mm");
    // The right camera's stamps run ahead of the left's by what the capture added to each
    // exposure (offset and jitter, on average): the motion told it within 1 ms.
    let exposure: std::collections::HashMap<(String, String), f64> =
        csv_rows(&dir.join("capture/truth/frames.csv"))
            .into_iter()
            .map(|r| {
                (
                    (r["camera"].clone(), r["frame"].clone()),
                    r["exposure_s"].parse().unwrap(),
                )
            })
            .collect();
    // With more cameras, the second camera's (cam2) against the first's.
    let mut lead = [Vec::new(), Vec::new()];
    for r in csv_rows(&dir.join("capture/frames/frames.csv")) {
        let Some(k) = [["left", "cam1"], ["right", "cam2"]]
            .iter()
            .position(|names| names.contains(&r["camera"].as_str()))
        else {
            continue;
        };
        let stamp: f64 = r["time_s"].parse().unwrap();
        lead[k].push(stamp - exposure[&(r["camera"].clone(), r["frame"].clone())]);
    }
    let avg = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    let offset_ms = 1e3 * (avg(&lead[1]) - avg(&lead[0]));
    let measured = dy["clock_offset_ms"].as_f64().unwrap();
    assert!(
        (measured - offset_ms).abs() < 1.0,
        "offset {measured} ms, truth {offset_ms} ms"
    );
    // History against static on the held-out trial, and the camera path's cost.
    let euclid = |k: usize| dy["scores"][k]["errors"]["euclid"].as_f64().unwrap();
    let (fixed, history, truth_history) = (euclid(0), euclid(1), euclid(2));
    assert!(
        fixed >= bars.history_over_static * history,
        "static {fixed} mm, history {history} mm"
    );
    assert!(
        history <= bars.history_over_truth * truth_history,
        "history {history} mm from the frames, {truth_history} mm from the truth"
    );
    for axis in ["x", "y"] {
        assert!(dir.join(format!("trajectory_{axis}_mm.svg")).is_file());
    }
}

/// Mean of a column.
fn mean(rows: &[std::collections::HashMap<String, String>], column: &str) -> f64 {
    rows.iter()
        .map(|r| r[column].parse::<f64>().unwrap())
        .sum::<f64>()
        / rows.len() as f64
}

#[test]
fn the_quick_demo_runs_end_to_end_and_its_numbers_hold_against_the_truth() {
    let _cores = every_core();
    let dir = tempdir();
    let d = dir.path();
    let out = handcap_ok(d, &["demo", "--out", "demo", "--quick", "--format", "png"]);
    for stage in [
        "[1/7] synth",
        "[2/7] calibrate",
        "[3/7] triangulate",
        "[4/7] model",
        "[5/7] inverse",
        "[6/7] dynamic",
        "[7/7] report",
    ] {
        assert!(out.contains(stage), "{stage} missing: {out}");
    }
    let demo = d.join("demo");
    let summary: serde_json::Value = read_json(&demo.join("summary.json"));

    // Calibration against the true rig (the tolerances).
    let c = &summary["calibration"];
    assert!(c["rms_px"].as_f64().unwrap() <= 0.3, "{c}");
    assert!(c["intrinsics_error_pct"].as_f64().unwrap() < 0.5, "{c}");
    assert!(c["baseline_error_pct"].as_f64().unwrap() < 0.5, "{c}");
    assert!(c["rotation_error_deg"].as_f64().unwrap() < 0.1, "{c}");
    assert!(c["hand_axes_error_deg"].as_f64().unwrap() < 0.1, "{c}");

    // The triangulated dataset against the truth, recomputed from the files.
    let (rms, n) = tip_rms_against_truth(
        &demo.join("triangulated/dataset.csv"),
        &demo.join("capture/truth/tips.csv"),
        |_| true,
    );
    assert_eq!(n, 39);
    assert!(rms <= 0.1, "tip RMS error {rms} mm");
    let all = summary["triangulation"].as_array().unwrap().last().unwrap();
    assert!(
        (all["rms_mm"].as_f64().unwrap() - rms).abs() < 1e-4,
        "{all} vs {rms}"
    );
    // The error every row shares (the rest position's own, mostly) is reported, and the
    // lab's occlusions (recorded) cost no step with three frames per camera and step.
    let shared: Vec<f64> = all["mean_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        shared.iter().map(|v| v * v).sum::<f64>().sqrt() <= rms,
        "{shared:?}"
    );
    assert_eq!(summary["realism"]["occluded"].as_f64(), Some(0.01));
    let html = std::fs::read_to_string(demo.join("report/index.html")).unwrap();
    assert!(html.contains("Every step has a tip."));

    demo_holds_against_truth(
        &demo,
        &Bars {
            over_default: 5.0,
            over_calibrated: 1.1,
            inverse_mean_mm: 1.0,
            sweep_coverage: 0.5,
        },
    );
    // The full demo's dynamic session (two trials of 8 s to train on) with a smaller search
    // budget: the bars for history (measured 4.7× and 0.99×); on PNG frames the
    // per-frame tip is as good as a settled one (0.011 mm).
    dynamic_holds_against_truth(
        &demo,
        &DynamicBars {
            tip_rms_mm: 0.03,
            history_over_static: 2.0,
            history_over_truth: 1.5,
        },
    );

    // Feed-forward: the planned pressures, run through the plant again here, land where the
    // check says, and the mean error is the summary's.
    let rows = csv_rows(&demo.join("inverse_check.csv"));
    assert_eq!(rows.len(), 20);
    let plant = Plant::default();
    for r in &rows {
        let p = |k: &str| r[k].parse::<f64>().unwrap();
        let planned = [p("P1_kpa"), p("P2_kpa"), p("P3_kpa")];
        assert!(planned.iter().all(|v| (0.0..=250.0).contains(v)), "{r:?}");
        let tip = plant.tip(planned).unwrap();
        let target = [p("x_mm"), p("y_mm"), p("z_mm")];
        let error = (0..3)
            .map(|k| (tip[k] - target[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!((error - p("plant_error_mm")).abs() < 1e-3, "{r:?}: {error}");
        let source = plant
            .tip([p("source_P1_kpa"), p("source_P2_kpa"), p("source_P3_kpa")])
            .unwrap();
        assert!(
            (0..3).all(|k| (source[k] - target[k]).abs() < 1e-3),
            "{r:?}"
        );
    }
    let inverse = &summary["inverse"][0];
    assert!((inverse["mean_mm"].as_f64().unwrap() - mean(&rows, "plant_error_mm")).abs() < 1e-3);

    // One self-contained page with every section.
    for id in [
        "summary",
        "calibration",
        "detection",
        "triangulation",
        "aco",
        "sweeps",
        "errors",
        "inverse",
        "dynamic",
        "manifest",
    ] {
        assert!(
            html.contains(&format!("<h2 id=\"{id}\">")),
            "section {id} missing"
        );
    }
    assert!(!html.contains("missing</p>"), "a figure is missing");
    assert!(
        !html.contains("src=\"http") && !html.contains("href=\"http"),
        "external references"
    );
    assert!(html.matches("data:image/png;base64,").count() >= 2);
    assert!(html.matches("<svg").count() >= 10);
    assert!(Path::new(&demo.join("model.json")).is_file());

    // Issue 44, item 12: the same seed gives the same bytes, but for the stage times (in
    // timings.json and the report's page).
    std::fs::rename(&demo, d.join("first")).unwrap();
    handcap_ok(d, &["demo", "--out", "demo", "--quick", "--format", "png"]);
    let mut compared = 0;
    for entry in walkdir(&d.join("first")) {
        let relative = entry.strip_prefix(d.join("first")).unwrap();
        if relative == Path::new("timings.json") || relative == Path::new("report/index.html") {
            continue;
        }
        let (a, b) = (
            std::fs::read(&entry).unwrap(),
            std::fs::read(demo.join(relative)).unwrap(),
        );
        assert!(
            a == b,
            "{} differs between two runs of one seed",
            relative.display()
        );
        compared += 1;
    }
    assert!(compared > 50, "{compared} files compared");
}

/// Every file under `dir`, depth first.
fn walkdir(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(walkdir(&path));
        } else {
            out.push(path);
        }
    }
    out
}

/// `demo --cameras 3`: the same pipeline with three cameras on an arc, calibrated as a graph
/// and triangulated with the χ² gate; each stage against the truth, recomputed from the files
/// where it can be.
#[test]
fn the_quick_demo_with_three_cameras_holds_against_the_truth() {
    let _cores = every_core();
    let dir = tempdir();
    let d = dir.path();
    let out = handcap_ok(d, &["demo", "--out", "demo", "--quick", "--cameras", "3"]);
    for stage in [
        "filmed by 3 webcams",
        "[2/7] calibrate: 3 cameras",
        "[3/7] triangulate",
        "[5/7] inverse",
        "[6/7] dynamic",
        "[7/7] report",
    ] {
        assert!(out.contains(stage), "{stage} missing: {out}");
    }
    let demo = d.join("demo");
    let summary: serde_json::Value = read_json(&demo.join("summary.json"));
    assert!(summary.get("calibration").is_none());
    let c = &summary["cameras"];
    let cameras = c["cameras"].as_array().unwrap();
    assert_eq!(cameras.len(), 3, "{c}");
    for camera in cameras {
        let value = |k: &str| camera[k].as_f64().unwrap();
        assert!(value("focal_error_pct").abs() < 0.1, "{camera}");
        assert!(
            value("rotation_error_deg") < 0.05 && value("centre_error_mm") < 0.2,
            "{camera}"
        );
    }
    assert!(c["hand_axes_error_deg"].as_f64().unwrap() < 0.1, "{c}");
    // Every step a tip, near the truth, inside its stated ellipsoid.
    let (rms, n) = tip_rms_against_truth(
        &demo.join("triangulated/dataset.csv"),
        &demo.join("capture/truth/tips.csv"),
        |_| true,
    );
    assert_eq!(n, 39);
    assert!(rms <= 0.05, "tip RMS error {rms} mm");
    assert!(c["ellipsoid_coverage"].as_f64().unwrap() >= 0.93, "{c}");
    // The model from those rows beats the previous one on the sweeps, against the truth.
    for sweep in ["sweep_a", "sweep_b"] {
        let [msvr, _, default, _] = sweep_errors_against_truth(&demo, sweep);
        assert!(
            3.0 * msvr <= default,
            "{sweep}: MSVR {msvr}, previous model {default}"
        );
    }
    let html = std::fs::read_to_string(demo.join("report/index.html")).unwrap();
    assert!(html.contains("More cameras: calibration and tips against the truth"));
    // The finger in motion, per frame with the three cameras (measured 0.0199 mm; history
    // 3.3 times better than static, 0.99 times the truth's).
    dynamic_holds_against_truth(
        &demo,
        &DynamicBars {
            tip_rms_mm: 0.05,
            history_over_static: 2.0,
            history_over_truth: 1.5,
        },
    );
}
