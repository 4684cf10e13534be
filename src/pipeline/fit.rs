//! The fit stage: choose (C, ε, σ), fit MSVR and the previous model, score them on held-out
//! files, write the report and the model file.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::outputs::{self, Output};
use super::{io_error, Event, PipelineError, Session};
use crate::data::{self, HAND_INPUTS, HAND_OUTPUTS};
use crate::model::file::ModelFile;
use crate::model::msvr::fitness::{Counters, FitnessKind};
use crate::model::msvr::folds::{self, FoldsBy};
use crate::model::msvr::tune::{self, BasisChoice, SearchSummary};
use crate::model::msvr::{self, Basis, MsvrParams, MIN_FIT_ROWS};
use crate::model::previous::{self, PreviousModel};
use crate::model::{self, ModelSpec};
use crate::report::{self, Comparison, ModelReport, NamedModel, PreviousSummary, TestResult};
use crate::search::{IterationRecord, Method, Observer, Search};

/// How the job chooses its hyper-parameters.
pub enum Selection {
    /// The parameters of [`FitJob::params`] as they are.
    Fixed,
    Search {
        method: Method,
        /// Candidates at most (ACO_R, grid); `None`: [`tune::budget_for`] the rows scored.
        budget: Option<usize>,
        fitness: FitnessKind,
        /// How cross-validation cuts the rows ([`folds::plan`]).
        folds_by: FoldsBy,
        seed: u64,
        /// The rows candidates are scored on, when not the training data.
        on: Option<PathBuf>,
    },
}

/// One model run, as the `model` and `demo` commands describe it.
pub struct FitJob {
    pub data: PathBuf,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    /// The fixed parameters (`Selection::Fixed`) and the solver controls (always).
    pub params: MsvrParams,
    pub selection: Selection,
    pub tests: Vec<PathBuf>,
    pub out: PathBuf,
    pub report: Option<PathBuf>,
    /// Rows kept at most from the training (and search) data, evenly spaced; `None` keeps all.
    pub max_rows: Option<usize>,
    /// The expansion: exact, a reduced basis, or chosen from the data.
    pub basis: BasisChoice,
}

/// What a run produced.
pub struct FitOutcome {
    pub report: ModelReport,
    /// The search, its work counters and its time (s), when there was one.
    pub search: Option<(SearchSummary, Counters, f64)>,
}

/// Folds of `--basis auto`'s cross-validation when no search gives them.
const AUTO_FOLDS: usize = 5;

/// Reports each search iteration as an [`Event::Iteration`].
struct Iterations<'a> {
    session: &'a Session<'a>,
    cap: usize,
}

impl Observer for Iterations<'_> {
    fn iteration(&mut self, record: &IterationRecord) {
        self.session.emit(Event::Iteration {
            record,
            cap: self.cap,
        });
    }
}

/// Chooses the parameters, fits, scores and writes: the report first (an interrupted search
/// still leaves its history), the model file last.
///
/// # Errors
/// [`PipelineError`]: bad parameters, unreadable or unusable data, `--out` naming an input, a
/// search or fit failure, or a file that cannot be written.
pub fn run(job: &FitJob, session: &Session) -> Result<FitOutcome, PipelineError> {
    let search_on = match &job.selection {
        Selection::Search { on: Some(p), .. } => Some(p.as_path()),
        _ => None,
    };
    let inputs: Vec<&Path> = std::iter::once(job.data.as_path())
        .chain(search_on)
        .chain(job.tests.iter().map(PathBuf::as_path))
        .collect();
    job.params
        .check()
        .map_err(|e| PipelineError::Usage(format!("model parameters: {e}")))?;
    let mut planned = vec![Output::new(&job.out, "--out")];
    if let Some(dir) = &job.report {
        let searched = matches!(job.selection, Selection::Search { .. });
        let tests: Vec<String> = job.tests.iter().map(|p| file_name(p)).collect();
        planned.extend(
            report::report_files(dir, searched, &tests, &job.outputs)
                .into_iter()
                .map(|(path, role)| Output::new(path, format!("{role} in --report"))),
        );
    }
    outputs::check(&inputs, &planned)?;
    for path in &inputs {
        let flagged = data::count_flagged(path)?;
        if flagged > 0 {
            session.emit(Event::Note(format!(
                "{}: {flagged} flagged rows left out (see their flag column)",
                path.display()
            )));
        }
    }
    let keep = |d: data::Dataset| match job.max_rows {
        Some(max) if d.rows() > max => {
            session.emit(Event::Note(format!(
                "{}: {} rows, {max} evenly spaced ones kept (--max-rows)",
                d.source.display(),
                d.rows()
            )));
            d.subsample(max)
        }
        _ => d,
    };
    let train = keep(data::read_dataset(&job.data, &job.inputs, &job.outputs)?);
    train.check_fittable(MIN_FIT_ROWS)?;
    let seed = match job.selection {
        Selection::Fixed => None,
        Selection::Search { seed, .. } => Some(seed),
    };
    let initial = tune::initial_basis(job.basis, train.rows(), seed.unwrap_or(crate::DEFAULT_SEED))
        .map_err(|e| PipelineError::Usage(e.to_string()))?;
    msvr::check_memory(train.rows(), initial.basis)?;
    session.emit(Event::Note(format!(
        "basis: {} ({})",
        initial.basis, initial.reason
    )));
    // Only `auto`'s reduced basis grows; exact and a given size are used as they are.
    let grows = job.basis == BasisChoice::Auto && initial.basis != Basis::Exact;
    let solver = job.params.basis(initial.basis);
    // Every test file is read before the search: a bad one must not cost the search.
    let test_data = job
        .tests
        .iter()
        .map(|path| {
            Ok((
                file_name(path),
                data::read_dataset(path, &job.inputs, &job.outputs)?,
            ))
        })
        .collect::<Result<Vec<_>, PipelineError>>()?;

    let (params, search, history, basis) = match &job.selection {
        Selection::Fixed => {
            let basis = if grows {
                // Scored as a search scores: on at most SEARCH_ROWS evenly spaced rows.
                let scored = train.subsample(tune::SEARCH_ROWS);
                let plan = folds::plan(
                    &FoldsBy::Auto,
                    &scored,
                    &other_columns(&job.data, &FoldsBy::Auto, job, scored.rows())?,
                    AUTO_FOLDS,
                )?;
                let fitness = FitnessKind::Cv { folds: AUTO_FOLDS };
                tune::grow_basis(initial, &scored, fitness, &plan, &solver, session.interrupt)?
            } else {
                initial
            };
            (solver.basis(basis.basis), None, None, basis)
        }
        Selection::Search {
            method,
            budget,
            fitness,
            folds_by,
            seed,
            on,
        } => {
            let scored_on = on.as_deref().unwrap_or(&job.data);
            let scored = match on {
                None if train.rows() > tune::SEARCH_ROWS => {
                    session.emit(Event::Note(format!(
                        "search: candidates scored on {} evenly spaced rows of {} (the model is fitted on all of them)",
                        tune::SEARCH_ROWS,
                        train.rows()
                    )));
                    train.subsample(tune::SEARCH_ROWS)
                }
                None => train.clone(),
                Some(path) => {
                    let d = keep(data::read_dataset(path, &job.inputs, &job.outputs)?);
                    d.check_fittable(MIN_FIT_ROWS)?;
                    d
                }
            };
            let folds = match fitness {
                FitnessKind::Cv { folds } => *folds,
                FitnessKind::Train => 2,
            };
            let plan = folds::plan(
                folds_by,
                &scored,
                &other_columns(scored_on, folds_by, job, scored.rows())?,
                folds,
            )?;
            if matches!(fitness, FitnessKind::Cv { .. }) {
                session.emit(Event::Note(format!("folds: {}", plan.choice)));
            }
            let method = &method.with_budget(budget.unwrap_or(tune::budget_for(scored.rows())));
            let started = Instant::now();
            let mut observer = Iterations {
                session,
                cap: method.iteration_cap(),
            };
            let (summary, result, counters) = tune::run(
                method,
                &scored,
                *fitness,
                *seed,
                &plan,
                &solver,
                &mut observer,
                session.interrupt,
            )?;
            session.emit(Event::Searched(&summary));
            let params = tune::solver_for(method, &solver).with_hyper(summary.best);
            let basis = if grows {
                tune::grow_basis(
                    initial,
                    &scored,
                    *fitness,
                    &plan,
                    &params,
                    session.interrupt,
                )?
            } else {
                initial
            };
            let seconds = started.elapsed().as_secs_f64();
            (
                params.basis(basis.basis),
                Some((summary, counters, seconds)),
                Some(result.history),
                basis,
            )
        }
    };
    if !basis.tried.is_empty() {
        session.emit(Event::Note(format!(
            "basis: {} ({})",
            basis.basis, basis.reason
        )));
    }

    let fitted = ModelSpec::Msvr(params).fit(&train)?;
    let train_errors = model::evaluate(fitted.predictor(), &train)?;

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
        model: fitted.predictor(),
    }];
    if let Some((default, calibrated, _)) = &previous {
        for m in [default, calibrated] {
            models.push(NamedModel {
                name: m.name(),
                model: m,
            });
        }
    }
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

    let mut provenance = session.provenance(seed);
    for path in &inputs {
        provenance = provenance.with_input(path).map_err(io_error(path))?;
    }
    let report = ModelReport {
        training_file: file_name(&job.data),
        inputs: fitted.predictor().inputs().to_vec(),
        outputs: fitted.predictor().outputs().to_vec(),
        spec: fitted.spec(),
        fit: fitted.diagnostics().clone(),
        basis: basis.clone(),
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
    // The model is saved even when the report cannot be written (a full disk), and the error
    // says so: the search is never lost to a report.
    let reported = job.report.as_ref().map(|dir| {
        let comparison = Comparison {
            models: &models,
            tests: &test_data,
        };
        report::write_model_report(dir, &report, history.as_deref(), &comparison)
    });
    ModelFile::new(fitted, report.search.clone(), Some(basis), provenance).save(&job.out)?;
    if let Some(Err(e)) = reported {
        return Err(PipelineError::Partial {
            source: Box::new(e.into()),
            written: job.out.clone(),
        });
    }
    Ok(FitOutcome { report, search })
}

/// The columns of `path` the fold choice may use, one value per kept row: the named column for
/// `--folds-by COLUMN`; for `auto`, every numeric column that is neither input nor output.
/// `rows`: the rows the folds cut (fewer than the file's when the search scores a subsample).
fn other_columns(
    path: &Path,
    by: &FoldsBy,
    job: &FitJob,
    rows: usize,
) -> Result<Vec<(String, Vec<f64>)>, PipelineError> {
    let names: Vec<String> = match by {
        FoldsBy::Shuffle | FoldsBy::Blocks => return Ok(Vec::new()),
        FoldsBy::Column(column) => vec![column.clone()],
        FoldsBy::Auto => data::header(path)?
            .into_iter()
            .filter(|h| !job.inputs.contains(h) && !job.outputs.contains(h) && h != "flag")
            .collect(),
    };
    let mut out = Vec::new();
    for name in names {
        let read = data::read_columns(path, std::slice::from_ref(&name));
        let values = match (read, by) {
            (Ok(c), _) => c.values,
            (Err(e), FoldsBy::Column(_)) => return Err(e.into()),
            (Err(_), _) => continue, // not numeric: not a candidate
        };
        // The rows `keep` kept, then those the search scores (as `Dataset::subsample` picks).
        let mut kept = data::evenly_spaced(values.len(), job.max_rows.unwrap_or(usize::MAX));
        if rows < kept.len() {
            kept = data::evenly_spaced(kept.len(), rows)
                .into_iter()
                .map(|i| kept[i])
                .collect();
        }
        out.push((name, kept.iter().map(|&i| values[i]).collect()));
    }
    Ok(out)
}

/// The file name of a path, for tables.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    )
}
