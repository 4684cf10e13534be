//! The fit stage: choose (C, ε, σ), fit MSVR and the previous model, score them on held-out
//! files, write the report and the model file.

use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::{io_error, Event, PipelineError, Session, Task};
use crate::data::{self, HAND_INPUTS, HAND_OUTPUTS};
use crate::model::file::ModelFile;
use crate::model::history::{self, History, HistoryChoice, HistoryTrial, Memory, Series};
use crate::model::interval::{Intervals, Radius};
use crate::model::msvr::fitness::FitnessKind;
use crate::model::msvr::folds::{self, FoldPlan, FoldScheme, FoldsBy};
use crate::model::msvr::tune::{self, BasisChoice, BasisDecision, Chosen, Pinned};
use crate::model::msvr::{self, Basis, Hyper, MsvrError, MsvrParams, MIN_FIT_ROWS};
use crate::model::previous::{self, PreviousModel};
use crate::model::{self, ModelSpec};
use crate::report::{
    self, Comparison, IntervalReport, ModelReport, NamedModel, PreviousSummary, TestCoverageReport,
    TestResult,
};
use crate::search::{IterationRecord, Method, Observer, Search};

/// How the job chooses its hyper-parameters.
pub enum Selection {
    /// The parameters of [`FitJob::params`] as they are; `auto`'s basis and the intervals
    /// are cross-validated on `folds` folds cut `folds_by`.
    Fixed { folds: usize, folds_by: FoldsBy },
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
    /// The time column (seconds, increasing within each group): input history may be used.
    pub time: Option<String>,
    /// The column naming the runs of a time series (history restarts in each).
    pub group: Option<String>,
    /// What history to try (with `time`).
    pub history: HistoryChoice,
}

impl FitJob {
    /// The rows `--max-rows` keeps.
    fn keep(&self, d: data::Dataset) -> data::Dataset {
        match self.max_rows {
            Some(max) if d.rows() > max => d.subsample(max),
            _ => d,
        }
    }
}

/// What a run produced.
pub struct FitOutcome {
    pub report: ModelReport,
    /// The search, when there was one.
    pub search: Option<tune::Searched>,
}

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

    fn ended(&mut self) {
        self.session.emit(Event::SearchEnded);
    }
}

/// Chooses the parameters (and the input history), fits, scores and writes: the report first
/// (an interrupted search still leaves its history), the model file last.
///
/// # Errors
/// [`PipelineError`]: bad parameters, unreadable or unusable data, `--out` naming an input, a
/// search or fit failure, or a file that cannot be written.
pub fn run(job: &FitJob, session: &Session) -> Result<FitOutcome, PipelineError> {
    // A stop (Ctrl-C, a termination signal) during a search ends the search, its best kept;
    // any other stops the run.
    let started = crate::control::Since::now();
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
    let train = Source::read(&job.data, job)?;
    train.raw.check_fittable(MIN_FIT_ROWS)?;
    if let Some(max) = job.max_rows.filter(|&max| train.raw.rows() > max) {
        session.emit(Event::Note(format!(
            "{}: {} rows, {max} evenly spaced ones kept (--max-rows)",
            job.data.display(),
            train.raw.rows()
        )));
    }
    let search_source = search_on.map(|p| Source::read(p, job)).transpose()?;
    let rows = job
        .max_rows
        .map_or(train.raw.rows(), |m| m.min(train.raw.rows()));
    if search_source.is_none()
        && rows > tune::SEARCH_ROWS
        && matches!(job.selection, Selection::Search { .. })
    {
        session.emit(Event::Note(format!(
            "search: candidates scored on {} evenly spaced rows of {rows} (the model is fitted on all of them)",
            tune::SEARCH_ROWS
        )));
    }
    // Every test file is read before the search: a bad one must not cost the search.
    let test_sources = job
        .tests
        .iter()
        .map(|path| Source::read(path, job))
        .collect::<Result<Vec<_>, _>>()?;
    let candidates = train.histories(job)?;
    let seed = match job.selection {
        Selection::Fixed { .. } => None,
        Selection::Search { seed, .. } => Some(seed),
    };
    let initial = tune::initial_basis(job.basis, rows, seed.unwrap_or(crate::DEFAULT_SEED))
        .map_err(|e| PipelineError::Usage(e.to_string()))?;
    msvr::check_memory(rows, initial.basis)?;
    session.emit(Event::Note(format!(
        "basis: {} ({})",
        initial.basis, initial.reason
    )));

    let history_for = |memory: Memory| History {
        time: job.time.clone().unwrap_or_default(),
        group: job.group.clone(),
        inputs: job.inputs.clone(),
        memory,
    };
    // Every feature set is scored on the same rows and folds: those of the present inputs.
    let present = Scoring::new(
        job,
        &job.keep(train.raw.clone()),
        search_source.as_ref().map(|s| job.keep(s.raw.clone())),
    )?;
    let scoring = |h: Option<&History>| -> Result<Scoring, PipelineError> {
        let data = job.keep(train.with(h)?);
        let on = search_source
            .as_ref()
            .map(|s| Ok::<_, PipelineError>(job.keep(s.with(h)?)))
            .transpose()?;
        present.with_features(&data, on)
    };
    let interrupted = || session.interrupt.load(std::sync::atomic::Ordering::Relaxed);
    let compare = candidates.static_first && !candidates.memories.is_empty();
    // Compared feature sets are searched on the initial basis; the kept one then grows.
    let mut tried: Vec<(Option<History>, Chosen, Scoring)> = Vec::new();
    let mut screened = Vec::new();
    if candidates.static_first {
        if compare {
            session.emit(Event::Note(
                "input history: none (the present inputs)".into(),
            ));
        }
        let scored = scoring(None)?;
        let pass = if compare { Pass::Reference } else { Pass::Only };
        let chosen = choose(job, &scored, initial.clone(), pass, session)?;
        tried.push((None, chosen, scored));
    }
    // `auto`: the ladder that scores best at the present-input model's parameters is searched.
    let memory = match (tried.first(), candidates.memories.len()) {
        (_, 0) => None,
        (_, 1) => candidates.memories.first().cloned().map(|m| (m, None)),
        (Some((_, reference, _)), _) if !interrupted() => {
            let mut best: Option<(Memory, f64, Scoring)> = None;
            for memory in &candidates.memories {
                let h = history_for(memory.clone());
                let copies = 1 + memory.blocks();
                let params = MsvrParams {
                    sigma: reference.params.sigma * (copies as f64).sqrt(),
                    ..reference.params
                };
                let scored = scoring(Some(&h))?;
                let fitness = scored.fitness_of(&params)?;
                session.emit(Event::Note(format!(
                    "input history: {memory} screened at the present inputs' parameters: {fitness:.5}"
                )));
                screened.push(HistoryTrial {
                    memory: Some(memory.clone()),
                    fitness,
                });
                if best.as_ref().is_none_or(|(_, f, _)| fitness < *f) {
                    best = Some((memory.clone(), fitness, scored));
                }
            }
            best.map(|(m, _, scored)| (m, Some(scored)))
        }
        _ => None,
    };
    if let Some((memory, screened_rows)) = memory.filter(|_| !interrupted() || tried.is_empty()) {
        let h = history_for(memory);
        session.emit(Event::Note(format!(
            "input history: {} ({} model inputs)",
            h.memory,
            h.feature_names().len()
        )));
        let scored = match screened_rows {
            Some(scored) => scored,
            None => scoring(Some(&h))?,
        };
        let pass = if compare { Pass::Compared } else { Pass::Only };
        let chosen = choose(job, &scored, initial.clone(), pass, session)?;
        tried.push((Some(h), chosen, scored));
    }
    let decision = job.time.as_ref().map(|_| {
        history::decide(
            tried
                .iter()
                .map(|(h, c, _)| (h.clone(), c.fitness.unwrap_or(f64::NAN)))
                .collect(),
            screened,
            &format!("--history {}", job.history),
        )
    });
    let kept = decision.as_ref().and_then(|d| d.used.clone());
    if let Some(d) = &decision {
        session.emit(Event::Note(format!("input history: {}", d.reason)));
    }
    let (mut chosen, scored) = tried
        .into_iter()
        .find(|(h, _, _)| *h == kept)
        .map(|(_, c, s)| (c, s))
        .expect("the kept history was tried");
    if compare && grows(job, &chosen.basis) {
        chosen.basis = tune::grow_basis(
            chosen.basis,
            &scored.scored,
            scored.fitness,
            &scored.plan,
            &chosen.params,
            session.interrupt,
        )?;
        chosen.params = chosen.params.basis(chosen.basis.basis);
    }
    let Chosen {
        params,
        search,
        basis,
        ..
    } = chosen;
    let searched = matches!(job.selection, Selection::Search { .. });
    let since = if searched && interrupted() {
        crate::control::Since::now()
    } else {
        started
    };
    let go_on = || {
        if since.stopped() {
            Err(PipelineError::Interrupted(
                "interrupted before the fit; nothing written".into(),
            ))
        } else {
            Ok(())
        }
    };
    if !basis.tried.is_empty() {
        session.emit(Event::Note(format!(
            "basis: {} ({})",
            basis.basis, basis.reason
        )));
    }

    let train_rows = job.keep(train.with(kept.as_ref())?);
    if let Selection::Fixed { .. } = job.selection {
        constant_tube(params.epsilon, &train_rows.outputs)?;
    }
    // Intervals come from the rows the model is fitted on (the scored rows, unless the search
    // scored another file), cut into the search's kind of folds.
    let calibration = match search_source {
        None => scored,
        Some(_) => Scoring::new(job, &job.keep(train.raw.clone()), None)?
            .with_features(&train_rows, None)?,
    };
    go_on()?;
    let intervals =
        calibrate_intervals(&calibration, &params, seed.unwrap_or(crate::DEFAULT_SEED))?;
    match &intervals {
        Some(Intervals { held_out: c, .. }) if !c.radii.is_empty() => {
            session.emit(Event::Note(format!(
                "prediction intervals: {} from {} held-out rows",
                radii_text(&c.radii),
                c.rows
            )))
        }
        Some(Intervals { held_out: c, .. }) => session.emit(Event::Note(format!(
            "prediction intervals: none ({} held-out rows are too few for a 90 % radius, which needs 9)",
            c.rows
        ))),
        None => session.emit(Event::Note(
            "prediction intervals: none (--fitness train scores no held-out rows)".into(),
        )),
    }
    // Test rows' groups: the column that names the runs, where a test file has it.
    let group_column = job
        .group
        .clone()
        .or_else(|| match &calibration.plan.choice.scheme {
            FoldScheme::Groups { column } => Some(column.clone()),
            _ => None,
        });

    let train = train_rows;
    let test_data = test_sources
        .iter()
        .map(|s| Ok((file_name(&s.raw.source), s.with(kept.as_ref())?)))
        .collect::<Result<Vec<_>, PipelineError>>()?;
    go_on()?;
    let fitted = final_fit(ModelSpec::Msvr(params), &train, session)?;
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
    let mut coverage = Vec::new();
    for (name, test) in &test_data {
        let mut msvr_predicted = None;
        for m in &models {
            let (errors, predicted) = model::evaluate_predicting(m.model, test)?;
            tests.push(TestResult {
                model: m.name.into(),
                test: name.clone(),
                errors,
            });
            if m.name == "msvr" {
                msvr_predicted = Some(predicted);
            }
        }
        let intervals = intervals.as_ref().filter(|i| !i.held_out.radii.is_empty());
        if let (Some(i), Some(predicted)) = (intervals, msvr_predicted) {
            let labels = group_column
                .as_ref()
                .and_then(|c| data::read_columns(&test.source, std::slice::from_ref(c)).ok());
            coverage.push(TestCoverageReport {
                test: name.clone(),
                column: labels.as_ref().and(group_column.clone()),
                coverage: i.test(
                    &test.outputs,
                    &predicted,
                    labels.as_ref().map(|l| l.values.as_slice()),
                ),
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
        history: decision.clone(),
        search: search.as_ref().map(|s| s.summary.clone()),
        train_errors,
        previous: previous.as_ref().map(|(d, c, cal)| PreviousSummary {
            default: d.params.clone(),
            calibrated: c.params.clone(),
            calibration: cal.clone(),
        }),
        tests,
        intervals: intervals.as_ref().map(|i| IntervalReport {
            held_out: i.held_out.clone(),
            tests: coverage,
        }),
        provenance: provenance.clone(),
    };
    // The model is saved even when the report cannot be written (a full disk), and the error
    // says so: the search is never lost to a report.
    let reported = job.report.as_ref().map(|dir| {
        let comparison = Comparison {
            models: &models,
            tests: &test_data,
        };
        let history = search.as_ref().map(|s| s.history.as_slice());
        report::write_model_report(dir, &report, history, &comparison)
    });
    ModelFile::new(
        fitted,
        report.search.clone(),
        Some(basis),
        decision,
        intervals,
        provenance,
    )
    .save(&job.out)?;
    if let Some(Err(e)) = reported {
        return Err(PipelineError::Partial {
            source: Box::new(e.into()),
            written: job.out.clone(),
        });
    }
    Ok(FitOutcome { report, search })
}

/// A data file as read, with its time series when `--time` was given.
struct Source {
    raw: data::Dataset,
    series: Option<(Series, Vec<u64>)>,
}

impl Source {
    /// Reads the job's inputs and outputs, and its time (and group) columns, checked for order.
    fn read(path: &Path, job: &FitJob) -> Result<Source, PipelineError> {
        let raw = data::read_dataset(path, &job.inputs, &job.outputs)?;
        let series = match &job.time {
            None => None,
            Some(time) => {
                let (series, lines) = history::read_series(path, time, job.group.as_deref())?;
                series
                    .check()
                    .map_err(|e| history::series_error(path, &lines, e))?;
                Some((series, lines))
            }
        };
        Ok(Source { raw, series })
    }

    /// The dataset as a model with `history` sees it.
    fn with(&self, history: Option<&History>) -> Result<data::Dataset, PipelineError> {
        match (history, &self.series) {
            (Some(h), Some((series, lines))) => h
                .dataset(&self.raw, series)
                .map_err(|e| history::series_error(&self.raw.source, lines, e).into()),
            _ => Ok(self.raw.clone()),
        }
    }

    /// What `--history` asks to try.
    fn histories(&self, job: &FitJob) -> Result<Candidates, PipelineError> {
        let none = Candidates {
            static_first: true,
            memories: Vec::new(),
        };
        let (Some((series, lines)), true) = (&self.series, job.time.is_some()) else {
            return Ok(none);
        };
        let ladders = || -> Result<Vec<Vec<f64>>, PipelineError> {
            series
                .time_constant_ladders()
                .map_err(|e| history::series_error(&self.raw.source, lines, e).into())
        };
        let (static_first, memories) = match &job.history {
            HistoryChoice::None => return Ok(none),
            HistoryChoice::Auto => (
                true,
                ladders()?
                    .into_iter()
                    .map(|tau| Memory::Ema { tau })
                    .collect(),
            ),
            HistoryChoice::Ema(tau) if tau.is_empty() => (
                false,
                vec![Memory::Ema {
                    tau: ladders()?.swap_remove(0),
                }],
            ),
            HistoryChoice::Ema(tau) => {
                let scale = series
                    .time_scale()
                    .map_err(|e| history::series_error(&self.raw.source, lines, e))?;
                if let Some(why) = history::useless_time_constant(tau, scale) {
                    return Err(PipelineError::Usage(format!("--history ema:…: {why}")));
                }
                (false, vec![Memory::Ema { tau: tau.clone() }])
            }
            HistoryChoice::Lags(rows) => (false, vec![Memory::Lags { rows: *rows }]),
        };
        // Groups too short for the memory are refused before any search.
        for memory in &memories {
            self.with(Some(&History {
                time: String::new(),
                group: None,
                inputs: job.inputs.clone(),
                memory: memory.clone(),
            }))?;
        }
        Ok(Candidates {
            static_first,
            memories,
        })
    }
}

/// The feature sets a run tries.
struct Candidates {
    /// The present inputs alone, searched first (and compared with the history).
    static_first: bool,
    /// The histories: one to search, or several for `auto` to screen.
    memories: Vec<Memory>,
}

/// The rows candidates are scored on and how cross-validation cuts them.
struct Scoring {
    scored: data::Dataset,
    plan: FoldPlan,
    fitness: FitnessKind,
}

impl Scoring {
    /// A search's (on `search_on`, the `--search-on` file's rows, when given, else on at most
    /// [`tune::SEARCH_ROWS`] evenly spaced rows of `train`), or for given parameters the
    /// cross-validation of `auto`'s basis and the intervals (its folds); the folds
    /// ([`folds::plan`]: fewer for a handful of rows) are cut from these inputs (the present
    /// ones: a history's filtered copies would hide a designed grid).
    fn new(
        job: &FitJob,
        train: &data::Dataset,
        search_on: Option<data::Dataset>,
    ) -> Result<Scoring, PipelineError> {
        let (by, fitness, file) = match &job.selection {
            Selection::Fixed { folds, folds_by } => {
                (folds_by, FitnessKind::Cv { folds: *folds }, None)
            }
            Selection::Search {
                folds_by,
                fitness,
                on,
                ..
            } => (folds_by, *fitness, on.as_deref()),
        };
        // The fold columns come from the file the rows are: `--search-on`'s or the training data's.
        let file = file.filter(|_| search_on.is_some()).unwrap_or(&job.data);
        let scored = scored_rows(train, search_on)?;
        let asked = match fitness {
            FitnessKind::Cv { folds } => folds,
            FitnessKind::Train => 2,
        };
        let plan = folds::plan(
            by,
            &scored,
            &other_columns(file, by, job, scored.rows())?,
            asked,
        )?;
        let fitness = match fitness {
            FitnessKind::Cv { .. } => FitnessKind::Cv { folds: plan.folds },
            FitnessKind::Train => FitnessKind::Train,
        };
        Ok(Scoring {
            scored,
            plan,
            fitness,
        })
    }

    /// The same rows and folds, with the features of `train` (and `search_on`): the same rows
    /// as [`Scoring::new`]'s, another set of input columns.
    fn with_features(
        &self,
        train: &data::Dataset,
        search_on: Option<data::Dataset>,
    ) -> Result<Scoring, PipelineError> {
        Ok(Scoring {
            scored: scored_rows(train, search_on)?,
            plan: self.plan.clone(),
            fitness: self.fitness,
        })
    }

    /// The cross-validated fitness of `params` itself.
    fn fitness_of(&self, params: &MsvrParams) -> Result<f64, PipelineError> {
        Ok(tune::cross_validate(
            &self.scored,
            self.fitness,
            &self.plan,
            params,
        )?)
    }
}

/// What a feature set's selection is for.
#[derive(Clone, Copy, PartialEq)]
enum Pass {
    /// The one feature set: `auto`'s basis grows at the parameters chosen.
    Only,
    /// One of several compared by cross-validated fitness (given parameters are scored too);
    /// the basis grows after the comparison, for the kept set only.
    Compared,
    /// The present inputs as `--history auto`'s reference: compared, and searched with half
    /// the default budget (its parameters also start the screen of time constants).
    Reference,
}

/// Chooses the parameters on `scoring`'s rows ([`Pass`]: growing the basis, scoring given
/// parameters, the budget), by [`tune::choose`].
fn choose(
    job: &FitJob,
    scoring: &Scoring,
    initial: BasisDecision,
    pass: Pass,
    session: &Session,
) -> Result<Chosen, PipelineError> {
    let search = match &job.selection {
        Selection::Fixed { .. } => None,
        Selection::Search {
            method,
            budget,
            seed,
            ..
        } => {
            if matches!(scoring.fitness, FitnessKind::Cv { .. }) {
                session.emit(Event::Note(format!("folds: {}", scoring.plan.choice)));
            }
            let rows = scoring.scored.rows();
            let budget = budget.unwrap_or(match pass {
                Pass::Reference => tune::budget_for(rows) / 2,
                _ => tune::budget_for(rows),
            });
            Some((method.with_budget(budget), *seed))
        }
    };
    let mut observer = Iterations {
        session,
        cap: search
            .as_ref()
            .map_or(0, |(m, _)| m.iteration_cap(Hyper::AXES.len())),
    };
    let choice = tune::Choice {
        rows: &scoring.scored,
        fitness: scoring.fitness,
        folds: &scoring.plan,
        search,
        pinned: Pinned::default(),
        grow: pass == Pass::Only && grows(job, &initial),
        score: pass != Pass::Only,
    };
    Ok(tune::choose(
        &choice,
        &job.params,
        initial,
        &mut observer,
        session.interrupt,
    )?)
}

/// Conformal intervals from the held-out residuals of `params` on the scoring's rows and folds
/// (cut with the search's `seed`); `None` with the training fitness, which holds no rows out.
fn calibrate_intervals(
    scoring: &Scoring,
    params: &MsvrParams,
    seed: u64,
) -> Result<Option<Intervals>, PipelineError> {
    let FitnessKind::Cv { folds } = scoring.fitness else {
        return Ok(None);
    };
    Ok(Some(tune::intervals(
        &scoring.scored,
        folds,
        seed,
        &scoring.plan,
        params,
    )?))
}

/// "90 %: 1.23, 95 %: 1.87".
pub(crate) fn radii_text(radii: &[Radius]) -> String {
    radii
        .iter()
        .map(|r| format!("{} %: {:.4}", r.level * 100.0, r.radius))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Whether the basis grows: only `auto`'s reduced basis does; exact and a given size are used
/// as they are.
fn grows(job: &FitJob, initial: &BasisDecision) -> bool {
    job.basis == BasisChoice::Auto && initial.basis != Basis::Exact
}

/// The rows a search scores: `search_on`'s when given, else at most [`tune::SEARCH_ROWS`]
/// evenly spaced rows of `train`.
fn scored_rows(
    train: &data::Dataset,
    search_on: Option<data::Dataset>,
) -> Result<data::Dataset, PipelineError> {
    Ok(match search_on {
        Some(d) => {
            d.check_fittable(MIN_FIT_ROWS)?;
            d
        }
        None => train.subsample(tune::SEARCH_ROWS),
    })
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
    let columns: Vec<(String, Vec<f64>)> = match by {
        FoldsBy::Shuffle | FoldsBy::Blocks => return Ok(Vec::new()),
        FoldsBy::Column(column) => vec![(column.clone(), data::read_labels(path, column)?.0)],
        FoldsBy::Auto => {
            let skip: Vec<String> = job.inputs.iter().chain(&job.outputs).cloned().collect();
            data::numeric_columns(path, &skip)?
        }
    };
    // The rows `keep` kept, then those the search scores (as `Dataset::subsample` picks).
    Ok(columns
        .into_iter()
        .map(|(name, values)| {
            let mut kept = data::evenly_spaced(values.len(), job.max_rows.unwrap_or(usize::MAX));
            if rows < kept.len() {
                kept = data::evenly_spaced(kept.len(), rows)
                    .into_iter()
                    .map(|i| kept[i])
                    .collect();
            }
            (name, kept.iter().map(|&i| values[i]).collect())
        })
        .collect())
}

/// Refuses a tube radius `epsilon` that holds every row of `outputs` around their mean: every
/// row would lie inside the tube, and the model would be a constant.
fn constant_tube(epsilon: f64, outputs: &data::Columns) -> Result<(), PipelineError> {
    let n = outputs.rows() as f64;
    let mean: Vec<f64> = (0..outputs.width())
        .map(|j| outputs.column(j).sum::<f64>() / n)
        .collect();
    let widest = outputs
        .iter_rows()
        .map(|row| {
            row.iter()
                .zip(&mean)
                .map(|(v, m)| (v - m).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max);
    if epsilon >= widest {
        return Err(PipelineError::Usage(format!(
            "--epsilon {epsilon:e}: every row's outputs lie within {widest:.4} of their mean, so every row is inside the tube and the model is a constant; give ε well below that (e.g. {:.2e})",
            widest / 100.0
        )));
    }
    Ok(())
}

/// Fits `spec` to `train`, showing the solver's iterations as they go (a fit on a million
/// rows takes minutes); a stop (Ctrl-C, a termination signal) ends it, and nothing is written.
fn final_fit(
    spec: ModelSpec,
    train: &data::Dataset,
    session: &Session,
) -> Result<model::StoredModel, PipelineError> {
    let ModelSpec::Msvr(params) = spec;
    let done = std::sync::atomic::AtomicBool::new(false);
    let before = crate::control::iterations();
    let fitted = std::thread::scope(|scope| {
        scope.spawn(|| {
            while !done.load(std::sync::atomic::Ordering::Relaxed) {
                std::thread::sleep(std::time::Duration::from_millis(100));
                session.emit(Event::Count {
                    task: Task::Fit,
                    done: crate::control::iterations() - before,
                    total: params.max_iter,
                });
            }
            session.emit(Event::Finished(Task::Fit));
        });
        let fitted = spec.fit(train);
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        fitted
    });
    fitted.map_err(|e| match e {
        MsvrError::Interrupted => PipelineError::Interrupted(format!(
            "interrupted during the final fit (C = {}, ε = {}, σ = {}); nothing written",
            params.c, params.epsilon, params.sigma
        )),
        e => e.into(),
    })
}

/// The file name of a path, for tables.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    )
}
