//! Reports of a model run: fit diagnostics, held-out errors, provenance.
//!
//! `DIR/metrics.csv` (columns `model,test,mae_mm,euclid_mm`, one row per model and test file)
//! is for scripts; `DIR/fit.json` holds the fit diagnostics and parameters; `DIR/report.md` ties
//! them together for a reader.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::data::format_number;
use crate::fsio;
use crate::model::msvr::{FitDiagnostics, MsvrParams};
use crate::model::Errors;
use crate::provenance::Provenance;
use crate::search::{IterationRecord, SearchSummary};

pub mod figures;

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
    pub params: MsvrParams,
    pub fit: FitDiagnostics,
    /// The search that chose the parameters, if any.
    pub search: Option<SearchSummary>,
    /// Errors on the training data itself (not a measure of generalisation).
    pub train_errors: Errors,
    pub tests: Vec<TestResult>,
    pub provenance: Provenance,
}

/// Writes `metrics.csv`, `fit.json`, `report.md` and, after a search, `history.csv` and the
/// paper's Figures 7-8 (`fig7_min_mae`, `fig8_mean_mae`, PNG and SVG) into `dir` (created if
/// needed).
///
/// # Errors
/// [`ReportError`] naming the file that could not be written.
pub fn write_model_report(
    dir: &Path,
    report: &ModelReport,
    history: Option<&[IterationRecord]>,
) -> Result<(), ReportError> {
    let err = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ReportError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(err(dir))?;
    let metrics = dir.join("metrics.csv");
    fsio::write_bytes(&metrics, metrics_csv(&report.tests).as_bytes()).map_err(err(&metrics))?;
    let fit = dir.join("fit.json");
    let json = serde_json::to_vec_pretty(report).expect("report serialises");
    fsio::write_bytes(&fit, &json).map_err(err(&fit))?;
    if let Some(history) = history {
        let path = dir.join("history.csv");
        fsio::write_bytes(&path, history_csv(history).as_bytes()).map_err(err(&path))?;
        convergence_figures(dir, history)?;
    }
    let md = dir.join("report.md");
    fsio::write_bytes(&md, markdown(report).as_bytes()).map_err(err(&md))?;
    Ok(())
}

/// The `metrics.csv` text.
pub fn metrics_csv(tests: &[TestResult]) -> String {
    let mut out = String::from("model,test,mae_mm,euclid_mm\n");
    for t in tests {
        let _ = writeln!(
            out,
            "{},{},{},{}",
            t.model,
            t.test,
            format_number(t.errors.mae),
            format_number(t.errors.euclid)
        );
    }
    out
}

/// The `history.csv` text: per iteration the minimum, mean and maximum fitness over its valid
/// candidates, and the best so far.
pub fn history_csv(history: &[IterationRecord]) -> String {
    let mut out = String::from(
        "iteration,min_mae,mean_mae,max_mae,valid,best_c,best_epsilon,best_sigma,best_mae\n",
    );
    for r in history {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{}",
            r.iteration,
            format_number(r.min),
            format_number(r.mean),
            format_number(r.max),
            r.valid,
            format_number(r.best.c),
            format_number(r.best.epsilon),
            format_number(r.best.sigma),
            format_number(r.best_fitness)
        );
    }
    out
}

/// The paper's Figures 7 and 8: minimum and mean fitness per iteration.
fn convergence_figures(dir: &Path, history: &[IterationRecord]) -> Result<(), ReportError> {
    let figure = |name: &str, title: &str, label: &str, value: fn(&IterationRecord) -> f64| {
        let plot = figures::LinePlot {
            title: title.to_string(),
            x_label: "iteration".into(),
            y_label: "MAE".into(),
            series: vec![figures::Series {
                label: label.into(),
                points: history
                    .iter()
                    .map(|r| (r.iteration as f64, value(r)))
                    .collect(),
                mark: figures::Mark::Line,
            }],
        };
        figures::write_line_plot(&dir.join(name), &plot)
    };
    figure(
        "fig7_min_mae",
        "Minimum MAE per iteration (paper Fig. 7)",
        "minimum",
        |r| r.min,
    )?;
    figure(
        "fig8_mean_mae",
        "Mean MAE per iteration (paper Fig. 8)",
        "mean",
        |r| r.mean,
    )?;
    Ok(())
}

/// The table of held-out errors, as printed and as in `report.md`.
pub fn errors_table(tests: &[TestResult], outputs: &[String]) -> String {
    let mut out = format!(
        "| model | test | rows | MAE | mean Euclidean | max Euclidean | {} |\n",
        outputs
            .iter()
            .map(|o| format!("MAE {o}"))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    out += &format!(
        "|---|---|---|---|---|---|{}\n",
        "---|".repeat(outputs.len())
    );
    for t in tests {
        let e = &t.errors;
        let _ = writeln!(
            out,
            "| {} | {} | {} | {:.4} | {:.4} | {:.4} | {} |",
            t.model,
            t.test,
            e.rows,
            e.mae,
            e.euclid,
            e.max_euclid,
            e.per_output_mae
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(" | ")
        );
    }
    out
}

fn markdown(r: &ModelReport) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# handcap model report\n");
    let _ = writeln!(
        s,
        "MSVR fitted on `{}`: inputs {} → outputs {} (errors in output units; mm for the micro-hand).\n",
        r.training_file,
        r.inputs.join(", "),
        r.outputs.join(", ")
    );
    if let Some(search) = &r.search {
        let _ = writeln!(s, "## Hyper-parameter search\n");
        let _ = writeln!(
            s,
            "{} scored by {}{}: {} iterations, stopped by {:?}; {} candidates scored ({} fits, {} memo hits). Best fitness {:.5} at C = {}, ε = {}, σ = {}. Per-iteration history: `history.csv`; Figures 7-8: `fig7_min_mae.png`, `fig8_mean_mae.png` (and `.svg`).\n",
            search.method,
            search.fitness,
            search
                .group_by
                .as_ref()
                .map(|c| format!(" with rows grouped by `{c}`"))
                .unwrap_or_default(),
            search.iterations,
            search.stop,
            search.evaluations,
            search.fits,
            search.memo_hits,
            search.best_fitness,
            search.best.c,
            search.best.epsilon,
            search.best.sigma
        );
    }
    let _ = writeln!(s, "## Fit\n");
    let _ = writeln!(
        s,
        "| C | ε | σ | rows | iterations | objective | support vectors | converged | stop |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    let _ = writeln!(
        s,
        "| {} | {} | {} | {} | {} | {:.6e} | {} | {} | {:?} |\n",
        r.params.c,
        r.params.epsilon,
        r.params.sigma,
        r.fit.rows,
        r.fit.iterations,
        r.fit.objective,
        r.fit.support_vectors,
        r.fit.converged,
        r.fit.stop
    );
    let _ = writeln!(
        s,
        "Training error (the data the model was fitted on, not a test): MAE {:.4}, mean Euclidean {:.4}.\n",
        r.train_errors.mae, r.train_errors.euclid
    );
    if !r.tests.is_empty() {
        let _ = writeln!(s, "## Held-out errors\n");
        s += &errors_table(&r.tests, &r.outputs);
        s.push('\n');
    }
    let _ = writeln!(s, "## Provenance\n");
    let _ = writeln!(s, "- handcap {}", r.provenance.handcap_version);
    let _ = writeln!(s, "- command: `{}`", r.provenance.command.join(" "));
    if let Some(seed) = r.provenance.seed {
        let _ = writeln!(s, "- seed: {seed}");
    }
    for input in &r.provenance.inputs {
        let _ = writeln!(s, "- input `{}` sha256 `{}`", input.path, input.sha256);
    }
    s
}
