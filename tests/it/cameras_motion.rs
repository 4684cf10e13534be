//! More than two cameras in motion (issue 59): `synth --cameras 4 --dynamic` calibrated and
//! triangulated per frame, against the true tip at every frame of the rows' camera and against
//! each pair of the same calibration with that camera.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use crate::common::{
    cameras_alarmed, csv_rows, handcap_err, handcap_ok, read_json, tempdir, write,
};

/// Per frame of camera `camera` in `truth/frames.csv`: the true tip, whether the bead was
/// hidden from it, and its stamp less its exposure's middle (s, from `frames/frames.csv`).
struct Truth {
    tip: [f64; 3],
    hidden: bool,
}

fn truth_of(session: &Path, camera: &str) -> BTreeMap<usize, Truth> {
    csv_rows(&session.join("truth/frames.csv"))
        .iter()
        .filter(|r| r["camera"] == camera)
        .map(|r| {
            let frame = r["frame"].parse().unwrap();
            let tip = ["x_mm", "y_mm", "z_mm"].map(|c| r[c].parse().unwrap());
            (
                frame,
                Truth {
                    tip,
                    hidden: r["occluded"] == "1",
                },
            )
        })
        .collect()
}

/// How far camera `camera`'s stamps run ahead of its exposures' middles, on average (ms).
fn stamp_lead_ms(session: &Path, camera: &str) -> f64 {
    let exposure: BTreeMap<String, f64> = csv_rows(&session.join("truth/frames.csv"))
        .iter()
        .filter(|r| r["camera"] == camera)
        .map(|r| (r["frame"].clone(), r["exposure_s"].parse().unwrap()))
        .collect();
    let leads: Vec<f64> = csv_rows(&session.join("frames/frames.csv"))
        .iter()
        .filter(|r| r["camera"] == camera)
        .map(|r| r["time_s"].parse::<f64>().unwrap() - exposure[&r["frame"]])
        .collect();
    1e3 * leads.iter().sum::<f64>() / leads.len() as f64
}

/// A per-frame dataset's rows with a tip and no flag, scored against `truth`: how many, their
/// RMS distance from the true tips (mm), and the share of true tips inside the row's 95 %
/// ellipsoid.
fn score(path: &Path, truth: &BTreeMap<usize, Truth>) -> (usize, f64, f64) {
    let rows: Vec<_> = csv_rows(path)
        .into_iter()
        .filter(|r| r["flag"].is_empty() && !r["x_mm"].is_empty())
        .collect();
    let (mut sum, mut inside) = (0.0, 0);
    for r in &rows {
        let value = |c: &str| -> f64 { r[c].parse().unwrap() };
        let want = truth[&r["frame"].parse::<usize>().unwrap()].tip;
        let error = Vector3::from_fn(|i, _| value(["x_mm", "y_mm", "z_mm"][i]) - want[i]);
        sum += error.norm_squared();
        let sd = [value("sd_x_mm"), value("sd_y_mm"), value("sd_z_mm")];
        let (xy, xz, yz) = (
            value("cov_xy_mm2"),
            value("cov_xz_mm2"),
            value("cov_yz_mm2"),
        );
        let covariance = Matrix3::new(
            sd[0] * sd[0],
            xy,
            xz, //
            xy,
            sd[1] * sd[1],
            yz, //
            xz,
            yz,
            sd[2] * sd[2],
        );
        // χ² of 3 degrees of freedom at 0.95.
        inside += usize::from(error.dot(&(covariance.try_inverse().unwrap() * error)) <= 7.815);
    }
    let n = rows.len();
    (n, (sum / n as f64).sqrt(), inside as f64 / n.max(1) as f64)
}

/// A dynamic session of four cameras in `d/s` (12 board views; `more` given to synth), and its
/// calibration `d/cal.yml` (and `cal.toml`).
fn four_cameras(d: &Path, more: &[&str]) {
    let synth = [
        "synth",
        "--out",
        "s",
        "--cameras",
        "4",
        "--dynamic",
        "--trials",
        "1",
    ];
    handcap_ok(d, &[&synth[..], &["--views", "12"], more].concat());
    handcap_ok(d, &["calibrate", "s/calib", "--out", "cal.yml"]);
}

/// `triangulate s/frames --per-frame` in `d` with `calib`, into `out`: what it said.
fn per_frame(d: &Path, calib: &str, out: &str) -> String {
    let args = ["triangulate", "s/frames", "--per-frame", "--calib", calib];
    let to = ["--pressures", "s/pressures.csv", "--out", out];
    handcap_ok(d, &[&args[..], &to].concat())
}

#[test]
fn four_cameras_in_motion_give_each_frame_a_tip_closer_than_any_pair_with_the_first() {
    let dir = tempdir();
    let d = dir.path();
    four_cameras(d, &["--duration-s", "8"]);
    let triangulate = |calib: &str, out: &str| per_frame(d, calib, out);
    let said = triangulate("cal.toml", "four.csv");
    // Each camera's JPEG quality said, per frame as for the steps.
    assert!(
        said.contains("colour: JPEG, cam1 4:2:0 at quality 85, cam2 4:2:0 at quality 85"),
        "{said}"
    );
    let truth = truth_of(&d.join("s"), "cam1");
    let rows = csv_rows(&d.join("four.csv"));
    assert_eq!(rows.len(), truth.len(), "a row per cam1 frame: {said}");
    let (good, four, inside) = score(&d.join("four.csv"), &truth);
    eprintln!(
        "{said}four cameras: {good} rows, {four:.4} mm, {:.1} % inside",
        100.0 * inside
    );
    // Every row but the first (no other camera's frame before it) has its tip: where cam1 lost
    // the bead too, from the other three.
    assert!(good + 1 >= rows.len(), "{good} of {}: {said}", rows.len());
    let hidden: Vec<usize> = truth
        .iter()
        .filter(|(_, t)| t.hidden)
        .map(|(&f, _)| f)
        .collect();
    assert!(hidden.len() >= 3, "{hidden:?}");
    for r in rows
        .iter()
        .filter(|r| hidden.contains(&r["frame"].parse().unwrap()))
    {
        assert!(
            !r["x_mm"].is_empty() && !r["cameras"].contains("cam1"),
            "cam1 frame {}: {:?}",
            r["frame"],
            r
        );
    }
    assert!(four < 0.025, "tip RMS {four:.4} mm: {said}");
    assert!(inside >= 0.93, "{inside}");
    // Each camera's view of the still scene, on one row in six: none moved, none wandered
    // half a pixel.
    for camera in ["cam1", "cam2", "cam3", "cam4"] {
        let column = format!("scene_{camera}_px");
        let px: Vec<f64> = rows
            .iter()
            .filter_map(|r| r[&column].parse().ok())
            .collect();
        assert!(
            px.len() * 7 > rows.len() && px.len() * 5 < rows.len(),
            "{column}: {}",
            px.len()
        );
        assert!(px.iter().all(|&v| v < 0.5), "{column}: {px:?}");
    }
    // Each camera's clock against cam1's, from the motion: the truth is how far its stamps
    // lead its exposures less how far cam1's do.
    let summary = read_json(&d.join("four_summary.json"));
    let lead1 = stamp_lead_ms(&d.join("s"), "cam1");
    for c in &summary["summary"]["cameras"].as_array().unwrap()[1..] {
        let name = c["name"].as_str().unwrap();
        let want = stamp_lead_ms(&d.join("s"), name) - lead1;
        let got = c["clock_offset_ms"].as_f64().unwrap();
        assert!((got - want).abs() < 1.0, "{name}: {got} ms against {want}");
    }
    // Split by the log's phase.
    let split: usize = ["rest", "dyn_1"]
        .iter()
        .map(|phase| csv_rows(&d.join(format!("four_{phase}.csv"))).len())
        .sum();
    assert_eq!(split, rows.len());
    // The held steps into the same place replace the per-frame files: the summary is theirs
    // and lists every file of the dataset's left (the per-frame run's dyn_1 file is gone).
    let args = ["triangulate", "s/frames", "--calib", "cal.toml"];
    let steps = [
        &args[..],
        &["--pressures", "s/pressures.csv", "--out", "four.csv"],
    ]
    .concat();
    handcap_ok(d, &steps);
    let summary = read_json(&d.join("four_summary.json"));
    assert_eq!(summary["per_frame"], false, "{summary}");
    let listed = summary["files"].as_array().unwrap();
    for entry in std::fs::read_dir(d).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        if name.starts_with("four") {
            assert!(listed.iter().any(|f| f == &name), "{name} left: {summary}");
        }
    }
    assert!(!d.join("four_dyn_1.csv").exists());
    // Each pair with cam1, of the same calibration.
    let calibrated: toml::Table = std::fs::read_to_string(d.join("cal.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let mut best_pair = f64::INFINITY;
    for other in 1..4 {
        let mut pair = calibrated.clone();
        pair.retain(|key, _| !key.starts_with("cam_") || key == "cam_0");
        pair.insert("cam_1".into(), calibrated[&format!("cam_{other}")].clone());
        write(d, "pair.toml", &toml::to_string(&pair).unwrap());
        triangulate("pair.toml", "pair.csv");
        let (rows, rms, _) = score(&d.join("pair.csv"), &truth);
        eprintln!("cam1 + cam{}: {rows} rows, {rms:.4} mm", other + 1);
        assert!(rows <= good, "cam1 + cam{}: {rows} rows", other + 1);
        best_pair = best_pair.min(rms);
    }
    assert!(
        four < best_pair,
        "four {four:.4} mm, the best pair with cam1 {best_pair:.4}"
    );
}

/// Four cameras, the second (cam2) panned 0.5° at 4 s: its view of the still scene moves by
/// f·tan 0.5° or more from then on, the other three's stay within half a pixel, and `handcap
/// monitor` of the rows names cam2 alone.
#[test]
fn of_four_cameras_the_one_that_panned_is_named_by_its_view_of_the_still_scene() {
    let dir = tempdir();
    let d = dir.path();
    four_cameras(d, &["--duration-s", "6", "--fault", "pan@4=0.5"]);
    per_frame(d, "cal.toml", "rows.csv");
    let rows = csv_rows(&d.join("rows.csv"));
    for camera in ["cam1", "cam2", "cam3", "cam4"] {
        let column = format!("scene_{camera}_px");
        let seen: Vec<(f64, f64)> = rows
            .iter()
            .filter_map(|r| Some((r["time_s"].parse().ok()?, r[&column].parse().ok()?)))
            .collect();
        let after: Vec<f64> = seen.iter().filter(|(t, _)| *t > 4.1).map(|s| s.1).collect();
        assert!(after.len() > 10, "{column}: {}", after.len());
        // Before the pan cam2's view stayed too (its frames rendered before the pan once
        // drew on canvases its panned view had handed back: 9 px off, some of them).
        let still: Vec<f64> = (seen.iter())
            .filter(|(t, _)| camera != "cam2" || *t < 3.9)
            .map(|s| s.1)
            .collect();
        assert!(still.iter().all(|&px| px < 0.5), "{column}: {still:?}");
        if camera == "cam2" {
            let panned = after.iter().all(|&px| (7.5..12.0).contains(&px));
            assert!(panned, "{column}: {after:?}");
        }
    }
    crate::monitor::fit(d);
    let watch = ["monitor", "rows.csv", "--model", "model.json", "--out", "w"];
    let said = handcap_ok(
        d,
        &[&watch[..], &["--baseline-s", "3", "--look-s", "0.1"]].concat(),
    );
    let v = read_json(&d.join("w/monitor.json"));
    let named = cameras_alarmed(&v);
    assert_eq!(named, ["cam2"], "{said}");
}

#[test]
fn more_cameras_in_motion_bad_input_gets_one_line() {
    let dir = tempdir();
    let d = dir.path();
    let synth = [
        "synth",
        "--out",
        "s",
        "--cameras",
        "3",
        "--dynamic",
        "--trials",
        "1",
        "--duration-s",
        "3",
        "--views",
        "8",
    ];
    handcap_ok(d, &synth);
    handcap_ok(d, &["calibrate", "s/calib", "--out", "cal.yml"]);
    let args = [
        "triangulate",
        "s/frames",
        "--per-frame",
        "--calib",
        "cal.toml",
        "--pressures",
        "s/pressures.csv",
        "--out",
        "x.csv",
    ];
    // A pair's clock options.
    let err = crate::common::handcap_usage(d, &[&args[..], &["--latency-ms", "10,20"]].concat());
    assert!(
        err.contains("--latency-ms takes a pair's LEFT,RIGHT"),
        "{err}"
    );
    let listed = std::fs::read_to_string(d.join("s/frames/frames.csv")).unwrap();
    let edit = |f: &dyn Fn(&str) -> String| {
        let text: String = listed.lines().map(|l| f(l) + "\n").collect();
        write(d, "s/frames/frames.csv", &text);
    };
    // A camera's stamp going back: the camera and frames named.
    edit(&|l| {
        if l.starts_with("20,cam2,") {
            "20,cam2,0.1".into()
        } else {
            l.into()
        }
    });
    let err = handcap_err(d, &args);
    assert!(
        err.contains("cam2 frame 20 is stamped 0.1 s, not after frame 19"),
        "{err}"
    );
    // A camera whose stamps are seconds off the others': named, with what to check.
    edit(&|l| match l.split(',').collect::<Vec<_>>()[..] {
        [frame, "cam3", t] => format!("{frame},cam3,{}", t.parse::<f64>().unwrap() + 10.0),
        _ => l.into(),
    });
    let err = handcap_err(d, &args);
    assert!(
        err.contains("camera cam3's frames") && err.contains("do not overlap camera cam1's"),
        "{err}"
    );
    // One camera's frames alone.
    edit(&|l| {
        if l.contains(",cam2,") || l.contains(",cam3,") {
            String::new()
        } else {
            l.into()
        }
    });
    let text: String = std::fs::read_to_string(d.join("s/frames/frames.csv"))
        .unwrap()
        .lines()
        .filter(|l| !l.is_empty())
        .map(|l| format!("{l}\n"))
        .collect();
    write(d, "s/frames/frames.csv", &text);
    let err = handcap_err(d, &args);
    assert!(
        err.contains("lists frames of camera cam1 alone: a tip takes two cameras' frames"),
        "{err}"
    );
    assert!(!d.join("x.csv").exists());
}
