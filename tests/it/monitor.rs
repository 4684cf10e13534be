//! `handcap monitor` on data-level virtual sessions (`synth --dynamic --no-images`) with faults
//! injected at known times (issue 60): a finger made softer raises the model alarm, a tilted
//! camera the geometry alarm, and a session where nothing changed raises none; the online
//! band holds its level on each.

use std::path::Path;

use crate::common::{
    csv_rows, every_core, handcap_err, handcap_ok, handcap_usage, read_json, tempdir, write,
};

/// A history model with intervals of three 40 s data-level trials of seed 1, in `d/model.json`
/// (the kernel the trajectory tests give, to spare the search).
pub fn fit(d: &Path) {
    let synth = ["synth", "--dynamic", "--no-images", "--out", "train"];
    handcap_ok(
        d,
        &[
            &synth[..],
            &["--duration-s", "40", "--trials", "3", "--seed", "1"],
        ]
        .concat(),
    );
    let intervals = ["--intervals", "--folds", "3"];
    crate::trajectory::fit_history_model(d, "train/session.csv", &intervals, "model.json");
}

/// A 300 s data-level session of seed 5 with `fault` (if any) in `d/name`, watched into
/// `d/name_watch`; the monitor's summary.
fn watch(d: &Path, name: &str, fault: Option<&str>) -> serde_json::Value {
    let mut synth = vec![
        "synth",
        "--dynamic",
        "--no-images",
        "--out",
        name,
        "--seed",
        "5",
    ];
    synth.extend(["--duration-s", "300", "--trials", "1"]);
    synth.extend(fault.iter().flat_map(|f| ["--fault", f]));
    handcap_ok(d, &synth);
    let session = format!("{name}/session.csv");
    let out = format!("{name}_watch");
    handcap_ok(
        d,
        &["monitor", &session, "--model", "model.json", "--out", &out],
    );
    let watched = read_json(&d.join(&out).join("monitor.json"));
    // The files watched, named by their hashes (the summary named none).
    let inputs = &watched["provenance"]["inputs"];
    assert_eq!(inputs[0]["path"], session.as_str(), "{inputs}");
    assert_eq!(inputs[1]["path"], "model.json", "{inputs}");
    assert_eq!(
        inputs[1]["sha256"].as_str().map(str::len),
        Some(64),
        "{inputs}"
    );
    watched
}

#[test]
fn a_softer_finger_and_a_tilted_camera_each_raise_their_own_alarm_and_nothing_else_does() {
    // Three sessions, a model and six watches on every core: never beside a live session.
    let _machine = every_core();
    let dir = tempdir();
    let d = dir.path();
    fit(d);
    let alarms = |v: &serde_json::Value| -> Vec<(String, f64, f64)> {
        v["alarms"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| {
                let n = |k: &str| a[k].as_f64().unwrap();
                (
                    a["channel"].as_str().unwrap().to_string(),
                    n("time_s"),
                    n("change_s"),
                )
            })
            .collect()
    };
    for (name, fault) in [
        ("calm", None),
        ("soft", Some("stiffness@150=-0.15")),
        ("tilt", Some("camera@150=0.3")),
    ] {
        let v = watch(d, name, fault);
        let coverage = v["coverage"].as_f64().unwrap();
        assert!(
            (coverage - 0.9).abs() < 0.01,
            "{name}: the band held {coverage}"
        );
        let raised = alarms(&v);
        eprintln!("monitor {name}: coverage {coverage:.4}, alarms {raised:?}");
        match name {
            "calm" => {
                assert!(raised.is_empty(), "{name}: {raised:?}");
                assert!(!d.join("calm_watch/after_change.csv").exists());
            }
            "soft" => {
                let (channel, time, change) = &raised[0];
                // Within the 30 s asked, by the response test (the exceedances took 49 s).
                assert_eq!(channel, "finger", "{raised:?}");
                assert!(*time > 150.0 && *time < 180.0, "{raised:?}");
                assert!((change - 150.0).abs() < 10.0, "{raised:?}");
                // The rows to refit on are the session's from the change on, as they were.
                let after = csv_rows(&d.join("soft_watch/after_change.csv"));
                let whole = csv_rows(&d.join("soft/session.csv"));
                let first: f64 = after[0]["time_s"].parse().unwrap();
                assert!((first - change).abs() < 0.05, "{first} {change}");
                assert_eq!(after.last(), whole.last());
            }
            _ => {
                let (channel, time, change) = &raised[0];
                assert_eq!(channel, "camera", "{raised:?}");
                assert!(*time > 150.0 && *time < 170.0, "{raised:?}");
                assert!((change - 150.0).abs() < 5.0, "{raised:?}");
            }
        }
    }
    // Each row's band is the online band times the row's widening factor (the model's radius
    // widens off its training rows), and a row counts as covered when its error lies within
    // it: the errors the band tracked were scaled as the band is.
    let rows = csv_rows(&d.join("soft_watch/monitor.csv"));
    for r in &rows {
        let (e, band): (f64, f64) = (r["error"].parse().unwrap(), r["band"].parse().unwrap());
        if (e - band).abs() > 1e-9 * band {
            assert_eq!(r["covered"] == "1", e < band, "{r:?}");
        }
    }
    // monitor.csv: a row per session row, the alarm on the row it was raised at.
    let rows = csv_rows(&d.join("tilt_watch/monitor.csv"));
    let raised: Vec<&str> = rows
        .iter()
        .map(|r| r["alarm"].as_str())
        .filter(|a| !a.is_empty())
        .collect();
    assert_eq!(raised, ["camera"]);
    assert!(d.join("tilt_watch/monitor.svg").is_file());
}

#[test]
fn monitor_refuses_a_model_without_intervals_a_session_without_time_and_another_rigs_calibration_in_one_line(
) {
    let dir = tempdir();
    let d = dir.path();
    let synth = [
        "synth",
        "--dynamic",
        "--no-images",
        "--out",
        "s",
        "--duration-s",
        "20",
    ];
    handcap_ok(d, &[&synth[..], &["--trials", "1"]].concat());
    let mut args = vec!["model", "s/session.csv", "--inputs", "P1_kpa,P2_kpa,P3_kpa"];
    args.extend([
        "--outputs",
        "x_mm,y_mm,z_mm",
        "--search",
        "none",
        "--out",
        "bare.json",
    ]);
    handcap_ok(d, &args);
    let e = handcap_err(
        d,
        &[
            "monitor",
            "s/session.csv",
            "--model",
            "bare.json",
            "--out",
            "w",
        ],
    );
    assert!(e.contains("bare.json") && e.contains("--intervals"), "{e}");
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(!d.join("w/monitor.csv").exists());
    args.pop();
    args.extend(["with.json", "--intervals"]);
    handcap_ok(d, &args);
    let e = handcap_err(
        d,
        &[
            "monitor",
            "s/session.csv",
            "--model",
            "with.json",
            "--out",
            "w",
            "--time",
            "t",
        ],
    );
    assert!(e.contains("--time"), "{e}");
    assert!(!d.join("w/monitor.csv").exists());
    // Hostile probes (stop 85): refused without leaving an empty folder; a header alone is
    // refused, not watched as 0 rows.
    assert!(!d.join("w").exists());
    let header = std::fs::read_to_string(d.join("s/session.csv")).unwrap();
    write(
        d,
        "header.csv",
        &format!("{}\n", header.lines().next().unwrap()),
    );
    let e = handcap_err(
        d,
        &[
            "monitor",
            "header.csv",
            "--model",
            "with.json",
            "--out",
            "w",
        ],
    );
    assert!(e.contains("header.csv: no rows"), "{e}");
    // A session within the baseline cannot raise an alarm, and says so.
    let short = [
        "monitor",
        "s/session.csv",
        "--model",
        "with.json",
        "--out",
        "short",
    ];
    let said = handcap_ok(d, &[&short[..], &["--baseline-s", "30"]].concat());
    assert!(
        said.contains("within the baseline of 30 s: no alarm could be raised"),
        "{said}"
    );
    let e = handcap_usage(d, &["synth", "--out", "r", "--fault", "leak@5=0.1"]);
    assert!(e.contains("--dynamic"), "{e}");
    let e = handcap_usage(
        d,
        &[
            "synth",
            "--dynamic",
            "--no-images",
            "--out",
            "r",
            "--fault",
            "mass@5=1",
        ],
    );
    assert!(e.contains("KIND@T=AMOUNT"), "{e}");
    // A calibration of another rig (here: the right camera turned 1° before the session):
    // every bead reprojects pixels off, and the monitor says so rather than watch.
    let knocked = ["--trials", "1", "--fault", "camera@0=1"];
    handcap_ok(d, &[&synth[..4], &["k"], &synth[5..], &knocked].concat());
    let e = handcap_err(
        d,
        &[
            "monitor",
            "k/session.csv",
            "--model",
            "with.json",
            "--out",
            "w",
        ],
    );
    assert!(
        e.contains("k/session.csv") && e.contains("calibration is not these cameras'"),
        "{e}"
    );
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(!d.join("w/monitor.csv").exists());
}

/// A session directory as capture writes it (a short rendered dynamic session whose right
/// camera is knocked by 0.3° at 6 s) and its calibration: monitor triangulates it per frame
/// (the rows kept beside its files), replays those rows, and the rows the triangulation refuses
/// once the views disagree raise the camera alarm; before it, a model of the data-level finger
/// predicts the rendered one's tips.
#[test]
fn a_session_directory_is_triangulated_then_watched_and_a_knocked_camera_seen() {
    // A rendered session, its calibration and triangulation: never beside a live session,
    // whose frames a busy machine delays (a lab's drops were then miscounted beside it).
    let _machine = every_core();
    let dir = tempdir();
    let d = dir.path();
    let (said, rows) = watch_rendered(d, "camera@6=0.3");
    let time = |r: &Row| -> f64 { r["time_s"].parse().unwrap() };
    let refused: Vec<&Row> = rows
        .iter()
        .filter(|r| r["flag"] == "reprojection")
        .collect();
    // Once the camera is knocked the triangulation refuses its rows; a few just before it too
    // (5 rows from 0.33 s before, on this seed, where a render of the same session without the
    // knock refuses none: the per-frame pass reads each instant through the frames around it).
    let after = refused.iter().filter(|r| time(r) >= 6.0).count();
    assert!(
        after > 100 && refused.len() - after < 10,
        "{after} of {}",
        refused.len()
    );
    let v = read_json(&d.join("w/monitor.json"));
    let camera: Vec<f64> = v["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["channel"] == "camera")
        .map(|a| a["time_s"].as_f64().unwrap())
        .collect();
    // Two camera alarms: the beads' residual, and the right camera's view of the still
    // scene (the wall behind the finger moved in its picture; measured five times a second,
    // so its eight looks past the reference take 1.6 s); the left camera's stays.
    assert!(
        camera.len() == 2 && camera.iter().all(|&t| t > 6.0 && t < 8.0),
        "{said}"
    );
    assert!(said.contains("alarm: camera (right) at"), "{said}");
    assert!(!said.contains("(left)"), "{said}");
    // Before the knock the rendered finger is the modelled one: its errors are the model's.
    let watched = csv_rows(&d.join("w/monitor.csv"));
    let mut errors: Vec<f64> = watched
        .iter()
        .filter(|r| time(r) < 6.0)
        .map(|r| r["error"].parse().unwrap())
        .collect();
    assert!(errors.len() > 100, "{}", errors.len());
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    assert!(median < 1.0, "median error {median} mm");
    let args = [
        "monitor",
        "w/rows.csv",
        "--calib",
        "calib.yml",
        "--model",
        "model.json",
    ];
    let e = handcap_usage(d, &[&args[..], &["--out", "v"]].concat());
    assert!(e.contains("--calib"), "{e}");
    let e = handcap_usage(d, &["monitor", "s", "--model", "model.json", "--out", "v"]);
    assert!(e.contains("--calib"), "{e}");
}

/// A camera that pans (turns about its vertical axis) moves its beads along their epipolar
/// lines: the triangulation refuses few rows and the residual raises nothing, the tips shift by
/// millimetres. Its view of the still scene moved: the monitor names the right camera, and the
/// finger alarm the shifted tips raise says to recalibrate first (without the still scene it
/// would say to refit the model on a moved camera's tips).
#[test]
fn a_camera_that_pans_is_named_by_its_view_of_the_still_scene_though_its_beads_agree() {
    let _machine = every_core();
    let dir = tempdir();
    let d = dir.path();
    let (said, rows) = watch_rendered(d, "pan@6=0.5");
    let time = |r: &Row| -> f64 { r["time_s"].parse().unwrap() };
    let scene =
        |r: &Row, camera: &str| -> Option<f64> { r[&format!("scene_{camera}_px")].parse().ok() };
    // The beads still agree after the pan but in a few rows (3 of 150 on this seed, where the
    // finger's reach takes them off the lines); the right camera's picture moved by f·tan 0.5°
    // (7.9 px) at its centre and up to 1.5 times that at its sides (f·0.5°/cos² of the angle
    // off its axis: the tiles' median 9.5-9.8 px on this seed), the left one's stayed within
    // a few tenths of a pixel throughout.
    let after: Vec<&Row> = rows.iter().filter(|r| time(r) >= 6.1).collect();
    assert!(after.len() > 50, "{}", after.len());
    let refused = after.iter().filter(|r| r["flag"] == "reprojection").count();
    assert!(refused * 20 < after.len(), "{refused} of {}", after.len());
    assert!(
        after
            .iter()
            .filter_map(|r| scene(r, "right"))
            .all(|px| (7.5..12.0).contains(&px)),
        "the right camera's view"
    );
    let left = rows
        .iter()
        .filter_map(|r| scene(r, "left"))
        .fold(0.0, f64::max);
    assert!(left < 0.5, "the left camera's view moved {left} px");
    // Before the pan the right camera's view stayed too.
    let before = (rows.iter().filter(|r| time(r) < 5.9))
        .filter_map(|r| scene(r, "right"))
        .fold(0.0, f64::max);
    assert!(
        before < 0.5,
        "the right camera's view moved {before} px before the pan"
    );
    let v = read_json(&d.join("w/monitor.json"));
    let alarms = v["alarms"].as_array().unwrap();
    let camera: Vec<&serde_json::Value> =
        alarms.iter().filter(|a| a["channel"] == "camera").collect();
    assert_eq!(camera.len(), 1, "{said}");
    assert_eq!(camera[0]["camera"], "right", "{said}");
    let raised = camera[0]["time_s"].as_f64().unwrap();
    assert!(raised > 6.0 && raised < 8.0, "{said}");
    assert!(said.contains("alarm: camera (right) at"), "{said}");
    // The report's section says so too.
    let section = std::fs::read_to_string(d.join("w/monitor.md")).unwrap();
    assert!(section.contains("| camera (right) |"), "{section}");
    assert!(
        section.contains("camera (the still scene, left) | 0.750 px"),
        "{section}"
    );
    // The tips moved by millimetres with the camera: the finger alarm they raise (before the
    // camera's, on this seed) points at the camera, not at a refit.
    let finger = alarms.iter().find(|a| a["channel"] == "finger");
    let advice = finger.map_or("", |a| a["advice"].as_str().unwrap());
    assert!(advice.contains("recalibrate"), "{said}");
}

type Row = std::collections::HashMap<String, String>;

/// An 8 s rendered session in `d/s` with `fault`, its calibration, [`fit`]'s model, and
/// `handcap monitor` of the session directory into `d/w` (a 4.5 s baseline with the finger
/// moving: a rest hold alone is no reference for motion; a look every 0.1 s): what it said,
/// and the rows it triangulated.
fn watch_rendered(d: &Path, fault: &str) -> (String, Vec<Row>) {
    let session = ["--duration-s", "8", "--trials", "1", "--fault", fault];
    crate::triangulate::dynamic_session_with(d, &session);
    fit(d);
    let mut args = vec![
        "monitor",
        "s",
        "--calib",
        "calib.yml",
        "--model",
        "model.json",
    ];
    args.extend(["--baseline-s", "4.5", "--look-s", "0.1", "--out", "w"]);
    let said = handcap_ok(d, &args);
    (said, csv_rows(&d.join("w/rows.csv")))
}
