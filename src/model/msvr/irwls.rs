//! The MSVR training problem on a given kernel matrix, solved by IRWLS with an exact segment
//! line search.
//!
//! Minimises F(β, b) = ½ tr(βᵀKβ) + C Σᵢ L(uᵢ), uᵢ = ‖yᵢ − (Kβ)ᵢ − b‖₂,
//! L(u) = 0 for u ≤ ε and (u − ε)² above (Sánchez-Fernández et al. 2004, eqs. 11-12 of the paper).
//!
//! Each iteration:
//! 1. the strict support set S = {i : uᵢ > ε} and weights aᵢ = 2C(uᵢ − ε)/uᵢ on S (never
//!    evaluated at uᵢ ≤ ε, so no 0/0 and no infinite 1/a);
//! 2. the weighted least-squares step, whose model of F has F's gradient at the iterate:
//!    A = K_SS + diag(1/a_S) (SPD), one Cholesky, A ξ = 1 and A η = Y_S,
//!    b* = 1ᵀη / 1ᵀξ, β*_S = η − ξ b*ᵀ, β* = 0 off S (with S empty the step is towards β = 0);
//! 3. a line search on the segment (β, b) → (β*, b*): Kβ(t) is linear and tr(βᵀKβ)(t) quadratic
//!    in t, so each trial costs O(nq); the first t in 1, ½, ¼, … that does not increase F is
//!    taken — the iterate never gets worse and a step can always shrink back towards it;
//! 4. stop when F falls by less than `tol` relative, when no step along the (descent) direction
//!    lowers F (the iterate is optimal to rounding), or at `max_iter`.
//!
//! This avoids every defect listed in `notes/msvr.md`: one objective for weights, line search and
//! stopping; backtracking on the true segment; no collapse to β = 0 when S is empty; the bias is
//! solved for; an iteration cap with a convergence flag; Cholesky, no explicit inverse.
//!
//! References: F. Pérez-Cruz et al., "An IRWLS procedure for SVR", EUSIPCO 2000;
//! M. Sánchez-Fernández et al., IEEE Trans. Signal Process. 52 (2004) 2298;
//! D. Tuia et al., IEEE Geosci. Remote Sens. Lett. 8 (2011) 804.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par};
use serde::{Deserialize, Serialize};

/// Smallest line-search step tried before concluding that no step lowers F.
const MIN_STEP: f64 = 1.0 / (1u64 << 40) as f64;

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The objective fell by less than the relative tolerance.
    Tolerance,
    /// No step along the descent direction lowered the objective: optimal to rounding.
    NoDescent,
    /// The iteration cap was reached first: the result is not converged.
    IterationCap,
}

impl StopReason {
    pub fn converged(self) -> bool {
        !matches!(self, StopReason::IterationCap)
    }
}

/// Solver controls.
#[derive(Clone, Copy, Debug)]
pub struct SolverOptions {
    /// Relative decrease of F below which the solver stops.
    pub tol: f64,
    pub max_iter: usize,
    /// Parallelism of the dense linear algebra (`Par::Seq` when fits run in parallel).
    pub par: Par,
}

/// A training problem: kernel matrix K (n × n, symmetric PSD), targets Y (n × q), C > 0, ε ≥ 0.
#[derive(Clone, Copy, Debug)]
pub struct Problem<'a> {
    pub kernel: MatRef<'a, f64>,
    pub targets: MatRef<'a, f64>,
    pub c: f64,
    pub epsilon: f64,
}

/// The solver's result.
#[derive(Clone, Debug)]
pub struct Solution {
    /// Coefficients β (n × q); zero rows are not support vectors.
    pub beta: Mat<f64>,
    /// Bias b (q).
    pub bias: Vec<f64>,
    pub objective: f64,
    pub iterations: usize,
    pub stop: StopReason,
}

/// The linear algebra failed: with a valid problem this means C is beyond what f64 resolves.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("the IRWLS system is not positive definite (pivot {pivot} of {size}); lower C")]
pub struct NotPositiveDefinite {
    pub pivot: usize,
    pub size: usize,
}

/// The iterate and what is derived from it.
struct Iterate {
    beta: Mat<f64>,
    k_beta: Mat<f64>,
    bias: Vec<f64>,
    /// Residuals Y − Kβ − 1bᵀ.
    resid: Mat<f64>,
    objective: f64,
}

/// Solves the problem from β = 0, b = mean(Y), or from `start` (β, b) when given.
///
/// # Errors
/// [`NotPositiveDefinite`] when a step system cannot be factored.
pub fn solve(
    problem: &Problem,
    options: &SolverOptions,
    start: Option<(MatRef<f64>, &[f64])>,
) -> Result<Solution, NotPositiveDefinite> {
    let (n, q) = problem.targets.shape();
    assert_eq!(problem.kernel.shape(), (n, n), "kernel must be n × n");
    let mut it = match start {
        Some((beta, bias)) => {
            assert_eq!(beta.shape(), (n, q), "start β must be n × q");
            problem.iterate(beta.to_owned(), bias.to_vec(), options.par)
        }
        None => {
            let mean = (0..q)
                .map(|j| problem.targets.col(j).iter().sum::<f64>() / n as f64)
                .collect();
            problem.iterate(Mat::zeros(n, q), mean, options.par)
        }
    };
    let mut iterations = 0;
    let stop = loop {
        if iterations == options.max_iter {
            break StopReason::IterationCap;
        }
        iterations += 1;
        let (beta_star, bias_star) = problem.step_target(&it, options.par)?;
        let previous = it.objective;
        match problem.line_search(&mut it, beta_star, bias_star, options.par) {
            None => break StopReason::NoDescent,
            Some(()) if previous - it.objective <= options.tol * previous => {
                break StopReason::Tolerance
            }
            Some(()) => {}
        }
    };
    Ok(Solution {
        beta: it.beta,
        bias: it.bias,
        objective: it.objective,
        iterations,
        stop,
    })
}

impl Problem<'_> {
    /// The ε-insensitive quadratic loss of a residual norm.
    fn loss(&self, u: f64) -> f64 {
        if u > self.epsilon {
            (u - self.epsilon) * (u - self.epsilon)
        } else {
            0.0
        }
    }

    /// F at β, b given Kβ.
    pub fn objective(&self, beta: MatRef<f64>, k_beta: MatRef<f64>, bias: &[f64]) -> f64 {
        let resid = self.residuals(k_beta, bias);
        0.5 * frobenius_dot(beta, k_beta) + self.c * self.loss_sum(resid.as_ref())
    }

    fn residuals(&self, k_beta: MatRef<f64>, bias: &[f64]) -> Mat<f64> {
        let y = self.targets;
        Mat::from_fn(y.nrows(), y.ncols(), |i, j| {
            y[(i, j)] - k_beta[(i, j)] - bias[j]
        })
    }

    fn loss_sum(&self, resid: MatRef<f64>) -> f64 {
        (0..resid.nrows())
            .map(|i| self.loss(row_norm(resid, i)))
            .sum()
    }

    fn iterate(&self, beta: Mat<f64>, bias: Vec<f64>, par: Par) -> Iterate {
        let mut k_beta = Mat::zeros(beta.nrows(), beta.ncols());
        matmul(
            k_beta.as_mut(),
            Accum::Replace,
            self.kernel,
            beta.as_ref(),
            1.0,
            par,
        );
        let resid = self.residuals(k_beta.as_ref(), &bias);
        let objective = 0.5 * frobenius_dot(beta.as_ref(), k_beta.as_ref())
            + self.c * self.loss_sum(resid.as_ref());
        Iterate {
            beta,
            k_beta,
            bias,
            resid,
            objective,
        }
    }

    /// The weighted least-squares solution (β*, b*) at the current iterate (step 2).
    fn step_target(
        &self,
        it: &Iterate,
        par: Par,
    ) -> Result<(Mat<f64>, Vec<f64>), NotPositiveDefinite> {
        let (n, q) = self.targets.shape();
        let (support, inv_weight): (Vec<usize>, Vec<f64>) = (0..n)
            .filter_map(|i| {
                let u = row_norm(it.resid.as_ref(), i);
                (u > self.epsilon).then(|| (i, u / (2.0 * self.c * (u - self.epsilon))))
            })
            .unzip();
        let s = support.len();
        let mut beta_star = Mat::zeros(n, q);
        if s == 0 {
            return Ok((beta_star, it.bias.clone()));
        }
        let k = self.kernel;
        let mut a = Mat::from_fn(s, s, |r, c| k[(support[r], support[c])]);
        for (r, w) in inv_weight.iter().enumerate() {
            a[(r, r)] += w;
        }
        let mut rhs = Mat::from_fn(s, q + 1, |r, c| {
            if c == 0 {
                1.0
            } else {
                self.targets[(support[r], c - 1)]
            }
        });
        let scratch = llt::factor::cholesky_in_place_scratch::<f64>(s, par, Default::default())
            .or(llt::solve::solve_in_place_scratch::<f64>(s, q + 1, par));
        let mut buffer = MemBuffer::new(scratch);
        let stack = MemStack::new(&mut buffer);
        llt::factor::cholesky_in_place(
            a.as_mut(),
            Default::default(),
            par,
            stack,
            Default::default(),
        )
        .map_err(|e| match e {
            llt::factor::LltError::NonPositivePivot { index } => NotPositiveDefinite {
                pivot: index,
                size: s,
            },
        })?;
        llt::solve::solve_in_place(a.as_ref(), rhs.as_mut(), par, stack);
        let sum_xi: f64 = rhs.col(0).iter().sum();
        let bias_star: Vec<f64> = (1..=q)
            .map(|j| rhs.col(j).iter().sum::<f64>() / sum_xi)
            .collect();
        for (r, &i) in support.iter().enumerate() {
            for j in 0..q {
                beta_star[(i, j)] = rhs[(r, j + 1)] - rhs[(r, 0)] * bias_star[j];
            }
        }
        Ok((beta_star, bias_star))
    }

    /// Moves the iterate along the segment towards (β*, b*) by the first step in 1, ½, ¼, …
    /// that does not increase F (step 3). Returns `None`, leaving the iterate as it was, when no
    /// step down to [`MIN_STEP`] does.
    fn line_search(
        &self,
        it: &mut Iterate,
        beta_star: Mat<f64>,
        bias_star: Vec<f64>,
        par: Par,
    ) -> Option<()> {
        let (n, q) = self.targets.shape();
        let mut k_delta = Mat::zeros(n, q);
        matmul(
            k_delta.as_mut(),
            Accum::Replace,
            self.kernel,
            beta_star.as_ref(),
            1.0,
            par,
        );
        let delta = &beta_star - &it.beta;
        k_delta -= &it.k_beta;
        let bias_delta: Vec<f64> = bias_star.iter().zip(&it.bias).map(|(s, b)| s - b).collect();
        // Along the segment: tr(βᵀKβ)(t) = q0 + 2 t q1 + t² q2, residual(t) = resid − t g.
        let q0 = frobenius_dot(it.beta.as_ref(), it.k_beta.as_ref());
        let q1 = frobenius_dot(delta.as_ref(), it.k_beta.as_ref());
        let q2 = frobenius_dot(delta.as_ref(), k_delta.as_ref());
        let g = Mat::from_fn(n, q, |i, j| k_delta[(i, j)] + bias_delta[j]);
        let objective_at = |t: f64| {
            let loss: f64 = (0..n)
                .map(|i| {
                    let u2: f64 = (0..q)
                        .map(|j| {
                            let e = it.resid[(i, j)] - t * g[(i, j)];
                            e * e
                        })
                        .sum();
                    self.loss(u2.sqrt())
                })
                .sum();
            0.5 * (q0 + t * (2.0 * q1 + t * q2)) + self.c * loss
        };
        let mut t = 1.0;
        let objective = loop {
            let f = objective_at(t);
            if f <= it.objective {
                break f;
            }
            t *= 0.5;
            if t < MIN_STEP {
                return None;
            }
        };
        if t == 1.0 {
            it.beta = beta_star;
            it.bias = bias_star;
            it.k_beta += &k_delta;
        } else {
            it.beta += t * &delta;
            it.k_beta += t * &k_delta;
            for (b, d) in it.bias.iter_mut().zip(&bias_delta) {
                *b += t * d;
            }
        }
        it.resid = self.residuals(it.k_beta.as_ref(), &it.bias);
        it.objective = objective;
        Some(())
    }
}

fn row_norm(m: MatRef<f64>, i: usize) -> f64 {
    (0..m.ncols())
        .map(|j| m[(i, j)] * m[(i, j)])
        .sum::<f64>()
        .sqrt()
}

/// Σᵢⱼ aᵢⱼ bᵢⱼ.
fn frobenius_dot(a: MatRef<f64>, b: MatRef<f64>) -> f64 {
    (0..a.ncols())
        .map(|j| {
            a.col(j)
                .iter()
                .zip(b.col(j).iter())
                .map(|(x, y)| x * y)
                .sum::<f64>()
        })
        .sum()
}
