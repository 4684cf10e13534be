//! Model selection: rows in memory → a chosen, fitted model with the record of how it was
//! chosen and its prediction intervals. Every front end calls [`select`]: `handcap model` (its
//! files read into [`Table`]s), the Python estimator, the demo and the benchmarks.
//!
//! [`select`] is the list of its steps:
//! 1. the feature sets to try ([`candidates`]): the present inputs, and with a time series
//!    the histories [`Plan::history`] asks for (groups too short for them refused first);
//! 2. the rows and folds every set is scored on ([`Scoring`]: at most
//!    [`tune::SEARCH_ROWS`] evenly spaced rows, the folds cut from the present inputs);
//! 3. each set's parameters chosen ([`tune::choose`]: the search, or the given ones), `auto`'s
//!    ladders of time constants screened at the present inputs' parameters first;
//! 4. the set kept ([`history::decide`]) and `auto`'s basis grown for it;
//! 5. the intervals, from the held-out predictions steps 3-4 made (no further fit), or when
//!    none were made and [`Plan::intervals`] asks, from k more fits;
//! 6. the final fit on every row.
//!
//! Messages name parameters as `field=value` (`basis=exact`, `folds_by=blocks`), as the
//! Python estimator takes them; the command line writes its flags instead.

use std::sync::atomic::{AtomicBool, Ordering};

use crate::control::Since;
use crate::data::{self, DataError, Dataset};
use crate::model::history::{
    self, History, HistoryChoice, HistoryDecision, HistoryError, HistoryTrial, Memory, Series,
};
use crate::model::interval::Intervals;
use crate::model::msvr::fitness::{Dealing, FitnessKind};
use crate::model::msvr::folds::{self, FoldPlan, FoldsBy, FoldsError};
use crate::model::msvr::tune::{
    self, BasisChoice, BasisDecision, BasisError, Chosen, Pinned, Searched, TuneError,
};
use crate::model::msvr::{self, Basis, Hyper, MsvrError, MsvrParams, MIN_FIT_ROWS};
use crate::model::{self, ModelSpec, StoredModel};
use crate::search::{IterationRecord, Method, Observer, Search};

/// Rows to select a model on: the dataset (present inputs and outputs), its time series, and
/// the columns folds may be cut by.
pub struct Table {
    pub data: Dataset,
    /// Each row's time (and group) when the rows are a time series.
    pub series: Option<Series>,
    /// Each row's line in its file, for errors (row numbers for rows from memory).
    pub lines: Vec<u64>,
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
        match (history, &self.series) {
            (Some(h), Some(series)) => h
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
        history::series_error(&self.data.source, &self.lines, e)
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
        /// Candidates at most (ACO_R, grid); `None`: [`tune::budget_for`] the rows scored.
        budget: Option<usize>,
        fitness: FitnessKind,
        /// How cross-validation cuts the rows ([`folds::plan`]).
        folds_by: FoldsBy,
        seed: u64,
    },
}

/// What to select.
pub struct Plan {
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
    fn seed(&self) -> Option<u64> {
        match self.selection {
            Selection::Fixed { .. } => None,
            Selection::Search { seed, .. } => Some(seed),
        }
    }

    fn searched(&self) -> bool {
        matches!(self.selection, Selection::Search { .. })
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
    let (tried, screened) = run.choose_each(&present, &candidates, initial)?;
    let (decision, mut chosen, scored) = run.keep(tried, screened);
    let kept = decision.as_ref().and_then(|d| d.used.clone());
    if candidates.compared() && run.grows(&chosen.basis) {
        run.grow(&mut chosen, &scored)?;
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
    let train_errors = match fitted {
        Some(fitted) => model::errors(&train_rows.outputs, &fitted),
        None => model::evaluate(model.predictor(), &train_rows)?,
    };
    Ok(Selected {
        model,
        train_errors,
        search: chosen.search,
        basis: chosen.basis,
        history: decision,
        intervals,
        train: train_rows,
        runs: present.runs(),
    })
}

/// One selection under way.
#[derive(Clone, Copy)]
struct Run<'a> {
    plan: &'a Plan,
    train: &'a Table,
    search_on: Option<&'a Table>,
    listener: &'a dyn Listener,
    interrupt: &'a AtomicBool,
    started: Since,
}

/// The feature sets a selection tries.
struct Candidates {
    /// The present inputs alone, searched first (and compared with the history).
    static_first: bool,
    /// The histories: one to search, or several for `auto` to screen.
    memories: Vec<Memory>,
}

impl Candidates {
    /// Whether the present inputs are compared with a history.
    fn compared(&self) -> bool {
        self.static_first && !self.memories.is_empty()
    }
}

/// The rows candidates are scored on and how cross-validation cuts them.
struct Scoring {
    scored: Dataset,
    plan: FoldPlan,
    fitness: FitnessKind,
}

impl Scoring {
    /// The column naming the runs the folds keep whole, when they do.
    fn runs(&self) -> Option<String> {
        match &self.plan.choice.scheme {
            folds::FoldScheme::Groups { column } => Some(column.clone()),
            _ => None,
        }
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
    /// The present inputs as `history=auto`'s reference: compared, and searched with half
    /// the default budget (its parameters also start the screen of time constants).
    Reference,
}

/// A feature set tried: its history, its choice and the rows it was scored on.
type Tried = (Option<History>, Chosen, Scoring);

impl Run<'_> {
    fn check(&self) -> Result<(), SelectError> {
        self.plan
            .params
            .check()
            .map_err(|e| SelectError::Parameter(e.to_string()))?;
        self.train.data.check_fittable(MIN_FIT_ROWS)?;
        for table in std::iter::once(self.train).chain(self.search_on) {
            table.check_series(self.plan.time.is_some())?;
        }
        let rows = self.rows();
        if self.search_on.is_none() && rows > tune::SEARCH_ROWS && self.plan.searched() {
            self.listener.note(format!(
                "search: candidates scored on {} evenly spaced rows of {rows} (the model is fitted on all of them)",
                tune::SEARCH_ROWS
            ));
        }
        Ok(())
    }

    /// The training rows kept ([`Plan::max_rows`]).
    fn rows(&self) -> usize {
        let n = self.train.data.rows();
        self.plan.max_rows.map_or(n, |m| m.min(n))
    }

    /// The history of `memory` on the present inputs.
    fn history(&self, memory: Memory) -> History {
        History {
            time: self.plan.time.clone().unwrap_or_default(),
            group: self.plan.group.clone(),
            inputs: self.train.data.inputs.names.clone(),
            memory,
        }
    }

    /// Step 1: what [`Plan::history`] asks to try on the training series; groups too short
    /// for a history are refused before any search.
    fn candidates(&self) -> Result<Candidates, SelectError> {
        let none = Candidates {
            static_first: true,
            memories: Vec::new(),
        };
        let (Some(series), Some(_)) = (&self.train.series, &self.plan.time) else {
            return Ok(none);
        };
        let error = |e| self.train.series_error(e);
        let ladders = || series.time_constant_ladders().map_err(error);
        let (static_first, memories) = match &self.plan.history {
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
                let scale = series.time_scale().map_err(error)?;
                if let Some(why) = history::useless_time_constant(tau, scale) {
                    return Err(SelectError::Parameter(format!("history=ema:…: {why}")));
                }
                (false, vec![Memory::Ema { tau: tau.clone() }])
            }
            HistoryChoice::Lags(rows) => (false, vec![Memory::Lags { rows: *rows }]),
        };
        for memory in &memories {
            self.train.with(Some(&self.history(memory.clone())))?;
        }
        Ok(Candidates {
            static_first,
            memories,
        })
    }

    /// The basis searched (and grown from, for `auto`).
    fn initial_basis(&self) -> Result<BasisDecision, SelectError> {
        let seed = self.plan.seed().unwrap_or(crate::DEFAULT_SEED);
        let initial = tune::initial_basis(self.plan.basis, self.rows(), seed)?;
        msvr::check_memory(self.rows(), initial.basis)?;
        self.listener
            .note(format!("basis: {} ({})", initial.basis, initial.reason));
        Ok(initial)
    }

    /// Step 2: a search's rows (`search_on`'s, else at most [`tune::SEARCH_ROWS`] evenly
    /// spaced rows of the training data), or for given parameters those `auto`'s basis and
    /// the intervals are cross-validated on; the folds ([`folds::plan`]) are cut from the
    /// present inputs (a history's filtered copies would hide a designed grid).
    fn scoring(&self) -> Result<Scoring, SelectError> {
        let (by, fitness) = match &self.plan.selection {
            Selection::Fixed { folds, folds_by } => (folds_by, FitnessKind::Cv { folds: *folds }),
            Selection::Search {
                folds_by, fitness, ..
            } => (folds_by, *fitness),
        };
        let scored = self.scored_rows(None)?;
        scored.check_fittable(MIN_FIT_ROWS)?;
        let table = self.search_on.unwrap_or(self.train);
        let kept = table.kept(self.plan.max_rows, scored.rows());
        let columns: Vec<(String, Vec<f64>)> = table
            .fold_columns
            .iter()
            .map(|(name, values)| (name.clone(), kept.iter().map(|&i| values[i]).collect()))
            .collect();
        let asked = match fitness {
            FitnessKind::Cv { folds } => folds,
            FitnessKind::Train => 2,
        };
        let folds = folds::plan(by, &scored, &columns, asked)?;
        let fitness = match fitness {
            FitnessKind::Cv { .. } => FitnessKind::Cv { folds: folds.folds },
            FitnessKind::Train => FitnessKind::Train,
        };
        Ok(Scoring {
            scored,
            plan: folds,
            fitness,
        })
    }

    /// The rows scored, with `history`'s features.
    fn scored_rows(&self, history: Option<&History>) -> Result<Dataset, SelectError> {
        Ok(match self.search_on {
            Some(t) => self.plan.keep(t.with(history)?),
            None => self
                .plan
                .keep(self.train.with(history)?)
                .subsample(tune::SEARCH_ROWS),
        })
    }

    /// `present`'s rows and folds with `history`'s features.
    fn scoring_with(
        &self,
        present: &Scoring,
        history: Option<&History>,
    ) -> Result<Scoring, SelectError> {
        Ok(Scoring {
            scored: self.scored_rows(history)?,
            plan: present.plan.clone(),
            fitness: present.fitness,
        })
    }

    fn interrupted(&self) -> bool {
        self.interrupt.load(Ordering::Relaxed)
    }

    /// Step 3: each feature set's parameters; `auto`'s ladders screened at the present
    /// inputs' parameters (σ widened by √(copies of the inputs)), the best one searched.
    fn choose_each(
        &self,
        present: &Scoring,
        candidates: &Candidates,
        initial: BasisDecision,
    ) -> Result<(Vec<Tried>, Vec<HistoryTrial>), SelectError> {
        let compare = candidates.compared();
        let mut tried: Vec<Tried> = Vec::new();
        let mut screened = Vec::new();
        if candidates.static_first {
            if compare {
                self.listener
                    .note("input history: none (the present inputs)".into());
            }
            let scored = self.scoring_with(present, None)?;
            let pass = if compare { Pass::Reference } else { Pass::Only };
            let chosen = self.choose(&scored, initial.clone(), pass)?;
            tried.push((None, chosen, scored));
        }
        let memory = match (tried.first(), candidates.memories.as_slice()) {
            (_, []) => None,
            (_, [only]) => Some((only.clone(), None)),
            (Some((_, reference, _)), ladders) if !self.interrupted() => {
                let mut best: Option<(Memory, f64, Scoring)> = None;
                for memory in ladders {
                    let h = self.history(memory.clone());
                    let copies = 1 + memory.blocks();
                    let params = MsvrParams {
                        sigma: reference.params.sigma * (copies as f64).sqrt(),
                        ..reference.params
                    };
                    let scored = self.scoring_with(present, Some(&h))?;
                    let (fitness, _) = tune::cross_validate(
                        &scored.scored,
                        scored.fitness,
                        &scored.plan,
                        &params,
                    )?;
                    self.listener.note(format!(
                        "input history: {memory} screened at the present inputs' parameters: {fitness:.5}"
                    ));
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
        if let Some((memory, scored)) = memory.filter(|_| !self.interrupted() || tried.is_empty()) {
            let h = self.history(memory);
            self.listener.note(format!(
                "input history: {} ({} model inputs)",
                h.memory,
                h.feature_names().len()
            ));
            let scored = match scored {
                Some(scored) => scored,
                None => self.scoring_with(present, Some(&h))?,
            };
            let pass = if compare { Pass::Compared } else { Pass::Only };
            let chosen = self.choose(&scored, initial, pass)?;
            tried.push((Some(h), chosen, scored));
        }
        Ok((tried, screened))
    }

    /// One feature set's parameters on `scoring`'s rows ([`Pass`]: growing the basis, scoring
    /// given parameters, the budget), by [`tune::choose`].
    fn choose(
        &self,
        scoring: &Scoring,
        initial: BasisDecision,
        pass: Pass,
    ) -> Result<Chosen, SelectError> {
        let search = match &self.plan.selection {
            Selection::Fixed { .. } => None,
            Selection::Search {
                method,
                budget,
                seed,
                ..
            } => {
                if matches!(scoring.fitness, FitnessKind::Cv { .. }) {
                    self.listener
                        .note(format!("folds: {}", scoring.plan.choice));
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
            listener: self.listener,
            cap: search
                .as_ref()
                .map_or(0, |(m, _)| m.iteration_cap(Hyper::AXES.len())),
        };
        let choice = tune::Choice {
            rows: &scoring.scored,
            fitness: scoring.fitness,
            folds: &scoring.plan,
            search,
            pinned: self.plan.pinned,
            grow: pass == Pass::Only && self.grows(&initial),
            score: pass != Pass::Only,
        };
        Ok(tune::choose(
            &choice,
            &self.plan.params,
            initial,
            &mut observer,
            self.interrupt,
        )?)
    }

    /// Step 4: the feature set kept, by [`history::decide`] with a time series.
    fn keep(
        &self,
        tried: Vec<Tried>,
        screened: Vec<HistoryTrial>,
    ) -> (Option<HistoryDecision>, Chosen, Scoring) {
        let decision = self.plan.time.as_ref().map(|_| {
            history::decide(
                tried
                    .iter()
                    .map(|(h, c, _)| (h.clone(), c.fitness.unwrap_or(f64::NAN)))
                    .collect(),
                screened,
                &format!("history={}", self.plan.history),
            )
        });
        let kept = decision.as_ref().and_then(|d| d.used.clone());
        if let Some(d) = &decision {
            self.listener.note(format!("input history: {}", d.reason));
        }
        let (_, chosen, scored) = tried
            .into_iter()
            .find(|(h, _, _)| *h == kept)
            .expect("the kept history was tried");
        (decision, chosen, scored)
    }

    /// Whether the basis grows: only `auto`'s reduced basis does; exact and a given size are
    /// used as they are.
    fn grows(&self, initial: &BasisDecision) -> bool {
        self.plan.basis == BasisChoice::Auto && initial.basis != Basis::Exact
    }

    /// `auto`'s basis grown at the kept set's parameters.
    fn grow(&self, chosen: &mut Chosen, scored: &Scoring) -> Result<(), SelectError> {
        let start = chosen.basis.clone();
        (chosen.basis, chosen.held_out) = tune::grow_basis(
            start,
            &scored.scored,
            scored.fitness,
            &scored.plan,
            &chosen.params,
            self.interrupt,
        )?;
        chosen.params = chosen.params.basis(chosen.basis.basis);
        if !chosen.basis.tried.is_empty() {
            self.listener.note(format!(
                "basis: {} ({})",
                chosen.basis.basis, chosen.basis.reason
            ));
        }
        Ok(())
    }

    /// What a stop ends from here on: one during a search ended the search (its best kept),
    /// so only a later one counts; without a search, any since the start.
    fn since_choice(&self) -> Since {
        if self.plan.searched() && self.interrupted() {
            Since::now()
        } else {
            self.started
        }
    }

    /// Step 5: conformal intervals of the chosen parameters on the training rows scored. Runs
    /// held out whole are dealt to the intervals' folds in blocks of consecutive runs (k more
    /// fits): runs recorded one after another drift, and the search's runs, dealt at random,
    /// are each held out among neighbours the fold still trains on, so their errors understate
    /// a block of new runs' (on the soft trunk the radius covered 84 % of held-out windows of
    /// six ramps at 90 %, from consecutive blocks 91 %). Otherwise the held-out predictions
    /// the choice made give them at no cost; without any, a search (which scored another
    /// file's rows) or [`Plan::intervals`] computes them (k more fits).
    fn intervals(
        &self,
        kept: Option<&History>,
        chosen: &Chosen,
        scored: Scoring,
    ) -> Result<Option<Intervals>, SelectError> {
        let FitnessKind::Cv { folds } = scored.fitness else {
            self.listener
                .note("prediction intervals: none (fitness=train scores no held-out rows)".into());
            return Ok(None);
        };
        let runs = scored.runs().is_some();
        let dealing = if runs {
            Dealing::Consecutive
        } else {
            Dealing::Shuffled
        };
        let intervals = match (&chosen.held_out, self.search_on) {
            (Some(predicted), None) if !runs => {
                tune::intervals(&scored.scored, &scored.plan, dealing, predicted)
            }
            _ if !self.plan.intervals && chosen.search.is_none() => {
                self.listener.note(format!(
                    "prediction intervals: none (no held-out predictions were made on the way; intervals=true makes them: {folds} more fits)"
                ));
                return Ok(None);
            }
            _ => {
                let on = match self.search_on {
                    None => scored,
                    Some(_) => {
                        let training = Run {
                            search_on: None,
                            ..*self
                        };
                        let present = training.scoring()?;
                        training.scoring_with(&present, kept)?
                    }
                };
                let seed = self.plan.seed().unwrap_or(crate::DEFAULT_SEED);
                let predicted = tune::held_out_predictions(
                    &on.scored,
                    on.plan.folds,
                    seed,
                    &on.plan,
                    dealing,
                    &chosen.params,
                )?;
                tune::intervals(&on.scored, &on.plan, dealing, &predicted)
            }
        };
        let c = &intervals.held_out;
        self.listener.note(match c.radii.as_slice() {
            [] => format!(
                "prediction intervals: none ({} held-out rows are too few for a 90 % radius, which needs 9)",
                c.rows
            ),
            radii => format!(
                "prediction intervals: {} from {} held-out rows",
                radii_text(radii),
                c.rows
            ),
        });
        Ok(Some(intervals))
    }
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
        .map(|r| format!("{} %: {:.4}", r.level * 100.0, r.radius))
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
