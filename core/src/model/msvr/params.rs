//! MSVR's hyper-parameters and solver controls ([`MsvrParams`]), and the same once checked
//! ([`ValidMsvrParams`]): what a fit may be asked, and why a request is refused.

use faer::{MatRef, Par};
use serde::{Deserialize, Serialize};

use super::irwls::{NotPositiveDefinite, Problem, SolverOptions, StopReason};
use super::tube::RowWeights;
use super::{
    basis, check_memory, irwls, kernel, reduced, to_columns, to_mat, tube, Basis, BasisFit,
    Expansion, FitDiagnostics, Hyper, InvalidParam, Loss, MinMaxScaler, Msvr, MsvrError, MsvrRepr,
    Weighing, DEFAULT_MAX_ITER, DEFAULT_TOL, MIN_FIT_ROWS, PAPER_TABLE2, STORED_FEATURE_BYTES,
};
use crate::data::{Columns, Dataset};

/// MSVR hyper-parameters and solver controls, not yet checked.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MsvrParams {
    /// Penalty C > 0.
    pub c: f64,
    /// Tube radius ε ≥ 0, in output units.
    pub epsilon: f64,
    /// RBF width σ > 0, in scaled input units.
    pub sigma: f64,
    /// Relative tolerance on the objective's decrease (default [`DEFAULT_TOL`]).
    pub tol: f64,
    /// Iteration cap (default [`DEFAULT_MAX_ITER`]).
    pub max_iter: usize,
    /// The loss outside the tube (model files written before it existed: the paper's).
    #[serde(default)]
    pub loss: Loss,
    /// The expansion: a kernel at every training row, or at a reduced basis of centres (model
    /// files written before it existed: exact).
    #[serde(default)]
    pub basis: Basis,
    /// [`irwls::SolverOptions::factor_updates`] (on by default; a solver detail, not written).
    #[serde(skip, default = "factor_updates_default")]
    pub factor_updates: bool,
}

fn factor_updates_default() -> bool {
    true
}

impl Default for MsvrParams {
    /// The paper's Table 2 ([`PAPER_TABLE2`]) with the default solver controls.
    fn default() -> Self {
        MsvrParams::new(PAPER_TABLE2.c, PAPER_TABLE2.epsilon, PAPER_TABLE2.sigma)
    }
}

impl MsvrParams {
    /// C, ε and σ with the default solver controls.
    pub fn new(c: f64, epsilon: f64, sigma: f64) -> Self {
        MsvrParams {
            c,
            epsilon,
            sigma,
            tol: DEFAULT_TOL,
            max_iter: DEFAULT_MAX_ITER,
            loss: Loss::Quadratic,
            basis: Basis::Exact,
            factor_updates: true,
        }
    }

    /// Sets the expansion (default [`Basis::Exact`]).
    pub fn basis(self, basis: Basis) -> Self {
        MsvrParams { basis, ..self }
    }

    /// Sets the relative tolerance (default [`DEFAULT_TOL`]).
    pub fn tol(self, tol: f64) -> Self {
        MsvrParams { tol, ..self }
    }

    /// Sets the loss (default the paper's quadratic).
    pub fn loss(self, loss: Loss) -> Self {
        MsvrParams { loss, ..self }
    }

    /// Sets the iteration cap (default [`DEFAULT_MAX_ITER`]).
    pub fn max_iter(self, max_iter: usize) -> Self {
        MsvrParams { max_iter, ..self }
    }

    /// The tube of these parameters (C, ε, loss).
    pub fn tube(&self) -> tube::Tube {
        tube::Tube {
            c: self.c,
            epsilon: self.epsilon,
            loss: self.loss,
        }
    }

    /// The (C, ε, σ) of these parameters.
    pub fn hyper(&self) -> Hyper {
        Hyper {
            c: self.c,
            epsilon: self.epsilon,
            sigma: self.sigma,
        }
    }

    /// These solver controls with another (C, ε, σ): the one place a search's candidate becomes
    /// parameters.
    pub fn with_hyper(self, h: Hyper) -> Self {
        MsvrParams {
            c: h.c,
            epsilon: h.epsilon,
            sigma: h.sigma,
            ..self
        }
    }

    /// Checks every value: (C, ε, σ) by [`Hyper::check`], the solver controls here.
    ///
    /// # Errors
    /// [`MsvrError::InvalidParam`] naming the first bad value.
    pub fn check(self) -> Result<ValidMsvrParams, MsvrError> {
        self.hyper().check()?;
        let bad = |name, value, requirement| {
            Err(MsvrError::InvalidParam(InvalidParam {
                name,
                value,
                requirement,
            }))
        };
        if !(self.tol > 0.0 && self.tol < 1.0) {
            return bad("tol", self.tol, "must be in (0, 1)");
        }
        if self.max_iter == 0 {
            return bad("max_iter", 0.0, "must be at least 1");
        }
        if let Basis::Reduced { centres: 0, .. } = self.basis {
            return bad("centres", 0.0, "a reduced basis needs at least 1 centre");
        }
        if self.loss == Loss::Robust && self.epsilon <= 0.0 {
            return bad(
                "epsilon",
                self.epsilon,
                "must be > 0 with the robust loss (its quadratic zone is 10 ε wide); use the quadratic loss for ε = 0",
            );
        }
        Ok(ValidMsvrParams(self))
    }
}

/// Checked parameters: the only way to fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValidMsvrParams(MsvrParams);

impl ValidMsvrParams {
    pub fn params(&self) -> &MsvrParams {
        &self.0
    }

    /// Solves the training problem on a kernel matrix and targets (each row weighted by
    /// `weights`) with these parameters, stopping at a stop asked after `since`
    /// ([`StopReason::Interrupted`]).
    ///
    /// # Errors
    /// [`NotPositiveDefinite`] when the linear algebra fails.
    pub fn solve(
        &self,
        kernel: MatRef<f64>,
        targets: MatRef<f64>,
        weights: RowWeights,
        par: Par,
        since: crate::control::Since,
    ) -> Result<irwls::Solution, NotPositiveDefinite> {
        let p = &self.0;
        let problem = Problem {
            kernel,
            targets,
            c: p.c,
            epsilon: p.epsilon,
            loss: p.loss,
            weights,
        };
        let options = SolverOptions {
            tol: p.tol,
            max_iter: p.max_iter,
            par,
            factor_updates: p.factor_updates,
            since,
        };
        irwls::solve(&problem, &options, None)
    }

    /// Fits the model, using every core for the linear algebra.
    ///
    /// # Errors
    /// [`MsvrError::Data`] for too few rows or a constant input; [`MsvrError::Solver`] when the
    /// linear algebra fails.
    pub fn fit(&self, data: &Dataset) -> Result<Msvr, MsvrError> {
        self.fit_with(data, Par::rayon(0))
    }

    /// Fits the model with the given parallelism (`Par::Seq` when fits run side by side).
    ///
    /// # Errors
    /// As [`ValidMsvrParams::fit`].
    pub fn fit_with(&self, data: &Dataset, par: Par) -> Result<Msvr, MsvrError> {
        Ok(self.fit_predicting(data, par)?.0)
    }

    /// Fits the model, and with the exact basis also gives its predictions of the training
    /// rows (Kβ + b from the kernel the fit built: no kernel evaluated twice).
    ///
    /// # Errors
    /// As [`ValidMsvrParams::fit`].
    pub fn fit_predicting(
        &self,
        data: &Dataset,
        par: Par,
    ) -> Result<(Msvr, Option<Columns>), MsvrError> {
        let since = crate::control::Since::now();
        data.check_fittable(MIN_FIT_ROWS)?;
        check_memory(data.rows(), self.0.basis)?;
        let p = &self.0;
        let scaler = MinMaxScaler::fit(&data.inputs);
        let scaled = scaler.transform(&data.inputs);
        let y = to_mat(&data.outputs);
        let mut fitted = None;
        let expansion = match p.basis {
            Basis::Exact => {
                let k = kernel::rbf_gram(&scaled, p.sigma);
                let solution =
                    self.solve(k.as_ref(), y.as_ref(), data.row_weights(), par, since)?;
                let mut k_beta = k.as_ref() * &solution.beta;
                for (j, b) in solution.bias.iter().enumerate() {
                    k_beta.col_mut(j).iter_mut().for_each(|v| *v += b);
                }
                fitted = Some(to_columns(data.outputs.names.clone(), k_beta.as_ref()));
                let sv_rows: Vec<usize> = (0..solution.beta.nrows())
                    .filter(|&i| solution.beta.row(i).iter().any(|&b| b != 0.0))
                    .collect();
                Expansion {
                    centres: sv_rows.iter().map(|&i| scaled.row(i).to_vec()).collect(),
                    coefficients: sv_rows
                        .iter()
                        .map(|&i| solution.beta.row(i).iter().copied().collect())
                        .collect(),
                    bias: solution.bias,
                    objective: solution.objective,
                    iterations: solution.iterations,
                    stop: solution.stop,
                    basis: None,
                }
            }
            Basis::Reduced { centres, seed } => {
                let chosen = basis::kmeans_pp(&scaled, centres, seed);
                let map = basis::NystromMap::new(&scaled.select_rows(&chosen), p.sigma);
                let stored;
                let features = if data.rows() * map.width() * 8 <= STORED_FEATURE_BYTES {
                    stored = map.features(&scaled);
                    reduced::FeatureRows::Stored {
                        all: stored.as_ref(),
                        rows: None,
                    }
                } else {
                    reduced::FeatureRows::Streamed {
                        map: &map,
                        x: &scaled,
                        rows: None,
                    }
                };
                let problem = reduced::ReducedProblem {
                    features,
                    targets: y.as_ref(),
                    tube: p.tube(),
                    weights: data.row_weights(),
                    gram: None,
                };
                let solution = reduced::solve(&problem, p.tol, p.max_iter, par, since)?;
                let beta = map.coefficients(solution.w.as_ref());
                Expansion {
                    centres: map.centres.iter_rows().map(<[f64]>::to_vec).collect(),
                    coefficients: (0..beta.nrows())
                        .map(|i| beta.row(i).iter().copied().collect())
                        .collect(),
                    bias: solution.bias,
                    objective: solution.objective,
                    iterations: solution.iterations,
                    stop: solution.stop,
                    basis: Some(BasisFit {
                        requested: centres,
                        chosen: chosen.len(),
                        kept: map.width(),
                        outside_tube: solution.outside,
                    }),
                }
            }
        };
        if expansion.stop == StopReason::Interrupted {
            return Err(MsvrError::Interrupted);
        }
        if !expansion.is_finite() {
            return Err(MsvrError::NonFinite {
                c: p.c,
                epsilon: p.epsilon,
                sigma: p.sigma,
            });
        }
        let fit = FitDiagnostics {
            rows: data.rows(),
            iterations: expansion.iterations,
            objective: expansion.objective,
            support_vectors: expansion.centres.len(),
            converged: expansion.stop.converged(),
            stop: expansion.stop,
            basis: expansion.basis,
            weights: data.weights.as_deref().map(Weighing::of),
        };
        let model = Msvr::from_repr(MsvrRepr {
            inputs: data.inputs.names.clone(),
            outputs: data.outputs.names.clone(),
            params: *p,
            scaler,
            support_vectors: expansion.centres,
            coefficients: expansion.coefficients,
            bias: expansion.bias,
            fit,
        });
        Ok((model, fitted))
    }
}
