//! `handcap model`: fit MSVR to a dataset, score it on held-out files, write model and report.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use handcap::data::{self, HAND_INPUTS, HAND_OUTPUTS};
use handcap::fsio;
use handcap::model::file::{ModelFile, StoredModel};
use handcap::model::msvr::{MsvrParams, DEFAULT_MAX_ITER, DEFAULT_TOL};
use handcap::model::{self, Predict};
use handcap::provenance::Provenance;
use handcap::report::{self, ModelReport, TestResult};

/// The paper's Table 2: the parameters its ACO selected for the micro-hand.
pub const PAPER_C: f64 = 326.7;
pub const PAPER_EPSILON: f64 = 0.0169;
pub const PAPER_SIGMA: f64 = 0.259;

/// How the hyper-parameters are chosen.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Search {
    /// Use --c, --epsilon and --sigma as given
    None,
}

#[derive(clap::Args)]
pub struct Args {
    /// Training data: CSV with a header row
    data: PathBuf,
    /// Input columns, comma-separated
    #[arg(long, value_delimiter = ',', default_values = HAND_INPUTS)]
    inputs: Vec<String>,
    /// Output columns, comma-separated
    #[arg(long, value_delimiter = ',', default_values = HAND_OUTPUTS)]
    outputs: Vec<String>,
    /// How to choose C, ε and σ
    #[arg(long, value_enum, default_value = "none")]
    search: Search,
    /// Penalty C (default: the paper's Table 2)
    #[arg(long = "c", default_value_t = PAPER_C)]
    c: f64,
    /// Tube radius ε, in output units (default: the paper's Table 2)
    #[arg(long, default_value_t = PAPER_EPSILON)]
    epsilon: f64,
    /// RBF width σ, in inputs scaled to [0, 1] (default: the paper's Table 2)
    #[arg(long, default_value_t = PAPER_SIGMA)]
    sigma: f64,
    /// Relative tolerance on the objective's decrease
    #[arg(long, default_value_t = DEFAULT_TOL)]
    tol: f64,
    /// Iteration cap of the solver
    #[arg(long, default_value_t = DEFAULT_MAX_ITER)]
    max_iter: usize,
    /// Held-out test data with the same columns (repeatable)
    #[arg(long = "test")]
    tests: Vec<PathBuf>,
    /// Model file to write
    #[arg(long, default_value = "model.json")]
    out: PathBuf,
    /// Directory for metrics.csv, fit.json and report.md
    #[arg(long)]
    report: Option<PathBuf>,
}

/// One model run, as the `model` and `demo` commands describe it.
pub struct Job {
    pub data: PathBuf,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    pub params: MsvrParams,
    pub tests: Vec<PathBuf>,
    pub out: PathBuf,
    pub report: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let Search::None = a.search;
    let job = Job {
        data: a.data,
        inputs: a.inputs,
        outputs: a.outputs,
        params: MsvrParams::new(a.c, a.epsilon, a.sigma)
            .tol(a.tol)
            .max_iter(a.max_iter),
        tests: a.tests,
        out: a.out,
        report: a.report,
    };
    let report = execute(&job)?;
    print_summary(&report);
    println!("wrote {}", job.out.display());
    if let Some(dir) = &job.report {
        println!("wrote {}/{{metrics.csv,fit.json,report.md}}", dir.display());
    }
    Ok(())
}

/// Fits, scores and writes; returns what the report shows.
pub fn execute(job: &Job) -> anyhow::Result<ModelReport> {
    let inputs: Vec<&Path> = std::iter::once(job.data.as_path())
        .chain(job.tests.iter().map(PathBuf::as_path))
        .collect();
    if fsio::is_same_file_as_any(&job.out, &inputs) {
        bail!(
            "--out {} is one of the input files; choose another name",
            job.out.display()
        );
    }
    let params = job.params.check().context("model parameters")?;
    let train = data::read_dataset(&job.data, &job.inputs, &job.outputs)?;
    let msvr = params.fit(&train)?;
    let train_errors = model::evaluate(&msvr, &train)?;

    let mut tests = Vec::new();
    for path in &job.tests {
        let test = data::read_dataset(path, &job.inputs, &job.outputs)?;
        tests.push(TestResult {
            model: "msvr".into(),
            test: file_name(path),
            errors: model::evaluate(&msvr, &test)?,
        });
    }

    let mut provenance = Provenance::new(super::command_line(), None);
    for path in &inputs {
        provenance = provenance
            .with_input(path)
            .with_context(|| format!("hashing {}", path.display()))?;
    }
    let report = ModelReport {
        training_file: file_name(&job.data),
        inputs: msvr.inputs().to_vec(),
        outputs: msvr.outputs().to_vec(),
        params: msvr.params,
        fit: msvr.fit.clone(),
        train_errors,
        tests,
        provenance: provenance.clone(),
    };
    ModelFile::new(StoredModel::Msvr(msvr), provenance).save(&job.out)?;
    if let Some(dir) = &job.report {
        report::write_model_report(dir, &report)?;
    }
    Ok(report)
}

pub fn print_summary(r: &ModelReport) {
    let (p, f) = (&r.params, &r.fit);
    println!(
        "MSVR on {}: {} rows, C = {}, ε = {}, σ = {}",
        r.training_file, f.rows, p.c, p.epsilon, p.sigma
    );
    println!(
        "  {} iterations, objective {:.6e}, {} support vectors, {} ({:?})",
        f.iterations,
        f.objective,
        f.support_vectors,
        if f.converged {
            "converged"
        } else {
            "NOT converged: raise --max-iter"
        },
        f.stop
    );
    println!(
        "  training error (not a test): MAE {:.4}, mean Euclidean {:.4}",
        r.train_errors.mae, r.train_errors.euclid
    );
    if !r.tests.is_empty() {
        println!("held-out errors (output units):");
        print!("{}", report::errors_table(&r.tests, &r.outputs));
    }
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    )
}
