//! The MSVR training problem on a given kernel matrix, solved by iteratively reweighted least
//! squares (IRWLS) with an exact line search on the true objective.
//!
//! Minimises F(β, b) = ½ tr(βᵀKβ) + C Σᵢ wᵢ L(uᵢ), uᵢ = ‖yᵢ − (Kβ)ᵢ − b‖₂, with the tube's
//! [`Loss`] ([`super::tube`]: the paper's quadratic or the robust one) and each row's weight
//! wᵢ (1 unless given; the weights below are then wᵢ times theirs).
//!
//! Each iteration:
//! 1. the strict support set S = {i : uᵢ > ε} (a sample on the tube's edge is not in S, so
//!    nothing divides by u − ε or by u = 0);
//! 2. a weighted least-squares step whose quadratic model of F has F's gradient at the iterate:
//!    A = K_SS + diag(1/aᵢ) (SPD), A ξ = 1 and A η = Y'_S, with weight aᵢ = 2C and the target
//!    pulled in to the tube's edge, y'ᵢ = yᵢ − ε eᵢ/uᵢ, where the loss is quadratic, and
//!    aᵢ = 2Cδ/uᵢ with y'ᵢ = yᵢ in the robust loss's linear part; then b* = 1ᵀη / 1ᵀξ,
//!    β*_S = η − ξ b*ᵀ, β* = 0 off S (with S empty the step is towards β = 0, b unchanged);
//! 3. a line search along (β, b) → (β*, b*): Kβ(t) is linear and tr(βᵀKβ)(t) quadratic in t,
//!    so F(t) and F'(t) cost O(nq) each; F is convex in t, so its minimiser on [0, 4] is found
//!    from F' by regula falsi, and halved back towards t = 0 should rounding make it worse than
//!    the current point — the objective never rises;
//! 4. stop when F falls by less than `tol` relative, when no step along the (descent) direction
//!    lowers F (the iterate is optimal to rounding), or at `max_iter`;
//! 5. once converged, return the last step target instead of the iterate when F there is within
//!    `tol` of it: steps shorter or longer than 1 leave rows that left S slightly non-zero, and
//!    the target is exactly zero off S, so the model keeps only its support vectors.
//!
//! The weights differ from the textbook IRWLS, which uses aᵢ = 2C(uᵢ − ε)/uᵢ with targets yᵢ.
//! Both models have F's gradient at the iterate, so both have F's optimum as their fixed point.
//! The textbook weight is the loss's curvature across the residual; along the residual it is
//! 2C, so the textbook step overshoots (the best step along it measured ≈ 0.25 on the micro-hand
//! data). Weight 2C with shifted targets is exact along the residual, and makes A depend on S
//! alone: its Cholesky factor is kept while S does not change, which after the first few
//! iterations it rarely does, and updated by low-rank changes when a few rows join or leave
//! (`Workspace::update`): on 1000 rows of the virtual hand (C 10, ε 0.1, σ 0.5) 2 factorisations
//! instead of 7. On the micro-hand data at n = 1000 this halves the fit time for
//! the same number of iterations and the same optimum. With ε = 0 both are the same step.
//! The robust loss's linear part takes the textbook weight 2Cδ/uᵢ with the target itself: the
//! quadratic it defines lies above the loss (the usual majoriser of a norm), so the step does not
//! overshoot. Weight 2C there with targets pulled to δ from the prediction (which would keep the
//! factor) moves a far row by about δ per iteration: 4.4× slower on the virtual hand's grid at
//! C = 10⁷. These weights change with uᵢ, so the factor is recomputed while rows sit in the
//! linear part.
//!
//! None of the defects listed in `notes/msvr.md`: the step, the line search and the stopping rule
//! all use the one objective F; the line search stays on the line through the current iterate, so
//! a short step lands near it; an iterate with every sample inside the tube steps towards β = 0
//! instead of returning it; the bias is solved for; an iteration cap with a convergence flag;
//! Cholesky, no explicit inverse.
//!
//! References: F. Pérez-Cruz et al., "An IRWLS procedure for SVR", EUSIPCO 2000;
//! M. Sánchez-Fernández et al., IEEE Trans. Signal Process. 52 (2004) 2298;
//! D. Tuia et al., IEEE Geosci. Remote Sens. Lett. 8 (2011) 804.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve;
use faer::reborrow::{IntoConst, ReborrowMut};
use faer::{Accum, Col, Mat, MatRef, Par};
use serde::{Deserialize, Serialize};

use super::tube::{frobenius_dot, row_norm, Tube};
pub use super::tube::{Loss, RowWeights, ROBUST_ZONE};

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
    /// A stop was asked ([`crate::control`]): the result is not converged, and no fit returns
    /// it.
    Interrupted,
}

impl StopReason {
    pub fn converged(self) -> bool {
        !matches!(self, StopReason::IterationCap | StopReason::Interrupted)
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
    /// Bring the step system's Cholesky factor up to date by low-rank changes when few rows
    /// change (see `Workspace::update`); off, every change refactors, as the paper's colony's
    /// histories were computed (the results then agree to rounding, not to the bit).
    pub factor_updates: bool,
    /// Stop at a stop asked after this ([`crate::control`]).
    pub since: crate::control::Since,
}

/// A training problem: kernel matrix K (n × n, symmetric PSD, contiguous columns, as any
/// column-major matrix or square sub-block of one), targets Y (n × q), C > 0, ε ≥ 0 (> 0 for the
/// robust loss).
#[derive(Clone, Copy, Debug)]
pub struct Problem<'a> {
    pub kernel: MatRef<'a, f64>,
    pub targets: MatRef<'a, f64>,
    pub c: f64,
    pub epsilon: f64,
    pub loss: Loss,
    pub weights: RowWeights<'a>,
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
    /// Cholesky factorisations of a whole step system (the others were updates or reuses).
    pub factorizations: usize,
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

/// Buffers of the step system, allocated once per solve (a fresh n × n matrix per iteration
/// costs more in page faults than the copy into it), and the support rows and inverse weights
/// whose Cholesky factor the block holds.
struct Workspace {
    block: Mat<f64>,
    rhs: Mat<f64>,
    stack: MemBuffer,
    factored: Vec<(usize, f64)>,
    /// [`SolverOptions::factor_updates`].
    updates: bool,
    factorizations: usize,
}

impl Workspace {
    fn new(n: usize, q: usize, par: Par, updates: bool) -> Self {
        let scratch = llt::factor::cholesky_in_place_scratch::<f64>(n, par, Default::default())
            .or(llt::solve::solve_in_place_scratch::<f64>(n, q + 1, par));
        Workspace {
            block: Mat::zeros(n, n),
            rhs: Mat::zeros(n, q + 1),
            stack: MemBuffer::new(scratch),
            factored: Vec::new(),
            updates,
            factorizations: 0,
        }
    }

    /// Factors A = K_SS + diag(1/aᵢ) into the block's leading s × s corner, for support rows
    /// given with their inverse weights. Only the lower triangle is copied: it is all the
    /// Cholesky reads.
    fn factor(
        &mut self,
        kernel: MatRef<f64>,
        support: &[(usize, f64)],
        par: Par,
    ) -> Result<(), NotPositiveDefinite> {
        let s = support.len();
        self.factored.clear();
        self.factorizations += 1;
        let mut a = self.block.as_mut().submatrix_mut(0, 0, s, s);
        for (c, &(col, inv_weight)) in support.iter().enumerate() {
            let src = column(kernel, col);
            let dst = a
                .rb_mut()
                .col_mut(c)
                .try_as_col_major_mut()
                .expect("column-major");
            for (d, &(row, _)) in dst.as_slice_mut()[c..].iter_mut().zip(&support[c..]) {
                *d = src[row];
            }
            a[(c, c)] += inv_weight;
        }
        let stack = MemStack::new(&mut self.stack);
        llt::factor::cholesky_in_place(a, Default::default(), par, stack, Default::default())
            .map_err(|e| match e {
                llt::factor::LltError::NonPositivePivot { index } => NotPositiveDefinite {
                    pivot: index,
                    size: s,
                },
            })?;
        self.factored.extend_from_slice(support);
        Ok(())
    }

    /// Makes the block hold the factor of `support` (rows ascending, with inverse weights): kept
    /// when it already does, updated when `self.updates` allows and [`Workspace::update`] can, else
    /// factored afresh. The factor's row order is then `self.factored`'s.
    fn prepare(
        &mut self,
        kernel: MatRef<f64>,
        support: &[(usize, f64)],
        par: Par,
    ) -> Result<(), NotPositiveDefinite> {
        if self.factored == support || self.updates && self.update(kernel, support, par) {
            return Ok(());
        }
        self.factor(kernel, support, par)
    }

    /// Brings the factor from the rows it holds to `support` by low-rank changes: rows that left
    /// are deleted (the kept rows' block of L, compacted, takes a rank-r update with the deleted
    /// columns: A_KK = L_KK L_KKᵀ + L_KD L_KDᵀ), rows whose weight changed take a rank-one update
    /// of their diagonal, rows that joined are appended (a bordered factor: L₂₁ = (L₁₁⁻¹ A₁₂)ᵀ,
    /// L₂₂ = chol(A₂₂ − L₂₁ L₂₁ᵀ)). Each costs O(s²) per row against s³/3 for a new factor, so
    /// it is done when at most 1/32 of the rows change. Returns `false`, the block then stale,
    /// when more change or an update is not positive definite in floating point.
    fn update(&mut self, kernel: MatRef<f64>, support: &[(usize, f64)], par: Par) -> bool {
        let n = kernel.nrows();
        let old = std::mem::take(&mut self.factored);
        let mut weight = vec![f64::NAN; n];
        for &(i, w) in support {
            weight[i] = w;
        }
        let mut held = vec![false; n];
        for &(i, _) in &old {
            held[i] = true;
        }
        let (kept, deleted): (Vec<usize>, Vec<usize>) =
            (0..old.len()).partition(|&p| !weight[old[p].0].is_nan());
        let added: Vec<(usize, f64)> = support.iter().filter(|(i, _)| !held[*i]).copied().collect();
        let changed: Vec<(usize, f64)> = kept
            .iter()
            .enumerate()
            .filter_map(|(a, &p)| {
                let (i, w) = old[p];
                (weight[i] != w).then_some((a, weight[i] - w))
            })
            .collect();
        let (k, m) = (kept.len(), added.len());
        let changes = deleted.len() + changed.len() + m;
        if changes == 0 {
            self.factored = old;
            return true;
        }
        if old.is_empty() || 32 * changes > k + m {
            return false;
        }
        // One rank-r update: the deleted columns of L on the kept rows (L is lower triangular),
        // weight +1, then a unit column per changed weight, scaled by √|Δ|, weight ±1.
        let r = deleted.len() + changed.len();
        let mut w = Mat::<f64>::zeros(k, r);
        let mut alpha = Col::<f64>::ones(r);
        for (c, &col) in deleted.iter().enumerate() {
            for (a, &row) in kept.iter().enumerate() {
                if row > col {
                    w[(a, c)] = self.block[(row, col)];
                }
            }
        }
        for (c, &(a, d)) in changed.iter().enumerate() {
            w[(a, deleted.len() + c)] = d.abs().sqrt();
            alpha[deleted.len() + c] = d.signum();
        }
        // Compact the kept rows and columns in place: the source (kept[a], kept[b]) is never
        // before the target (a, b) in either index, so column by column it is still unread.
        for (b, &pb) in kept.iter().enumerate() {
            for (a, &pa) in kept.iter().enumerate().skip(b) {
                self.block[(a, b)] = self.block[(pa, pb)];
            }
        }
        let lower = self.block.as_mut().submatrix_mut(0, 0, k, k);
        if r > 0
            && llt::update::rank_r_update_clobber(lower, w.as_mut(), alpha.as_diagonal_mut())
                .is_err()
        {
            return false;
        }
        if m > 0 {
            let mut x = Mat::from_fn(k, m, |a, j| kernel[(old[kept[a]].0, added[j].0)]);
            triangular_solve::solve_lower_triangular_in_place(
                self.block.as_ref().submatrix(0, 0, k, k),
                x.as_mut(),
                par,
            );
            let mut corner = Mat::from_fn(m, m, |i, j| {
                kernel[(added[i].0, added[j].0)] + if i == j { added[i].1 } else { 0.0 }
            });
            matmul(
                corner.as_mut(),
                Accum::Add,
                x.transpose(),
                x.as_ref(),
                -1.0,
                par,
            );
            for j in 0..m {
                for a in 0..k {
                    self.block[(k + j, a)] = x[(a, j)];
                }
                for i in j..m {
                    self.block[(k + i, k + j)] = corner[(i, j)];
                }
            }
            let stack = MemStack::new(&mut self.stack);
            let corner = self.block.as_mut().submatrix_mut(k, k, m, m);
            if llt::factor::cholesky_in_place(
                corner,
                Default::default(),
                par,
                stack,
                Default::default(),
            )
            .is_err()
            {
                return false;
            }
        }
        self.factored = kept
            .iter()
            .map(|&p| (old[p].0, weight[old[p].0]))
            .chain(added)
            .collect();
        true
    }
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
    assert_eq!(
        problem.kernel.row_stride(),
        1,
        "kernel columns must be contiguous"
    );
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
    let mut work = Workspace::new(n, q, options.par, options.factor_updates);
    let mut iterations = 0;
    let stop = loop {
        if iterations == options.max_iter {
            break StopReason::IterationCap;
        }
        if options.since.stopped() {
            break StopReason::Interrupted;
        }
        iterations += 1;
        crate::control::iteration_done();
        let (beta_star, bias_star) = problem.step_target(&it, &mut work, options.par)?;
        let previous = it.objective;
        match problem.line_search(&mut it, beta_star, bias_star, options.par) {
            None => break StopReason::NoDescent,
            Some(()) if previous - it.objective <= options.tol * previous => {
                break StopReason::Tolerance
            }
            Some(()) => {}
        }
    };
    if stop.converged() {
        // The step target is exactly zero off the support set; at convergence it is the
        // iterate up to the tolerance, so take it when F agrees: the model is then sparse.
        let (beta_star, bias_star) = problem.step_target(&it, &mut work, options.par)?;
        let sparse = problem.iterate(beta_star, bias_star, options.par);
        if sparse.objective <= it.objective * (1.0 + options.tol) {
            it = sparse;
        }
    }
    Ok(Solution {
        beta: it.beta,
        bias: it.bias,
        objective: it.objective,
        iterations,
        stop,
        factorizations: work.factorizations,
    })
}

impl Problem<'_> {
    /// The loss of this problem's tube.
    pub fn tube(&self) -> Tube {
        Tube {
            c: self.c,
            epsilon: self.epsilon,
            loss: self.loss,
        }
    }

    /// F at β, b given Kβ.
    pub fn objective(&self, beta: MatRef<f64>, k_beta: MatRef<f64>, bias: &[f64]) -> f64 {
        self.objective_with(beta, k_beta, self.residuals(k_beta, bias).as_ref())
    }

    /// F from β, Kβ and the residuals they leave.
    fn objective_with(&self, beta: MatRef<f64>, k_beta: MatRef<f64>, resid: MatRef<f64>) -> f64 {
        0.5 * frobenius_dot(beta, k_beta) + self.tube().data_term(resid, self.weights)
    }

    fn residuals(&self, k_beta: MatRef<f64>, bias: &[f64]) -> Mat<f64> {
        let y = self.targets;
        Mat::from_fn(y.nrows(), y.ncols(), |i, j| {
            y[(i, j)] - k_beta[(i, j)] - bias[j]
        })
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
        let objective = self.objective_with(beta.as_ref(), k_beta.as_ref(), resid.as_ref());
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
        work: &mut Workspace,
        par: Par,
    ) -> Result<(Mat<f64>, Vec<f64>), NotPositiveDefinite> {
        let (n, q) = self.targets.shape();
        let rows: Vec<Option<(f64, f64)>> = (0..n)
            .map(|i| {
                let u = row_norm(it.resid.as_ref(), i);
                self.tube().step_row(u, self.weights.of(i))
            })
            .collect();
        let support: Vec<(usize, f64)> = rows
            .iter()
            .enumerate()
            .filter_map(|(i, row)| row.map(|(inv_weight, _)| (i, inv_weight)))
            .collect();
        let s = support.len();
        let mut beta_star = Mat::zeros(n, q);
        if s == 0 {
            return Ok((beta_star, it.bias.clone()));
        }
        work.prepare(self.kernel, &support, par)?;
        let mut rhs = work.rhs.as_mut().submatrix_mut(0, 0, s, q + 1);
        for (r, &(i, _)) in work.factored.iter().enumerate() {
            let (_, shrink) = rows[i].expect("the factor holds support rows");
            rhs[(r, 0)] = 1.0;
            for j in 0..q {
                rhs[(r, j + 1)] = self.targets[(i, j)] - shrink * it.resid[(i, j)];
            }
        }
        let factor = work.block.as_ref().submatrix(0, 0, s, s);
        llt::solve::solve_in_place(factor, rhs.rb_mut(), par, MemStack::new(&mut work.stack));
        let rhs = rhs.into_const();
        let sum_xi: f64 = rhs.col(0).iter().sum();
        let bias_star: Vec<f64> = (1..=q)
            .map(|j| rhs.col(j).iter().sum::<f64>() / sum_xi)
            .collect();
        for (r, &(i, _)) in work.factored.iter().enumerate() {
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
        let (t, objective) = self.tube().step_along(
            it.resid.as_ref(),
            g.as_ref(),
            [q0, q1, q2],
            it.objective,
            self.weights,
        )?;
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

/// Column `j` of a matrix with contiguous columns, as a slice.
fn column(m: MatRef<'_, f64>, j: usize) -> &[f64] {
    m.col(j)
        .try_as_col_major()
        .expect("contiguous columns")
        .as_slice()
}
