//! The steps of [`super::select`], on one selection under way ([`Run`]).

use std::sync::atomic::{AtomicBool, Ordering};

use super::family::Family;
use super::{radii_text, Iterations, Listener, Plan, SelectError, Selection, Table};
use crate::control::Since;
use crate::data::Dataset;
use crate::model::history::{self, History, HistoryChoice, HistoryDecision, HistoryTrial, Memory};
use crate::model::interval::Intervals;
use crate::model::msvr::{self, Basis, Hyper, MsvrParams, MIN_FIT_ROWS};
use crate::search::{Search, SearchError};
use crate::select::fitness::FitnessKind;
use crate::select::folds::{self, Dealing, FoldPlan};
use crate::select::tune::{self, BasisChoice, BasisDecision, Chosen, TuneError};

/// One selection under way.
#[derive(Clone, Copy)]
pub(super) struct Run<'a> {
    pub(super) plan: &'a Plan,
    /// The family being selected.
    pub(super) family: Family,
    pub(super) train: &'a Table,
    pub(super) search_on: Option<&'a Table>,
    pub(super) listener: &'a dyn Listener,
    pub(super) interrupt: &'a AtomicBool,
    pub(super) started: Since,
}

/// The feature sets a selection tries.
pub(super) struct Candidates {
    /// The present inputs alone, searched first (and compared with the history).
    static_first: bool,
    /// The histories: one to search, or several for `auto` to screen.
    memories: Vec<Memory>,
}

impl Candidates {
    /// Whether the present inputs are compared with a history.
    pub(super) fn compared(&self) -> bool {
        self.static_first && !self.memories.is_empty()
    }

    /// The one feature set `decision` kept (the present inputs without one): what a second
    /// family is searched on, the history already chosen by the first.
    pub(super) fn kept(decision: Option<&HistoryDecision>) -> Candidates {
        match decision.and_then(|d| d.used.as_ref()) {
            Some(h) => Candidates {
                static_first: false,
                memories: vec![h.memory.clone()],
            },
            None => Candidates {
                static_first: true,
                memories: Vec::new(),
            },
        }
    }
}

/// The rows candidates are scored on and how cross-validation cuts them.
pub(super) struct Scoring {
    pub(super) scored: Dataset,
    pub(super) plan: FoldPlan,
    pub(super) fitness: FitnessKind,
}

impl Scoring {
    /// The column naming the runs the folds keep whole, when they do.
    pub(super) fn runs(&self) -> Option<String> {
        match &self.plan.choice.scheme {
            folds::FoldScheme::Groups { column } => Some(column.clone()),
            _ => None,
        }
    }
}

/// The screen of `auto`'s ladders scores each around the present inputs' (C, ε, σ): σ widened
/// by √(copies of the inputs) and multiplied by each of these, C by each of [`SCREEN_C`]; a
/// ladder scores the best of the four. The parameters that suit the present inputs need not
/// suit a history's features. At those parameters alone the demo's dynamic session scored its
/// five ladders 0.800-0.840, and the pick (ema 0.267, 1.07 s) searched to 0.670 and held its
/// trial out at 1.00 mm. On the grid they spread 0.614-0.801; the pick (ema 0.0167, 0.0667,
/// 0.267 s) searches to 0.596 and holds out 0.50 mm. The real data's picks are kept: the soft
/// trunk's ema 0.1, 0.4, 1.6 s, the tendon arm's 0.5, 2, 8 steps, the 45 000-row log's 0.333,
/// 1.33, 5.33 s. The grid costs three more cross-validations a ladder, scored by one scorer
/// (the 45 000-row log's `model`: 150 s against 140; 167 with a scorer per point); searching
/// every ladder ranks them as well but costs a search each (597 s). A σ doubled never scored
/// best, on the demo's session nor the 45 000-row log.
const SCREEN_SIGMA: [f64; 2] = [0.5, 1.0];
const SCREEN_C: [f64; 2] = [1.0, 10.0];

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

/// A family's selection: the history decision, its choice and the rows it was scored on.
pub(super) type Kept = (Option<HistoryDecision>, Chosen, Scoring);

impl Run<'_> {
    pub(super) fn check(&self) -> Result<(), SelectError> {
        self.plan.check()?;
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
    pub(super) fn candidates(&self) -> Result<Candidates, SelectError> {
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
    pub(super) fn initial_basis(&self) -> Result<BasisDecision, SelectError> {
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
    pub(super) fn scoring(&self) -> Result<Scoring, SelectError> {
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

    /// The solver's settings with what the family fixes.
    fn solver(&self) -> MsvrParams {
        self.family.solver(self.plan.params)
    }

    pub(super) fn interrupted(&self) -> bool {
        self.interrupt.load(Ordering::Relaxed)
    }

    /// Step 3: each feature set's parameters; `auto`'s ladders screened on a small grid around
    /// the present inputs' parameters ([`SCREEN_SIGMA`], [`SCREEN_C`]), the best one searched.
    /// `alone`: the one family selected (else the basis grows after the families' comparison,
    /// as after the feature sets').
    pub(super) fn choose_each(
        &self,
        present: &Scoring,
        candidates: &Candidates,
        initial: BasisDecision,
        alone: bool,
    ) -> Result<(Vec<Tried>, Vec<HistoryTrial>), SelectError> {
        let compare = candidates.compared();
        let only = if alone { Pass::Only } else { Pass::Compared };
        let mut tried: Vec<Tried> = Vec::new();
        let mut screened = Vec::new();
        if candidates.static_first {
            if compare {
                self.listener
                    .note("input history: none (the present inputs)".into());
            }
            let scored = self.scoring_with(present, None)?;
            let pass = if compare { Pass::Reference } else { only };
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
                    let scored = self.scoring_with(present, Some(&h))?;
                    // The best of a small grid around the present inputs' parameters.
                    let widened = reference.params.sigma * (copies as f64).sqrt();
                    let grid: Vec<Hyper> = SCREEN_SIGMA
                        .iter()
                        .flat_map(|s| {
                            SCREEN_C.iter().map(move |c| Hyper {
                                sigma: widened * s,
                                c: reference.params.c * c,
                                epsilon: reference.params.epsilon,
                            })
                        })
                        .collect();
                    let scores = tune::cross_validate_each(
                        &scored.scored,
                        scored.fitness,
                        &scored.plan,
                        &reference.params,
                        &grid,
                    )?;
                    let mut params = reference.params;
                    let mut fitness = f64::INFINITY;
                    for (h, f) in grid.into_iter().zip(scores) {
                        if f < fitness {
                            (fitness, params) = (f, reference.params.with_hyper(h));
                        }
                    }
                    self.listener.note(format!(
                        "input history: {memory} screened around the present inputs' parameters: {fitness:.5}"
                    ));
                    screened.push(HistoryTrial {
                        memory: Some(memory.clone()),
                        fitness,
                        params: Some(params),
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
            let pass = if compare { Pass::Compared } else { only };
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
                .map_or(0, |(m, _)| m.iteration_cap(self.family.axes().len())),
        };
        let choice = tune::Choice {
            rows: &scoring.scored,
            fitness: scoring.fitness,
            folds: &scoring.plan,
            search,
            axes: self.family.axes(),
            pinned: self.plan.pinned,
            grow: pass == Pass::Only && self.grows(&initial),
            score: pass != Pass::Only,
        };
        tune::choose(
            &choice,
            &self.solver(),
            initial,
            &mut observer,
            self.interrupt,
        )
        .map_err(|e| match e {
            // A stop before the search's first iteration ended has no best to keep.
            TuneError::Search(SearchError::NothingValid) if self.interrupted() => {
                SelectError::Interrupted(
                    "interrupted before the search scored a candidate; nothing written".into(),
                )
            }
            e => e.into(),
        })
    }

    /// Step 4: the feature set kept, by [`history::decide`] with a time series.
    pub(super) fn keep(
        &self,
        tried: Vec<Tried>,
        screened: Vec<HistoryTrial>,
    ) -> Result<(Option<HistoryDecision>, Chosen, Scoring), SelectError> {
        // The present inputs against a history, fold by fold (the same folds for both).
        let paired = match tried.as_slice() {
            [(None, present, on_present), (Some(_), history, on_history)] => {
                let (a, values) = self.fold_errors(present, on_present)?;
                let (b, _) = self.fold_errors(history, on_history)?;
                (!values.is_empty()).then(|| crate::stats::paired_difference(&a, &b, &values))
            }
            _ => None,
        };
        let decision = self.plan.time.as_ref().map(|_| {
            history::decide(
                tried
                    .iter()
                    .map(|(h, c, _)| (h.clone(), c.fitness.unwrap_or(f64::NAN), c.params))
                    .collect(),
                screened,
                &format!("history={}", self.plan.history),
                paired,
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
        Ok((decision, chosen, scored))
    }

    /// The present inputs, when `history=auto` kept them over every history: their reference
    /// search had half the default budget, so they are searched again with the whole of it
    /// (the same search, rows and folds as without a time column: the same model). Any other
    /// choice is returned as it was.
    pub(super) fn present_in_full(
        &self,
        kept: Kept,
        candidates: &Candidates,
        initial: BasisDecision,
    ) -> Result<Kept, SelectError> {
        let (decision, chosen, scored) = kept;
        let halved = candidates.compared()
            && matches!(self.plan.selection, Selection::Search { budget: None, .. });
        let history_kept = decision.as_ref().is_some_and(|d| d.used.is_some());
        if !halved || history_kept || self.interrupted() {
            return Ok((decision, chosen, scored));
        }
        self.listener.note(
            "input history: none kept; the present inputs are searched again with the whole budget (their reference search had half)".into(),
        );
        // Compared, not Only: the basis grows after, as for any set compared.
        let chosen = self.choose(&scored, initial, Pass::Compared)?;
        Ok((decision, chosen, scored))
    }

    /// Whether the basis grows: only `auto`'s reduced basis does; exact and a given size are
    /// used as they are.
    pub(super) fn grows(&self, initial: &BasisDecision) -> bool {
        self.plan.basis == BasisChoice::Auto && initial.basis != Basis::Exact
    }

    /// `auto`'s basis grown at the kept set's parameters.
    pub(super) fn grow(&self, chosen: &mut Chosen, scored: &Scoring) -> Result<(), SelectError> {
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
        Ok(())
    }

    /// What a stop ends from here on: one during a search ended the search (its best kept),
    /// so only a later one counts; without a search, any since the start.
    pub(super) fn since_choice(&self) -> Since {
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
    pub(super) fn intervals(
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
        // Runs are dealt to the intervals' folds in blocks of consecutive runs.
        let dealing = |on: &Scoring| match on.runs() {
            Some(_) => Dealing::Consecutive,
            None => Dealing::Shuffled,
        };
        let seed = self.plan.seed().unwrap_or(crate::DEFAULT_SEED);
        let intervals = match (&chosen.held_out, self.search_on) {
            (Some(predicted), None) if dealing(&scored) == Dealing::Shuffled => tune::intervals(
                &scored.scored,
                &scored.plan,
                Dealing::Shuffled,
                seed,
                &chosen.params,
                predicted,
            )?,
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
                let predicted = tune::held_out_predictions(
                    &on.scored,
                    seed,
                    &on.plan,
                    dealing(&on),
                    &chosen.params,
                )?;
                tune::intervals(
                    &on.scored,
                    &on.plan,
                    dealing(&on),
                    seed,
                    &chosen.params,
                    &predicted,
                )?
            }
        };
        let c = &intervals.held_out;
        self.listener.note(match c.radii.as_slice() {
            [] => format!(
                "prediction intervals: none ({} held-out rows are too few for a 90 % radius, which needs 9)",
                c.rows
            ),
            radii => format!(
                "prediction intervals: {} from {} held-out rows, wider off the training rows",
                radii_text(radii),
                c.rows
            ),
        });
        Ok(Some(intervals))
    }
}
