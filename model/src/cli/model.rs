//! `handcap model`: choose (C, ε, σ), fit MSVR and the previous model, score them on held-out
//! files, write model and report.

use std::path::PathBuf;

use super::usage;

use crate::data::{HAND_INPUTS, HAND_OUTPUTS};
use crate::model::history::HistoryChoice;
use crate::model::msvr::{Loss, MsvrParams, DEFAULT_MAX_ITER, DEFAULT_TOL, PAPER_TABLE2};
use crate::pipeline::fit::{self, FitJob, Selection};
use crate::search::aco_paper::AcoPaper;
use crate::search::aco_r::AcoR;
use crate::search::grid::Grid;
use crate::search::{Method, SearchStop};
use crate::select::family::FamilyChoice;
use crate::select::fitness::FitnessKind;
use crate::select::folds::FoldsBy;
use crate::select::tune::{BasisChoice, Pinned};
use crate::DEFAULT_SEED;

/// How the hyper-parameters are chosen.
#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum SearchKind {
    /// The paper's digit-encoded ant colony (--ants, --rho, --tau0, --max-iter)
    AcoPaper,
    /// Continuous ACO_R on log C, log ε, log σ, racing candidates over the folds (--budget)
    AcoR,
    /// Log-spaced grid (--budget)
    Grid,
    /// Use --c, --epsilon and --sigma as given
    None,
}

/// The loss outside the ε-tube.
#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum LossArg {
    /// The paper's with --search aco-paper, robust otherwise
    Auto,
    /// (u − ε)²: the paper's
    Quadratic,
    /// Quadratic for 10 ε beyond the tube, linear further out: rows far off the surface
    /// (transients, lost markers, hysteresis) pull the fit less
    Robust,
}

/// How candidates are scored.
#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum FitnessArg {
    /// k-fold cross-validated MAE (--folds)
    Cv,
    /// MAE on the training data (the paper's choice; rewards over-fitting)
    Train,
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
    /// The model: msvr (the paper's: C, ε and σ shared by the outputs), krr (kernel ridge: the
    /// squared loss, no tube; C and σ), or auto (each searched on the same folds, the lower
    /// cross-validated error kept)
    #[arg(long, default_value = "auto", value_parser = clap::value_parser!(FamilyChoice))]
    model: FamilyChoice,
    /// How to choose C, ε and σ
    #[arg(long, value_enum, default_value = "aco-r")]
    search: SearchKind,
    /// The MSVR loss outside the ε-tube
    #[arg(long, value_enum, default_value = "auto")]
    loss: LossArg,
    /// How a search scores candidates
    #[arg(long, value_enum, default_value = "cv")]
    fitness: FitnessArg,
    /// Folds of the cross-validated fitness (fewer rows than 2 per fold: as many folds as they
    /// allow; fewer groups than folds: one fold per group)
    #[arg(long, default_value_t = 5)]
    folds: usize,
    /// How cross-validation cuts the rows: auto (a designed grid → shuffled; a run/ramp/trial
    /// column → whole groups; a time series of near-copies → contiguous blocks), shuffle,
    /// blocks, or a column whose values group rows held out together
    #[arg(long, default_value = "auto", value_parser = clap::value_parser!(FoldsBy))]
    folds_by: FoldsBy,
    /// The same as --folds-by COLUMN
    #[arg(long, conflicts_with = "folds_by")]
    group_by: Option<String>,
    /// Weigh each row's loss in the fit by this column (above 0; a row of weight 3 counts as
    /// three copies of it), e.g. runs played since the session against the session. The folds'
    /// scores and the intervals count every row once
    #[arg(long, value_name = "COLUMN")]
    weight: Option<String>,
    /// Seed of the search and of the folds' shuffle
    #[arg(long, default_value_t = DEFAULT_SEED)]
    seed: u64,
    /// Score the search's candidates on this file's rows instead of the training data's (e.g. a
    /// coarser subset of a dense grid: the search stays fast, the fit uses every row)
    #[arg(long)]
    search_on: Option<PathBuf>,
    /// Calibrate the prediction intervals with --search none too (one more fit per fold); a
    /// search's own held-out predictions give them at no cost
    #[arg(long)]
    intervals: bool,
    /// aco-paper: ants per iteration
    #[arg(long, default_value_t = AcoPaper::default().ants)]
    ants: usize,
    /// aco-paper: pheromone evaporation ρ
    #[arg(long, default_value_t = AcoPaper::default().rho)]
    rho: f64,
    /// aco-paper: initial pheromone τ0
    #[arg(long, default_value_t = AcoPaper::default().tau0)]
    tau0: f64,
    /// aco-paper: iteration cap N_max
    #[arg(long, default_value_t = AcoPaper::default().max_iter)]
    max_iter: usize,
    /// aco-r, grid: candidates evaluated at most [default: from the rows: 400 up to 400 rows,
    /// 200 up to 700, 120 above]
    #[arg(long)]
    budget: Option<usize>,
    /// Penalty C: held at this value while a search chooses the others; with --search none
    /// used as given [default: the paper's Table 2]
    #[arg(long = "c")]
    c: Option<f64>,
    /// Tube radius ε in output units, as --c
    #[arg(long)]
    epsilon: Option<f64>,
    /// RBF width σ in inputs scaled to [0, 1], as --c
    #[arg(long)]
    sigma: Option<f64>,
    /// MSVR solver: relative tolerance on the objective's decrease
    #[arg(long, default_value_t = DEFAULT_TOL)]
    solver_tol: f64,
    /// MSVR solver: iteration cap
    #[arg(long, default_value_t = DEFAULT_MAX_ITER)]
    solver_max_iter: usize,
    /// Held-out test data with the same columns (repeatable)
    #[arg(long = "test")]
    tests: Vec<PathBuf>,
    /// Model file to write
    #[arg(long, default_value = "model.json")]
    out: PathBuf,
    /// Directory for metrics.csv, history.csv, fit.json, report.md and the figures
    #[arg(long)]
    report: Option<PathBuf>,
    /// Keep at most N training rows, evenly spaced through the file (rows are never dropped
    /// otherwise: a reduced basis fits any number)
    #[arg(long, value_parser = clap::value_parser!(u64).range(10..))]
    max_rows: Option<u64>,
    /// The kernel's expansion: exact (a kernel at every row; n × n memory), M (a reduced basis
    /// of M centres picked by k-means++; O(n M²) time), or auto (exact up to 2000 rows, else a
    /// reduced basis grown while the cross-validated error falls)
    #[arg(long, default_value = "auto", value_parser = clap::value_parser!(BasisChoice))]
    basis: BasisChoice,
    /// Time column (seconds, or any unit; increasing within each --group-by group): the rows
    /// form time series, and the model may see the inputs' recent history (--history)
    #[arg(long)]
    time: Option<String>,
    /// With --time: none, ema:τ1,τ2,… (exponentially filtered copies of each input, time
    /// constants in the time column's unit), ema (time constants from the sampling), lags:K
    /// (the inputs K rows back), or auto (ema from the data, kept only if cross-validation
    /// says it lowers the error)
    #[arg(long, default_value = "auto", value_parser = clap::value_parser!(HistoryChoice))]
    history: HistoryChoice,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let fitness = match a.fitness {
        FitnessArg::Cv => FitnessKind::Cv { folds: a.folds },
        FitnessArg::Train => FitnessKind::Train,
    };
    // The runs a time series restarts in: the groups the folds hold out together.
    let group = a.group_by.clone().or(match &a.folds_by {
        FoldsBy::Column(c) if a.time.is_some() => Some(c.clone()),
        _ => None,
    });
    let method = match a.search {
        SearchKind::None => None,
        SearchKind::AcoPaper => Some(Method::AcoPaper(AcoPaper {
            ants: a.ants,
            rho: a.rho,
            tau0: a.tau0,
            max_iter: a.max_iter,
            seed: a.seed,
        })),
        SearchKind::AcoR => Some(Method::AcoR(AcoR {
            seed: a.seed,
            ..AcoR::default()
        })),
        SearchKind::Grid => Some(Method::Grid(Grid::default())),
    };
    let loss = match a.loss {
        LossArg::Auto if a.search == SearchKind::AcoPaper => Loss::Quadratic,
        LossArg::Auto | LossArg::Robust => Loss::Robust,
        LossArg::Quadratic => Loss::Quadratic,
    };
    if a.budget.is_some() && !matches!(a.search, SearchKind::AcoR | SearchKind::Grid) {
        usage!("--budget is the candidate budget of --search aco-r and grid");
    }
    // Every parameter the family moves given: nothing is left to search.
    let pinned = Pinned {
        c: a.c,
        epsilon: a.epsilon,
        sigma: a.sigma,
        loss: (a.loss != LossArg::Auto).then_some(loss),
    };
    let method = method.filter(|_| a.model.searches(&pinned));
    let job = FitJob {
        family: a.model,
        data: a.data,
        inputs: a.inputs,
        outputs: a.outputs,
        params: MsvrParams::new(
            a.c.unwrap_or(PAPER_TABLE2.c),
            a.epsilon.unwrap_or(PAPER_TABLE2.epsilon),
            a.sigma.unwrap_or(PAPER_TABLE2.sigma),
        )
        .tol(a.solver_tol)
        .max_iter(a.solver_max_iter)
        .loss(loss),
        pinned,
        selection: match method {
            None => Selection::Fixed {
                folds: a.folds,
                folds_by: a
                    .group_by
                    .clone()
                    .map_or(a.folds_by.clone(), FoldsBy::Column),
            },
            Some(method) => Selection::Search {
                method,
                budget: a.budget,
                fitness,
                folds_by: a.group_by.map_or(a.folds_by, FoldsBy::Column),
                seed: a.seed,
            },
        },
        search_on: a.search_on,
        intervals: a.intervals,
        tests: a.tests,
        out: a.out,
        report: a.report,
        max_rows: a.max_rows.map(|n| n as usize),
        basis: a.basis,
        time: a.time,
        group,
        weight: a.weight,
        history: a.history,
    };
    let outcome = super::with_session(|s| fit::run(&job, s))?;
    print!("{}", super::said(&outcome.to_string()));
    println!("wrote {}", job.out.display());
    if let Some(dir) = &job.report {
        println!("wrote {}/", dir.display());
    }
    if outcome
        .search
        .as_ref()
        .is_some_and(|s| s.summary.stop == SearchStop::Interrupted)
    {
        return Err(crate::pipeline::PipelineError::Interrupted(format!(
            "interrupted: {} holds the model with the best parameters found before Ctrl-C",
            job.out.display()
        ))
        .into());
    }
    Ok(())
}
