//! Hyper-parameter search for MSVR: which (C, ε, σ) to fit with.
//!
//! A search sees only an objective — a function scoring a batch of candidates, lower is better —
//! and reports each iteration to an [`Observer`] (progress bars and history writers live there).
//! Every search takes a seed; the same seed gives the same result.
//!
//! - [`aco_paper`]: the paper's digit-encoded ant colony (§2.3.2, Table 1).
//! - [`aco_r`]: continuous ACO_R (Socha & Dorigo 2008) on (log C, log ε, log σ).
//! - [`grid`]: a log-spaced grid, the baseline the paper says ACO beats.
//!
//! [`fitness`] provides the objective: cross-validated (default) or training MAE.

pub mod aco_paper;
pub mod aco_r;
pub mod fitness;
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

impl Hyper {
    /// Whether every parameter is finite and > 0 (the paper's zero-valued paths are invalid).
    pub fn is_valid(&self) -> bool {
        [self.c, self.epsilon, self.sigma]
            .iter()
            .all(|v| v.is_finite() && *v > 0.0)
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

/// Receives each iteration as it ends.
pub trait Observer {
    fn iteration(&mut self, record: &IterationRecord);
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
    #[error(transparent)]
    Folds(#[from] fitness::FitnessError),
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
/// candidate or a failed fit.
pub type Objective<'a> = dyn Fn(&[Hyper]) -> Vec<f64> + Sync + 'a;

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

/// The box searched by [`aco_r`] and [`grid`], in (ln C, ln ε, ln σ), derived from the data:
/// - σ from half the median nearest-neighbour distance of the scaled inputs (a narrower kernel
///   sees no neighbour) to 2√d (twice the diagonal of the unit cube: nearly linear);
/// - ε from 10⁻⁴ to ½ of the outputs' RMS distance from their mean (a wider tube fits nothing);
/// - C from 0.1 to 10⁷ (the loss and the regulariser scale alike with the outputs, so C needs no
///   output scale; the ridge 1/(2C) of the step system stays far above rounding of K's unit
///   diagonal, and on smooth, lightly noisy data the best C found is at the top of this range).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchSpace {
    pub c: (f64, f64),
    pub epsilon: (f64, f64),
    pub sigma: (f64, f64),
}

impl SearchSpace {
    /// The box for a dataset.
    pub fn from_data(data: &crate::data::Dataset) -> Self {
        let scaled = crate::model::msvr::MinMaxScaler::fit(&data.inputs).transform(&data.inputs);
        let d2 = crate::model::msvr::kernel::squared_distances(&scaled, &scaled);
        let n = scaled.rows();
        let mut nearest: Vec<f64> = (0..n)
            .map(|j| {
                (0..n)
                    .filter(|&i| i != j)
                    .map(|i| d2[(i, j)])
                    .filter(|&v| v > 0.0)
                    .fold(f64::INFINITY, f64::min)
                    .sqrt()
            })
            .filter(|v| v.is_finite())
            .collect();
        nearest.sort_by(f64::total_cmp);
        let median_nn = nearest.get(nearest.len() / 2).copied().unwrap_or(0.1);
        let q = data.outputs.width();
        let mean: Vec<f64> = (0..q)
            .map(|j| data.outputs.column(j).sum::<f64>() / n as f64)
            .collect();
        let spread = (data
            .outputs
            .iter_rows()
            .map(|r| {
                r.iter()
                    .zip(&mean)
                    .map(|(v, m)| (v - m) * (v - m))
                    .sum::<f64>()
            })
            .sum::<f64>()
            / n as f64)
            .sqrt()
            .max(f64::MIN_POSITIVE);
        let d = scaled.width() as f64;
        SearchSpace {
            c: (0.1, 1e7),
            epsilon: (1e-4 * spread, 0.5 * spread),
            sigma: (0.5 * median_nn, 2.0 * d.sqrt()),
        }
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

/// Group labels of the training rows (one per row) and the column they came from: rows of a
/// group are held out together, as when consecutive rows of one ramp are nearly the same.
#[derive(Clone, Debug, PartialEq)]
pub struct Groups {
    pub column: String,
    pub labels: Vec<f64>,
}

impl Method {
    /// The `--search` name.
    pub fn name(&self) -> &'static str {
        match self {
            Method::AcoPaper(_) => "aco-paper",
            Method::AcoR(_) => "aco-r",
            Method::Grid(_) => "grid",
        }
    }
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

/// What the model file records of the search that chose its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchSummary {
    #[serde(flatten)]
    pub method: Method,
    pub fitness: fitness::FitnessKind,
    /// The column whose values group rows into whole folds, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group_by: Option<String>,
    /// Seed of the folds' shuffle (the method's own `seed` is in its settings, flattened beside
    /// this; one name for both made the model file unreadable).
    pub fold_seed: u64,
    pub space: Option<SearchSpace>,
    pub best: Hyper,
    pub best_fitness: f64,
    pub iterations: usize,
    pub stop: SearchStop,
    /// Distinct candidates scored; each costs one fit per fold.
    pub evaluations: usize,
    pub fits: usize,
    /// Candidates answered from the memo of scored ones.
    pub memo_hits: usize,
}

/// Runs `method` on `data` with the given fitness; returns the summary, the full result and
/// the work counters.
///
/// # Errors
/// [`SearchError`] from the method, or a fitness set-up error as
/// [`SearchError::InvalidSetting`].
#[allow(clippy::too_many_arguments)]
pub fn run(
    method: &Method,
    data: &crate::data::Dataset,
    fitness: fitness::FitnessKind,
    seed: u64,
    groups: Option<&Groups>,
    solver: &crate::model::msvr::MsvrParams,
    observer: &mut dyn Observer,
    interrupt: &AtomicBool,
) -> Result<(SearchSummary, SearchResult, fitness::Counters), SearchError> {
    let labels = groups.map(|g| g.labels.as_slice());
    let scorer = fitness::Fitness::new(data, fitness, seed, labels, solver)?;
    let objective = |batch: &[Hyper]| scorer.evaluate(batch);
    let (result, space) = match method {
        Method::AcoPaper(m) => (m.run(&objective, observer, interrupt)?, None),
        Method::AcoR(m) => {
            let space = SearchSpace::from_data(data);
            (m.run(&space, &objective, observer, interrupt)?, Some(space))
        }
        Method::Grid(m) => {
            let space = SearchSpace::from_data(data);
            (m.run(&space, &objective, observer, interrupt)?, Some(space))
        }
    };
    let counters = scorer.counters();
    let summary = SearchSummary {
        method: *method,
        fitness,
        group_by: groups.map(|g| g.column.clone()),
        fold_seed: seed,
        space,
        best: result.best,
        best_fitness: result.best_fitness,
        iterations: result.history.len(),
        stop: result.stop,
        evaluations: counters.evaluations,
        fits: counters.fits,
        memo_hits: counters.memo_hits,
    };
    Ok((summary, result, counters))
}
