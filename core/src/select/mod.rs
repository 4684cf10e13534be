//! Model selection: rows in memory → a chosen, fitted model with the record of how it was
//! chosen and its prediction intervals. Every front end calls [`select`]: `handcap model` (its
//! files read into [`Table`]s), the Python estimator, the demo and the benchmarks.
//!
//! [`select`] is the list of its steps:
//! 1. the feature sets to try: the present inputs, and with a time series
//!    the histories [`Plan::history`] asks for (groups too short for them refused first);
//! 2. the rows and folds every set is scored on (`Scoring`: at most
//!    [`crate::select::tune::SEARCH_ROWS`] evenly spaced rows, the folds cut from the present inputs);
//! 3. each set's parameters chosen ([`crate::select::tune::choose`]: the search, or the given ones), `auto`'s
//!    ladders of time constants screened on a small grid around the present inputs'
//!    parameters first;
//! 4. the set kept ([`history::decide`]; the present inputs kept over the histories are
//!    searched again with the whole budget their reference search had half of) and `auto`'s
//!    basis grown for it;
//! 5. the intervals: from the held-out predictions steps 3-4 made (no further fit), or from
//!    one more fit per fold for runs (dealt to the folds in blocks of consecutive runs), after
//!    a search that scored another file's rows, or when [`Plan::intervals`] asks;
//! 6. the final fit on every row.
//!
//! Messages name parameters as `field=value` (`basis=exact`, `folds_by=blocks`), as the
//! Python estimator takes them; the command line writes its flags instead.

use std::sync::atomic::AtomicBool;

use crate::control::Since;
use crate::data::{self, DataError, Dataset};
use crate::model::file::ModelFile;
use crate::model::history::{
    series_error, Context, History, HistoryChoice, HistoryDecision, HistoryError, Series,
};
use crate::model::interval::{percent, Intervals};
use crate::model::msvr::{Hyper, MsvrError, MsvrParams};
use crate::model::{self, ModelSpec, StoredModel};
use crate::provenance::Provenance;
use crate::search::{IterationRecord, Method, Observer};
use crate::select::fitness::FitnessKind;
use crate::select::folds::{FoldsBy, FoldsError};
use crate::select::tune::{BasisChoice, BasisDecision, BasisError, Pinned, Searched, TuneError};

pub mod auto_basis;
pub mod family;
pub mod fitness;
pub mod folds;
mod run;
pub mod tune;

use family::{Family, FamilyChoice, FamilyDecision};
use run::{Candidates, Run};

/// Rows to select a model on: the dataset (present inputs and outputs), its time series, and
/// the columns folds may be cut by.
pub struct Table {
    pub data: Dataset,
    /// Each row's time (and group) when the rows are a time series.
    pub series: Option<Series>,
    /// Each row's line in its file, for errors (row numbers for rows from memory).
    pub lines: Vec<u64>,
    /// Every row of the file the history's filters run through, flagged rows too (`None`:
    /// the rows above are all there were).
    pub context: Option<Context>,
    /// Columns the folds may be cut by, one value per row: the `folds_by` column, or for
    /// `folds_by=auto` every numeric column that is neither input nor output.
    pub fold_columns: Vec<(String, Vec<f64>)>,
}

impl Table {
    /// The dataset as a model with `history` sees it (the present inputs without one).
    ///
    /// # Errors
    /// [`DataError::Input`] naming the row's line when the series cannot carry the history.
    pub fn with(&self, history: Option<&History>) -> Result<Dataset, DataError> {
        match (history, &self.series, &self.context) {
            (Some(h), _, Some(context)) => Ok(Dataset {
                source: self.data.source.clone(),
                inputs: h
                    .features_at(context, &self.lines)
                    .map_err(|e| series_error(&self.data.source, &context.lines, e))?,
                outputs: self.data.outputs.clone(),
                weights: self.data.weights.clone(),
            }),
            (Some(h), Some(series), None) => h
                .dataset(&self.data, series)
                .map_err(|e| self.series_error(e)),
            _ => Ok(self.data.clone()),
        }
    }

    /// Checks the series' order (time increasing within each group); for `history`, also that
    /// no group is a single row (a run of one row has no history to learn from).
    ///
    /// # Errors
    /// [`DataError::Input`] naming the row's line.
    pub fn check_series(&self, history: bool) -> Result<(), DataError> {
        let Some(series) = &self.series else {
            return Ok(());
        };
        let groups = series.check().map_err(|e| self.series_error(e))?;
        match groups.iter().find(|(_, rows)| rows.len() < 2) {
            Some((Some(group), rows)) if history && groups.len() > 1 => Err(DataError::Input {
                path: self.data.source.clone(),
                line: self.lines[rows[0]],
                message: format!(
                    "group {group} is this one row: a run of one row has no history to learn from; give it the label of its run (groups=…) or leave it out"
                ),
            }),
            _ => Ok(()),
        }
    }

    /// A history error as a data error naming the file and the row's line.
    pub fn series_error(&self, e: HistoryError) -> DataError {
        series_error(&self.data.source, &self.lines, e)
    }

    /// The rows [`Plan::max_rows`] keeps (evenly spaced), then of those the `at_most` a search
    /// scores ([`Dataset::subsample`]'s choice): indices into the table's rows.
    fn kept(&self, max_rows: Option<usize>, at_most: usize) -> Vec<usize> {
        let kept = data::evenly_spaced(self.data.rows(), max_rows.unwrap_or(usize::MAX));
        if at_most >= kept.len() {
            return kept;
        }
        data::evenly_spaced(kept.len(), at_most)
            .into_iter()
            .map(|i| kept[i])
            .collect()
    }
}

/// How the parameters are chosen.
#[derive(Clone, Debug)]
pub enum Selection {
    /// [`Plan::params`] as they are; `auto`'s basis and intervals asked for are
    /// cross-validated on `folds` folds cut `folds_by`.
    Fixed { folds: usize, folds_by: FoldsBy },
    Search {
        method: Method,
        /// Candidates at most (ACO_R, grid); `None`: [`crate::select::tune::budget_for`] the rows scored.
        budget: Option<usize>,
        fitness: FitnessKind,
        /// How cross-validation cuts the rows ([`crate::select::folds::plan`]).
        folds_by: FoldsBy,
        seed: u64,
    },
}

impl Selection {
    /// The search's seed (also its folds'), `None` for fixed parameters.
    pub fn seed(&self) -> Option<u64> {
        match self {
            Selection::Fixed { .. } => None,
            Selection::Search { seed, .. } => Some(*seed),
        }
    }

    pub fn searched(&self) -> bool {
        matches!(self, Selection::Search { .. })
    }

    /// Whether the paper's colony searches (its own digits, MSVR's three parameters).
    pub fn paper(&self) -> bool {
        matches!(
            self,
            Selection::Search {
                method: Method::AcoPaper(_),
                ..
            }
        )
    }

    /// `handcap model`'s default search: ACO_R with its own settings and `seed`, at most
    /// `budget` candidates (`None`: by the rows), cross-validated on `folds` folds cut
    /// `folds_by`.
    pub fn aco_r(seed: u64, budget: Option<usize>, folds: usize, folds_by: FoldsBy) -> Selection {
        Selection::Search {
            method: Method::AcoR(crate::search::aco_r::AcoR {
                seed,
                ..Default::default()
            }),
            budget,
            fitness: FitnessKind::Cv { folds },
            folds_by,
            seed,
        }
    }
}

/// What to select.
pub struct Plan {
    /// The family to fit, or `auto`'s choice by cross-validation.
    pub family: FamilyChoice,
    /// The fixed parameters ([`Selection::Fixed`], and those [`Plan::pinned`]) and the solver
    /// controls (always).
    pub params: MsvrParams,
    pub selection: Selection,
    /// Parameters a search holds at [`Plan::params`]'s values.
    pub pinned: Pinned,
    pub basis: BasisChoice,
    /// What history to try (with a time series).
    pub history: HistoryChoice,
    /// The names of the time and group columns, as the model file records them.
    pub time: Option<String>,
    pub group: Option<String>,
    /// Rows kept at most from the training (and search) data, evenly spaced.
    pub max_rows: Option<usize>,
    /// Intervals also without a search, when no held-out predictions were made on the way
    /// (k more fits).
    pub intervals: bool,
}

impl Plan {
    /// Refuses a plan whose parts do not fit together, naming them as `field=value`: parameters
    /// a family cannot fit with, too few
    /// folds, folds cut for a fitness that has none, a history without times or compared
    /// without cross-validation, a budget the method has no use for or cannot start with.
    ///
    /// # Errors
    /// [`SelectError::Parameter`] saying what to change.
    pub fn check(&self) -> Result<(), SelectError> {
        let refuse = |why: String| Err(SelectError::Parameter(why));
        for family in self.family.families() {
            if let Err(e) = family.solver(self.params).check() {
                return refuse(format!("model parameters: {e}"));
            }
        }
        // The folds cross-validation cuts (none for the training fitness), and how.
        let (folds, folds_by) = match &self.selection {
            Selection::Fixed { folds, folds_by }
            | Selection::Search {
                fitness: FitnessKind::Cv { folds },
                folds_by,
                ..
            } => (Some(*folds), folds_by),
            Selection::Search {
                fitness: FitnessKind::Train,
                folds_by,
                ..
            } => (None, folds_by),
        };
        if let Some(folds) = folds.filter(|&k| k < 2) {
            return refuse(format!(
                "folds={folds}: cross-validation needs 2 folds or more"
            ));
        }
        let train = folds.is_none();
        // With a time series a column of runs is the groups history restarts in, folds or not.
        let names_runs = matches!(folds_by, FoldsBy::Column(c) if self.group.as_ref() == Some(c));
        if train && *folds_by != FoldsBy::Auto && !(self.time.is_some() && names_runs) {
            return refuse(format!("folds_by={folds_by} cuts the folds of cross-validation (the search's, the basis' and the intervals'): use it with fitness=cv"));
        }
        match (&self.time, &self.history) {
            (None, HistoryChoice::Auto | HistoryChoice::None) => {}
            (None, history) => {
                return refuse(format!(
                    "history={history} builds on the rows' times: give time=COLUMN"
                ))
            }
            (Some(_), HistoryChoice::Auto) if train => return refuse("history=auto compares feature sets by cross-validation: use fitness=cv, or name the history (history=none, ema, lags:K)".into()),
            _ => {}
        }
        let asked = match self.family {
            FamilyChoice::One(family) => Some(family),
            FamilyChoice::Auto => None,
        };
        if self.selection.paper() {
            if let Some(family) = asked.filter(|f| f.axes() != Hyper::AXES) {
                return refuse(format!("model={family} with search=aco-paper: the paper's colony searches all three of (C, ε, σ) and {} moves {}; use model={} (or auto), or search=aco-r or grid", family.title(), family.moves(), Family::names_where(|f| f.axes() == Hyper::AXES)));
            }
            if let Some((name, value)) = self.pinned.values().next() {
                return refuse(format!("{name}={value} is held by search=aco-r and search=grid; the paper's colony searches all three of its digits"));
            }
        }
        self.family
            .check_pinned(&self.pinned, self.params, self.selection.searched())
            .map_err(SelectError::Parameter)?;
        if let Selection::Search {
            method,
            budget: Some(budget),
            ..
        } = &self.selection
        {
            match method {
                Method::AcoPaper(_) => {
                    return refuse(format!("budget={budget} is the candidate budget of search=aco-r and search=grid; the paper's colony runs its ants and iterations"))
                }
                Method::AcoR(m) if *budget < m.archive => {
                    return refuse(format!("budget={budget}: must be at least {} candidates: the first fill of the colony's archive", m.archive))
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn seed(&self) -> Option<u64> {
        self.selection.seed()
    }

    fn searched(&self) -> bool {
        self.selection.searched()
    }

    /// The rows [`Plan::max_rows`] keeps.
    fn keep(&self, d: Dataset) -> Dataset {
        match self.max_rows {
            Some(max) if d.rows() > max => d.subsample(max),
            _ => d,
        }
    }
}

/// Hears what [`select`] does as it goes (called from worker threads too).
pub trait Listener: Sync {
    /// A sentence for the log: what was chosen and why.
    fn note(&self, _text: String) {}
    /// One search iteration; `cap` the iterations the search may take.
    fn iteration(&self, _record: &IterationRecord, _cap: usize) {}
    fn search_ended(&self) {}
    /// The final fit's solver iterations so far, of at most `cap`.
    fn fitting(&self, _done: usize, _cap: usize) {}
    fn fitted(&self) {}
}

/// A listener that hears nothing.
impl Listener for () {}

/// Errors of a selection.
#[derive(Debug, thiserror::Error)]
pub enum SelectError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Msvr(#[from] MsvrError),
    #[error(transparent)]
    Tune(#[from] TuneError),
    #[error(transparent)]
    Folds(#[from] FoldsError),
    #[error(transparent)]
    Basis(#[from] BasisError),
    #[error(transparent)]
    Model(#[from] model::ModelError),
    /// A parameter that cannot work with these rows, named as `field=value`.
    #[error("{0}")]
    Parameter(String),
    /// A stop (Ctrl-C, a termination signal) before the model was fitted.
    #[error("{0}")]
    Interrupted(String),
}

/// What [`select`] chose and fitted.
pub struct Selected {
    pub model: StoredModel,
    pub family: FamilyDecision,
    pub search: Option<Searched>,
    pub basis: BasisDecision,
    /// The choice between the present inputs and history (with a time series).
    pub history: Option<HistoryDecision>,
    pub intervals: Option<Intervals>,
    /// The rows the model was fitted on, as it sees them (with the history's features).
    pub train: Dataset,
    /// The model's errors on those rows (not a measure of generalisation).
    pub train_errors: model::Errors,
    /// The column naming the runs the folds kept whole, when they did.
    pub runs: Option<String>,
}

impl Selected {
    /// The history the model sees, if any.
    pub fn used(&self) -> Option<&History> {
        self.history.as_ref().and_then(|d| d.used.as_ref())
    }

    /// The model file of the selection, and the search it records the summary of (its
    /// iterations stay out of the file).
    pub fn into_file(self, provenance: Provenance) -> (ModelFile, Option<Searched>) {
        let mut file = ModelFile::new(
            self.model,
            self.search.as_ref().map(|s| s.summary.clone()),
            Some(self.basis),
            self.history,
            self.intervals,
            provenance,
        );
        file.family = Some(self.family);
        (file, self.search)
    }
}

/// Chooses, fits and calibrates a model of `train` (see the module docs for the steps);
/// `search_on` gives other rows to score candidates on. A search stopped by `interrupt` keeps
/// its best so far; a stop during the final fit is [`SelectError::Interrupted`].
///
/// # Errors
/// [`SelectError`]: unusable rows or parameters, a failed search or fit, or a stop.
pub fn select(
    train: &Table,
    search_on: Option<&Table>,
    plan: &Plan,
    listener: &dyn Listener,
    interrupt: &AtomicBool,
) -> Result<Selected, SelectError> {
    let run = Run {
        plan,
        family: Family::MSVR,
        train,
        search_on,
        listener,
        interrupt,
        started: Since::now(),
    };
    run.check()?;
    let candidates = run.candidates()?;
    let initial = run.initial_basis()?;
    let present = run.scoring()?;
    let families = run.families(&present);
    let alone = families.len() == 1;
    // The first family chooses the history; the others are searched on the features it kept.
    let mut each: Vec<(Family, run::Kept)> = Vec::new();
    for &family in &families {
        let run = Run { family, ..run };
        if !alone {
            listener.note(format!("model: {} (model=auto)", family.title()));
        }
        let kept = match each.first() {
            None => {
                let (tried, screened) =
                    run.choose_each(&present, &candidates, initial.clone(), alone)?;
                let kept = run.keep(tried, screened)?;
                run.present_in_full(kept, &candidates, initial.clone())?
            }
            Some((_, (decision, ..))) => {
                let decision = decision.clone();
                let only = Candidates::kept(decision.as_ref());
                let (tried, _) = run.choose_each(&present, &only, initial.clone(), alone)?;
                let (_, chosen, scored) = tried.into_iter().next().expect("one feature set");
                (decision, chosen, scored)
            }
        };
        each.push((family, kept));
        if run.interrupted() {
            break;
        }
    }
    let (family, (decision, mut chosen, scored)) = match each.len() {
        1 => {
            let (family, kept) = each.pop().expect("one family");
            (run.asked(family, families.len()), kept)
        }
        _ => run.compare(each)?,
    };
    if plan.family == FamilyChoice::Auto {
        listener.note(format!(
            "model: {} ({})",
            family.used.title(),
            family.reason
        ));
    }
    let run = Run {
        family: family.used,
        ..run
    };
    let kept = decision.as_ref().and_then(|d| d.used.clone());
    if (candidates.compared() || !alone) && run.grows(&chosen.basis) {
        run.grow(&mut chosen, &scored)?;
    }
    if !chosen.basis.tried.is_empty() {
        listener.note(format!(
            "basis: {} ({})",
            chosen.basis.basis, chosen.basis.reason
        ));
    }
    let since = run.since_choice();
    let go_on = || match since.stopped() {
        true => Err(SelectError::Interrupted(
            "interrupted before the fit; nothing written".into(),
        )),
        false => Ok(()),
    };
    let train_rows = plan.keep(train.with(kept.as_ref())?);
    if !plan.searched() {
        constant_tube(chosen.params.epsilon, &train_rows.outputs)?;
    }
    go_on()?;
    let intervals = run.intervals(kept.as_ref(), &chosen, scored)?;
    go_on()?;
    let (model, fitted) = final_fit(ModelSpec::Msvr(chosen.params), &train_rows, listener)?;
    // A stop in the fit's last iteration, which it finishes: nothing is written either.
    if since.stopped() {
        return Err(SelectError::Interrupted(format!(
            "interrupted during the final fit (C = {}, ε = {}, σ = {}); nothing written",
            chosen.params.c, chosen.params.epsilon, chosen.params.sigma
        )));
    }
    let train_errors = match fitted {
        Some(fitted) => model::errors(&train_rows.outputs, &fitted),
        None => model::evaluate(model.predictor(), &train_rows)?,
    };
    Ok(Selected {
        model,
        family,
        train_errors,
        search: chosen.search,
        basis: chosen.basis,
        history: decision,
        intervals,
        train: train_rows,
        runs: present.runs(),
    })
}

/// Reports a search's iterations to a [`Listener`].
struct Iterations<'a> {
    listener: &'a dyn Listener,
    cap: usize,
}

impl Observer for Iterations<'_> {
    fn iteration(&mut self, record: &IterationRecord) {
        self.listener.iteration(record, self.cap);
    }

    fn ended(&mut self) {
        self.listener.search_ended();
    }
}

/// "90 %: 1.23, 95 %: 1.87".
pub fn radii_text(radii: &[crate::model::interval::Radius]) -> String {
    radii
        .iter()
        .map(|r| format!("{} %: {:.4}", percent(r.level), r.radius))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Refuses a tube radius `epsilon` that holds every row of `outputs` around their mean: every
/// row would lie inside the tube, and the model would be a constant.
fn constant_tube(epsilon: f64, outputs: &data::Columns) -> Result<(), SelectError> {
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
        return Err(SelectError::Parameter(format!(
            "epsilon={epsilon:e}: every row's outputs lie within {widest:.4} of their mean, so every row is inside the tube and the model is a constant; give ε well below that (e.g. {:.2e})",
            widest / 100.0
        )));
    }
    Ok(())
}

/// Step 6: fits `spec` to `train`, telling the listener the solver's iterations as they go (a
/// fit on a million rows takes minutes); a stop (Ctrl-C, a termination signal) ends it.
fn final_fit(
    spec: ModelSpec,
    train: &Dataset,
    listener: &dyn Listener,
) -> Result<(StoredModel, Option<data::Columns>), SelectError> {
    let ModelSpec::Msvr(params) = spec;
    // Set, and the watcher woken, when the fit ends: the run does not wait out its tick.
    let done = (std::sync::Mutex::new(false), std::sync::Condvar::new());
    let before = crate::control::iterations();
    let fitted = std::thread::scope(|scope| {
        scope.spawn(|| {
            let tick = std::time::Duration::from_millis(100);
            let mut ended = done.0.lock().expect("the flag");
            while !*ended {
                ended = done.1.wait_timeout(ended, tick).expect("the flag").0;
                listener.fitting(crate::control::iterations() - before, params.max_iter);
            }
            listener.fitted();
        });
        let fitted = spec.fit_predicting(train);
        *done.0.lock().expect("the flag") = true;
        done.1.notify_all();
        fitted
    });
    fitted.map_err(|e| match e {
        MsvrError::Interrupted => SelectError::Interrupted(format!(
            "interrupted during the final fit (C = {}, ε = {}, σ = {}); nothing written",
            params.c, params.epsilon, params.sigma
        )),
        e => e.into(),
    })
}
