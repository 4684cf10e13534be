//! The fitness of a hyper-parameter tuple: MAE of MSVR in output units, cross-validated or on
//! the training data.
//!
//! - `cv` (default): k-fold cross-validation. Rows are shuffled once with the seed and cut into
//!   k folds of near-equal size; each fold is predicted by a model fitted on the others, and the
//!   fitness is the MAE over every held-out prediction.
//! - `train` (the paper's choice, for reproduction): fitted and scored on all rows. It rewards
//!   over-fitting — it falls towards 0 as σ → 0, C → ∞, ε → 0.
//!
//! Inputs are min-max scaled with the whole training set's range (the range of the experiment's
//! design, not information about the outputs), so every fold's kernel is a block of one kernel.
//!
//! Speed: the squared distances of every fold are computed once; the fold kernels of a σ are
//! cached (a converging colony keeps revisiting the same σ); every evaluated tuple is memoised,
//! so a repeated path costs nothing; candidates run in parallel (rayon), each fit single-threaded.
//! Fits inside the search stop at a relative decrease of the objective of [`SEARCH_TOL`] (or the
//! looser solver tolerance given): a fitness needs a few significant digits, not eight, and at
//! large C the solver's last digits cost the most iterations. The chosen model is then fitted to
//! the full tolerance.
//! Racing: a candidate's folds are fitted in turn, and once the absolute errors summed so far,
//! divided by every held-out prediction to come, reach the search's bar (the worst fitness in
//! ACO_R's archive, the grid's best; +∞ for the paper's colony, whose history stays the
//! paper's), the candidate cannot matter (the remaining folds only add) and stops there, scored
//! with that lower bound. The eventual best is therefore never raced out, and the bar is fixed
//! for a whole batch, so the result does not depend on thread timing.
//! Fits are not warm-started from neighbouring tuples: with parallel evaluation the neighbour
//! found would depend on thread timing, and a seeded search must give the same result every run.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use faer::{Mat, Par};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::folds::{assign_folds, Dealing};
use crate::data::{Columns, Dataset};
use crate::model::msvr::basis::{self, NystromMap};
use crate::model::msvr::irwls::StopReason;
use crate::model::msvr::kernel::{self, rbf_from_squared};
use crate::model::msvr::reduced::{self, FeatureRows, ReducedProblem};
use crate::model::msvr::{
    Basis, Hyper, MinMaxScaler, MsvrError, MsvrParams, RowWeights, ValidMsvrParams,
};

/// How candidates are scored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FitnessKind {
    /// k-fold cross-validated MAE.
    Cv { folds: usize },
    /// MAE on the training data itself.
    Train,
}

impl std::fmt::Display for FitnessKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FitnessKind::Cv { folds } => write!(f, "{folds}-fold cross-validated MAE"),
            FitnessKind::Train => write!(f, "training MAE"),
        }
    }
}

/// Errors of setting up the fitness.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitnessError {
    #[error("{folds} folds: cross-validation needs 2 or more folds of 2 rows or more each, which {rows} rows in {groups} groups do not give ({})", if *folds < 2 { "give 2 folds or more".to_string() } else { format!("give more rows, or at most {} folds", groups.min(&(rows / 2))) })]
    BadFolds {
        folds: usize,
        rows: usize,
        groups: usize,
    },
}

/// One fold: its training and held-out rows, their targets, and their weights when the rows
/// carry weights (the held-out rows' for the reduced basis' Gram matrices). A fold's held-out
/// error counts every row once, as a user's cross-validation scores it: the weights are the
/// fit's, not the score's.
struct Fold {
    train: Vec<usize>,
    held_out: Vec<usize>,
    y_train: Mat<f64>,
    y_held_out: Mat<f64>,
    w_train: Option<Vec<f64>>,
    w_held_out: Option<Vec<f64>>,
}

/// What every fold needs of one σ: the exact basis's kernel of every row with every row (each
/// fold takes its training and held-out rows from it: one exponential per pair of rows, not
/// one per pair in each fold), or the reduced basis's features of every row and Gram matrices.
enum PerSigma {
    Exact(Mat<f64>),
    /// Features of every row and each fold's Φ̃ᵀΦ̃ over its training rows (all rows' less the
    /// held-out rows': two passes over the rows instead of one per fold).
    Reduced {
        features: Mat<f64>,
        grams: Vec<Mat<f64>>,
    },
}

/// Every row's prediction by the model fitted without its fold, and each row's fold: the
/// out-of-fold predictions of one tuple (for conformal intervals and paired fold differences).
#[derive(Clone, Debug)]
pub struct HeldOutRows {
    /// Rows × outputs, in the data's row order.
    pub predicted: Mat<f64>,
    /// Each row's fold.
    pub fold_of: Vec<usize>,
}

impl HeldOutRows {
    /// Each fold's MAE against `data`'s outputs (the rows predicted), and each fold's held-out
    /// values.
    pub fn fold_maes(&self, data: &Dataset) -> (Vec<f64>, Vec<usize>) {
        let folds = self.fold_of.iter().max().map_or(0, |f| f + 1);
        let (mut sum, mut count) = (vec![0.0; folds], vec![0usize; folds]);
        for (i, y) in data.outputs.iter_rows().enumerate() {
            let fold = self.fold_of[i];
            for (j, v) in y.iter().enumerate() {
                sum[fold] += (v - self.predicted[(i, j)]).abs();
                count[fold] += 1;
            }
        }
        let maes = sum.iter().zip(&count).map(|(s, &c)| s / c.max(1) as f64);
        (maes.collect(), count)
    }
}

/// Counters of the work done, for the search report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Counters {
    /// Distinct tuples evaluated (each one MSVR fit per fold).
    pub evaluations: usize,
    /// MSVR fits run.
    pub fits: usize,
    /// Requests answered from the memo of evaluated tuples.
    pub memo_hits: usize,
    /// Fold kernels taken from the per-σ cache.
    pub kernel_hits: usize,
    /// Candidates stopped before their last fold by racing.
    pub raced: usize,
}

/// Scores (C, ε, σ) tuples on one dataset.
pub struct Fitness {
    kind: FitnessKind,
    folds: Vec<Fold>,
    /// Held-out predictions over all folds (rows × outputs): the MAE's divisor.
    held_out_values: usize,
    /// Solver controls (tol, max_iter) of every fit.
    solver: MsvrParams,
    /// What the kernels of every σ come from.
    expansion: Expansion,
    /// Every row's weight, when the rows carry weights.
    weights: Option<Vec<f64>>,
    memo: Mutex<HashMap<[u64; 3], f64>>,
    kernels: Mutex<HashMap<u64, Arc<PerSigma>>>,
    kernel_cache_entries: usize,
    evaluations: AtomicUsize,
    fits: AtomicUsize,
    memo_hits: AtomicUsize,
    kernel_hits: AtomicUsize,
    raced: AtomicUsize,
    /// Candidates' fits stop at a stop asked after this ([`crate::control`]).
    since: crate::control::Since,
    /// The held-out predictions of the best candidate scored on every fold (ties: the first
    /// by its key), kept so that intervals cost no further fit.
    best: Mutex<Option<Best>>,
}

/// A candidate's held-out predictions (rows × outputs, in the data's row order).
struct Best {
    fitness: f64,
    key: [u64; 3],
    predicted: Mat<f64>,
}

/// A candidate's memo key: its three numbers' bits.
fn key(h: &Hyper) -> [u64; 3] {
    [h.c.to_bits(), h.epsilon.to_bits(), h.sigma.to_bits()]
}

/// What [`Fitness`] computes the kernels of a σ from.
enum Expansion {
    /// The squared distances between every two rows (scaled inputs).
    Exact { d2: Mat<f64> },
    /// The scaled inputs and the centres k-means++ chose among them.
    Reduced { scaled: Columns, centres: Columns },
}

/// Relative objective tolerance of the fits that score candidates.
pub const SEARCH_TOL: f64 = 1e-6;

/// Memory allowed for cached fold kernels (bytes).
const KERNEL_CACHE_BYTES: usize = 1 << 30;

impl Fitness {
    /// Prepares the folds of `data` for `cv`: rows, or whole groups of rows when `groups` gives
    /// each row's group label, shuffled with `seed`.
    ///
    /// # Errors
    /// [`FitnessError::BadFolds`] when there are fewer than 2 folds, fewer groups than folds, or
    /// a fold would hold fewer than 2 rows.
    pub fn new(
        data: &Dataset,
        kind: FitnessKind,
        seed: u64,
        groups: Option<&[f64]>,
        solver: &MsvrParams,
    ) -> Result<Self, FitnessError> {
        Self::dealt(data, kind, seed, groups, Dealing::Shuffled, solver)
    }

    /// [`Fitness::new`] with the groups dealt to the folds as `dealing` says.
    ///
    /// # Errors
    /// As [`Fitness::new`].
    pub fn dealt(
        data: &Dataset,
        kind: FitnessKind,
        seed: u64,
        groups: Option<&[f64]>,
        dealing: Dealing,
        solver: &MsvrParams,
    ) -> Result<Self, FitnessError> {
        let n = data.rows();
        let scaled = MinMaxScaler::fit(&data.inputs).transform(&data.inputs);
        let splits: Vec<(Vec<usize>, Vec<usize>)> = match kind {
            FitnessKind::Train => vec![((0..n).collect(), (0..n).collect())],
            FitnessKind::Cv { folds } => {
                let fold_of = assign_folds(n, folds, seed, groups, dealing)?;
                (0..folds)
                    .map(|f| (0..n).partition(|&i| fold_of[i] != f))
                    .collect()
            }
        };
        let folds: Vec<Fold> = splits
            .into_par_iter()
            .map(|(train, held_out)| {
                let targets = |rows: &[usize]| {
                    Mat::from_fn(rows.len(), data.outputs.width(), |r, j| {
                        data.outputs.row(rows[r])[j]
                    })
                };
                Fold {
                    y_train: targets(&train),
                    y_held_out: targets(&held_out),
                    w_train: data.weights_of(&train),
                    w_held_out: data.weights_of(&held_out),
                    train,
                    held_out,
                }
            })
            .collect();
        let per_sigma: usize = match solver.basis {
            Basis::Exact => 8 * n * n,
            Basis::Reduced { centres, .. } => 8 * n * centres.min(n),
        };
        let expansion = match solver.basis {
            Basis::Exact => Expansion::Exact {
                d2: kernel::squared_distances(&scaled, &scaled),
            },
            Basis::Reduced { centres, seed } => {
                let chosen = basis::kmeans_pp(&scaled, centres, seed);
                let centres = scaled.select_rows(&chosen);
                Expansion::Reduced { scaled, centres }
            }
        };
        let held_out_values = folds
            .iter()
            .map(|f| f.y_held_out.nrows() * f.y_held_out.ncols())
            .sum();
        Ok(Fitness {
            since: crate::control::Since::now(),
            kind,
            folds,
            held_out_values,
            solver: MsvrParams {
                tol: solver.tol.max(SEARCH_TOL),
                ..*solver
            },
            expansion,
            weights: data.weights.clone(),
            memo: Mutex::new(HashMap::new()),
            kernels: Mutex::new(HashMap::new()),
            kernel_cache_entries: (KERNEL_CACHE_BYTES / per_sigma.max(1)).max(1),
            evaluations: AtomicUsize::new(0),
            fits: AtomicUsize::new(0),
            memo_hits: AtomicUsize::new(0),
            kernel_hits: AtomicUsize::new(0),
            raced: AtomicUsize::new(0),
            best: Mutex::new(None),
        })
    }

    pub fn kind(&self) -> FitnessKind {
        self.kind
    }

    pub fn counters(&self) -> Counters {
        Counters {
            evaluations: self.evaluations.load(Ordering::Relaxed),
            fits: self.fits.load(Ordering::Relaxed),
            memo_hits: self.memo_hits.load(Ordering::Relaxed),
            kernel_hits: self.kernel_hits.load(Ordering::Relaxed),
            raced: self.raced.load(Ordering::Relaxed),
        }
    }

    /// Fitness of every candidate, in order, evaluating new ones in parallel; a new one whose
    /// fitness reaches `bar` may stop there with a lower bound ≥ `bar` (racing, see the module
    /// docs). A candidate that breaks [`Hyper::check`] scores +∞.
    pub fn evaluate(&self, batch: &[Hyper], bar: f64) -> Vec<f64> {
        let is_valid = |h: &Hyper| h.check().is_ok();
        let mut fresh: Vec<Hyper> = Vec::new();
        {
            let memo = self.memo.lock().expect("memo lock");
            for h in batch {
                if is_valid(h)
                    && !memo.contains_key(&key(h))
                    && !fresh.iter().any(|f| key(f) == key(h))
                {
                    fresh.push(*h);
                }
            }
        }
        let scores: Vec<f64> = fresh.par_iter().map(|h| self.score(h, bar)).collect();
        let mut memo = self.memo.lock().expect("memo lock");
        for (h, s) in fresh.iter().zip(&scores) {
            memo.insert(key(h), *s);
        }
        self.evaluations.fetch_add(fresh.len(), Ordering::Relaxed);
        let valid = batch.iter().filter(|h| is_valid(h)).count();
        self.memo_hits
            .fetch_add(valid - fresh.len(), Ordering::Relaxed);
        batch
            .iter()
            .map(|h| {
                if is_valid(h) {
                    memo[&key(h)]
                } else {
                    f64::INFINITY
                }
            })
            .collect()
    }

    /// MAE over every held-out prediction for one tuple, or a lower bound of it that is at
    /// least `bar` once one is reached (racing). A tuple scored on every fold that beats the
    /// best so far leaves its held-out predictions ([`Fitness::held_out_of`]).
    fn score(&self, h: &Hyper, bar: f64) -> f64 {
        let per_sigma = self.per_sigma(h.sigma);
        let Ok(params) = self.solver.with_hyper(*h).check() else {
            return f64::INFINITY;
        };
        let all = self.held_out_values as f64;
        let mut abs_sum = 0.0;
        let mut predicted = Mat::zeros(self.rows(), self.folds[0].y_held_out.ncols());
        for (k, fold) in self.folds.iter().enumerate() {
            if k > 0 && abs_sum / all >= bar {
                self.raced.fetch_add(1, Ordering::Relaxed);
                return abs_sum / all;
            }
            let Ok((pred, bias)) = self.fold_prediction(&per_sigma, k, &params, self.since) else {
                return f64::INFINITY;
            };
            let y = &fold.y_held_out;
            for (r, &row) in fold.held_out.iter().enumerate() {
                for j in 0..y.ncols() {
                    abs_sum += (y[(r, j)] - pred[(r, j)] - bias[j]).abs();
                    predicted[(row, j)] = pred[(r, j)] + bias[j];
                }
            }
        }
        let fitness = abs_sum / all;
        let mut best = self.best.lock().expect("best lock");
        let better = best
            .as_ref()
            .is_none_or(|b| fitness < b.fitness || (fitness == b.fitness && key(h) < b.key));
        if better && fitness.is_finite() && self.kind != FitnessKind::Train {
            *best = Some(Best {
                fitness,
                key: key(h),
                predicted,
            });
        }
        fitness
    }

    /// The held-out predictions of `h` when it is the best tuple scored on every fold so far
    /// (what [`Fitness::held_out_predictions`] would compute, without its fits).
    pub fn held_out_of(&self, h: &Hyper) -> Option<HeldOutRows> {
        let best = self.best.lock().expect("best lock");
        best.as_ref()
            .filter(|b| b.key == key(h))
            .map(|b| HeldOutRows {
                predicted: b.predicted.clone(),
                fold_of: self.fold_of(),
            })
    }

    /// Each row's fold.
    fn fold_of(&self) -> Vec<usize> {
        let mut fold_of = vec![0; self.rows()];
        for (k, fold) in self.folds.iter().enumerate() {
            for &row in &fold.held_out {
                fold_of[row] = k;
            }
        }
        fold_of
    }

    /// Rows over every fold's held-out rows (each row once; with the training fitness, all).
    fn rows(&self) -> usize {
        self.folds.iter().map(|f| f.held_out.len()).sum()
    }

    /// Every row's prediction by the model fitted without its fold (rows × outputs, in the
    /// data's row order): the out-of-fold predictions of one tuple, for conformal intervals.
    /// With the training fitness a row's "fold" is all rows, itself included. These fits run
    /// after a search a stop ended; a stop asked after they begin ends them.
    ///
    /// # Errors
    /// [`MsvrError`]: the tuple's parameters, or a failed solve.
    pub fn held_out_predictions(&self, h: &Hyper) -> Result<HeldOutRows, MsvrError> {
        let per_sigma = self.per_sigma(h.sigma);
        let params = self.solver.with_hyper(*h).check()?;
        let mut out = Mat::zeros(self.rows(), self.folds[0].y_held_out.ncols());
        let since = crate::control::Since::now();
        for (k, fold) in self.folds.iter().enumerate() {
            let (pred, bias) = self.fold_prediction(&per_sigma, k, &params, since)?;
            for (r, &row) in fold.held_out.iter().enumerate() {
                for j in 0..pred.ncols() {
                    out[(row, j)] = pred[(r, j)] + bias[j];
                }
            }
        }
        Ok(HeldOutRows {
            predicted: out,
            fold_of: self.fold_of(),
        })
    }

    /// Fold `k`'s held-out predictions by the model fitted on its training rows, and the bias
    /// they leave out; a fit stopped (a stop asked after `since`) is an error, not a
    /// prediction.
    fn fold_prediction(
        &self,
        per_sigma: &PerSigma,
        k: usize,
        params: &ValidMsvrParams,
        since: crate::control::Since,
    ) -> Result<(Mat<f64>, Vec<f64>), MsvrError> {
        let fold = &self.folds[k];
        self.fits.fetch_add(1, Ordering::Relaxed);
        let (pred, bias) = match per_sigma {
            PerSigma::Exact(kernel) => {
                let (train, held_out) = (&fold.train, &fold.held_out);
                let k_train = Mat::from_fn(train.len(), train.len(), |r, c| {
                    kernel[(train[r], train[c])]
                });
                let k_held_out = Mat::from_fn(held_out.len(), train.len(), |r, c| {
                    kernel[(held_out[r], train[c])]
                });
                let (y, w) = (fold.y_train.as_ref(), RowWeights(fold.w_train.as_deref()));
                let sol = params.solve(k_train.as_ref(), y, w, Par::Seq, since)?;
                if sol.stop == StopReason::Interrupted {
                    return Err(MsvrError::Interrupted);
                }
                (k_held_out * &sol.beta, sol.bias)
            }
            PerSigma::Reduced { features, grams } => {
                let problem = ReducedProblem {
                    features: FeatureRows::Stored {
                        all: features.as_ref(),
                        rows: Some(&fold.train),
                    },
                    targets: fold.y_train.as_ref(),
                    tube: params.params().tube(),
                    weights: RowWeights(fold.w_train.as_deref()),
                    gram: Some(grams[k].as_ref()),
                };
                let p = params.params();
                let sol = reduced::solve(&problem, p.tol, p.max_iter, Par::Seq, since)?;
                if sol.stop == StopReason::Interrupted {
                    return Err(MsvrError::Interrupted);
                }
                let held_out = Mat::from_fn(fold.held_out.len(), features.ncols(), |r, j| {
                    features[(fold.held_out[r], j)]
                });
                (&held_out * &sol.w, sol.bias)
            }
        };
        Ok((pred, bias))
    }

    /// Centres a reduced basis keeps at σ (0 for the exact basis), from the features the
    /// folds use (cached when σ was scored).
    pub fn kept_centres(&self, sigma: f64) -> usize {
        match &*self.per_sigma(sigma) {
            PerSigma::Exact(_) => 0,
            PerSigma::Reduced { features, .. } => features.ncols(),
        }
    }

    /// What the folds need of σ, from the cache or computed (and cached).
    fn per_sigma(&self, sigma: f64) -> Arc<PerSigma> {
        if let Some(k) = self
            .kernels
            .lock()
            .expect("kernel lock")
            .get(&sigma.to_bits())
        {
            self.kernel_hits.fetch_add(1, Ordering::Relaxed);
            return Arc::clone(k);
        }
        let computed = Arc::new(match &self.expansion {
            Expansion::Exact { d2 } => PerSigma::Exact(rbf_from_squared(d2.as_ref(), sigma)),
            Expansion::Reduced { scaled, centres } => {
                let features = NystromMap::new(centres, sigma).features(scaled);
                let gram = |rows: Option<&[usize]>, weights: &Option<Vec<f64>>| {
                    let all = features.as_ref();
                    let weights = RowWeights(weights.as_deref());
                    FeatureRows::Stored { all, rows }.gram(weights, Par::rayon(0))
                };
                let all = gram(None, &self.weights);
                let grams = self
                    .folds
                    .iter()
                    .map(|f| {
                        if f.held_out.len() == f.train.len() {
                            return gram(Some(&f.train), &f.w_train); // the training fitness
                        }
                        &all - gram(Some(&f.held_out), &f.w_held_out)
                    })
                    .collect();
                PerSigma::Reduced { features, grams }
            }
        });
        let mut cache = self.kernels.lock().expect("kernel lock");
        if cache.len() >= self.kernel_cache_entries {
            cache.clear();
        }
        cache.insert(sigma.to_bits(), Arc::clone(&computed));
        computed
    }
}
