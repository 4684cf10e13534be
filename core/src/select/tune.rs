//! Tuning MSVR: a [`Search`] from [`crate::search`] scores candidates named by the axes `c`,
//! `epsilon` and `sigma` ([`Hyper::AXES`]) by fitting MSVR ([`super::fitness`]); this module
//! joins the two and records what was done.
//!
//! The box searched by ACO_R and the grid comes from the data ([`space_for`]):
//! - σ from half the median nearest-neighbour distance of the scaled inputs (a narrower kernel
//!   sees no neighbour) to 2√d (twice the diagonal of the unit cube: nearly linear);
//! - ε from 10⁻⁴ to ½ of the outputs' RMS distance from their mean (a wider tube fits nothing);
//! - C from 0.1 to 10⁷ (the loss and the regulariser scale alike with the outputs, so C needs no
//!   output scale; the ridge 1/(2C) of the step system stays far above rounding of K's unit
//!   diagonal, and on smooth, lightly noisy data the best C found is at the top of this range).

use std::sync::atomic::AtomicBool;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use super::auto_basis::{
    grow_basis, initial_basis, BasisChoice, BasisDecision, BasisError, BasisTrial, AUTO_EXACT_ROWS,
    AUTO_FIRST_CENTRES, AUTO_GAIN, AUTO_MAX_CENTRES,
};
use super::fitness::{Counters, Fitness, FitnessError, FitnessKind, HeldOutRows};
use super::folds::{Dealing, FoldChoice, FoldPlan};
use crate::data::Dataset;
use crate::model::interval::{Intervals, Widening};
use crate::model::msvr::{kernel, Basis, Hyper, MinMaxScaler, MsvrParams};
use crate::search::{
    Method, Observer, Point, Search, SearchError, SearchResult, SearchSpace, SearchStop,
};

/// Errors of a tuning run.
#[derive(Debug, thiserror::Error)]
pub enum TuneError {
    #[error(transparent)]
    Search(#[from] SearchError),
    #[error(transparent)]
    Folds(#[from] FitnessError),
    #[error(transparent)]
    Msvr(#[from] crate::model::msvr::MsvrError),
    #[error("prediction intervals: {0}")]
    Widening(String),
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

/// Rows whose nearest neighbour sets σ's lower bound (evenly spaced; all rows when fewer).
const NN_SAMPLE: usize = 2000;

/// The box for a dataset (see the module docs).
pub fn space_for(data: &Dataset) -> SearchSpace {
    let scaled = MinMaxScaler::fit(&data.inputs).transform(&data.inputs);
    let n = scaled.rows();
    // The nearest neighbour of up to NN_SAMPLE evenly spaced rows among all rows: O(n) work.
    let mut nearest: Vec<f64> = crate::data::evenly_spaced(n, NN_SAMPLE)
        .into_par_iter()
        .map(|j| {
            let xj = scaled.row(j);
            scaled
                .iter_rows()
                .map(|xi| kernel::squared_distance(xi, xj))
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
    let ranges = [
        (0.1, 1e7),
        (1e-4 * spread, 0.5 * spread),
        (0.5 * median_nn, 2.0 * d.sqrt()),
    ];
    Hyper::AXES.into_iter().zip(ranges).collect()
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
/// update the factor ([`crate::model::msvr::irwls::SolverOptions::factor_updates`]).
pub fn solver_for(method: &Method, solver: &MsvrParams) -> MsvrParams {
    MsvrParams {
        factor_updates: !matches!(method, Method::AcoPaper(_)),
        ..*solver
    }
}

/// Hyper-parameters held at given values while a search chooses the others (their axis of the
/// box shrinks to the value; the paper's colony, which has no box, ignores them).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pinned {
    pub c: Option<f64>,
    pub epsilon: Option<f64>,
    pub sigma: Option<f64>,
    /// The loss, when it was given (not a default).
    pub loss: Option<crate::model::msvr::Loss>,
}

impl Pinned {
    /// (name, value) of each pinned parameter.
    pub fn values(&self) -> impl Iterator<Item = (&'static str, f64)> {
        Hyper::AXES
            .into_iter()
            .zip([self.c, self.epsilon, self.sigma])
            .filter_map(|(name, v)| Some((name, v?)))
    }

    /// The box with each pinned axis shrunk to its value.
    fn apply(&self, space: SearchSpace) -> SearchSpace {
        self.values()
            .fold(space, |space, (name, v)| space.with(name, (v, v)))
    }
}

/// What [`run`] returns: the summary, the full result, the work counters and the best tuple's
/// held-out predictions.
pub type Ran = (SearchSummary, SearchResult, Counters, Option<HeldOutRows>);

/// Runs `method` on `data` with the given fitness over the box's `axes` (the others held at
/// `solver`'s values), the [`Pinned`] hyper-parameters held; returns the summary, the full result, the work counters and the best tuple's held-out
/// predictions (for intervals; `None` with the training fitness).
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
    axes: &[&str],
    pinned: &Pinned,
    observer: &mut dyn Observer,
    interrupt: &AtomicBool,
) -> Result<Ran, TuneError> {
    crate::model::msvr::check_memory(data.rows(), solver.basis)?;
    let labels = folds.labels.as_deref();
    let scorer = Fitness::new(data, fitness, seed, labels, &solver_for(method, solver))?;
    let held = solver.hyper();
    let objective = |batch: &[Point], bar: f64| {
        let batch: Vec<Hyper> = batch.iter().map(|p| held.at(p)).collect();
        scorer.evaluate(&batch, bar)
    };
    let space = method.uses_space().then(|| {
        let full = pinned.apply(space_for(data));
        full.iter()
            .filter(|(name, _)| axes.contains(name))
            .collect::<SearchSpace>()
    });
    // The paper's colony has its own digit box and ignores this one.
    let searched = space.clone().unwrap_or_default();
    let result = method.run(&searched, &objective, observer, interrupt)?;
    let best = held.at(&result.best);
    let counters = scorer.counters();
    let summary = SearchSummary {
        method: *method,
        fitness,
        folds: matches!(fitness, FitnessKind::Cv { .. }).then(|| folds.choice.clone()),
        fold_seed: seed,
        space,
        best,
        best_fitness: result.best_fitness,
        iterations: result.history.len(),
        stop: result.stop,
        evaluations: counters.evaluations,
        fits: counters.fits,
        memo_hits: counters.memo_hits,
        raced: counters.raced,
    };
    let held_out = scorer.held_out_of(&best);
    Ok((summary, result, counters, held_out))
}

/// The cross-validated fitness of `params` itself, on the folds of `folds`, and its held-out
/// predictions (`None` with the training fitness).
///
/// # Errors
/// [`TuneError`] when the folds cannot be cut.
pub fn cross_validate(
    data: &Dataset,
    fitness: FitnessKind,
    folds: &FoldPlan,
    params: &MsvrParams,
) -> Result<(f64, Option<HeldOutRows>), TuneError> {
    let scorer = scorer(data, fitness, folds, params)?;
    let score = scorer.evaluate(&[params.hyper()], f64::INFINITY)[0];
    Ok((score, scorer.held_out_of(&params.hyper())))
}

/// The cross-validated fitness of each of `hypers` with `solver`'s other controls, on the
/// folds of `folds`: one scorer for them all, so the folds, the distances and each σ's kernel
/// are made once and the candidates scored in parallel.
///
/// # Errors
/// [`TuneError`] when the folds cannot be cut.
pub fn cross_validate_each(
    data: &Dataset,
    fitness: FitnessKind,
    folds: &FoldPlan,
    solver: &MsvrParams,
    hypers: &[Hyper],
) -> Result<Vec<f64>, TuneError> {
    Ok(scorer(data, fitness, folds, solver)?.evaluate(hypers, f64::INFINITY))
}

/// What scores `solver`'s candidates on `data` by `fitness` over the folds of `folds`.
fn scorer(
    data: &Dataset,
    fitness: FitnessKind,
    folds: &FoldPlan,
    solver: &MsvrParams,
) -> Result<Fitness, TuneError> {
    crate::model::msvr::check_memory(data.rows(), solver.basis)?;
    Ok(Fitness::new(
        data,
        fitness,
        crate::DEFAULT_SEED,
        folds.labels.as_deref(),
        solver,
    )?)
}

/// Held-out predictions of `params` on `data`: every row predicted by the model fitted without
/// the row's fold (the folds of `folds`, their groups dealt as `dealing` says, shuffled with
/// `seed` as a search with that seed shuffles them). One fit per fold: what intervals cost
/// when no search made them.
///
/// # Errors
/// [`TuneError`] when the folds cannot be cut or a fit fails.
pub fn held_out_predictions(
    data: &Dataset,
    seed: u64,
    folds: &FoldPlan,
    dealing: Dealing,
    params: &MsvrParams,
) -> Result<HeldOutRows, TuneError> {
    crate::model::msvr::check_memory(data.rows(), params.basis)?;
    let scorer = Fitness::dealt(
        data,
        FitnessKind::Cv { folds: folds.folds },
        seed,
        folds.labels.as_deref(),
        dealing,
        params,
    )?;
    Ok(scorer.held_out_predictions(&params.hyper())?)
}

/// Conformal prediction intervals from held-out predictions of `data`'s rows (cut by `folds`,
/// their groups dealt as `dealing` says), widening off the training rows with the kernel and
/// C of `params` (its centres chosen with `seed`).
///
/// # Errors
/// [`TuneError`] when the folds give no widening.
pub fn intervals(
    data: &Dataset,
    folds: &FoldPlan,
    dealing: Dealing,
    seed: u64,
    params: &MsvrParams,
    held_out: &HeldOutRows,
) -> Result<Intervals, TuneError> {
    let predicted =
        crate::model::msvr::to_columns(data.outputs.names.clone(), held_out.predicted.as_ref());
    let mut choice = folds.choice.clone();
    if dealing == Dealing::Consecutive {
        choice.reason += "; for the intervals, each fold a block of consecutive runs";
    }
    let labels = folds.labels.as_deref();
    let h = params.hyper();
    let widening = Widening::calibrate(&data.inputs, &held_out.fold_of, h.sigma, h.c, seed)
        .map_err(TuneError::Widening)?;
    Ok(Intervals::calibrate(
        &data.outputs,
        &predicted,
        labels,
        choice,
        Some(widening),
    ))
}

/// How [`choose`] picks a fit's (C, ε, σ) and basis on rows scored by cross-validation.
pub struct Choice<'a> {
    /// The rows candidates are scored on.
    pub rows: &'a Dataset,
    pub fitness: FitnessKind,
    /// How cross-validation cuts `rows`.
    pub folds: &'a FoldPlan,
    /// The search (its budget set) and the seed of its folds; `None` keeps the solver's
    /// (C, ε, σ).
    pub search: Option<(Method, u64)>,
    /// The axes the search moves (a family's); the others stay at the solver's values.
    pub axes: &'a [&'a str],
    /// Hyper-parameters the search holds at the solver's values.
    pub pinned: Pinned,
    /// `auto`'s growth of a reduced starting basis ([`grow_basis`]) at the parameters chosen.
    pub grow: bool,
    /// Whether the cross-validated fitness of given parameters is wanted (a search's is its
    /// best, always known).
    pub score: bool,
}

/// What [`choose`] chose.
pub struct Chosen {
    /// The solver with the chosen (C, ε, σ) and basis.
    pub params: MsvrParams,
    pub search: Option<Searched>,
    pub basis: BasisDecision,
    /// The cross-validated fitness of `params`, when measured.
    pub fitness: Option<f64>,
    /// The held-out predictions of `params` on the scored rows, when the choice made them.
    pub held_out: Option<HeldOutRows>,
}

/// What a search did.
pub struct Searched {
    pub summary: SearchSummary,
    pub counters: Counters,
    pub history: Vec<crate::search::IterationRecord>,
    /// The search's time with the basis' growth after it (s).
    pub seconds: f64,
}

/// The parameters of a fit, as every front end chooses them: `choice`'s search (when there is
/// one) from `solver`, started on the `initial` basis, then `auto`'s growth of that basis at
/// the parameters found. The search reports its iterations to `observer` and stops early (with
/// the best so far) when `interrupt` is set.
///
/// # Errors
/// [`TuneError`]: the search's own, or folds that cannot be cut.
pub fn choose(
    choice: &Choice,
    solver: &MsvrParams,
    initial: BasisDecision,
    observer: &mut dyn Observer,
    interrupt: &AtomicBool,
) -> Result<Chosen, TuneError> {
    let started = std::time::Instant::now();
    let solver = solver.basis(initial.basis);
    let Choice {
        rows,
        fitness,
        folds,
        ..
    } = *choice;
    let grow = |basis: BasisDecision, params: &MsvrParams| {
        if choice.grow {
            grow_basis(basis, rows, fitness, folds, params, interrupt)
        } else {
            Ok((basis, None))
        }
    };
    let Some((method, seed)) = &choice.search else {
        if !choice.grow && !choice.score {
            return Ok(Chosen {
                params: solver,
                search: None,
                basis: initial,
                fitness: None,
                held_out: None,
            });
        }
        let (basis, grown) = grow(initial, &solver)?;
        let params = solver.basis(basis.basis);
        let (fitness, held_out) = match (grown_fitness(&basis), grown) {
            (Some(f), grown) => (f, grown),
            (None, _) => cross_validate(rows, fitness, folds, &params)?,
        };
        return Ok(Chosen {
            params,
            search: None,
            basis,
            fitness: Some(fitness),
            held_out,
        });
    };
    let (summary, result, counters, searched) = run(
        method,
        rows,
        fitness,
        *seed,
        folds,
        &solver,
        choice.axes,
        &choice.pinned,
        observer,
        interrupt,
    )?;
    let params = solver_for(method, &solver).with_hyper(summary.best);
    let (basis, grown) = grow(initial, &params)?;
    Ok(Chosen {
        params: params.basis(basis.basis),
        fitness: Some(grown_fitness(&basis).unwrap_or(summary.best_fitness)),
        held_out: if basis.tried.is_empty() {
            searched
        } else {
            grown
        },
        search: Some(Searched {
            summary,
            counters,
            history: result.history,
            seconds: started.elapsed().as_secs_f64(),
        }),
        basis,
    })
}

/// The cross-validated fitness [`grow_basis`] measured for the basis it chose.
fn grown_fitness(decision: &BasisDecision) -> Option<f64> {
    let Basis::Reduced { centres, .. } = decision.basis else {
        return None;
    };
    decision
        .tried
        .iter()
        .find(|t| t.centres == centres)
        .map(|t| t.fitness)
}

/// A search scores its candidates on at most this many evenly spaced rows of the training data
/// (the model is then fitted on every row). A long log's consecutive rows are near copies:
/// decimating it keeps its coverage of the inputs, and the search's time falls with its rows.
/// Measured against 8000 (docs/benchmarks.md), the same budget and seeds: on a 7,620-row
/// dynamic session (30 Hz) the held-out error of the history model went 0.498 → 0.455 mm and
/// the pair of default models took 55 s instead of 130; on 41 000 rows of a generated
/// pneumatic arm (12 Hz), 0.0569 → 0.0570 mm in 30 s instead of 93. The real datasets (780 and
/// 1096 training rows) are below it.
pub const SEARCH_ROWS: usize = 3000;
