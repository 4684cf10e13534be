//! A radius that widens where the inputs are farther from the training rows than the held-out
//! rows usually were.
//!
//! A constant radius is calibrated on held-out rows, and covers new rows at its level when
//! they are like those. A time series' later block is often not: on the tendon arm's rows
//! 200-399 the inputs lie where the training rows are thin, and a model's error there is far
//! beyond any fold's (the constant 90 % radius covered 39 % of them). The spread s(x) of a
//! Gaussian process with the model's kernel width σ and noise variance λ = 1/(2C) (the ridge
//! of the squared loss at the model's C), conditioned on the training rows, says how far x is
//! from them: s² = 1 − k(x)ᵀ (K + λI)⁻¹ k(x), near √λ at a training row, 1 far from all.
//!
//! The widening factor is d(x) = max(1, s(x) / s_ref), with s_ref the spread of the held-out
//! rows at [`REFERENCE_SHARE`] (each held-out row's spread given the training rows of its
//! fold). The scores the radius is calibrated on are the held-out errors divided by d, and the
//! radius at x is that radius times d(x): the constant radius wherever x is as near the
//! training rows as nine held-out rows in ten were, wider where it is not. Split conformal
//! prediction's guarantee holds for any such normalisation fixed before the held-out errors
//! are seen (Lei et al. 2018, "locally weighted" conformal prediction).
//!
//! The process is conditioned on at most [`CENTRES`] rows, chosen by k-means++ seeding (the
//! reduced basis' [`kmeans_pp`], seeded): all of them for smaller sets, a spread-out subset of
//! larger ones, so a model file stays small and its spread costs O(m²) per row. Each fold's
//! held-out spread is conditioned on centres chosen the same way among the fold's training
//! rows, the model file's on those among all of them.
//!
//! Measured (`scripts/bench_coverage.py`, docs/benchmarks.md): see "A radius that widens off
//! the training rows".

use faer::linalg::triangular_solve;
use faer::{Mat, Side};
use serde::{Deserialize, Serialize};

use crate::data::Columns;
use crate::model::msvr::basis::kmeans_pp;
use crate::model::msvr::kernel;
use crate::model::msvr::MinMaxScaler;

/// The most rows the spread is conditioned on.
pub const CENTRES: usize = 1000;

/// The share of held-out rows whose spread the radius is not widened at: s_ref is their
/// spread's quantile at this share.
pub const REFERENCE_SHARE: f64 = 0.9;

/// The least noise variance: keeps K + λI positive definite when C is very large.
const MIN_RIDGE: f64 = 1e-10;

/// What widens the radius at an input, as the model file keeps it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Widening {
    /// The scaling of the inputs (the model's inputs, its features with history) to [0, 1].
    pub scaler: MinMaxScaler,
    /// The kernel's width σ, on the scaled inputs.
    pub sigma: f64,
    /// The process' noise variance λ.
    pub ridge: f64,
    /// s_ref: the held-out rows' spread at [`REFERENCE_SHARE`].
    pub reference: f64,
    /// The rows the spread is conditioned on, scaled.
    pub centres: Vec<Vec<f64>>,
}

/// The spread of a Gaussian process conditioned on a set of centres.
#[derive(Clone, Debug)]
struct Spread {
    centres: Columns,
    sigma: f64,
    /// The Cholesky factor of K + λI among the centres.
    factor: faer::linalg::solvers::Llt<f64>,
}

impl Spread {
    fn new(centres: Columns, sigma: f64, ridge: f64) -> Result<Spread, String> {
        let mut k = kernel::rbf_gram(&centres, sigma);
        for i in 0..k.nrows() {
            k[(i, i)] += ridge.max(MIN_RIDGE);
        }
        let factor = k
            .llt(Side::Lower)
            .map_err(|_| "the centres' kernel is not positive definite".to_string())?;
        Ok(Spread {
            centres,
            sigma,
            factor,
        })
    }

    /// s(x) of every row of `x` (scaled inputs): s² = 1 − ‖L⁻¹ k(x)‖², K + λI = L Lᵀ (one
    /// triangular solve, not the two of (K + λI)⁻¹ k).
    fn of(&self, x: &Columns) -> Vec<f64> {
        let mut k: Mat<f64> = kernel::rbf(&self.centres, x, self.sigma);
        triangular_solve::solve_lower_triangular_in_place(
            self.factor.L(),
            k.as_mut(),
            faer::get_global_parallelism(),
        );
        (0..x.rows())
            .map(|i| (1.0 - k.col(i).squared_norm_l2()).max(1e-24).sqrt())
            .collect()
    }
}

/// Up to [`CENTRES`] rows of `scaled` (seeded k-means++).
fn centres(scaled: &Columns, seed: u64) -> Columns {
    scaled.select_rows(&kmeans_pp(scaled, CENTRES, seed))
}

impl Widening {
    /// Calibrates on the rows of `inputs` (the model's inputs), each held out in the fold
    /// `fold_of` gives it: the widening, and each row's factor d. `sigma` and `c` are the
    /// model's; `seed` chooses the centres.
    ///
    /// # Errors
    /// When a fold's centres give no spread (a kernel matrix not positive definite).
    pub fn calibrate(
        inputs: &Columns,
        fold_of: &[usize],
        sigma: f64,
        c: f64,
        seed: u64,
    ) -> Result<(Widening, Vec<f64>), String> {
        let scaler = MinMaxScaler::fit(inputs);
        let scaled = scaler.transform(inputs);
        let ridge = (0.5 / c).max(MIN_RIDGE);
        let folds = fold_of.iter().max().map_or(0, |f| f + 1);
        let mut spread = vec![0.0; scaled.rows()];
        for f in 0..folds {
            let (train, held): (Vec<usize>, Vec<usize>) =
                (0..scaled.rows()).partition(|&i| fold_of[i] != f);
            let given = Spread::new(centres(&scaled.select_rows(&train), seed), sigma, ridge)?;
            for (&i, s) in held.iter().zip(given.of(&scaled.select_rows(&held))) {
                spread[i] = s;
            }
        }
        let mut sorted = spread.clone();
        sorted.sort_by(f64::total_cmp);
        let at = ((sorted.len() as f64 * REFERENCE_SHARE).ceil() as usize).clamp(1, sorted.len());
        let reference = sorted[at - 1];
        let kept = centres(&scaled, seed);
        let widening = Widening {
            scaler,
            sigma,
            ridge,
            reference,
            centres: kept.iter_rows().map(<[f64]>::to_vec).collect(),
        };
        let factors = spread.iter().map(|s| widening.factor_of(*s)).collect();
        Ok((widening, factors))
    }

    /// What computes d(x) at the model's inputs (a factorisation of the centres' kernel, made
    /// once).
    ///
    /// # Errors
    /// When the centres give no spread (a tampered file).
    pub fn widener(&self) -> Result<Widener, String> {
        let centres = Columns::new(
            (0..self.scaler.min.len())
                .map(|j| format!("x{j}"))
                .collect(),
            self.centres.iter().flatten().copied().collect(),
        );
        Ok(Widener {
            widening: self.clone(),
            spread: Spread::new(centres, self.sigma, self.ridge)?,
        })
    }

    fn factor_of(&self, s: f64) -> f64 {
        (s / self.reference).max(1.0)
    }

    /// Checks what a model file holds, for a model of `inputs` inputs, kernel width `sigma` and
    /// `c`: the widening's σ and noise are the model's (as [`Self::calibrate`] takes them), and
    /// s_ref is a spread, in [1e-12, 1] (s is floored at 1e-12 and at most 1).
    ///
    /// # Errors
    /// What is wrong, naming the field.
    pub fn validate(&self, inputs: usize, sigma: f64, c: f64) -> Result<(), String> {
        let same = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs();
        if !same(self.sigma, sigma) {
            return Err(format!(
                "intervals.widening.sigma is {:e}, the model's σ {sigma:e}: they must be the same",
                self.sigma
            ));
        }
        let ridge = (0.5 / c).max(MIN_RIDGE);
        if !same(self.ridge, ridge) {
            return Err(format!(
                "intervals.widening.ridge is {:e}, not the model's 1/(2C) = {ridge:e}",
                self.ridge
            ));
        }
        if !(1e-12..=1.0).contains(&self.reference) {
            return Err(format!(
                "intervals.widening.reference is {:e}: a spread, between 1e-12 and 1",
                self.reference
            ));
        }
        if self.scaler.min.len() != inputs || self.scaler.max.len() != inputs {
            return Err(format!(
                "intervals.widening.scaler does not have the model's {inputs} inputs"
            ));
        }
        if self
            .scaler
            .min
            .iter()
            .zip(&self.scaler.max)
            .any(|(lo, hi)| !(lo.is_finite() && hi.is_finite() && hi > lo))
        {
            return Err("intervals.widening.scaler: each max must exceed its min".into());
        }
        if self.centres.is_empty()
            || self
                .centres
                .iter()
                .any(|c| c.len() != inputs || c.iter().any(|v| !v.is_finite()))
        {
            return Err(format!(
                "intervals.widening.centres must be rows of {inputs} finite numbers"
            ));
        }
        Ok(())
    }
}

/// d(x) of a model file's widening, ready for rows one at a time or many.
#[derive(Clone, Debug)]
pub struct Widener {
    widening: Widening,
    spread: Spread,
}

impl Widener {
    /// d(x) of every row of `inputs` (the model's inputs, unscaled).
    pub fn factors(&self, inputs: &Columns) -> Vec<f64> {
        let w = &self.widening;
        self.spread
            .of(&w.scaler.transform(inputs))
            .into_iter()
            .map(|s| w.factor_of(s))
            .collect()
    }

    /// d(x) of one row of the model's inputs.
    pub fn factor(&self, x: &[f64]) -> f64 {
        let names = (0..x.len()).map(|j| format!("x{j}")).collect();
        self.factors(&Columns::new(names, x.to_vec()))[0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(values: &[f64]) -> Columns {
        Columns::new(vec!["u".into()], values.to_vec())
    }

    /// The spread is the Gaussian process' posterior standard deviation, computed apart.
    #[test]
    fn the_spread_is_the_posterior_standard_deviation() {
        use nalgebra::{DMatrix, DVector};
        let centres = [0.0, 0.3, 0.35, 0.9];
        let (sigma, ridge) = (0.2, 0.01);
        let spread = Spread::new(line(&centres), sigma, ridge).unwrap();
        let k = |a: f64, b: f64| (-(a - b) * (a - b) / (2.0 * sigma * sigma)).exp();
        let gram = DMatrix::from_fn(4, 4, |i, j| k(centres[i], centres[j]))
            + DMatrix::identity(4, 4) * ridge;
        let inverse = gram.try_inverse().unwrap();
        let at = [0.0, 0.32, 0.6, 2.0];
        for (x, s) in at.iter().zip(spread.of(&line(&at))) {
            let kx = DVector::from_fn(4, |i, _| k(centres[i], *x));
            let expected = (1.0 - (kx.transpose() * &inverse * &kx)[(0, 0)]).sqrt();
            assert!(
                (s - expected).abs() < 1e-12,
                "x = {x}: {s} against {expected}"
            );
        }
    }

    /// Rows among the training rows keep factor 1; a row far from them gets the ratio of
    /// its spread to the reference.
    #[test]
    fn the_radius_widens_only_off_the_training_rows() {
        // Each row twice, its twin in another fold: every held-out row has one at its input.
        let x: Vec<f64> = (0..60).map(|i| f64::from(i % 30) / 29.0).collect();
        let fold_of: Vec<usize> = (0..60).map(|i| i % 7).collect();
        let (widening, factors) = Widening::calibrate(&line(&x), &fold_of, 0.1, 100.0, 1).unwrap();
        // The range's two ends, with neighbours on one side only, are the least covered.
        for (i, d) in factors.iter().enumerate() {
            let end = [0.0, 1.0].contains(&x[i]);
            assert!(if end { *d < 1.5 } else { *d < 1.0 + 1e-9 }, "row {i}: {d}");
        }
        let far = widening.widener().unwrap().factors(&line(&[0.5, 3.0]));
        assert_eq!(far[0], 1.0);
        assert!((far[1] - 1.0 / widening.reference).abs() < 1e-6 && far[1] > 5.0);
        assert!(widening.validate(1, 0.1, 100.0).is_ok());
        assert!(widening.validate(2, 0.1, 100.0).is_err());
        // Not the model's σ or C, or a reference that is no spread: refused.
        assert!(widening.validate(1, 0.2, 100.0).is_err());
        assert!(widening.validate(1, 0.1, 1e308).is_err());
        for reference in [0.0, 1e-320, 1.5, f64::NAN] {
            let tampered = Widening {
                reference,
                ..widening.clone()
            };
            assert!(tampered.validate(1, 0.1, 100.0).is_err(), "{reference}");
        }
    }

    /// Rows a hair apart (a 30 Hz log's repeated commands) and a C so large that the noise is
    /// the floor still give a spread: K + λI stays positive definite.
    #[test]
    fn near_copies_and_a_huge_c_still_give_a_spread() {
        let x: Vec<f64> = (0..400)
            .map(|i| f64::from(i / 2) / 199.0 + 1e-13 * f64::from(i % 2))
            .collect();
        let fold_of: Vec<usize> = (0..400).map(|i| i % 5).collect();
        let (widening, factors) = Widening::calibrate(&line(&x), &fold_of, 0.5, 1e15, 3).unwrap();
        assert_eq!(widening.ridge, MIN_RIDGE);
        assert!(factors.iter().all(|d| d.is_finite() && *d >= 1.0));
        assert!(widening.widener().unwrap().factors(&line(&[5.0]))[0] > 10.0);
    }

    /// Centres are at most [`CENTRES`], and all rows of a smaller set.
    #[test]
    fn larger_sets_are_conditioned_on_a_spread_out_subset() {
        let x: Vec<f64> = (0..1500).map(|i| f64::from(i) / 1499.0).collect();
        let fold_of: Vec<usize> = (0..1500).map(|i| i % 3).collect();
        let (big, _) = Widening::calibrate(&line(&x), &fold_of, 0.05, 10.0, 2).unwrap();
        assert_eq!(big.centres.len(), CENTRES);
        let (small, _) =
            Widening::calibrate(&line(&x[..200]), &fold_of[..200], 0.05, 10.0, 2).unwrap();
        assert_eq!(small.centres.len(), 200);
    }
}
