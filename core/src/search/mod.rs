//! Optimisers over (C, ε, σ): which candidate scores best on an objective.
//!
//! A search sees only an objective — a function scoring a batch of candidates, lower is better —
//! and a box, and reports each iteration to an [`Observer`] (progress bars and history writers
//! live there). It knows nothing of MSVR or data: the bridge that scores candidates by fitting
//! MSVR is [`crate::model::msvr::tune`]. Every search takes a seed; the same seed gives the same
//! result.
//!
//! - [`aco_paper`]: the paper's digit-encoded ant colony (§2.3.2, Table 1).
//! - [`aco_r`]: continuous ACO_R (Socha & Dorigo 2008) on (log C, log ε, log σ).
//! - [`grid`]: a log-spaced grid, the baseline the paper says ACO beats.

pub mod aco_paper;
pub mod aco_r;
pub mod grid;

use std::sync::atomic::{AtomicBool, Ordering};

use serde::{Deserialize, Serialize};

/// One candidate: penalty C, tube radius ε (output units), RBF width σ (scaled input units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hyper {
    pub c: f64,
    pub epsilon: f64,
    pub sigma: f64,
}

/// A parameter outside its range: which one, its value and the rule.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("{name} = {value}: {requirement}")]
pub struct InvalidParam {
    pub name: &'static str,
    pub value: f64,
    pub requirement: &'static str,
}

impl Hyper {
    /// The one rule for (C, ε, σ): C finite and > 0, ε finite and ≥ 0 (ε = 0 is kernel ridge
    /// regression), σ > 0 with 1/(2σ²) a finite number > 0.
    ///
    /// # Errors
    /// [`InvalidParam`] naming the first value that breaks it.
    pub fn check(&self) -> Result<(), InvalidParam> {
        let bad = |name, value, requirement| {
            Err(InvalidParam {
                name,
                value,
                requirement,
            })
        };
        if !(self.c > 0.0 && self.c.is_finite()) {
            return bad("C", self.c, "must be finite and > 0");
        }
        if !(self.epsilon >= 0.0 && self.epsilon.is_finite()) {
            return bad("epsilon", self.epsilon, "must be finite and ≥ 0");
        }
        if !(self.sigma >= 1e-150 && self.sigma <= 1e150) {
            return bad(
                "sigma",
                self.sigma,
                "must lie in [1e-150, 1e150] (the kernel's 1/(2σ²) must be a finite number > 0)",
            );
        }
        Ok(())
    }
}

/// What one iteration of a search did.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct IterationRecord {
    /// 1-based.
    pub iteration: usize,
    /// Fitness over this iteration's valid candidates.
    pub min: f64,
    pub mean: f64,
    pub max: f64,
    /// Valid candidates this iteration.
    pub valid: usize,
    pub best: Hyper,
    pub best_fitness: f64,
}

/// Receives each iteration as it ends, and the end of the search.
pub trait Observer {
    fn iteration(&mut self, record: &IterationRecord);
    /// The search ended (finished, stopped or failed).
    fn ended(&mut self) {}
}

/// An observer that does nothing.
impl Observer for () {
    fn iteration(&mut self, _: &IterationRecord) {}
}

/// Why a search stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SearchStop {
    /// Every ant took the same path (the paper's convergence rule).
    SamePath,
    /// The iteration cap.
    MaxIterations,
    /// The evaluation budget.
    Budget,
    /// Interrupted (Ctrl-C): the best found so far.
    Interrupted,
}

/// The outcome of a search.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SearchResult {
    pub best: Hyper,
    pub best_fitness: f64,
    pub stop: SearchStop,
    pub history: Vec<IterationRecord>,
}

/// Errors of a search.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SearchError {
    #[error("the search found no candidate with a finite fitness (interrupted too early, or every fit failed)")]
    NothingValid,
    #[error("{name} = {value}: {requirement}")]
    InvalidSetting {
        name: &'static str,
        value: f64,
        requirement: &'static str,
    },
}

/// The error for a setting outside its range.
fn invalid<T>(name: &'static str, value: f64, requirement: &'static str) -> Result<T, SearchError> {
    Err(SearchError::InvalidSetting {
        name,
        value,
        requirement,
    })
}

/// What a search optimises: scores a batch of candidates, lower is better, +∞ for an invalid
/// candidate or a failed fit. The second argument is the search's bar: a candidate whose
/// fitness reaches it cannot change the search (it would not enter ACO_R's archive, nor beat
/// the grid's best), so the objective may stop scoring it early and return any value ≥ the bar
/// (racing). +∞ asks for every fitness in full.
pub type Objective<'a> = dyn Fn(&[Hyper], f64) -> Vec<f64> + Sync + 'a;

/// Keeps the best candidate and the history, and builds each iteration's record.
struct Tracker<'a> {
    best: Option<(Hyper, f64)>,
    history: Vec<IterationRecord>,
    observer: &'a mut dyn Observer,
    interrupt: &'a AtomicBool,
}

impl<'a> Tracker<'a> {
    fn new(observer: &'a mut dyn Observer, interrupt: &'a AtomicBool) -> Self {
        Tracker {
            best: None,
            history: Vec::new(),
            observer,
            interrupt,
        }
    }

    fn interrupted(&self) -> bool {
        self.interrupt.load(Ordering::Relaxed)
    }

    /// The best fitness so far (+∞ before any).
    fn best_fitness(&self) -> f64 {
        self.best.map_or(f64::INFINITY, |(_, f)| f)
    }

    /// Records one iteration's candidates and scores (+∞ marks an invalid candidate).
    fn record(&mut self, candidates: &[Hyper], scores: &[f64]) {
        let valid: Vec<f64> = scores.iter().copied().filter(|s| s.is_finite()).collect();
        for (h, &s) in candidates.iter().zip(scores) {
            if s.is_finite() && self.best.is_none_or(|(_, b)| s < b) {
                self.best = Some((*h, s));
            }
        }
        let (best, best_fitness) = self.best.unwrap_or((candidates[0], f64::INFINITY));
        let (min, max) = valid
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &s| {
                (lo.min(s), hi.max(s))
            });
        let record = IterationRecord {
            iteration: self.history.len() + 1,
            min,
            mean: valid.iter().sum::<f64>() / valid.len() as f64,
            max,
            valid: valid.len(),
            best,
            best_fitness,
        };
        self.observer.iteration(&record);
        self.history.push(record);
    }

    fn finish(self, stop: SearchStop) -> Result<SearchResult, SearchError> {
        let (best, best_fitness) = self.best.ok_or(SearchError::NothingValid)?;
        Ok(SearchResult {
            best,
            best_fitness,
            stop,
            history: self.history,
        })
    }
}

/// The box searched by [`aco_r`] and [`grid`], searched in (ln C, ln ε, ln σ); the MSVR bridge
/// derives it from the data ([`crate::model::msvr::tune::space_for`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchSpace {
    pub c: (f64, f64),
    pub epsilon: (f64, f64),
    pub sigma: (f64, f64),
}

impl SearchSpace {
    /// Each axis a range 0 < lo ≤ hi of finite numbers (the searches work in logarithms).
    ///
    /// # Errors
    /// [`SearchError::InvalidSetting`] naming the axis.
    pub fn check(&self) -> Result<(), SearchError> {
        for (name, (lo, hi)) in [
            ("C", self.c),
            ("epsilon", self.epsilon),
            ("sigma", self.sigma),
        ] {
            if !(lo > 0.0 && lo <= hi && hi.is_finite()) {
                return invalid(name, lo, "its search range must be 0 < low ≤ high, finite");
            }
        }
        Ok(())
    }

    /// (ln lo, ln hi) per axis, in the order C, ε, σ.
    fn log_bounds(&self) -> [(f64, f64); 3] {
        [self.c, self.epsilon, self.sigma].map(|(lo, hi)| (lo.ln(), hi.ln()))
    }

    fn from_log(x: [f64; 3]) -> Hyper {
        Hyper {
            c: x[0].exp(),
            epsilon: x[1].exp(),
            sigma: x[2].exp(),
        }
    }
}

/// A search method with its settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "kebab-case")]
pub enum Method {
    AcoPaper(aco_paper::AcoPaper),
    AcoR(aco_r::AcoR),
    Grid(grid::Grid),
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Method::AcoPaper(m) => write!(
                f,
                "the paper's ant colony ({} ants, ρ {}, τ0 {}, at most {} iterations, seed {})",
                m.ants, m.rho, m.tau0, m.max_iter, m.seed
            ),
            Method::AcoR(m) => write!(
                f,
                "ACO_R (archive {}, {} ants, q {}, ξ {}, budget {}, seed {})",
                m.archive, m.ants, m.q, m.xi, m.budget, m.seed
            ),
            Method::Grid(m) => write!(f, "a log-spaced grid ({} values per axis)", m.per_axis()),
        }
    }
}

impl Method {
    /// The same method with another candidate budget (ACO_R and the grid; the paper's colony
    /// has none).
    #[must_use]
    pub fn with_budget(self, budget: usize) -> Method {
        match self {
            Method::AcoPaper(_) => self,
            Method::AcoR(m) => Method::AcoR(aco_r::AcoR { budget, ..m }),
            Method::Grid(m) => Method::Grid(grid::Grid { budget, ..m }),
        }
    }
}

/// An optimiser: runs on an objective inside a box and says why it stopped.
pub trait Search {
    /// The `--search` name.
    fn name(&self) -> &'static str;
    /// Iterations it runs at most (for a progress bar).
    fn iteration_cap(&self) -> usize;
    /// Whether it searches `space` (the paper's colony has its own digit box and ignores it).
    fn uses_space(&self) -> bool;
    /// Runs the search.
    ///
    /// # Errors
    /// [`SearchError::InvalidSetting`] for a bad setting; [`SearchError::NothingValid`] when no
    /// candidate scored a finite fitness.
    fn run(
        &self,
        space: &SearchSpace,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError>;
}

impl Search for Method {
    fn name(&self) -> &'static str {
        match self {
            Method::AcoPaper(_) => "aco-paper",
            Method::AcoR(_) => "aco-r",
            Method::Grid(_) => "grid",
        }
    }

    fn iteration_cap(&self) -> usize {
        match self {
            Method::AcoPaper(m) => m.max_iter,
            Method::AcoR(m) => (m.budget.saturating_sub(m.archive)).div_ceil(m.ants.max(1)) + 1,
            Method::Grid(m) => (m.per_axis().pow(3)).div_ceil(m.batch.max(1)),
        }
    }

    fn uses_space(&self) -> bool {
        !matches!(self, Method::AcoPaper(_))
    }

    fn run(
        &self,
        space: &SearchSpace,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError> {
        let result = match self {
            Method::AcoPaper(m) => m.run(objective, observer, interrupt),
            Method::AcoR(m) => m.run(space, objective, observer, interrupt),
            Method::Grid(m) => m.run(space, objective, observer, interrupt),
        };
        observer.ended();
        result
    }
}
