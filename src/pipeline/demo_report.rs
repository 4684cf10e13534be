//! The demo's report page: every stage's result against the truth, on one self-contained page.

use std::path::Path;

use super::demo_summary::{CamerasCheck, Score, Summary};
use crate::calib::{gates, StereoCalibration};
use crate::model::inverse::PlannedTarget;
use crate::report::html::Page;
use crate::select::tune::SearchSummary;
use crate::triangulate::Triangulation;

fn f4(v: f64) -> String {
    format!("{v:.4}")
}

/// The report page; `timings` each stage's seconds (the only figures that differ between two
/// runs of one seed).
pub(super) fn page(
    out: &Path,
    s: &Summary,
    timings: &[(String, f64)],
    pair: Option<(&Triangulation, &StereoCalibration)>,
    search: Option<&SearchSummary>,
    planned: &[PlannedTarget],
) -> Page {
    let report = Report {
        out,
        s,
        timings,
        pair,
        search,
        planned,
    };
    let mut page = Page::new("handcap demo: the virtual micro-hand, end to end");
    summary_section(&mut page, &report);
    match (pair, &s.cameras) {
        (Some((tri, cal)), _) => {
            calibration_section(&mut page, &report, cal);
            detection_section(&mut page, &report, tri);
            triangulation_section(&mut page, &report, tri);
        }
        (None, Some(c)) => cameras_section(&mut page, &report, c),
        (None, None) => {}
    }
    aco_section(&mut page, &report);
    sweeps_section(&mut page, &report);
    errors_section(&mut page, &report);
    intervals_section(&mut page, &report);
    inverse_section(&mut page, &report);
    if let Some(d) = &s.dynamic {
        dynamic_section(&mut page, &report, d);
    }
    manifest_section(&mut page, &report);
    page
}

/// What the page is made of.
struct Report<'a> {
    out: &'a Path,
    s: &'a Summary,
    timings: &'a [(String, f64)],
    /// A pair's triangulation and calibration; `None` with more cameras (`s.cameras`).
    pair: Option<(&'a Triangulation, &'a StereoCalibration)>,
    search: Option<&'a SearchSummary>,
    planned: &'a [PlannedTarget],
}

/// The page's "summary" section.
fn summary_section(page: &mut Page, r: &Report) {
    let (s, timings) = (r.s, r.timings);
    let all = s.triangulation.iter().find(|t| t.phase == "all");
    let (synth, calibrate) = match (r.pair, &s.calibration, &s.cameras) {
        (Some((tri, cal)), Some(c), _) => (
            format!(
                "{} board pairs, {} pressure steps",
                cal.pairs.len(),
                tri.summary.steps_logged
            ),
            format!(
                "RMS {:.3} px; intrinsics within {:.3} %, baseline {:.3} %, rotation {:.4}°",
                c.rms_px, c.intrinsics_error_pct, c.baseline_error_pct, c.rotation_error_deg
            ),
        ),
        (_, _, Some(c)) => {
            let worst = |f: fn(&super::demo_summary::CameraCheck) -> f64| {
                c.cameras.iter().map(f).fold(0.0, f64::max)
            };
            (
                format!("{} cameras on an arc, {} steps with a tip", c.cameras.len(), c.steps_with_tip),
                format!("RMS {:.3} px; focal lengths within {:.3} %, rotations {:.4}°, camera centres {:.3} mm", c.rms_px, worst(|x| x.focal_error_pct.abs()), worst(|x| x.rotation_error_deg), worst(|x| x.centre_error_mm)),
            )
        }
        _ => ("-".into(), "-".into()),
    };
    let dynamic = s.dynamic.as_ref().map(|d| {
        let euclid = |k: usize| d.scores.get(k).map_or(f64::NAN, |x| x.errors.euclid);
        vec![
            "dynamic".into(),
            format!("per-frame tip RMS {:.4} mm; held-out trial: {:.4} mm static, {:.4} mm with input history", d.tip_rms_mm, euclid(0), euclid(1)),
            timing(timings, "dynamic"),
        ]
    });
    page.paragraph(&format!(
        "A virtual micro-hand (three McKibben muscles, 50 mm) filmed by {} virtual 1280×720 webcams while its pressures step through the paper's protocol; every stage of the pipeline run on the files, and checked against the ground truth the virtual capture wrote. Seed {}{}.",
        s.cameras.as_ref().map_or("two".into(), |c| c.cameras.len().to_string()),
        s.seed,
        if s.quick { ", reduced run (--quick)" } else { "" }
    ))
    .section("summary", "Key numbers")
    .table(
        &["stage", "result", "time (s)"],
        &[
            vec!["synth".into(), synth, timing(timings, "synth")],
            vec!["calibrate".into(), calibrate, timing(timings, "calibrate")],
            vec![
                "triangulate".into(),
                all.map_or("-".into(), |t| format!("tip RMS error {:.4} mm over {} steps", t.rms_mm, t.rows)),
                timing(timings, "triangulate"),
            ],
            vec![
                "model".into(),
                {
                    let mae = |model: &str| {
                        s.scores
                            .iter()
                            .find(|x| x.model == model && x.test == "dataset_sweep_a.csv")
                            .map_or(f64::NAN, |x| x.errors.mae)
                    };
                    let auto = Score::auto_model(s.auto.used);
                    format!("held-out MAE on sweep A: MSVR {:.4} mm; `handcap model`'s default picks {} ({:.4} mm)", mae("msvr"), s.auto.used.title(), mae(&auto))
                },
                timing(timings, "model"),
            ],
            vec![
                "inverse".into(),
                s.inverse.first().map_or("-".into(), |i| format!("planned pressures put the plant's tip {:.4} mm (mean) from the target", i.mean_mm)),
                timing(timings, "inverse"),
            ],
        ]
        .into_iter()
        .chain(dynamic)
        .chain([vec!["total".into(), String::new(), timing(timings, "total")]])
        .collect::<Vec<_>>(),
    );
}

/// The page's "calibration" section.
fn calibration_section(page: &mut Page, r: &Report, cal: &StereoCalibration) {
    let (out, s) = (r.out, r.s);
    let Some(c) = &s.calibration else { return };
    page.section("calibration", "Calibration")
        .paragraph(&format!(
            "{} chessboard pairs used. Reprojection RMS {:.3} px, mean epipolar distance {:.3} px; the boards triangulate back to {:.4} ± {:.4} squares, {:.3} mm off their plane. {} Against the true rig: focal lengths and principal points within {:.3} %, baseline within {:.3} %, rotation within {:.4}°, hand axes within {}.",
            c.pairs_used, c.rms_px, c.epipolar_px,
            cal.board_check.neighbour_mean_squares, cal.board_check.neighbour_sd_squares, cal.board_check.planarity_rms_mm,
            if cal.implausible.is_empty() {
                format!(
                    "It passes every gate that refuses a calibration: reprojection RMS at most {} px, the boards triangulated back within {} % of a square apart (sd at most {} %) and flat within {} of a square, a baseline at most {} × the boards' distance.",
                    gates::MAX_RMS_PX,
                    100.0 * gates::MAX_SPACING_ERROR,
                    100.0 * gates::MAX_SPACING_SD,
                    gates::MAX_PLANARITY_SQUARES,
                    gates::MAX_BASELINE_DISTANCES
                )
            } else {
                format!("Written although it fails a gate: {}.", cal.implausible.join("; "))
            },
            c.intrinsics_error_pct, c.baseline_error_pct, c.rotation_error_deg,
            c.hand_axes_error_deg.map_or("(no reference pair)".into(), |d| format!("{d:.4}°"))
        ))
        .paragraph(&match (c.baseline_sd_pct, &c.tip_sd) {
            (Some(b), Some(t)) => {
                let axes = |v: [f64; 3]| format!("±{:.3} / {:.3} / {:.3} mm", v[0], v[1], v[2]);
                format!(
                    "How sure the calibration says it is (1 sd, from the covariance of its fit): baseline ±{b:.3} %. At the reference board (the finger's base), along x / y / depth: a tip's position {}, a 10 mm move of it {}; 0.1 px of marker noise in each image moves it {}. {}",
                    axes(t.position), axes(t.displacement), axes(t.marker),
                    if c.advice.is_empty() { "Nothing more to capture.".to_string() } else { format!("Advice: {}.", c.advice.join("; ")) }
                )
            }
            _ => "The calibration reports no standard deviations.".into(),
        })
        .paragraph(&match &c.validation {
            Some(v) => format!(
                "Checked against itself (`calibrate --validate`): the pairs split in halves ({} splits), each calibrated alone; at 27 points within ±{} mm of the finger's base the halves' tips disagree by {:.4} / {:.4} / {:.4} mm RMS (x / y / depth), where their covariances predict {:.4} / {:.4} / {:.4} mm: a ratio of {:.2} (about 1 when the stated deviations are honest; above, they are too small). The finger's base is {:.0} mm from the nearest board corner the calibration saw.{}",
                v.splits, crate::calib::validate::VOLUME_MM,
                v.disagreement_mm[0], v.disagreement_mm[1], v.disagreement_mm[2],
                v.predicted_mm[0], v.predicted_mm[1], v.predicted_mm[2],
                v.ratio, v.base_distance_mm,
                v.warnings.iter().map(|w| format!(" Warning: {w}.")).collect::<String>()
            ),
            None => "The calibration was not checked against halves of its pairs.".into(),
        })
        .figure(&out.join("calib_pairs.svg"), "Reprojection error of each chessboard pair (left and right image).")
        .figure(&out.join("calib_rectified.png"), "A pair rectified with the calibration: corresponding points lie on the same horizontal line.");
}

/// The page's "detection" section.
fn detection_section(page: &mut Page, r: &Report, tri: &Triangulation) {
    let out = r.out;
    let f = &tri.summary.frames;
    page.section("detection", "Tip detection")
        .paragraph(&format!(
            "{} left and {} right frames; (left / right) the marker missing in {} / {}, several red candidates (the epipolar line chooses among them) in {} / {}. {} frame pairs, {} used; reprojection error of the used pairs: median {:.3} px, largest {:.3} px.",
            f.listed[0], f.listed[1], f.marker_missing[0], f.marker_missing[1], f.several_candidates[0], f.several_candidates[1],
            tri.summary.pairs_formed,
            tri.summary.pairs.iter().filter(|(k, _)| **k == "used" || **k == "resolved").map(|(_, v)| v).sum::<usize>(),
            tri.summary.reproj_px[0], tri.summary.reproj_px[2]
        ))
        .figure(&out.join("triangulated/dataset_detections.png"), "Detected tip (green cross) and the triangulated tip reprojected (magenta circle), left and right crops, and where the crop lies in the left frame.")
        .paragraph(&{
            let c = &tri.summary.clock;
            format!(
                "The clock, from the timestamps alone: a pair's frames {:.1} ms apart (median; 95 % within {:.1} ms), drifting {:+.1} ms over the session (the virtual webcams run free, their rates within ±50 ppm of each other); frame periods {} (left/right; — for a camera with one frame per step); frames dropped within steps {} / {}; steps filmed only while settling: {}.",
                c.skew_ms[0], c.skew_ms[1], c.drift_ms, c.periods(), c.dropped[0], c.dropped[1], c.settling_only.len()
            )
        })
        .paragraph(&format!(
            "The cameras' {}.",
            tri.summary.latency.describe().join("; ")
        ))
        .figure(&out.join("triangulated/dataset_clock.svg"), "Right − left time of each frame pair over the session (unwrapped across frame periods) and the straight line of its drift.");
}

/// The page's "triangulation" section.
fn triangulation_section(page: &mut Page, r: &Report, tri: &Triangulation) {
    let s = r.s;
    let f = &tri.summary.frames;
    page.section("triangulation", "Triangulated tip against the truth")
        .paragraph(&format!(
            "Each row of the dataset is the median of a pressure step's frame pairs, in the hand frame (axes from the reference pair, origin from the zero-pressure steps). Error: Euclidean distance from the settled tip the virtual plant reports. The mean error is what every row shares: mostly the rest position's own error, since each tip is measured from it. {}",
            match tri.summary.steps_without_tip.len() {
                0 => "Every step has a tip.".to_string(),
                missing => {
                    let kept = (f.listed[0].min(f.listed[1]) as f64
                        / tri.summary.steps_logged.max(1) as f64)
                        .round();
                    format!(
                        "{missing} of {} steps have no tip: something passes in front of the bead in {:.0} % of the frames, and this run keeps about {kept} {} per camera and step (to stay short), so a hidden frame can cost its step; a full `handcap synth` capture keeps three per step and loses none.",
                        tri.summary.steps_logged,
                        100.0 * s.realism.occluded,
                        if kept == 1.0 { "frame" } else { "frames" }
                    )
                }
            }
        ))
        .table(
            &["phase", "steps", "RMS error (mm)", "largest (mm)", "mean error x, y, z (mm)"],
            &tips_rows(s),
        );
}

/// The page's section of more cameras: their calibration against the rig they were rendered
/// with, and their tips against the truth, each with its covariance.
fn cameras_section(page: &mut Page, r: &Report, c: &CamerasCheck) {
    let s = r.s;
    page.section("cameras", "More cameras: calibration and tips against the truth")
        .paragraph(&format!(
            "The cameras stand on an arc around the finger, each seeing its share of the board views (the arc's two ends never one together: they are tied through the cameras between). `handcap calibrate` refines every camera's intrinsics and pose and every board pose together; every corner reprojects at {:.3} px RMS; the hand axes are within {} of the truth. Each camera against the rig it was rendered with, beside what the calibration states (1 sd):",
            c.rms_px,
            c.hand_axes_error_deg.map_or("(no reference board)".into(), |d| format!("{d:.4}°")),
        ))
        .table(
            &["camera", "board views", "focal length error", "rotation error (stated sd)", "centre error (stated sd)"],
            &c.cameras.iter().map(|x| vec![
                x.name.clone(),
                x.views.to_string(),
                format!("{:+.3} %", x.focal_error_pct),
                format!("{:.4}° ({:.4}°)", x.rotation_error_deg, x.rotation_sd_deg),
                format!("{:.3} mm ({:.3} mm)", x.centre_error_mm, x.position_sd_mm),
            ]).collect::<Vec<_>>(),
        )
        .paragraph(&format!(
            "Each row of `triangulated/dataset.csv` is a pressure step's tip from every camera that saw its bead, the views gated by a χ² test (a camera left out in {} steps); its columns say which cameras it used and its covariance (`sd_*_mm`, `cov_*_mm2`: the beads' error and the calibration's). {} of {} steps have a tip ({}). The residuals show a bead error of {}; the rows' median standard deviations are {:.4} / {:.4} / {:.4} mm along x / y / z, and {:.1} % of the true tips lie inside their row's 95 % ellipsoid.",
            c.steps_with_left_out,
            c.steps_with_tip,
            s.triangulation.iter().find(|t| t.phase == "all").map_or(0, |t| t.rows),
            c.by_cameras.iter().map(|(n, k)| format!("{k} by {n} cameras")).collect::<Vec<_>>().join(", "),
            c.bead_noise_px.map_or("(too few steps to say)".into(), |px| format!("{px:.3} px")),
            c.median_sd_mm[0], c.median_sd_mm[1], c.median_sd_mm[2],
            100.0 * c.ellipsoid_coverage,
        ))
        .table(
            &["phase", "steps", "RMS error (mm)", "largest (mm)", "mean error x, y, z (mm)"],
            &tips_rows(s),
        );
}

/// The triangulated tips' errors, a row per phase.
fn tips_rows(s: &Summary) -> Vec<Vec<String>> {
    s.triangulation
        .iter()
        .map(|t| {
            let m = t.mean_mm;
            vec![
                t.phase.clone(),
                t.rows.to_string(),
                f4(t.rms_mm),
                f4(t.max_mm),
                format!("{:+.4}, {:+.4}, {:+.4}", m[0], m[1], m[2]),
            ]
        })
        .collect()
}

/// The page's "aco" section.
fn aco_section(page: &mut Page, r: &Report) {
    let (out, search) = (r.out, r.search);
    let m = out.join("model");
    page.section("aco", "ACO convergence (paper's Figures 7-8)")
        .paragraph("The paper's digit-encoded ant colony choosing (C, ε, σ), each ant scored by 5-fold cross-validated MAE on the triangulated training grid's 50 kPa points (the paper's 216 steps); the model is then fitted on every step of the grid.")
        .paragraph(&search.map_or("No search ran.".to_string(), |r| format!(
            "The colony chose C = {:.1}, ε = {:.4} mm, σ = {:.3} (in the scaled inputs), a cross-validated MAE of {:.4} mm, after {} iterations ({} candidates scored; stopped: {}).",
            r.best.c, r.best.epsilon, r.best.sigma, r.best_fitness, r.iterations, r.evaluations,
            match r.stop {
                crate::search::SearchStop::SamePath => "every ant took the same path",
                crate::search::SearchStop::MaxIterations => "the iteration cap",
                crate::search::SearchStop::Budget => "the evaluation budget",
                crate::search::SearchStop::Interrupted => "interrupted",
            }
        )))
        .figure(&m.join("fig7_min_mae.svg"), "Figure 7: the best ant's error per iteration.")
        .figure(&m.join("fig8_mean_mae.svg"), "Figure 8: the mean error of the ants per iteration.");
}

/// The page's "sweeps" section.
fn sweeps_section(page: &mut Page, r: &Report) {
    let out = r.out;
    let m = out.join("model");
    page.section("sweeps", "The two test sweeps (paper's Figures 9-14)")
        .paragraph("Held-out sweeps (never trained on): A, P1 = P2 = 0 with P3 from 0 to 250 kPa; B, P1 = 0 with P2 = P3 from 0 to 250 kPa. Points: triangulated tips; curves: MSVR and the previous physics model (default and calibrated constants).");
    for (sweep, name) in [
        ("dataset_sweep_a", "Sweep A"),
        ("dataset_sweep_b", "Sweep B"),
    ] {
        for axis in ["x", "y", "z"] {
            page.figure(
                &m.join(format!("{sweep}_{axis}_mm.svg")),
                &format!("{name}: the tip's {axis} (mm), measured and modelled."),
            );
        }
        page.figure(
            &m.join(format!("{sweep}_residuals.svg")),
            &format!("{name}: each model's Euclidean tip error (mm, log scale)."),
        );
    }
}

/// The page's "errors" section.
fn errors_section(page: &mut Page, r: &Report) {
    let s = r.s;
    page.section("errors", "Held-out errors")
        .paragraph("MAE: mean over steps and coordinates of |measured − predicted| (the paper's measure); Euclidean: mean distance. Models trained on the triangulated frames and, for comparison, the same model (the C, ε, σ the search chose) trained on the plant's own data (its exact tips with 0.02 mm noise): what the camera path costs; tested on the triangulated sweeps (dataset_*) and on the plant's sweeps. Rows `auto: …` are what `handcap model` fits on the same rows with its defaults: each family searched by ACO_R on the same folds, the pick by cross-validation (model_auto/).")
        .table(
            &["trained on", "model", "test", "MAE (mm)", "mean Euclidean (mm)", "max Euclidean (mm)"],
            &s.scores.iter().map(|x| vec![x.trained_on.clone(), x.model.clone(), x.test.clone(), f4(x.errors.mae), f4(x.errors.euclid), f4(x.errors.max_euclid)]).collect::<Vec<_>>(),
        );
    page.paragraph(&format!(
        "`handcap model`'s default picked {}: {}.",
        s.auto.used.title(),
        s.auto.verdict()
    ));
}

/// The page's "intervals" section.
fn intervals_section(page: &mut Page, r: &Report) {
    let s = r.s;
    page.section("intervals", "Prediction intervals")
        .paragraph("Conformal radii of the tip's Euclidean error, from the training rows held out by the cross-validation's folds: the measured tip lies within the radius of the prediction that share of the time. The radii below hold where the pressures are as near the training grid as nine held-out rows in ten were; farther from it each row's radius widens (docs/models.md), and the coverage counts each row within its own. The guarantee is marginal, over rows exchangeable with the held-out grid points, not for each input: the sweeps run along the edges of the pressure box (P1 = 0), where the model has neighbours on one side only, and with 24-26 rows each their coverage moves by about 6 points from chance alone.")
        .table(
            &["trained on", "held-out rows", "90 % radius (mm)", "95 % radius (mm)", "test", "covered at 90 %", "covered at 95 %"],
            &s.intervals.iter().flat_map(|i| {
                let radius = |k: usize| i.intervals.held_out.radii.get(k).map_or("-".into(), |r| f4(r.radius));
                let covered = |t: &crate::report::TestCoverageReport, k: usize| {
                    t.coverage.pooled.get(k).map_or("-".into(), |(_, c)| format!("{:.1} %", 100.0 * c))
                };
                i.intervals.tests.iter().map(move |t| vec![
                    i.trained_on.clone(), i.intervals.held_out.rows.to_string(), radius(0), radius(1),
                    t.test.clone(), covered(t, 0), covered(t, 1),
                ])
            }).collect::<Vec<_>>(),
        );
}

/// The page's "inverse" section.
fn inverse_section(page: &mut Page, r: &Report) {
    let (s, planned) = (r.s, r.planned);
    page.section("inverse", "Inverse model: feed-forward on the virtual plant")
        .paragraph("Targets: the plant's tip at random pressures in [0, 250] kPa (so each is reachable). The inverse model plans pressures for each target (bounded Levenberg-Marquardt on the MSVR with its analytic gradient, several starts); the virtual plant runs the planned pressures; the error is the distance of the plant's tip from the target — sensorless feed-forward, measured. It cannot be smaller than the forward model's own error at those pressures, which the training grid's spacing sets: the second row fits the same parameters to the 50 kPa points alone.")
        .table(
            &["model", "targets", "reached by the model", "mean (mm)", "median (mm)", "90 % (mm)", "max (mm)", "plant tip within the 90 % interval"],
            &s.inverse.iter().map(|i| vec![
                i.model.clone(), i.targets.to_string(), i.reached_by_model.to_string(), f4(i.mean_mm), f4(i.median_mm), f4(i.p90_mm), f4(i.max_mm),
                i.interval.map_or("-".into(), |(r, c)| format!("{:.1} % (radius {r:.4} mm)", 100.0 * c)),
            ]).collect::<Vec<_>>(),
        )
        .table(
            &["target x, y, z (mm)", "planned P1, P2, P3 (kPa)", "plant tip x, y, z (mm)", "error (mm)"],
            &planned.iter().take(10).map(|r| vec![
                triple(&r.target, 3), triple(&r.solution.inputs, 1), triple(&r.plant, 3), f4(r.plant_error),
            ]).collect::<Vec<_>>(),
        )
        .paragraph("All targets: inverse_check.csv. The last column: the share of planned tips whose plant tip lies within the model's 90 % interval of the model's own tip there. The interval is calibrated on triangulated tips, so it cannot see what every triangulated row shares (the hand frame's origin, the triangulation table's mean error), nor the inverse's own error; against the plant's truth it covers less than its level.");
}

/// The page's "dynamic" section.
fn dynamic_section(page: &mut Page, r: &Report, d: &super::demo_dynamic::DynamicCheck) {
    let out = r.out;
    page.section("dynamic", "The finger in motion: per-frame tips and input history")
        .paragraph(&format!(
            "A dynamic session: {} trials of {} s, each muscle commanded {} times a second by a rate-limited random sequence (APRBS) over 0-{} kPa, with rest holds at 0, 0, 0 kPa first, between trials and last. The muscles follow through a pneumatic line (delay {} ms, lags {} s, muscles 1-3), {} % of the response creeping with a time constant of {} s; the cameras run free at 30 fps, each on its own clock. `triangulate --per-frame` gives one row per left frame: the right camera's track interpolated to its instant across the clocks' offset (measured from the motion: {:+.2} ms), the pressures in force then.",
            d.design.trials, d.design.duration_s, d.design.rate_hz, d.design.max_kpa,
            1e3 * d.dynamics.delay_s, triple(&d.dynamics.lag_s, 2), 100.0 * d.dynamics.creep_share, d.dynamics.creep_s,
            d.clock_offset_ms,
        ))
        .table(
            &["frames", "rows with a tip, unflagged", "tip RMS vs truth (mm)", "largest (mm)"],
            &[vec![d.rows.to_string(), format!("{} ({:.1} %)", d.unflagged, 100.0 * d.unflagged as f64 / d.rows.max(1) as f64), f4(d.tip_rms_mm), f4(d.tip_max_mm)]],
        )
        .paragraph(&format!(
            "Trial {} held out whole; the models trained on the others (the search's folds are whole trials). The history model chose `{}` (exponentially filtered pressures, time constants in s); the last row is that same model (its history and C, ε, σ) fitted on the plant's per-frame truth: what the camera path costs.",
            d.held_out, d.history
        ))
        .table(
            &["model", "trained on", "held-out MAE (mm)", "mean Euclidean (mm)", "max Euclidean (mm)"],
            &d.scores.iter().map(|x| vec![x.model.clone(), x.trained_on.clone(), f4(x.errors.mae), f4(x.errors.euclid), f4(x.errors.max_euclid)]).collect::<Vec<_>>(),
        );
    for axis in ["x", "y"] {
        page.figure(
            &out.join(format!("dynamic/trajectory_{axis}_mm.svg")),
            &format!("The held-out trial: the tip's {axis} against time, the truth at each frame's instant, the triangulated rows, and both models' predictions from the commanded pressures."),
        );
    }
}

/// The page's "manifest" section.
fn manifest_section(page: &mut Page, r: &Report) {
    let (s, timings) = (r.s, r.timings);
    page.section("manifest", "Run manifest")
        .table(
            &["item", "value"],
            &[
                vec!["handcap version".into(), s.provenance.handcap_version.clone()],
                vec!["command".into(), s.provenance.command.join(" ")],
                vec!["seed".into(), s.seed.to_string()],
                vec!["stage timings (s)".into(), timings.iter().map(|(k, v)| format!("{k} {v:.1}")).collect::<Vec<_>>().join(", ")],
            ],
        )
        .paragraph("Files: capture/ (images, pressures.csv, truth/), calib.yml, triangulated/ (dataset and its diagnostics), search/ (the rows the search scored), model.json and model/ (report.md, metrics.csv, history.csv, figures), model_plant/, inverse_check.csv, summary.json (the same bytes for the same seed), timings.json (the stage times).");
}

fn triple(v: &[f64], digits: usize) -> String {
    v.iter()
        .map(|x| format!("{x:.digits$}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn timing(timings: &[(String, f64)], stage: &str) -> String {
    timings
        .iter()
        .find(|(k, _)| k == stage)
        .map_or(String::new(), |(_, v)| format!("{v:.1}"))
}
