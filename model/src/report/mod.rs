//! Reports of a model run: fit diagnostics, held-out errors, provenance.
//!
//! `DIR/metrics.csv` (columns `model,test,mae_mm,euclid_mm`, one row per model and test file)
//! is for scripts; `DIR/fit.json` holds the fit diagnostics and parameters; `DIR/report.md` ties
//! them together for a reader. Test files that sweep one pressure (the paper's sweeps) get the
//! paper's Figures 9-14: each output against the swept pressure, with the measured points and
//! every model's curve, and a residual plot of every model's tip error along the sweep.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::data::{format_number, Columns, Csv, Dataset};
use crate::fsio;
use crate::model::history::HistoryDecision;
use crate::model::interval::{HeldOut, TestCoverage};
use crate::model::msvr::FitDiagnostics;
use crate::model::previous::{Calibration, PreviousParams};
use crate::model::{Errors, ModelSpec, Predict};
use crate::provenance::Provenance;
use crate::search::IterationRecord;
use crate::select::family::FamilyDecision;
use crate::select::tune::{BasisDecision, SearchSummary};

use crate::plot as figures;
pub mod html;
mod markdown;

pub use markdown::errors_table;
use markdown::markdown;

/// Errors of writing a report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("writing {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Figure(#[from] figures::FigureError),
}

/// One model's errors on one test file.
#[derive(Clone, Debug, Serialize)]
pub struct TestResult {
    pub model: String,
    /// The test file's name.
    pub test: String,
    pub errors: Errors,
}

/// Everything a model report shows.
#[derive(Clone, Debug, Serialize)]
pub struct ModelReport {
    pub training_file: String,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    pub spec: ModelSpec,
    /// The family the model is, and why.
    pub family: FamilyDecision,
    pub fit: FitDiagnostics,
    /// The basis and why it was chosen.
    pub basis: BasisDecision,
    /// The input history and why, when a time column was given.
    pub history: Option<HistoryDecision>,
    /// The search that chose the parameters, if any.
    pub search: Option<SearchSummary>,
    /// Errors on the training data itself (not a measure of generalisation).
    pub train_errors: Errors,
    /// The previous physics model, when the data are the micro-hand's.
    pub previous: Option<PreviousSummary>,
    pub tests: Vec<TestResult>,
    /// Conformal prediction intervals: their calibration and coverage on the test files.
    pub intervals: Option<IntervalReport>,
    pub provenance: Provenance,
}

impl ModelReport {
    /// The model's settings by name, as the log and the report show them: the family's name,
    /// without what it fixes (kernel ridge's ε = 0 and squared loss).
    pub fn settings(&self) -> Vec<(&'static str, String)> {
        let mut settings = self.spec.settings();
        settings[0].1 = self.family.used.title().to_string();
        self.family.used.shown(settings)
    }
}

/// The intervals as the report shows them (the model file also keeps the scores), and their
/// coverage of each test file.
#[derive(Clone, Debug, Serialize)]
pub struct IntervalReport {
    #[serde(flatten)]
    pub held_out: HeldOut,
    /// Whether the radius widens off the training rows (files before it: the same radius
    /// everywhere).
    pub widens: bool,
    pub tests: Vec<TestCoverageReport>,
}

/// Coverage of one test file.
#[derive(Clone, Debug, Serialize)]
pub struct TestCoverageReport {
    pub test: String,
    /// The column that names the test file's groups, when it has one.
    pub column: Option<String>,
    #[serde(flatten)]
    pub coverage: TestCoverage,
}

/// The previous model's two variants as the report shows them.
#[derive(Clone, Debug, Serialize)]
pub struct PreviousSummary {
    pub default: PreviousParams,
    pub calibrated: PreviousParams,
    pub calibration: Calibration,
}

/// A model the figures draw, under the name the tables use.
#[derive(Clone, Copy)]
pub struct NamedModel<'a> {
    pub name: &'a str,
    pub model: &'a dyn Predict,
}

/// What the comparison figures draw: the models and the test files (name, data).
#[derive(Clone, Copy)]
pub struct Comparison<'a> {
    pub models: &'a [NamedModel<'a>],
    pub tests: &'a [(String, Dataset)],
}

/// Writes `metrics.csv`, `fit.json`, `report.md`; after a search, `history.csv` and the paper's
/// Figures 7-8 (`fig7_min_mae`, `fig8_mean_mae`); for every test file that is a one-pressure
/// sweep, `<test>_<output>` (Figures 9-14) and `<test>_residuals`; figures as PNG and SVG, all
/// into `dir` (created if needed).
///
/// # Errors
/// [`ReportError`] naming the file that could not be written.
pub fn write_model_report(
    dir: &Path,
    report: &ModelReport,
    history: Option<&[IterationRecord]>,
    comparison: &Comparison,
) -> Result<(), ReportError> {
    let err = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ReportError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(err(dir))?;
    let fit = dir.join("fit.json");
    let previous = fsio::listed_files(&fit);
    let metrics = dir.join("metrics.csv");
    fsio::write_bytes(&metrics, metrics_csv(&report.tests).as_bytes()).map_err(err(&metrics))?;
    let mut written = vec![metrics];
    if let Some(history) = history {
        let path = dir.join("history.csv");
        fsio::write_bytes(&path, history_csv(history).as_bytes()).map_err(err(&path))?;
        convergence_figures(dir, history, &unit(&report.outputs))?;
        written.push(path);
        for stem in CONVERGENCE {
            written.extend(figures::line_plot_files(&dir.join(stem)));
        }
    }
    let sweeps = sweep_figures(dir, comparison)?;
    for stem in sweeps.iter().flat_map(|s| &s.stems) {
        written.extend(figures::line_plot_files(&dir.join(stem)));
    }
    let md = dir.join("report.md");
    fsio::write_bytes(&md, markdown(report, &sweeps).as_bytes()).map_err(err(&md))?;
    written.extend([md, fit.clone()]);
    // fit.json last, listing this run's files: the next run into `dir` removes the figures of
    // this one that it does not draw again.
    #[derive(Serialize)]
    struct Listed<'a> {
        #[serde(flatten)]
        report: &'a ModelReport,
        files: Vec<String>,
    }
    let listed = Listed {
        report,
        files: fsio::file_names(&written),
    };
    let bytes = serde_json::to_vec_pretty(&listed).expect("report serialises");
    fsio::write_bytes(&fit, &bytes).map_err(err(&fit))?;
    fsio::remove_stale(dir, &previous, &written, |path| {
        is_report_file(path, &report.outputs)
    });
    Ok(())
}

/// The files [`write_model_report`] may write into `dir` and what each is: with a search
/// (`searched`), the history and Figures 7-8; for each test file (by name) that is a sweep,
/// a figure per output and one of residuals. A run writes a subset of these, never another.
pub fn report_files(
    dir: &Path,
    searched: bool,
    tests: &[String],
    outputs: &[String],
) -> Vec<(PathBuf, String)> {
    let mut files: Vec<(PathBuf, String)> = ["metrics.csv", "fit.json", "report.md"]
        .map(|f| (dir.join(f), format!("report file {f}")))
        .to_vec();
    let figure = |stem: &str, what: &str| {
        figures::line_plot_files(&dir.join(stem)).map(|path| (path, what.to_string()))
    };
    if searched {
        files.push((dir.join("history.csv"), "report file history.csv".into()));
        files.extend(figure(CONVERGENCE[0], "the report's Figure 7"));
        files.extend(figure(CONVERGENCE[1], "the report's Figure 8"));
    }
    for test in tests {
        for output in outputs {
            files.extend(figure(
                &sweep_stem(test, output),
                &format!("the report's sweep figure of {test}"),
            ));
        }
        files.extend(figure(
            &sweep_stem(test, RESIDUALS),
            &format!("the report's residual figure of {test}"),
        ));
    }
    files
}

/// Whether `path` is named as a file [`write_model_report`] writes for a model of `outputs`
/// (whatever the test files): the fixed files, Figures 7-8, and sweep figures
/// ([`sweep_stem`]) of an output or the residuals.
fn is_report_file(path: &Path, outputs: &[String]) -> bool {
    let Some(name) = path.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return false;
    };
    if ["metrics.csv", "fit.json", "report.md", "history.csv"].contains(&name.as_str()) {
        return true;
    }
    let Some(stem) = name
        .strip_suffix(".svg")
        .or_else(|| name.strip_suffix(".png"))
    else {
        return false;
    };
    CONVERGENCE.contains(&stem)
        || outputs
            .iter()
            .map(String::as_str)
            .chain([RESIDUALS])
            .any(|figure| stem.ends_with(&format!("_{figure}")))
}

/// The paper's Figures 7 and 8 (file stems).
const CONVERGENCE: [&str; 2] = ["fig7_min_mae", "fig8_mean_mae"];

/// The residual figure's name beside the outputs' ([`sweep_stem`]).
const RESIDUALS: &str = "residuals";

/// The stem of a sweep figure of test file `test`: its name without the extension, then
/// `_<figure>` (an output column, or [`RESIDUALS`]).
fn sweep_stem(test: &str, figure: &str) -> String {
    let stem = Path::new(test)
        .file_stem()
        .map_or_else(|| test.to_string(), |s| s.to_string_lossy().into_owned());
    format!("{stem}_{figure}")
}

/// A test file whose inputs move along one line: some columns rise together (equal on every
/// row), the others stay fixed.
#[derive(Clone, Debug, PartialEq)]
pub struct Sweep {
    /// Indices of the swept input columns.
    pub swept: Vec<usize>,
    /// Fixed input columns and their value.
    pub fixed: Vec<(usize, f64)>,
    pub from: f64,
    pub to: f64,
}

impl Sweep {
    /// Recognises a sweep in `inputs`; `None` when no column moves or the moving ones differ.
    pub fn detect(inputs: &Columns) -> Option<Sweep> {
        let first = inputs.iter_rows().next()?;
        let moves = |j: usize| inputs.column(j).any(|v| v != first[j]);
        let (swept, fixed): (Vec<usize>, Vec<usize>) = (0..inputs.width()).partition(|&j| moves(j));
        let lead = *swept.first()?;
        if inputs
            .iter_rows()
            .any(|row| swept.iter().any(|&j| row[j] != row[lead]))
        {
            return None;
        }
        let (from, to) = inputs
            .column(lead)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        Some(Sweep {
            fixed: fixed.into_iter().map(|j| (j, first[j])).collect(),
            swept,
            from,
            to,
        })
    }

    /// `points` evenly spaced inputs from `from` to `to`, in the columns of `names`.
    pub fn inputs(&self, names: &[String], points: usize) -> Columns {
        let mut values = vec![0.0; names.len() * points];
        for (k, row) in values.chunks_mut(names.len()).enumerate() {
            let t = self.from + (self.to - self.from) * k as f64 / (points - 1) as f64;
            for &j in &self.swept {
                row[j] = t;
            }
            for &(j, v) in &self.fixed {
                row[j] = v;
            }
        }
        Columns::new(names.to_vec(), values)
    }

    /// The swept columns' label, e.g. `P2_kpa = P3_kpa`.
    fn label(&self, names: &[String]) -> String {
        self.swept
            .iter()
            .map(|&j| names[j].as_str())
            .collect::<Vec<_>>()
            .join(" = ")
    }

    /// The fixed columns, e.g. `P1_kpa = 0`.
    fn held(&self, names: &[String]) -> String {
        self.fixed
            .iter()
            .map(|&(j, v)| format!("{} = {}", names[j], format_number(v)))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Points on each model's curve along a sweep.
const CURVE_POINTS: usize = 126;

/// The figures written for one sweep test file.
struct SweepFigures {
    test: String,
    sweep_label: String,
    held: String,
    stems: Vec<String>,
}

/// Figures 9-14 and the residual plot for every sweep among the test files.
fn sweep_figures(dir: &Path, c: &Comparison) -> Result<Vec<SweepFigures>, ReportError> {
    let mut written = Vec::new();
    for (test, data) in c.tests {
        let Some(sweep) = Sweep::detect(&data.inputs) else {
            continue;
        };
        let names = &data.inputs.names;
        let lead = sweep.swept[0];
        let measured_t: Vec<f64> = data.inputs.column(lead).collect();
        let dense = sweep.inputs(names, CURVE_POINTS);
        let dense_t: Vec<f64> = dense.column(lead).collect();
        let mut curves = Vec::new();
        let mut at_data = Vec::new();
        for m in c.models {
            let (Ok(curve), Ok(fitted)) = (m.model.predict(&dense), m.model.predict(&data.inputs))
            else {
                continue;
            };
            curves.push((m.name, curve));
            at_data.push((m.name, fitted));
        }
        let label = sweep.label(names);
        let held = sweep.held(names);
        let mut stems = Vec::new();
        for (j, output) in data.outputs.names.iter().enumerate() {
            let mut series = vec![figures::Series {
                label: "measured".into(),
                points: measured_t
                    .iter()
                    .copied()
                    .zip(data.outputs.column(j))
                    .collect(),
                mark: figures::Mark::Points,
                colour: figures::BLACK_INDEX,
            }];
            for (k, (name, curve)) in curves.iter().enumerate() {
                series.push(figures::Series {
                    label: (*name).to_string(),
                    points: dense_t.iter().copied().zip(curve.column(j)).collect(),
                    mark: figures::Mark::Line,
                    colour: k,
                });
            }
            let name = sweep_stem(test, output);
            let plot = figures::LinePlot {
                title: format!("{output} along {test} ({held})"),
                x_label: format!("{label} (swept)"),
                y_label: output.clone(),
                series,
                log_y: false,
                x_names: Vec::new(),
            };
            figures::write_line_plot(&dir.join(&name), &plot)?;
            stems.push(name);
        }
        let residual_series = at_data
            .iter()
            .enumerate()
            .map(|(k, (name, fitted))| figures::Series {
                label: (*name).to_string(),
                points: data
                    .outputs
                    .iter_rows()
                    .zip(fitted.iter_rows())
                    .zip(&measured_t)
                    .map(|((y, f), &t)| {
                        let sq: f64 = y.iter().zip(f).map(|(a, b)| (a - b).powi(2)).sum();
                        (t, sq.sqrt())
                    })
                    .collect(),
                mark: figures::Mark::Line,
                colour: k,
            })
            .collect();
        let name = sweep_stem(test, RESIDUALS);
        let plot = figures::LinePlot {
            title: format!("Euclidean error along {test} ({held})"),
            x_label: format!("{label} (swept)"),
            y_label: format!(
                "‖measured − model‖ ({}, log scale)",
                unit(&data.outputs.names)
            ),
            series: residual_series,
            log_y: true,
            x_names: Vec::new(),
        };
        figures::write_line_plot(&dir.join(&name), &plot)?;
        stems.push(name);
        written.push(SweepFigures {
            test: test.clone(),
            sweep_label: label,
            held,
            stems,
        });
    }
    Ok(written)
}

/// The outputs' unit, when their names share one (`x_mm`, `y_mm` → `mm`); else "output units".
fn unit(outputs: &[String]) -> String {
    let suffix = |name: &String| name.rsplit_once('_').map(|(_, u)| u.to_string());
    let first = outputs.first().and_then(suffix);
    match first {
        Some(u)
            if !u.is_empty()
                && u.len() <= 4
                && u.chars().all(|c| c.is_ascii_alphabetic())
                && outputs.iter().all(|n| suffix(n).as_ref() == Some(&u)) =>
        {
            u
        }
        _ => "output units".into(),
    }
}

/// The `metrics.csv` text.
pub fn metrics_csv(tests: &[TestResult]) -> String {
    let mut csv = Csv::new(["model", "test", "mae_mm", "euclid_mm"]);
    for t in tests {
        csv.row([
            t.model.clone(),
            t.test.clone(),
            format_number(t.errors.mae),
            format_number(t.errors.euclid),
        ]);
    }
    csv.into_string()
}

/// The `history.csv` text: per iteration the minimum, mean and maximum fitness over its valid
/// candidates, and the best so far (a `best_` column per searched axis, named as the axis).
pub fn history_csv(history: &[IterationRecord]) -> String {
    let axes: Vec<&str> = history
        .first()
        .map(|r| r.best.iter().map(|(name, _)| name).collect())
        .unwrap_or_default();
    let mut csv = Csv::new(
        ["iteration", "min_mae", "mean_mae", "max_mae", "valid"]
            .map(String::from)
            .into_iter()
            .chain(axes.iter().map(|name| format!("best_{name}")))
            .chain(["best_mae".to_string()]),
    );
    for r in history {
        let best = axes
            .iter()
            .map(|name| format_number(r.best.get(name).unwrap_or(f64::NAN)));
        csv.row(
            [r.iteration.to_string()]
                .into_iter()
                .chain([r.min, r.mean, r.max].map(format_number))
                .chain([r.valid.to_string()])
                .chain(best)
                .chain([format_number(r.best_fitness)]),
        );
    }
    csv.into_string()
}

/// The paper's Figures 7 and 8: minimum and mean fitness per iteration.
fn convergence_figures(
    dir: &Path,
    history: &[IterationRecord],
    unit: &str,
) -> Result<(), ReportError> {
    let figure = |name: &str, title: &str, label: &str, value: fn(&IterationRecord) -> f64| {
        let plot = figures::LinePlot {
            title: title.to_string(),
            x_label: "iteration".into(),
            y_label: format!("cross-validated MAE ({unit})"),
            series: vec![figures::Series {
                label: label.into(),
                points: history
                    .iter()
                    .map(|r| (r.iteration as f64, value(r)))
                    .collect(),
                mark: figures::Mark::Line,
                colour: 0,
            }],
            log_y: false,
            x_names: Vec::new(),
        };
        figures::write_line_plot(&dir.join(name), &plot)
    };
    figure(
        CONVERGENCE[0],
        "Minimum MAE per iteration (paper Fig. 7)",
        "minimum",
        |r| r.min,
    )?;
    figure(
        CONVERGENCE[1],
        "Mean MAE per iteration (paper Fig. 8)",
        "mean",
        |r| r.mean,
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{names, HAND_INPUTS};

    fn inputs(rows: &[[f64; 3]]) -> Columns {
        Columns::new(names(&HAND_INPUTS), rows.concat())
    }

    #[test]
    fn sweeps_are_recognised_and_other_files_are_not() {
        let a = Sweep::detect(&inputs(&[
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 10.0],
            [0.0, 0.0, 20.0],
        ]));
        assert_eq!(
            a,
            Some(Sweep {
                swept: vec![2],
                fixed: vec![(0, 0.0), (1, 0.0)],
                from: 0.0,
                to: 20.0
            })
        );
        let b = Sweep::detect(&inputs(&[
            [5.0, 10.0, 10.0],
            [5.0, 0.0, 0.0],
            [5.0, 30.0, 30.0],
        ]))
        .unwrap();
        assert_eq!((b.swept.as_slice(), b.from, b.to), (&[1, 2][..], 0.0, 30.0));
        assert_eq!(b.label(&names(&HAND_INPUTS)), "P2_kpa = P3_kpa");
        assert_eq!(b.held(&names(&HAND_INPUTS)), "P1_kpa = 5");
        let curve = b.inputs(&names(&HAND_INPUTS), 4);
        assert_eq!(
            curve.values,
            [5.0, 0.0, 0.0, 5.0, 10.0, 10.0, 5.0, 20.0, 20.0, 5.0, 30.0, 30.0]
        );
        // Two columns moving differently (a grid), or nothing moving: not a sweep.
        assert_eq!(
            Sweep::detect(&inputs(&[[0.0, 0.0, 0.0], [0.0, 10.0, 20.0]])),
            None
        );
        assert_eq!(
            Sweep::detect(&inputs(&[[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])),
            None
        );
    }
}
