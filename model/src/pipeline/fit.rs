//! The fit stage: the model chosen, fitted and calibrated by [`crate::select`] on the files'
//! rows, scored with the previous model on held-out files, then the report and the model file.

use std::fmt;
use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::{io_error, Event, PipelineError, Session, Task};
use crate::data::{self, HAND_INPUTS, HAND_OUTPUTS};
use crate::model;
use crate::model::file::ModelFile;
use crate::model::history::{self, HistoryChoice};
use crate::model::msvr::{Basis, MsvrParams};
use crate::model::previous::{self, PreviousModel};
use crate::model::StoredModel;
use crate::report::{
    self, Comparison, IntervalReport, ModelReport, NamedModel, PreviousSummary, TestCoverageReport,
    TestResult,
};
use crate::search::{IterationRecord, Search, SearchStop};
use crate::select::family::{Family, FamilyChoice};
use crate::select::folds::FoldsBy;
use crate::select::tune::{self, BasisChoice, Pinned};
use crate::select::{self, Listener, Plan, SelectError, Selected, Table};

pub use crate::select::Selection;

/// One model run, as the `model` and `demo` commands describe it.
pub struct FitJob {
    pub data: PathBuf,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    /// The family to fit, or `auto`'s choice by cross-validation.
    pub family: FamilyChoice,
    /// The fixed parameters (`Selection::Fixed`) and the solver controls (always).
    pub params: MsvrParams,
    pub selection: Selection,
    /// Parameters a search holds at [`FitJob::params`]' values.
    pub pinned: Pinned,
    /// The rows a search scores candidates on, when not the training data.
    pub search_on: Option<PathBuf>,
    pub tests: Vec<PathBuf>,
    pub out: PathBuf,
    pub report: Option<PathBuf>,
    /// Rows kept at most from the training (and search) data, evenly spaced; `None` keeps all.
    pub max_rows: Option<usize>,
    /// The expansion: exact, a reduced basis, or chosen from the data.
    pub basis: BasisChoice,
    /// The time column (seconds, increasing within each group): input history may be used.
    pub time: Option<String>,
    /// The column naming the runs of a time series (history restarts in each).
    pub group: Option<String>,
    /// The column of each row's weight in the fit's loss (`--weight`).
    pub weight: Option<String>,
    /// What history to try (with `time`).
    pub history: HistoryChoice,
    /// Intervals also without a search (k more fits when nothing else made the held-out
    /// predictions they need).
    pub intervals: bool,
}

impl FitJob {
    /// The job that fits `model`'s own settings again on `data`, its rows weighed by the
    /// `weight` column: the same family, C, ε, σ, loss, basis, history, time and group columns,
    /// no search, into `out` (the learning loop's refit on the runs it played).
    pub fn refit(model: &ModelFile, data: PathBuf, weight: Option<String>, out: PathBuf) -> Self {
        let StoredModel::Msvr(fitted) = &model.model;
        let used = model.history.as_ref().and_then(|h| h.used.as_ref());
        let params = fitted.params;
        let h = params.hyper();
        FitJob {
            data,
            inputs: used.map_or_else(|| fitted.inputs.clone(), |u| u.inputs.clone()),
            outputs: fitted.outputs.clone(),
            family: FamilyChoice::One(
                model
                    .family
                    .as_ref()
                    .map_or_else(Family::default, |f| f.used),
            ),
            params,
            selection: Selection::Fixed {
                folds: 5,
                folds_by: used
                    .and_then(|u| u.group.clone())
                    .map_or(FoldsBy::Auto, FoldsBy::Column),
            },
            pinned: Pinned {
                c: Some(h.c),
                epsilon: Some(h.epsilon),
                sigma: Some(h.sigma),
                loss: None,
            },
            search_on: None,
            tests: Vec::new(),
            out,
            report: None,
            max_rows: None,
            basis: match params.basis {
                Basis::Exact => BasisChoice::Exact,
                Basis::Reduced { centres, .. } => BasisChoice::Centres(centres),
            },
            time: used.map(|u| u.time.clone()),
            group: used.and_then(|u| u.group.clone()),
            weight,
            history: HistoryChoice::of(used.map(|u| &u.memory)),
            intervals: false,
        }
    }

    /// What [`select::select`] is asked.
    fn plan(&self) -> Plan {
        Plan {
            family: self.family,
            params: self.params,
            selection: self.selection.clone(),
            pinned: self.pinned,
            basis: self.basis,
            history: self.history.clone(),
            time: self.time.clone(),
            group: self.group.clone(),
            max_rows: self.max_rows,
            intervals: self.intervals,
        }
    }

    /// Every file read: the training data, the search's rows, the tests.
    fn inputs(&self) -> Vec<&Path> {
        std::iter::once(self.data.as_path())
            .chain(self.search_on.as_deref())
            .chain(self.tests.iter().map(PathBuf::as_path))
            .collect()
    }

    /// Every file written: the model file and the report's.
    fn outputs(&self) -> Vec<Output> {
        let mut planned = vec![Output::new(&self.out, "the model file")];
        if let Some(dir) = &self.report {
            let searched = self.selection.searched();
            let tests: Vec<String> = self.tests.iter().map(|p| file_name(p)).collect();
            planned.extend(
                report::report_files(dir, searched, &tests, &self.outputs)
                    .into_iter()
                    .map(|(path, role)| Output::new(path, format!("{role} in the report"))),
            );
        }
        planned
    }
}

/// What a run produced.
pub struct FitOutcome {
    pub report: ModelReport,
    /// The search, when there was one.
    pub search: Option<tune::Searched>,
}

/// Tells the session what the selection does.
impl Listener for Session<'_> {
    fn note(&self, text: String) {
        self.emit(Event::Note(text));
    }

    fn iteration(&self, record: &IterationRecord, cap: usize) {
        self.emit(Event::Iteration { record, cap });
    }

    fn search_ended(&self) {
        self.emit(Event::SearchEnded);
    }

    fn fitting(&self, done: usize, total: usize) {
        self.emit(Event::Count {
            task: Task::Fit,
            done,
            total,
        });
    }

    fn fitted(&self) {
        self.emit(Event::Finished(Task::Fit));
    }
}

/// Chooses the parameters (and the input history), fits, scores and writes: the report first
/// (an interrupted search still leaves its history), the model file last.
///
/// # Errors
/// [`PipelineError`]: bad parameters, unreadable or unusable data, `--out` naming an input, a
/// search or fit failure, or a file that cannot be written.
pub fn run(job: &FitJob, session: &Session) -> Result<FitOutcome, PipelineError> {
    job.plan()
        .check()
        .map_err(|e| PipelineError::Request(e.to_string()))?;
    if let Some(w) = job
        .weight
        .as_ref()
        .filter(|w| job.inputs.contains(w) || job.outputs.contains(w))
    {
        return Err(PipelineError::Request(format!("weight={w}: the model reads `{w}` as an input or output; name the column of the rows' weights")));
    }
    if job.search_on.is_some() && !job.selection.searched() {
        return Err(PipelineError::Request(
            "search_on=FILE gives the rows a search scores candidates on: use it with a search"
                .into(),
        ));
    }
    outputs::check(&job.inputs(), &job.outputs())?;
    note_flagged(job, session)?;
    let train = read_table(&job.data, job, true)?;
    note_copies(&train.data, session);
    if let Some(max) = job.max_rows.filter(|&max| train.data.rows() > max) {
        session.emit(Event::Note(format!(
            "{}: {} rows, {max} evenly spaced ones kept (--max-rows)",
            job.data.display(),
            train.data.rows()
        )));
    }
    let search_on = job
        .search_on
        .as_ref()
        .map(|p| read_table(p, job, true))
        .transpose()?;
    // Every test file is read before the search: a bad one must not cost the search.
    let tests = job
        .tests
        .iter()
        .map(|p| read_table(p, job, false))
        .collect::<Result<Vec<_>, _>>()?;
    let selected = select::select(
        &train,
        search_on.as_ref(),
        &job.plan(),
        session,
        session.interrupt,
    )
    .map_err(|e| match e {
        SelectError::Parameter(message) => PipelineError::Request(message),
        SelectError::Basis(e) => PipelineError::Request(e.to_string()),
        SelectError::Interrupted(message) => PipelineError::Interrupted(message),
        e => PipelineError::Select(e),
    })?;
    let scored = score(job, &selected, &tests)?;
    let mut provenance = session.provenance(job.selection.seed());
    for path in job.inputs() {
        provenance = provenance.with_input(path).map_err(io_error(path))?;
    }
    let report = scored.report(job, &selected, provenance.clone());
    // The model is saved even when the report cannot be written (a full disk), and the error
    // says so: the search is never lost to a report.
    let reported = job.report.as_ref().map(|dir| {
        let models = scored.models(&selected);
        let comparison = Comparison {
            models: &models,
            tests: &scored.test_data,
        };
        let history = selected.search.as_ref().map(|s| s.history.as_slice());
        report::write_model_report(dir, &report, history, &comparison)
    });
    let (file, search) = selected.into_file(provenance);
    file.save(&job.out)?;
    if let Some(Err(e)) = reported {
        return Err(PipelineError::Partial {
            source: Box::new(e.into()),
            written: job.out.clone(),
        });
    }
    Ok(FitOutcome { report, search })
}

/// Says how many flagged rows each input file leaves out.
fn note_flagged(job: &FitJob, session: &Session) -> Result<(), PipelineError> {
    for path in job.inputs() {
        let flagged = data::count_flagged(path)?;
        if flagged > 0 {
            session.emit(Event::Note(format!(
                "{}: {flagged} flagged rows left out (see their flag column)",
                path.display()
            )));
        }
    }
    Ok(())
}

/// Says when rows repeat another row exactly (inputs and outputs): a held-out copy is predicted
/// from its twin, so the cross-validated error and the intervals understate a new row's (a
/// file whose rows repeat gave radii of 0.00002 mm far from its data).
fn note_copies(data: &crate::data::Dataset, session: &Session) {
    let mut seen = std::collections::HashSet::new();
    let copies = (0..data.rows())
        .filter(|&i| {
            let row = data.inputs.row(i).iter().chain(data.outputs.row(i));
            !seen.insert(row.map(|v| v.to_bits()).collect::<Vec<u64>>())
        })
        .count();
    if copies > 0 {
        session.emit(Event::Note(format!(
            "{}: {copies} of {} rows repeat another row exactly (inputs and outputs): a held-out copy is predicted from its twin, so the cross-validated error and the intervals understate a new row's; drop the copies, or hold each set of copies out together (--folds-by COLUMN)",
            data.source.display(),
            data.rows()
        )));
    }
}

/// A data file's job columns, its time series (checked for order) when `--time` was given,
/// and for a file a model is fitted or searched on (`fitted`) the columns the folds may be cut
/// by and the rows' weights.
fn read_table(path: &Path, job: &FitJob, fitted: bool) -> Result<Table, PipelineError> {
    let mut data = data::read_dataset(path, &job.inputs, &job.outputs)?;
    if !fitted && data.rows() == 0 {
        return Err(data::DataError::NoRows {
            path: path.into(),
            what: "--test".into(),
        }
        .into());
    }
    if let Some(column) = job.weight.as_ref().filter(|_| fitted) {
        data.weights = Some(data::read_weights(path, column)?);
    }
    let (series, lines, context) = match &job.time {
        None => (None, Vec::new(), None),
        Some(time) => {
            let group = job.group.as_deref();
            let (series, lines) = history::read_series(path, time, group)?;
            let context = history::Context::read(path, &job.inputs, time, group)?;
            (Some(series), lines, Some(context))
        }
    };
    let fold_columns = match &job.selection {
        _ if !fitted => Vec::new(),
        Selection::Fixed { folds_by, .. } | Selection::Search { folds_by, .. } => {
            fold_columns(path, folds_by, job)?
        }
    };
    let table = Table {
        data,
        series,
        lines,
        context,
        fold_columns,
    };
    table.check_series(false)?;
    Ok(table)
}

/// The columns of `path` the fold choice may use: the named column for `--folds-by COLUMN`;
/// for `auto`, every numeric column that is neither input nor output.
fn fold_columns(
    path: &Path,
    by: &FoldsBy,
    job: &FitJob,
) -> Result<Vec<(String, Vec<f64>)>, PipelineError> {
    Ok(match by {
        FoldsBy::Shuffle | FoldsBy::Blocks => Vec::new(),
        FoldsBy::Column(column) => vec![(column.clone(), data::read_labels(path, column)?.0)],
        FoldsBy::Auto => {
            let skip: Vec<String> = (job.inputs.iter().chain(&job.outputs))
                .chain(&job.weight)
                .cloned()
                .collect();
            data::numeric_columns(path, &skip)?
        }
    })
}

/// The selected model and the previous physics model scored on the test files.
struct Scored {
    test_data: Vec<(String, data::Dataset)>,
    previous: Option<(PreviousModel, PreviousModel, previous::Calibration)>,
    tests: Vec<TestResult>,
    coverage: Vec<TestCoverageReport>,
}

/// Scores the selected model (and, on the micro-hand's data, the previous model with its
/// default and calibrated parameters) on every test file, with the intervals' coverage.
fn score(job: &FitJob, selected: &Selected, tests: &[Table]) -> Result<Scored, PipelineError> {
    let used = selected.used();
    let test_data = tests
        .iter()
        .map(|t| Ok((file_name(&t.data.source), t.with(used)?)))
        .collect::<Result<Vec<_>, PipelineError>>()?;
    let train = &selected.train;
    // The previous physics model describes the micro-hand only.
    let is_hand = train.inputs.names == HAND_INPUTS && train.outputs.names == HAND_OUTPUTS;
    let previous = if is_hand {
        let default = PreviousModel::with_defaults();
        let (calibrated, calibration) = previous::calibrate(train, &default.params)?;
        Some((default, calibrated, calibration))
    } else {
        None
    };
    let mut scored = Scored {
        test_data,
        previous,
        tests: Vec::new(),
        coverage: Vec::new(),
    };
    // Test rows' groups: the column that names the runs, where a test file has it.
    let group_column = job.group.clone().or_else(|| selected.runs.clone());
    let intervals = selected
        .intervals
        .as_ref()
        .filter(|i| !i.held_out.radii.is_empty());
    let mut results = Vec::new();
    let mut coverage = Vec::new();
    for (name, test) in &scored.test_data {
        // The model fitted first, then the previous model's: the intervals are the first's.
        for (k, m) in scored.models(selected).into_iter().enumerate() {
            let (errors, predicted) = model::evaluate_predicting(m.model, test)?;
            if let (Some(i), 0) = (intervals, k) {
                let labels = group_column
                    .as_ref()
                    .and_then(|c| data::read_columns(&test.source, std::slice::from_ref(c)).ok());
                coverage.push(TestCoverageReport {
                    test: name.clone(),
                    column: labels.as_ref().and(group_column.clone()),
                    coverage: i
                        .test(
                            &test.outputs,
                            &predicted,
                            &test.inputs,
                            labels.as_ref().map(|l| l.values.as_slice()),
                        )
                        .map_err(|e| PipelineError::Input(format!("{name}: {e}")))?,
                });
            }
            results.push(TestResult {
                model: m.name.into(),
                test: name.clone(),
                errors,
            });
        }
    }
    scored.tests = results;
    scored.coverage = coverage;
    Ok(scored)
}

impl Scored {
    /// The models compared: the one fitted (named by its family), then the previous model
    /// (default, calibrated) on the hand.
    fn models<'a>(&'a self, selected: &'a Selected) -> Vec<NamedModel<'a>> {
        let mut models = vec![NamedModel {
            name: selected.family.used.name(),
            model: selected.model.predictor(),
        }];
        if let Some((default, calibrated, _)) = &self.previous {
            for m in [default, calibrated] {
                models.push(NamedModel {
                    name: m.name(),
                    model: m,
                });
            }
        }
        models
    }

    /// The report of the run.
    fn report(
        &self,
        job: &FitJob,
        selected: &Selected,
        provenance: crate::provenance::Provenance,
    ) -> ModelReport {
        let predictor = selected.model.predictor();
        ModelReport {
            training_file: file_name(&job.data),
            inputs: predictor.inputs().to_vec(),
            outputs: predictor.outputs().to_vec(),
            spec: selected.model.spec(),
            family: selected.family.clone(),
            fit: selected.model.diagnostics().clone(),
            basis: selected.basis.clone(),
            history: selected.history.clone(),
            search: selected.search.as_ref().map(|s| s.summary.clone()),
            train_errors: selected.train_errors.clone(),
            previous: self.previous.as_ref().map(|(d, c, cal)| PreviousSummary {
                default: d.params.clone(),
                calibrated: c.params.clone(),
                calibration: cal.clone(),
            }),
            tests: self.tests.clone(),
            intervals: selected.intervals.as_ref().map(|i| IntervalReport {
                held_out: i.held_out.clone(),
                widens: i.widening.is_some(),
                tests: self.coverage.clone(),
            }),
            provenance,
        }
    }
}

/// The file name of a path, for tables.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    )
}

impl fmt::Display for FitOutcome {
    /// The search, the fit and the held-out errors, as `handcap model` prints them.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let r = &self.report;
        if let Some(searched) = &self.search {
            let (s, counters) = (&searched.summary, &searched.counters);
            writeln!(
                f,
                "search {}: {} iterations ({:?}), best {} {:.5}",
                s.method.name(),
                s.iterations,
                s.stop,
                s.fitness,
                s.best_fitness
            )?;
            writeln!(f,
            "  {} candidates scored ({} stopped early by racing), {} fits, {} memo hits, {} kernel cache hits, {:.1} s",
            counters.evaluations,
            counters.raced,
            counters.fits,
            counters.memo_hits,
            counters.kernel_hits,
            searched.seconds
        )?;
            if s.stop == SearchStop::Interrupted {
                writeln!(
                    f,
                    "  interrupted: the model uses the best parameters found so far"
                )?;
            }
        }
        let fit = &r.fit;
        let settings: Vec<String> = r
            .settings()
            .iter()
            .skip(1)
            .map(|(name, value)| format!("{name} = {value}"))
            .collect();
        let weighted = fit.weights.map_or_else(String::new, |w| format!(" ({w})"));
        writeln!(
            f,
            "{} on {}: {} rows{weighted}, {}",
            r.family.used.title(),
            r.training_file,
            fit.rows,
            settings.join(", ")
        )?;
        writeln!(
            f,
            "  {} iterations, objective {:.6e}, {} terms, {} ({:?})",
            fit.iterations,
            fit.objective,
            fit.support_vectors,
            if fit.converged {
                "converged"
            } else {
                "NOT converged: raise the solver's iteration cap"
            },
            fit.stop
        )?;
        writeln!(
            f,
            "  training error (not a test): MAE {:.4}, mean Euclidean {:.4}",
            r.train_errors.mae, r.train_errors.euclid
        )?;
        if let Some(p) = &r.previous {
            let (c, cal) = (&p.calibrated, &p.calibration);
            writeln!(f,
            "previous model calibrated on {} rows: α₀ {:.2}°, K {:.2} N, P_th {:.1} kPa, arms {:.3} × {:.3}; RMS {:.4} ({})",
            cal.rows,
            c.braid_angle_deg,
            c.load_n,
            c.threshold_kpa,
            c.arm_x,
            c.arm_y,
            cal.rms_mm,
            if cal.converged { "converged" } else { "NOT converged" }
        )?;
        }
        if !r.tests.is_empty() {
            writeln!(f, "held-out errors (output units):")?;
            write!(f, "{}", report::errors_table(&r.tests, &r.outputs))?;
        }
        Ok(())
    }
}
