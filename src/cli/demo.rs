//! `handcap demo`: the whole pipeline on the built-in virtual micro-hand, checked against its
//! ground truth, with one report a lab can read.
//!
//! Stages: synth (images, log, truth: `DIR/capture/`) → calibrate (`DIR/calib.yml`) →
//! triangulate (`DIR/triangulated/`) → model: MSVR with the default search and fitness, and the
//! previous model, from the triangulated data (`DIR/model.json`, `DIR/model/`) and, for
//! comparison, from the plant's own data (`DIR/model_plant/`) → inverse: pressures planned for
//! targets the virtual plant can reach, run through the plant (`DIR/inverse_check.csv`) →
//! `DIR/report/index.html` and `DIR/summary.json`.
//!
//! The training grid is 25 kPa (1331 steps): feed-forward needs the model within 0.1 mm between
//! grid levels, and the paper's 50 kPa grid leaves about 0.18 mm there (the report shows both).
//! The search scores its candidates on the 50 kPa points of the grid (`DIR/search/`, the paper's
//! 216 steps), so it takes as long as the paper's; the fit uses every step.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rand::{Rng, SeedableRng};
use serde::Serialize;

use handcap::calib::{CalibOptions, StereoCalibration};
use handcap::data::{names, HAND_INPUTS, HAND_OUTPUTS};
use handcap::fsio;
use handcap::model::file::{ModelFile, StoredModel};
use handcap::model::inverse::{self, InverseOptions, PlannedTarget};
use handcap::model::msvr::{Msvr, MsvrParams};
use handcap::model::Errors;
use handcap::provenance::Provenance;
use handcap::report::html::Page;
use handcap::search::aco_paper::AcoPaper;
use handcap::search::fitness::FitnessKind;
use handcap::search::Method;
use handcap::stereo::{self, CalibrationFile};
use handcap::synth::capture::CaptureConfig;
use handcap::synth::plant::Plant;
use handcap::synth::render::ImageFormat;
use handcap::synth::{self, SynthConfig};
use handcap::triangulate::{TriangulateOptions, Triangulation};

use super::model::{self, Job, Outcome, Selection, PAPER_C, PAPER_EPSILON, PAPER_SIGMA};
use super::synth::FormatArg;

#[derive(clap::Args)]
pub struct Args {
    /// Output directory
    #[arg(long, default_value = "handcap-demo")]
    out: PathBuf,
    /// Seed of every random choice
    #[arg(long, default_value_t = synth::DEFAULT_SEED)]
    seed: u64,
    /// A reduced run for a first look and the tests: 8 board pairs, a 125 kPa grid and 50 kPa
    /// sweeps, a short search, 20 inverse targets
    #[arg(long)]
    quick: bool,
    /// Frame images: jpeg (as webcams stream; the capture is about 130 MB) or png (1.6 GB)
    #[arg(long, value_enum, default_value = "jpeg")]
    format: FormatArg,
}

/// The sizes of a run.
struct Plan {
    views: usize,
    grid_step_kpa: f64,
    sweep_step_kpa: f64,
    /// The search scores candidates on the grid points at this step only (none: all of them),
    /// so that a dense grid keeps the search fast; the fit uses every row.
    search_grid_kpa: Option<f64>,
    /// Frames kept per step: stamped this far into it (s).
    window_s: [f64; 2],
    triangulate: TriangulateOptions,
    aco: AcoPaper,
    targets: usize,
}

impl Plan {
    fn new(quick: bool, seed: u64) -> Self {
        let aco = AcoPaper {
            seed,
            ..AcoPaper::default()
        };
        if quick {
            Plan {
                views: 8,
                grid_step_kpa: 125.0,
                sweep_step_kpa: 50.0,
                search_grid_kpa: None,
                window_s: CaptureConfig::default().window_s,
                triangulate: TriangulateOptions::default(),
                aco: AcoPaper {
                    ants: 8,
                    max_iter: 6,
                    ..aco
                },
                targets: 20,
            }
        } else {
            // A 25 kPa training grid (1331 steps): the 50 kPa grid of the paper leaves 0.18 mm of
            // interpolation error between its levels, too much for feed-forward. One or two
            // frames per camera and step (the finger holds still, so a pair may be up to 50 ms
            // apart) keep the capture to about 3300 frames.
            Plan {
                views: 20,
                grid_step_kpa: 25.0,
                sweep_step_kpa: 10.0,
                search_grid_kpa: Some(50.0),
                window_s: [0.10, 0.14],
                triangulate: TriangulateOptions {
                    max_dt_s: 0.05,
                    min_frames: 1,
                    ..TriangulateOptions::default()
                },
                aco,
                targets: 100,
            }
        }
    }
}

/// Calibration against the truth.
#[derive(Serialize)]
struct CalibrationCheck {
    pairs_used: usize,
    rms_px: f64,
    epipolar_px: f64,
    /// Largest relative error of fx, fy, cx, cy over both cameras (%).
    intrinsics_error_pct: f64,
    baseline_error_pct: f64,
    rotation_error_deg: f64,
    hand_axes_error_deg: Option<f64>,
}

/// Triangulated tips against the truth, per phase.
#[derive(Serialize)]
struct TipCheck {
    phase: String,
    rows: usize,
    rms_mm: f64,
    max_mm: f64,
}

/// One model × test file.
#[derive(Serialize)]
struct Score {
    trained_on: String,
    model: String,
    test: String,
    errors: Errors,
}

/// Planned pressures run through the plant.
#[derive(Serialize)]
struct InverseCheck {
    model: String,
    targets: usize,
    reached_by_model: usize,
    mean_mm: f64,
    median_mm: f64,
    p90_mm: f64,
    max_mm: f64,
}

#[derive(Serialize)]
struct Summary {
    seed: u64,
    quick: bool,
    timings_s: Vec<(String, f64)>,
    calibration: CalibrationCheck,
    triangulation: Vec<TipCheck>,
    scores: Vec<Score>,
    inverse: Vec<InverseCheck>,
    provenance: Provenance,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let started = Instant::now();
    let plan = Plan::new(a.quick, a.seed);
    let out = &a.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let provenance = Provenance::new(super::command_line(), Some(a.seed));
    let mut timings: Vec<(String, f64)> = Vec::new();
    let mut clock = Instant::now();
    let mut lap = |name: &str, timings: &mut Vec<(String, f64)>| {
        let s = clock.elapsed().as_secs_f64();
        println!("      {name} done in {s:.1} s");
        timings.push((name.to_string(), s));
        clock = Instant::now();
    };

    // 1. The virtual capture.
    let capture = out.join("capture");
    println!(
        "[1/6] synth: the virtual micro-hand filmed by two webcams → {}",
        capture.display()
    );
    let config = SynthConfig {
        seed: a.seed,
        grid_step_kpa: plan.grid_step_kpa,
        sweep_step_kpa: plan.sweep_step_kpa,
        ..SynthConfig::default()
    };
    let capture_config = CaptureConfig {
        views: plan.views,
        window_s: plan.window_s,
        format: match a.format {
            FormatArg::Png => ImageFormat::Png,
            FormatArg::Jpeg => ImageFormat::Jpeg { quality: 95 },
        },
        ..CaptureConfig::default()
    };
    super::synth::write_all(&capture, &config, Some(&capture_config), &provenance)?;
    lap("synth", &mut timings);

    // 2. Calibration.
    println!(
        "[2/6] calibrate: {} chessboard pairs → calib.yml",
        plan.views
    );
    let calib_dir = capture.join("calib");
    let board = super::calibrate::board_spec(&calib_dir, None, None)?;
    let calib_path = out.join("calib.yml");
    let cal = super::calibrate::calibrate_and_write(
        &calib_dir,
        &board,
        &CalibOptions::default(),
        &calib_path,
    )?;
    let truth = stereo::read_calibration(&capture.join("truth/rig.yml"))?;
    let calibration = check_calibration(&cal, &truth);
    lap("calibrate", &mut timings);

    // 3. Triangulation.
    println!("[3/6] triangulate: the red tip in every frame pair → dataset");
    let tri = super::triangulate::triangulate_and_write(
        &capture.join("frames"),
        &calib_path,
        &capture.join("pressures.csv"),
        &plan.triangulate,
        &out.join("triangulated/dataset.csv"),
    )?;
    let triangulation = check_tips(&tri, &capture.join("truth/tips.csv"))?;
    for t in &triangulation {
        println!(
            "      tip vs truth, {}: RMS {:.4} mm, max {:.4} mm over {} steps",
            t.phase, t.rms_mm, t.max_mm, t.rows
        );
    }
    lap("triangulate", &mut timings);

    // 4. Models: from the triangulated data (the pipeline) and from the plant's own data.
    println!("[4/6] model: MSVR, (C, ε, σ) by the paper's ant colony on 5-fold CV, and the previous model");
    let tri_dir = out.join("triangulated");
    let plant_tests = [capture.join("sweep_a.csv"), capture.join("sweep_b.csv")];
    let (tri_train, plant_train) = (tri_dir.join("dataset_train.csv"), capture.join("train.csv"));
    let (tri_coarse, plant_coarse) = match plan.search_grid_kpa {
        Some(step) => (
            Some(coarse_rows(
                &tri_train,
                step,
                &out.join("search/triangulated_train.csv"),
            )?),
            Some(coarse_rows(
                &plant_train,
                step,
                &out.join("search/plant_train.csv"),
            )?),
        ),
        None => (None, None),
    };
    let images = model::execute(&job(
        &plan,
        tri_train.clone(),
        tri_coarse.clone(),
        [
            tri_dir.join("dataset_sweep_a.csv"),
            tri_dir.join("dataset_sweep_b.csv"),
        ]
        .into_iter()
        .chain(plant_tests.iter().cloned())
        .collect(),
        out.join("model.json"),
        out.join("model"),
    ))?;
    model::print_summary(&images);
    let plant_data = model::execute(&job(
        &plan,
        plant_train,
        plant_coarse,
        plant_tests.to_vec(),
        out.join("model_plant.json"),
        out.join("model_plant"),
    ))?;
    let mut scores = scores_of("triangulated frames", &images);
    scores.extend(scores_of("the plant's data", &plant_data));
    lap("model", &mut timings);

    // 5. Feed-forward: planned pressures run through the virtual plant.
    println!(
        "[5/6] inverse: pressures planned for {} reachable targets, run through the virtual plant",
        plan.targets
    );
    let plant = Plant::new(config.plant.clone());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(a.seed ^ 0x494e_5645);
    let sources: Vec<Vec<f64>> = (0..plan.targets)
        .map(|_| (0..3).map(|_| rng.random_range(0.0..=250.0)).collect())
        .collect();
    let msvr = load_msvr(&out.join("model.json"))?;
    let planned = feedforward(&msvr, &plant, &sources)?;
    write_inverse_csv(&out.join("inverse_check.csv"), &planned)?;
    let mut inverse = vec![inverse_stats(
        &format!(
            "MSVR from the triangulated frames ({} kPa grid)",
            plan.grid_step_kpa
        ),
        &planned,
    )];
    if let (Some(step), Some(coarse)) = (plan.search_grid_kpa, &tri_coarse) {
        // The same check with the same parameters fitted on the coarse grid alone: what the
        // training grid's spacing costs.
        let data =
            handcap::data::read_dataset(coarse, &names(&HAND_INPUTS), &names(&HAND_OUTPUTS))?;
        let sparse = msvr.params.check()?.fit(&data)?;
        inverse.push(inverse_stats(
            &format!(
                "MSVR from the triangulated frames, {step} kPa grid only ({} rows)",
                data.rows()
            ),
            &feedforward(&sparse, &plant, &sources)?,
        ));
    }
    for c in &inverse {
        println!(
            "      {}: plant tip error mean {:.4} mm, median {:.4}, 90 % {:.4}, max {:.4} ({} of {} reached by the model)",
            c.model, c.mean_mm, c.median_mm, c.p90_mm, c.max_mm, c.reached_by_model, c.targets
        );
    }
    lap("inverse", &mut timings);

    // 6. The report.
    println!("[6/6] report");
    timings.push(("total".into(), started.elapsed().as_secs_f64()));
    let summary = Summary {
        seed: a.seed,
        quick: a.quick,
        timings_s: timings,
        calibration,
        triangulation,
        scores,
        inverse,
        provenance,
    };
    fsio::write_bytes(
        &out.join("summary.json"),
        (serde_json::to_string_pretty(&summary)? + "\n").as_bytes(),
    )?;
    let index = out.join("report/index.html");
    std::fs::create_dir_all(out.join("report"))?;
    report(out, &summary, &tri, &cal, &planned)
        .write(&index)
        .with_context(|| format!("writing {}", index.display()))?;
    println!(
        "      done in {:.1} s (total {:.1} s)",
        clock.elapsed().as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
    println!("report: {}", index.display());
    Ok(())
}

fn job(
    plan: &Plan,
    data: PathBuf,
    search_on: Option<PathBuf>,
    tests: Vec<PathBuf>,
    out: PathBuf,
    report: PathBuf,
) -> Job {
    Job {
        data,
        inputs: names(&HAND_INPUTS),
        outputs: names(&HAND_OUTPUTS),
        params: MsvrParams::new(PAPER_C, PAPER_EPSILON, PAPER_SIGMA),
        selection: Selection::Search {
            method: Method::AcoPaper(plan.aco),
            fitness: FitnessKind::Cv { folds: 5 },
            group_by: None,
            seed: plan.aco.seed,
            on: search_on,
        },
        tests,
        out,
        report: Some(report),
    }
}

fn scores_of(trained_on: &str, outcome: &Outcome) -> Vec<Score> {
    outcome
        .report
        .tests
        .iter()
        .map(|t| Score {
            trained_on: trained_on.to_string(),
            model: t.model.clone(),
            test: t.test.clone(),
            errors: t.errors.clone(),
        })
        .collect()
}

/// The rows of a dataset whose pressures all lie on a `step_kpa` grid, written to `to`.
fn coarse_rows(from: &Path, step_kpa: f64, to: &Path) -> anyhow::Result<PathBuf> {
    let text = std::fs::read_to_string(from).with_context(|| from.display().to_string())?;
    let mut lines = text.lines();
    let mut out = String::from(lines.next().unwrap_or_default());
    out.push('\n');
    for line in lines {
        let on_grid = line.split(',').take(3).all(|v| {
            v.parse::<f64>()
                .is_ok_and(|p| (p / step_kpa - (p / step_kpa).round()).abs() < 1e-9)
        });
        if on_grid {
            out += line;
            out.push('\n');
        }
    }
    if let Some(dir) = to.parent() {
        std::fs::create_dir_all(dir)?;
    }
    fsio::write_bytes(to, out.as_bytes()).with_context(|| format!("writing {}", to.display()))?;
    Ok(to.to_path_buf())
}

fn load_msvr(path: &Path) -> anyhow::Result<Msvr> {
    let StoredModel::Msvr(m) = ModelFile::load(path)?.model;
    Ok(m)
}

fn feedforward(
    model: &Msvr,
    plant: &Plant,
    sources: &[Vec<f64>],
) -> anyhow::Result<Vec<PlannedTarget>> {
    let options = InverseOptions::within_training_range(model, |_| Some((0.0, 250.0)));
    Ok(inverse::feedforward_check(
        model,
        |p| plant.tip([p[0], p[1], p[2]]).ok().map(|t| t.to_vec()),
        sources,
        &options,
    )?)
}

fn inverse_stats(model: &str, rows: &[PlannedTarget]) -> InverseCheck {
    let mut e: Vec<f64> = rows.iter().map(|r| r.plant_error).collect();
    e.sort_by(f64::total_cmp);
    let at = |q: f64| e[((e.len() - 1) as f64 * q).round() as usize];
    InverseCheck {
        model: model.to_string(),
        targets: rows.len(),
        reached_by_model: rows.iter().filter(|r| r.solution.reached).count(),
        mean_mm: e.iter().sum::<f64>() / e.len() as f64,
        median_mm: at(0.5),
        p90_mm: at(0.9),
        max_mm: at(1.0),
    }
}

fn write_inverse_csv(path: &Path, rows: &[PlannedTarget]) -> anyhow::Result<()> {
    let mut text = String::from("x_mm,y_mm,z_mm,P1_kpa,P2_kpa,P3_kpa,x_model_mm,y_model_mm,z_model_mm,x_plant_mm,y_plant_mm,z_plant_mm,plant_error_mm,source_P1_kpa,source_P2_kpa,source_P3_kpa\n");
    for r in rows {
        let cells: Vec<String> = r
            .target
            .iter()
            .chain(&r.solution.inputs)
            .chain(&r.solution.achieved)
            .chain(&r.plant)
            .chain(std::iter::once(&r.plant_error))
            .chain(&r.source_inputs)
            .map(|v| format!("{v:.4}"))
            .collect();
        text += &cells.join(",");
        text.push('\n');
    }
    fsio::write_bytes(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

fn check_calibration(cal: &StereoCalibration, truth: &CalibrationFile) -> CalibrationCheck {
    use nalgebra::{Matrix3, Rotation3, Vector3};
    let t = &truth.rig;
    let mut intrinsics = 0.0f64;
    for (got, want) in [(&cal.rig.left.k, &t.left.k), (&cal.rig.right.k, &t.right.k)] {
        for i in [0, 4, 2, 5] {
            intrinsics = intrinsics.max(100.0 * ((got[i] - want[i]) / want[i]).abs());
        }
    }
    let (gt, tt) = (
        Vector3::from_row_slice(&cal.rig.t),
        Vector3::from_row_slice(&t.t),
    );
    let rot = |m: &[f64; 9]| Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(m));
    CalibrationCheck {
        pairs_used: cal.used().count(),
        rms_px: cal.rms_px,
        epipolar_px: cal.epipolar_px,
        intrinsics_error_pct: intrinsics,
        baseline_error_pct: 100.0 * (gt.norm() - tt.norm()).abs() / tt.norm(),
        rotation_error_deg: (rot(&cal.rig.r).inverse() * rot(&t.r)).angle().to_degrees(),
        hand_axes_error_deg: cal
            .hand_axes
            .as_ref()
            .zip(truth.r_hand.as_ref())
            .map(|(g, w)| {
                (rot(g).inverse() * Rotation3::from_matrix_unchecked(*w))
                    .angle()
                    .to_degrees()
            }),
    }
}

/// RMS and largest Euclidean error of the rows against `truth/tips.csv`, per phase and overall.
fn check_tips(tri: &Triangulation, truth: &Path) -> anyhow::Result<Vec<TipCheck>> {
    let column = |name: &str| tri.extra_columns.iter().position(|c| c == name);
    let (Some(step_col), Some(phase_col)) = (column("step"), column("phase")) else {
        anyhow::bail!("the synthetic log has step and phase columns");
    };
    let mut reader = csv::Reader::from_path(truth).with_context(|| truth.display().to_string())?;
    let mut tips = std::collections::HashMap::new();
    for r in reader.records() {
        let r = r?;
        let v = |i: usize| r[i].parse::<f64>().unwrap_or(f64::NAN);
        tips.insert(r[0].to_string(), [v(5), v(6), v(7)]);
    }
    let mut by_phase: Vec<(String, Vec<f64>)> = Vec::new();
    for row in tri.rows.iter().filter(|r| r.flags.is_empty()) {
        let t = tips
            .get(&row.extra[step_col])
            .with_context(|| format!("step {} not in {}", row.extra[step_col], truth.display()))?;
        let e = (0..3)
            .map(|k| (row.tip_mm[k] - t[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        let phase = &row.extra[phase_col];
        match by_phase.iter_mut().find(|(p, _)| p == phase) {
            Some((_, v)) => v.push(e),
            None => by_phase.push((phase.clone(), vec![e])),
        }
    }
    let all: Vec<f64> = by_phase.iter().flat_map(|(_, v)| v.clone()).collect();
    by_phase.push(("all".into(), all));
    Ok(by_phase
        .into_iter()
        .map(|(phase, e)| TipCheck {
            rows: e.len(),
            rms_mm: (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt(),
            max_mm: e.iter().copied().fold(0.0, f64::max),
            phase,
        })
        .collect())
}

fn f4(v: f64) -> String {
    format!("{v:.4}")
}

/// The report page.
fn report(
    out: &Path,
    s: &Summary,
    tri: &Triangulation,
    cal: &StereoCalibration,
    planned: &[PlannedTarget],
) -> Page {
    let mut page = Page::new("handcap demo: the virtual micro-hand, end to end");
    let c = &s.calibration;
    let all = s.triangulation.iter().find(|t| t.phase == "all");
    page.paragraph(&format!(
        "A virtual micro-hand (three McKibben muscles, 50 mm) filmed by two virtual 1280×720 webcams while its pressures step through the paper's protocol; every stage of the pipeline run on the files, and checked against the ground truth the virtual capture wrote. Seed {}{}.",
        s.seed,
        if s.quick { ", reduced run (--quick)" } else { "" }
    ))
    .section("summary", "Key numbers")
    .table(
        &["stage", "result", "time (s)"],
        &[
            vec![
                "synth".into(),
                format!("{} board pairs, {} pressure steps", cal.pairs.len(), tri.summary.steps_logged),
                timing(s, "synth"),
            ],
            vec![
                "calibrate".into(),
                format!("RMS {:.3} px; intrinsics within {:.3} %, baseline {:.3} %, rotation {:.4}°", c.rms_px, c.intrinsics_error_pct, c.baseline_error_pct, c.rotation_error_deg),
                timing(s, "calibrate"),
            ],
            vec![
                "triangulate".into(),
                all.map_or("-".into(), |t| format!("tip RMS error {:.4} mm over {} steps", t.rms_mm, t.rows)),
                timing(s, "triangulate"),
            ],
            vec![
                "model".into(),
                s.scores
                    .iter()
                    .find(|x| x.model == "msvr" && x.test == "dataset_sweep_a.csv")
                    .map_or("-".into(), |x| format!("MSVR held-out MAE {:.4} mm on sweep A", x.errors.mae)),
                timing(s, "model"),
            ],
            vec![
                "inverse".into(),
                s.inverse.first().map_or("-".into(), |i| format!("planned pressures put the plant's tip {:.4} mm (mean) from the target", i.mean_mm)),
                timing(s, "inverse"),
            ],
            vec!["total".into(), String::new(), timing(s, "total")],
        ],
    );

    page.section("calibration", "Calibration")
        .paragraph(&format!(
            "{} chessboard pairs used. Reprojection RMS {:.3} px, mean epipolar distance {:.3} px. Against the true rig: focal lengths and principal points within {:.3} %, baseline within {:.3} %, rotation within {:.4}°, hand axes within {}.",
            c.pairs_used, c.rms_px, c.epipolar_px, c.intrinsics_error_pct, c.baseline_error_pct, c.rotation_error_deg,
            c.hand_axes_error_deg.map_or("(no reference pair)".into(), |d| format!("{d:.4}°"))
        ))
        .figure(&out.join("calib_pairs.svg"), "Reprojection error of each chessboard pair (left and right image).")
        .figure(&out.join("calib_rectified.png"), "A pair rectified with the calibration: corresponding points lie on the same horizontal line.");

    let f = &tri.summary.frames;
    page.section("detection", "Tip detection")
        .paragraph(&format!(
            "{} left and {} right frames; marker missing in {} / {}, several candidates in {} / {}. {} frame pairs, {} used; reprojection error of the used pairs: median {:.3} px, largest {:.3} px.",
            f.listed[0], f.listed[1], f.marker_missing[0], f.marker_missing[1], f.several_candidates[0], f.several_candidates[1],
            tri.summary.pairs_formed,
            tri.summary.pairs.iter().filter(|(k, _)| **k == "used" || **k == "resolved").map(|(_, v)| v).sum::<usize>(),
            tri.summary.reproj_px[0], tri.summary.reproj_px[2]
        ))
        .figure(&out.join("triangulated/dataset_detections.png"), "Detected tip (green cross) and the triangulated tip reprojected (magenta circle), left and right crops, and where the crop lies in the left frame.");

    page.section("triangulation", "Triangulated tip against the truth")
        .paragraph("Each row of the dataset is the median of a pressure step's frame pairs, in the hand frame (axes from the reference pair, origin from the zero-pressure steps). Error: Euclidean distance from the settled tip the virtual plant reports.")
        .table(
            &["phase", "steps", "RMS error (mm)", "largest (mm)"],
            &s.triangulation.iter().map(|t| vec![t.phase.clone(), t.rows.to_string(), f4(t.rms_mm), f4(t.max_mm)]).collect::<Vec<_>>(),
        );

    let m = out.join("model");
    page.section("aco", "ACO convergence (paper's Figures 7-8)")
        .paragraph("The paper's digit-encoded ant colony choosing (C, ε, σ), each ant scored by 5-fold cross-validated MAE on the triangulated training grid's 50 kPa points (the paper's 216 steps); the model is then fitted on every step of the grid.")
        .figure(&m.join("fig7_min_mae.svg"), "Figure 7: the best ant's error per iteration.")
        .figure(&m.join("fig8_mean_mae.svg"), "Figure 8: the mean error of the ants per iteration.");

    page.section("sweeps", "The two test sweeps (paper's Figures 9-14)")
        .paragraph("Held-out sweeps (never trained on): A, P1 = P2 = 0 with P3 from 0 to 250 kPa; B, P1 = 0 with P2 = P3 from 0 to 250 kPa. Points: triangulated tips; curves: MSVR and the previous physics model (default and calibrated constants).");
    for sweep in ["dataset_sweep_a", "dataset_sweep_b"] {
        for axis in ["x_mm", "y_mm", "z_mm", "residuals"] {
            page.figure(
                &m.join(format!("{sweep}_{axis}.svg")),
                &format!("{sweep}: {axis}"),
            );
        }
    }

    page.section("errors", "Held-out errors")
        .paragraph("MAE: mean over steps and coordinates of |measured − predicted| (the paper's measure); Euclidean: mean distance. Models trained on the triangulated frames and, for comparison, on the plant's own data (its exact tips with 0.02 mm noise); tested on the triangulated sweeps (dataset_*) and on the plant's sweeps.")
        .table(
            &["trained on", "model", "test", "MAE (mm)", "mean Euclidean (mm)", "max Euclidean (mm)"],
            &s.scores.iter().map(|x| vec![x.trained_on.clone(), x.model.clone(), x.test.clone(), f4(x.errors.mae), f4(x.errors.euclid), f4(x.errors.max_euclid)]).collect::<Vec<_>>(),
        );

    page.section("inverse", "Inverse model: feed-forward on the virtual plant")
        .paragraph("Targets: the plant's tip at random pressures in [0, 250] kPa (so each is reachable). The inverse model plans pressures for each target (bounded Levenberg-Marquardt on the MSVR with its analytic gradient, several starts); the virtual plant runs the planned pressures; the error is the distance of the plant's tip from the target — sensorless feed-forward, measured. It cannot be smaller than the forward model's own error at those pressures, which the training grid's spacing sets: the second row fits the same parameters to the 50 kPa points alone.")
        .table(
            &["model", "targets", "reached by the model", "mean (mm)", "median (mm)", "90 % (mm)", "max (mm)"],
            &s.inverse.iter().map(|i| vec![i.model.clone(), i.targets.to_string(), i.reached_by_model.to_string(), f4(i.mean_mm), f4(i.median_mm), f4(i.p90_mm), f4(i.max_mm)]).collect::<Vec<_>>(),
        )
        .table(
            &["target x, y, z (mm)", "planned P1, P2, P3 (kPa)", "plant tip x, y, z (mm)", "error (mm)"],
            &planned.iter().take(10).map(|r| vec![
                triple(&r.target, 3), triple(&r.solution.inputs, 1), triple(&r.plant, 3), f4(r.plant_error),
            ]).collect::<Vec<_>>(),
        )
        .paragraph("All targets: inverse_check.csv.");

    page.section("manifest", "Run manifest")
        .table(
            &["item", "value"],
            &[
                vec!["handcap version".into(), s.provenance.handcap_version.clone()],
                vec!["command".into(), s.provenance.command.join(" ")],
                vec!["seed".into(), s.seed.to_string()],
                vec!["stage timings (s)".into(), s.timings_s.iter().map(|(k, v)| format!("{k} {v:.1}")).collect::<Vec<_>>().join(", ")],
            ],
        )
        .paragraph("Files: capture/ (images, pressures.csv, truth/), calib.yml, triangulated/ (dataset and its diagnostics), search/ (the rows the search scored), model.json and model/ (report.md, metrics.csv, history.csv, figures), model_plant/, inverse_check.csv, summary.json.");
    page
}

fn triple(v: &[f64], digits: usize) -> String {
    v.iter()
        .map(|x| format!("{x:.digits$}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn timing(s: &Summary, stage: &str) -> String {
    s.timings_s
        .iter()
        .find(|(k, _)| k == stage)
        .map_or(String::new(), |(_, v)| format!("{v:.1}"))
}
