//! Tuning MSVR: a [`Search`] from [`crate::search`] scores (C, ε, σ) candidates by fitting
//! MSVR ([`super::fitness`]); this module joins the two and records what was done.
//!
//! The box searched by ACO_R and the grid comes from the data ([`space_for`]):
//! - σ from half the median nearest-neighbour distance of the scaled inputs (a narrower kernel
//!   sees no neighbour) to 2√d (twice the diagonal of the unit cube: nearly linear);
//! - ε from 10⁻⁴ to ½ of the outputs' RMS distance from their mean (a wider tube fits nothing);
//! - C from 0.1 to 10⁷ (the loss and the regulariser scale alike with the outputs, so C needs no
//!   output scale; the ridge 1/(2C) of the step system stays far above rounding of K's unit
//!   diagonal, and on smooth, lightly noisy data the best C found is at the top of this range).

use std::sync::atomic::AtomicBool;

use serde::{Deserialize, Serialize};

use super::fitness::{Counters, Fitness, FitnessError, FitnessKind};
use super::folds::{FoldChoice, FoldPlan};
use super::{kernel, MinMaxScaler, MsvrParams};
use crate::data::Dataset;
use crate::search::{
    Hyper, Method, Observer, Search, SearchError, SearchResult, SearchSpace, SearchStop,
};

/// Errors of a tuning run.
#[derive(Debug, thiserror::Error)]
pub enum TuneError {
    #[error(transparent)]
    Search(#[from] SearchError),
    #[error(transparent)]
    Folds(#[from] FitnessError),
    #[error(transparent)]
    Msvr(#[from] super::MsvrError),
}

/// What the model file records of the search that chose its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchSummary {
    #[serde(flatten)]
    pub method: Method,
    pub fitness: FitnessKind,
    /// How the cross-validation folds were cut, and why (`None` for the training fitness).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub folds: Option<FoldChoice>,
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
    /// Candidates stopped before their last fold, unable to change the search (racing).
    #[serde(default)]
    pub raced: usize,
}

/// The box for a dataset (see the module docs).
pub fn space_for(data: &Dataset) -> SearchSpace {
    let scaled = MinMaxScaler::fit(&data.inputs).transform(&data.inputs);
    let d2 = kernel::squared_distances(&scaled, &scaled);
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
    let median_nn = crate::stats::upper_median(&mut nearest).unwrap_or(0.1);
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

/// The candidate budget of ACO_R and the grid when none is given, from the rows scored: one
/// candidate costs a fit per fold, and a fit grows as n² to n³, so small sets get a finer search
/// for the same time. Measured with 5 folds on 2 cores (ACO_R, robust loss): 780 rows × 3
/// inputs (tendon arm) 120 candidates in 11 s, 13.7 mm held out (400: 34 s, 14.4 mm); 1096 rows
/// × 6 inputs (soft trunk) 120 in 20 s, 3.73 mm (400: 74 s, 3.82 mm).
pub fn budget_for(rows: usize) -> usize {
    match rows {
        0..=400 => 400,
        401..=700 => 200,
        _ => 120,
    }
}

/// The solver controls of a method's fits: the paper's colony factors afresh at every change
/// of the support set, as its histories were computed, so they stay bit for bit; the others
/// update the factor ([`super::irwls::SolverOptions::factor_updates`]).
pub fn solver_for(method: &Method, solver: &MsvrParams) -> MsvrParams {
    MsvrParams {
        factor_updates: !matches!(method, Method::AcoPaper(_)),
        ..*solver
    }
}

/// Runs `method` on `data` with the given fitness; returns the summary, the full result and
/// the work counters.
///
/// # Errors
/// [`TuneError`]: the method's own, or a fold set-up error.
#[allow(clippy::too_many_arguments)]
pub fn run(
    method: &Method,
    data: &Dataset,
    fitness: FitnessKind,
    seed: u64,
    folds: &FoldPlan,
    solver: &MsvrParams,
    observer: &mut dyn Observer,
    interrupt: &AtomicBool,
) -> Result<(SearchSummary, SearchResult, Counters), TuneError> {
    super::check_memory(data.rows())?;
    let labels = folds.labels.as_deref();
    let scorer = Fitness::new(data, fitness, seed, labels, &solver_for(method, solver))?;
    let objective = |batch: &[Hyper], bar: f64| scorer.evaluate(batch, bar);
    let space = method.uses_space().then(|| space_for(data));
    // The paper's colony ignores the box; any box will do for it.
    let searched = space.unwrap_or(SearchSpace {
        c: (1.0, 1.0),
        epsilon: (1.0, 1.0),
        sigma: (1.0, 1.0),
    });
    let result = method.run(&searched, &objective, observer, interrupt)?;
    let counters = scorer.counters();
    let summary = SearchSummary {
        method: *method,
        fitness,
        folds: matches!(fitness, FitnessKind::Cv { .. }).then(|| folds.choice.clone()),
        fold_seed: seed,
        space,
        best: result.best,
        best_fitness: result.best_fitness,
        iterations: result.history.len(),
        stop: result.stop,
        evaluations: counters.evaluations,
        fits: counters.fits,
        memo_hits: counters.memo_hits,
        raced: counters.raced,
    };
    Ok((summary, result, counters))
}
