//! The demo's dynamic part: the finger in motion, from the protocol to the history model.
//!
//! 1. synth: a dynamic session (random excitation between rest holds, the muscles lagging
//!    through the pneumatic line and creeping) filmed by the same rig (`DIR/dynamic/capture/`,
//!    no board images: `DIR/calib.yml` is this rig's).
//! 2. triangulate per frame (`DIR/dynamic/dataset.csv`), checked against the truth at every
//!    row's instant.
//! 3. model: the last trial held out; MSVR on the present pressures (static) and with input
//!    history (`--time time_s --group-by phase`), both from the triangulated rows, and the
//!    same history model (its history and parameters) fitted on the plant's own per-frame
//!    truth (what the camera path costs).
//! 4. the held-out trial's trajectory: truth, measured, both models (`DIR/dynamic/trajectory_*`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::fit::{self, FitJob, Selection};
use super::{PipelineError, Session};
use crate::data::{self, names, Csv, HAND_INPUTS, HAND_OUTPUTS};
use crate::model::file::ModelFile;
use crate::model::history::HistoryChoice;
use crate::model::msvr::MsvrParams;
use crate::model::Errors;
use crate::plot::{self, LinePlot, Mark, Series};
use crate::select::family::FamilyChoice;
use crate::select::folds::FoldsBy;
use crate::select::tune::{BasisChoice, Pinned};
use crate::session::protocol::DynamicDesign;
use crate::synth::capture::{CaptureConfig, DynamicSession};
use crate::synth::dynamics::Dynamics;
use crate::synth::SynthConfig;
use crate::triangulate::per_frame;
use crate::triangulate::TriangulateOptions;

/// What the dynamic part measured, for `summary.json` and the report.
#[derive(Clone, Debug, Serialize)]
pub struct DynamicCheck {
    pub design: DynamicDesign,
    pub dynamics: Dynamics,
    /// Left frames, and the rows with a tip and no flag.
    pub rows: usize,
    pub unflagged: usize,
    /// The unflagged rows' tips against the truth at their instants (mm).
    pub tip_rms_mm: f64,
    pub tip_max_mm: f64,
    /// The right camera's stamps ahead of the left's, as the motion showed (ms); with more
    /// cameras, the second camera's ahead of the first's.
    pub clock_offset_ms: f64,
    /// The trial held out.
    pub held_out: String,
    /// The history the model chose.
    pub history: String,
    /// Held-out errors: static and history from the triangulated rows, history from the truth.
    pub scores: Vec<DynamicScore>,
}

/// One model's error on the held-out trial.
#[derive(Clone, Debug, Serialize)]
pub struct DynamicScore {
    pub model: String,
    pub trained_on: String,
    pub errors: Errors,
}

/// Runs the dynamic part into `dir` with the rig calibrated in `calib`; `budget` caps each
/// model search's candidates (`None`: `handcap model`'s default).
///
/// # Errors
/// [`PipelineError`] from any stage, or a file that cannot be written.
pub fn run(
    dir: &Path,
    synth: &SynthConfig,
    capture: &CaptureConfig,
    design: DynamicDesign,
    budget: Option<usize>,
    calib: &Path,
    session: &Session,
) -> Result<DynamicCheck, PipelineError> {
    // 1. The session.
    let capture_dir = dir.join("capture");
    let config = CaptureConfig {
        calibration_images: false,
        dynamic: Some(DynamicSession::Design(design.clone())),
        dynamics: Dynamics::PNEUMATIC,
        ..capture.clone()
    };
    let synthesized = super::synth::run(&capture_dir, synth, Some(&config), session)?;
    if synthesized.capture.is_some_and(|c| c.interrupted) {
        return Err(PipelineError::Interrupted(
            "interrupted while rendering the dynamic session; run the demo again".into(),
        ));
    }

    // 2. Per-frame tips against the truth (more cameras' rows are the first camera's frames,
    // as the truth's are).
    let dataset = dir.join("dataset.csv");
    let (frames, pressures) = (
        capture_dir.join("frames"),
        capture_dir.join("pressures.csv"),
    );
    let options = TriangulateOptions::default();
    let (rows, good_rows, clock_offset_ms) = if super::triangulate::more_cameras(calib) {
        let done = super::triangulate::run_per_frame_cameras(
            &frames, calib, &pressures, &options, &dataset, session,
        )?;
        let s = &done.per_frame.summary;
        let rows: Vec<per_frame::FrameRow> =
            done.per_frame.rows.iter().map(|r| r.row.clone()).collect();
        (
            rows,
            s.good_rows,
            s.cameras.get(1).map_or(0.0, |c| c.clock_offset_ms),
        )
    } else {
        let done = super::triangulate::run_per_frame(
            &frames, calib, &pressures, &options, &dataset, session,
        )?;
        let s = &done.per_frame.summary;
        (done.per_frame.rows, s.good_rows, s.clock_offset_ms)
    };
    let truth_path = capture_dir.join("truth/per_frame.csv");
    let errors = per_frame::errors_against(&rows, &truth_by_frame(&truth_path)?);
    let tip_rms_mm =
        (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();

    // 3. Models, the last trial held out.
    let models = fit_models(
        dir,
        synth.seed,
        budget,
        &design,
        &dataset,
        &truth_path,
        session,
    )?;

    // 4. The held-out trajectory.
    trajectory_figures(dir, &models.test, &models.truth_test, &models.held_out)?;
    Ok(DynamicCheck {
        design,
        dynamics: Dynamics::PNEUMATIC,
        rows: rows.len(),
        unflagged: good_rows,
        tip_rms_mm,
        tip_max_mm: errors.iter().copied().fold(0.0, f64::max),
        clock_offset_ms,
        held_out: models.held_out,
        history: models.history,
        scores: models.scores,
    })
}

/// The models of step 3 and what they score on the held-out trial.
struct Models {
    /// The trial held out.
    held_out: String,
    scores: Vec<DynamicScore>,
    /// The history the model chose.
    history: String,
    /// The held-out trial's rows: triangulated, and the truth.
    test: PathBuf,
    truth_test: PathBuf,
}

/// Step 3: the last trial of `dataset` (and of the truth, `truth_path`) held out; MSVR on the
/// present pressures and with input history from the triangulated rows, and the same history
/// model fitted on the truth.
fn fit_models(
    dir: &Path,
    seed: u64,
    budget: Option<usize>,
    design: &DynamicDesign,
    dataset: &Path,
    truth_path: &Path,
    session: &Session,
) -> Result<Models, PipelineError> {
    let held_out = format!("dyn_{}", design.trials);
    let split = |from: &Path, stem: &str| -> Result<[PathBuf; 2], PipelineError> {
        let train = dir.join(format!("{stem}_train.csv"));
        let test = dir.join(format!("{stem}_{held_out}.csv"));
        split_rows(from, &train, &test, |phase| phase == held_out)?;
        Ok([train, test])
    };
    let [train, test] = split(dataset, "triangulated")?;
    let [truth_train, truth_test] = split(truth_path, "truth")?;
    // Folds are whole phases: the training trials and the rest holds.
    let folds = design.trials.min(5);
    let fit = |data: &Path, test: &Path, name: &str, history: bool| {
        // `handcap model`'s default search, the phases as folds.
        let selection = Selection::aco_r(seed, budget, folds, FoldsBy::Column("phase".into()));
        fit::run(
            &job(data, test, &dir.join(name), history, selection),
            session,
        )
    };
    let fitted_history = fit(&train, &test, "history", true)?;
    // `auto` searched the present inputs first, to compare: the static model is that search's
    // (C, ε, σ) fitted again, not searched a second time.
    let fitted_static = match present_inputs(&fitted_history) {
        Some(params) => {
            let fixed = job(&train, &test, &dir.join("static"), false, phases(folds));
            fit::run(&FitJob { params, ..fixed }, session)?
        }
        None => fit(&train, &test, "static", false)?,
    };
    let same = same_model(
        &fitted_history,
        &truth_train,
        &truth_test,
        &dir.join("history_truth"),
        folds,
    );
    let fitted_truth = fit::run(&same, session)?;
    let score = |model: &str, trained_on: &str, outcome: &fit::FitOutcome| DynamicScore {
        model: model.into(),
        trained_on: trained_on.into(),
        errors: outcome
            .report
            .tests
            .iter()
            .find(|t| t.model == "msvr")
            .map(|t| t.errors.clone())
            .expect("the held-out trial is tested"),
    };
    let scores = vec![
        score(
            "MSVR, present pressures",
            "triangulated frames",
            &fitted_static,
        ),
        score(
            "MSVR with input history",
            "triangulated frames",
            &fitted_history,
        ),
        score(
            "MSVR with input history",
            "the plant's per-frame truth",
            &fitted_truth,
        ),
    ];
    let history = fitted_history
        .report
        .history
        .as_ref()
        .and_then(|h| h.used.as_ref())
        .map_or("none".to_string(), |h| h.memory.to_string());
    Ok(Models {
        held_out,
        scores,
        history,
        test,
        truth_test,
    })
}

/// A model of the dynamic part (robust loss, the folds whole phases), with input history or
/// without, its parameters chosen as `selection` says.
fn job(data: &Path, test: &Path, out: &Path, history: bool, selection: Selection) -> FitJob {
    let group = history.then(|| "phase".to_string());
    FitJob {
        data: data.to_path_buf(),
        inputs: names(&HAND_INPUTS),
        outputs: names(&HAND_OUTPUTS),
        // The paper's model, its headline.
        family: FamilyChoice::MSVR,
        params: MsvrParams::default(),
        pinned: Pinned::default(),
        selection,
        search_on: None,
        intervals: false,
        tests: vec![test.to_path_buf()],
        out: out.with_extension("json"),
        report: Some(out.to_path_buf()),
        max_rows: None,
        basis: BasisChoice::Auto,
        time: history.then(|| "time_s".to_string()),
        group,
        weight: None,
        history: if history {
            HistoryChoice::Auto
        } else {
            HistoryChoice::None
        },
    }
}

/// `fitted`'s model (its history and parameters) fitted on other rows as they are, without a
/// search: what the same model makes of them.
fn same_model(
    fitted: &fit::FitOutcome,
    data: &Path,
    test: &Path,
    out: &Path,
    folds: usize,
) -> FitJob {
    let crate::model::ModelSpec::Msvr(params) = fitted.report.spec;
    let memory = fitted
        .report
        .history
        .as_ref()
        .and_then(|h| h.used.as_ref())
        .map(|h| &h.memory);
    FitJob {
        params,
        history: HistoryChoice::of(memory),
        ..job(data, test, out, true, phases(folds))
    }
}

/// The (C, ε, σ) the search of `fitted`'s `auto` chose on the present inputs alone.
fn present_inputs(fitted: &fit::FitOutcome) -> Option<MsvrParams> {
    let history = fitted.report.history.as_ref()?;
    let present = history.tried.iter().find(|t| t.memory.is_none())?;
    present.params
}

/// Given parameters, scored on `folds` whole phases.
fn phases(folds: usize) -> Selection {
    Selection::Fixed {
        folds,
        folds_by: FoldsBy::Column("phase".into()),
    }
}

/// The truth's tip per left frame number.
fn truth_by_frame(path: &Path) -> Result<BTreeMap<usize, [f64; 3]>, PipelineError> {
    let columns = ["frame", "x_mm", "y_mm", "z_mm"].map(String::from);
    let table = data::read_columns(path, &columns)?;
    Ok((0..table.rows())
        .map(|r| {
            let v = table.row(r);
            (v[0] as usize, [v[1], v[2], v[3]])
        })
        .collect())
}

/// Copies the rows of `from` whose `phase` satisfies `test` to `to_test`, the others to
/// `to_train` (header kept, bytes as written).
fn split_rows(
    from: &Path,
    to_train: &Path,
    to_test: &Path,
    test: impl Fn(&str) -> bool,
) -> Result<(), PipelineError> {
    let mut reader = csv::Reader::from_path(from)
        .map_err(|e| PipelineError::Place(format!("{}: {e}", from.display())))?;
    let header = reader
        .headers()
        .map_err(|e| PipelineError::Place(format!("{}: {e}", from.display())))?
        .clone();
    let phase = header
        .iter()
        .position(|h| h == "phase")
        .ok_or_else(|| PipelineError::Place(format!("{}: no phase column", from.display())))?;
    let mut out = [Csv::new(&header), Csv::new(&header)];
    for record in reader.records() {
        let record =
            record.map_err(|e| PipelineError::Place(format!("{}: {e}", from.display())))?;
        out[usize::from(test(record.get(phase).unwrap_or_default()))].row(&record);
    }
    for (csv, path) in out.into_iter().zip([to_train, to_test]) {
        csv.write(path)?;
    }
    Ok(())
}

/// The held-out trial's tip, x and y against time: the truth, the triangulated rows, and the
/// two models' predictions (`DIR/trajectory_x_mm.png`/`.svg`, `trajectory_y_mm.*`).
fn trajectory_figures(
    dir: &Path,
    test: &Path,
    truth_test: &Path,
    held_out: &str,
) -> Result<(), PipelineError> {
    let columns = |path: &Path| -> Result<data::Columns, PipelineError> {
        Ok(data::read_columns(
            path,
            &["time_s", "x_mm", "y_mm", "z_mm"].map(String::from),
        )?)
    };
    let (measured, truth) = (columns(test)?, columns(truth_test)?);
    let predicted = |name: &str| -> Result<data::Columns, PipelineError> {
        let file = ModelFile::load(&dir.join(format!("{name}.json")))?;
        let (_, x) = file.read_inputs(test)?;
        Ok(file.model.predictor().predict(&x)?)
    };
    let (fixed, history) = (predicted("static")?, predicted("history")?);
    let t0 = truth.row(0)[0];
    for (axis, name) in [(1, "x"), (2, "y")] {
        let series =
            |label: &str, cols: &data::Columns, times: &data::Columns, col: usize, mark, colour| {
                Series {
                    label: label.into(),
                    points: (0..cols.rows())
                        .map(|r| (times.row(r)[0] - t0, cols.row(r)[col]))
                        .collect(),
                    mark,
                    colour,
                }
            };
        let plot = LinePlot {
            title: format!("Held-out trial {held_out}: the tip's {name} while the pressures move"),
            x_label: "time since the trial's start (s)".into(),
            y_label: format!("{name} (mm, hand frame)"),
            series: vec![
                series("truth", &truth, &truth, axis, Mark::Line, plot::BLACK_INDEX),
                series("triangulated", &measured, &measured, axis, Mark::Points, 2),
                series(
                    "MSVR, present pressures",
                    &fixed,
                    &measured,
                    axis - 1,
                    Mark::Line,
                    1,
                ),
                series(
                    "MSVR with input history",
                    &history,
                    &measured,
                    axis - 1,
                    Mark::Line,
                    0,
                ),
            ],
            log_y: false,
            x_names: Vec::new(),
        };
        plot::write_line_plot(&dir.join(format!("trajectory_{name}_mm")), &plot)
            .map_err(|e| PipelineError::Report(e.into()))?;
    }
    Ok(())
}
