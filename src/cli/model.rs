//! `handcap model`: choose (C, ε, σ), fit MSVR and the previous model, score them on held-out
//! files, write model and report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};

use handcap::data::{self, HAND_INPUTS, HAND_OUTPUTS};
use handcap::fsio;
use handcap::model::file::{ModelFile, StoredModel};
use handcap::model::msvr::{MsvrParams, DEFAULT_MAX_ITER, DEFAULT_TOL};
use handcap::model::previous::{self, PreviousModel};
use handcap::model::{self, Predict};
use handcap::provenance::Provenance;
use handcap::report::{self, Comparison, ModelReport, NamedModel, PreviousSummary, TestResult};
use handcap::search::aco_paper::AcoPaper;
use handcap::search::aco_r::AcoR;
use handcap::search::fitness::{Counters, FitnessKind};
use handcap::search::grid::Grid;
use handcap::search::{self, IterationRecord, Method, Observer, SearchStop, SearchSummary};
use handcap::synth::DEFAULT_SEED;

/// The paper's Table 2: the parameters its ACO selected for the micro-hand.
pub const PAPER_C: f64 = 326.7;
pub const PAPER_EPSILON: f64 = 0.0169;
pub const PAPER_SIGMA: f64 = 0.259;

/// How the hyper-parameters are chosen.
#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum SearchKind {
    /// The paper's digit-encoded ant colony (--ants, --rho, --tau0, --max-iter)
    AcoPaper,
    /// Continuous ACO_R on log C, log ε, log σ (--budget)
    AcoR,
    /// Log-spaced grid (--budget)
    Grid,
    /// Use --c, --epsilon and --sigma as given
    None,
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
    /// How to choose C, ε and σ
    #[arg(long, value_enum, default_value = "aco-paper")]
    search: SearchKind,
    /// How a search scores candidates
    #[arg(long, value_enum, default_value = "cv")]
    fitness: FitnessArg,
    /// Folds of the cross-validated fitness
    #[arg(long, default_value_t = 5)]
    folds: usize,
    /// Column whose values group rows that must be held out together (e.g. a ramp or trial id
    /// when consecutive rows are nearly the same); with --fitness cv
    #[arg(long)]
    group_by: Option<String>,
    /// Seed of the search and of the folds' shuffle
    #[arg(long, default_value_t = DEFAULT_SEED)]
    seed: u64,
    /// Score the search's candidates on this file's rows instead of the training data's (e.g. a
    /// coarser subset of a dense grid: the search stays fast, the fit uses every row)
    #[arg(long)]
    search_on: Option<PathBuf>,
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
    /// aco-r, grid: candidates evaluated at most
    #[arg(long, default_value_t = AcoR::default().budget)]
    budget: usize,
    /// Penalty C, with --search none (default: the paper's Table 2)
    #[arg(long = "c", default_value_t = PAPER_C)]
    c: f64,
    /// Tube radius ε in output units, with --search none (default: the paper's Table 2)
    #[arg(long, default_value_t = PAPER_EPSILON)]
    epsilon: f64,
    /// RBF width σ in inputs scaled to [0, 1], with --search none (default: the paper's Table 2)
    #[arg(long, default_value_t = PAPER_SIGMA)]
    sigma: f64,
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
}

/// How the job chooses its hyper-parameters.
pub enum Selection {
    Fixed,
    Search {
        method: Method,
        fitness: FitnessKind,
        group_by: Option<String>,
        seed: u64,
        /// The rows candidates are scored on, when not the training data.
        on: Option<PathBuf>,
    },
}

/// One model run, as the `model` and `demo` commands describe it.
pub struct Job {
    pub data: PathBuf,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    /// The fixed parameters (`Selection::Fixed`) and the solver controls (always).
    pub params: MsvrParams,
    pub selection: Selection,
    pub tests: Vec<PathBuf>,
    pub out: PathBuf,
    pub report: Option<PathBuf>,
}

/// What a run produced, for printing.
pub struct Outcome {
    pub report: ModelReport,
    pub search: Option<(SearchSummary, Counters, f64)>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let fitness = match a.fitness {
        FitnessArg::Cv => FitnessKind::Cv { folds: a.folds },
        FitnessArg::Train => FitnessKind::Train,
    };
    if a.search_on.is_some() && a.search == SearchKind::None {
        bail!("--search-on gives the rows a search scores candidates on: use it with a --search");
    }
    if a.group_by.is_some() && (a.fitness != FitnessArg::Cv || a.search == SearchKind::None) {
        bail!("--group-by groups the folds of a cross-validated search: use it with --fitness cv and a --search");
    }
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
            budget: a.budget,
            seed: a.seed,
            ..AcoR::default()
        })),
        SearchKind::Grid => Some(Method::Grid(Grid {
            budget: a.budget,
            ..Grid::default()
        })),
    };
    let job = Job {
        data: a.data,
        inputs: a.inputs,
        outputs: a.outputs,
        params: MsvrParams::new(a.c, a.epsilon, a.sigma)
            .tol(a.solver_tol)
            .max_iter(a.solver_max_iter),
        selection: match method {
            None => Selection::Fixed,
            Some(method) => Selection::Search {
                method,
                fitness,
                group_by: a.group_by,
                seed: a.seed,
                on: a.search_on,
            },
        },
        tests: a.tests,
        out: a.out,
        report: a.report,
    };
    let outcome = execute(&job)?;
    print_summary(&outcome);
    println!("wrote {}", job.out.display());
    if let Some(dir) = &job.report {
        println!("wrote {}/", dir.display());
    }
    Ok(())
}

/// A progress bar over a search's iterations.
struct Progress(ProgressBar);

impl Observer for Progress {
    fn iteration(&mut self, r: &IterationRecord) {
        self.0.set_position(r.iteration as u64);
        self.0.set_message(format!(
            "best {:.5} (C {:.4}, ε {:.4}, σ {:.4})",
            r.best_fitness, r.best.c, r.best.epsilon, r.best.sigma
        ));
    }
}

/// Iterations a method runs at most, for the progress bar's length.
fn iteration_cap(method: &Method) -> u64 {
    match method {
        Method::AcoPaper(m) => m.max_iter as u64,
        Method::AcoR(m) => (m.budget.saturating_sub(m.archive)).div_ceil(m.ants.max(1)) as u64 + 1,
        Method::Grid(m) => (m.per_axis().pow(3)).div_ceil(m.batch.max(1)) as u64,
    }
}

/// Chooses the parameters, fits, scores and writes; returns what was done.
pub fn execute(job: &Job) -> anyhow::Result<Outcome> {
    let search_on = match &job.selection {
        Selection::Search { on: Some(p), .. } => Some(p.as_path()),
        _ => None,
    };
    let inputs: Vec<&Path> = std::iter::once(job.data.as_path())
        .chain(search_on)
        .chain(job.tests.iter().map(PathBuf::as_path))
        .collect();
    if fsio::is_same_file_as_any(&job.out, &inputs) {
        bail!(
            "--out {} is one of the input files; choose another name",
            job.out.display()
        );
    }
    job.params.check().context("model parameters")?;
    if let Some(parent) = job.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    for path in &inputs {
        let flagged = data::count_flagged(path)?;
        if flagged > 0 {
            println!(
                "{}: {flagged} flagged rows left out (see their flag column)",
                path.display()
            );
        }
    }
    let train = data::read_dataset(&job.data, &job.inputs, &job.outputs)?;
    train.check_fittable(handcap::model::msvr::MIN_FIT_ROWS)?;

    let (params, search, history) = match &job.selection {
        Selection::Fixed => (job.params, None, None),
        Selection::Search {
            method,
            fitness,
            group_by,
            seed,
            on,
        } => {
            let scored_on = on.as_deref().unwrap_or(&job.data);
            let scored = match on {
                None => train.clone(),
                Some(path) => {
                    let d = data::read_dataset(path, &job.inputs, &job.outputs)?;
                    d.check_fittable(handcap::model::msvr::MIN_FIT_ROWS)?;
                    d
                }
            };
            let groups = match group_by {
                None => None,
                Some(column) => Some(search::Groups {
                    column: column.clone(),
                    labels: data::read_columns(scored_on, std::slice::from_ref(column))?.values,
                }),
            };
            let started = Instant::now();
            let bar = ProgressBar::new(iteration_cap(method)).with_style(
                ProgressStyle::with_template("search {bar:30} {pos}/{len} iterations  {msg}")
                    .expect("valid template"),
            );
            let mut progress = Progress(bar);
            let (summary, result, counters) = search::run(
                method,
                &scored,
                *fitness,
                *seed,
                groups.as_ref(),
                &job.params,
                &mut progress,
                &super::interrupt_flag(),
            )?;
            progress.0.finish_and_clear();
            let best = summary.best;
            let params = MsvrParams {
                c: best.c,
                epsilon: best.epsilon,
                sigma: best.sigma,
                ..job.params
            };
            let seconds = started.elapsed().as_secs_f64();
            (
                params,
                Some((summary, counters, seconds)),
                Some(result.history),
            )
        }
    };

    let msvr = params.check()?.fit(&train)?;
    let train_errors = model::evaluate(&msvr, &train)?;

    // The previous physics model describes the micro-hand only.
    let is_hand = train.inputs.names == HAND_INPUTS && train.outputs.names == HAND_OUTPUTS;
    let previous = if is_hand {
        let default = PreviousModel::with_defaults();
        let (calibrated, calibration) = previous::calibrate(&train, &default.params)?;
        Some((default, calibrated, calibration))
    } else {
        None
    };
    let mut models = vec![NamedModel {
        name: "msvr",
        model: &msvr,
    }];
    if let Some((default, calibrated, _)) = &previous {
        for m in [default, calibrated] {
            models.push(NamedModel {
                name: m.name(),
                model: m,
            });
        }
    }
    let test_data = job
        .tests
        .iter()
        .map(|path| {
            Ok((
                file_name(path),
                data::read_dataset(path, &job.inputs, &job.outputs)?,
            ))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut tests = Vec::new();
    for (name, test) in &test_data {
        for m in &models {
            tests.push(TestResult {
                model: m.name.into(),
                test: name.clone(),
                errors: model::evaluate(m.model, test)?,
            });
        }
    }

    let seed = match job.selection {
        Selection::Fixed => None,
        Selection::Search { seed, .. } => Some(seed),
    };
    let mut provenance = Provenance::new(super::command_line(), seed);
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
        search: search.as_ref().map(|(s, _, _)| s.clone()),
        train_errors,
        previous: previous.as_ref().map(|(d, c, cal)| PreviousSummary {
            default: d.params.clone(),
            calibrated: c.params.clone(),
            calibration: cal.clone(),
        }),
        tests,
        provenance: provenance.clone(),
    };
    // The report first: an interrupted search still leaves its history, and the model last.
    if let Some(dir) = &job.report {
        let comparison = Comparison {
            models: &models,
            tests: &test_data,
        };
        report::write_model_report(dir, &report, history.as_deref(), &comparison)?;
    }
    ModelFile::new(StoredModel::Msvr(msvr), report.search.clone(), provenance).save(&job.out)?;
    Ok(Outcome { report, search })
}

pub fn print_summary(outcome: &Outcome) {
    let r = &outcome.report;
    if let Some((s, counters, seconds)) = &outcome.search {
        println!(
            "search {}: {} iterations ({:?}), best {} {:.5}",
            s.method.name(),
            s.iterations,
            s.stop,
            s.fitness,
            s.best_fitness
        );
        println!(
            "  {} candidates scored, {} fits, {} memo hits, {} kernel cache hits, {:.1} s",
            counters.evaluations, counters.fits, counters.memo_hits, counters.kernel_hits, seconds
        );
        if s.stop == SearchStop::Interrupted {
            println!("  interrupted: the model uses the best parameters found so far");
        }
    }
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
            "NOT converged: raise --solver-max-iter"
        },
        f.stop
    );
    println!(
        "  training error (not a test): MAE {:.4}, mean Euclidean {:.4}",
        r.train_errors.mae, r.train_errors.euclid
    );
    if let Some(p) = &r.previous {
        let (c, cal) = (&p.calibrated, &p.calibration);
        println!(
            "previous model calibrated on {} rows: α₀ {:.2}°, K {:.2} N, P_th {:.1} kPa, arms {:.3} × {:.3}; RMS {:.4} ({})",
            cal.rows,
            c.braid_angle_deg,
            c.load_n,
            c.threshold_kpa,
            c.arm_x,
            c.arm_y,
            cal.rms_mm,
            if cal.converged { "converged" } else { "NOT converged" }
        );
    }
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
