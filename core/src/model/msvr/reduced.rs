//! MSVR on a reduced basis ([`super::basis`]): the same tube, loss and IRWLS as [`super::irwls`],
//! on the Nyström features of m centres, for any number of rows.
//!
//! Minimises F(w, b) = ½‖w‖² + C Σᵢ wᵢ L(uᵢ), uᵢ = ‖yᵢ − Φᵢw − b‖₂, Φ the n × r features and
//! wᵢ each row's weight (1 unless given), which is exact MSVR's objective with β restricted to
//! the centres (β = L⁻ᵀ w, ½‖w‖² = ½ tr(βᵀK_mmβ)).
//! Each iteration:
//! 1. every row's part from [`Tube::step_row`]: weight aᵢ (0 inside the tube) and its pulled-in
//!    target y'ᵢ, as in the exact solver (so the same fixed point: F's optimum);
//! 2. the weighted least-squares step in the primal, with Φ̃ = [Φ 1] and R = diag(1, …, 1, 0):
//!    (R + Φ̃ᵀ A Φ̃) [w*; b*ᵀ] = Φ̃ᵀ A Y', an (r + 1)² system whatever n. Its matrix is built from
//!    the rows that are not in the loss's quadratic zone when they are fewer than the support:
//!    Φ̃ᵀAΦ̃ = 2C G − Σ_{i not quadratic} (2Cwᵢ − aᵢ) φ̃ᵢφ̃ᵢᵀ, with G = Φ̃ᵀWΦ̃ computed once per fit
//!    (an ε-tube holding few rows, or few far rows in the robust loss, makes an iteration cost
//!    O(k r²) for those k rows instead of O(n r²));
//! 3. the exact line search along (w, b) → (w*, b*) ([`Tube::step_along`]), so F never rises;
//! 4. the exact solver's stopping rule.
//!
//! Features are taken block by block ([`FeatureRows`]): stored once per σ (what a search's folds
//! share), or computed from the centres on demand, so a fit holds O(r²) plus O(nq) numbers.

use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::solvers::Solve;
use faer::reborrow::{IntoConst, Reborrow, ReborrowMut};
use faer::{Accum, Mat, MatMut, MatRef, Par, Side};

use super::basis::NystromMap;
use super::irwls::{NotPositiveDefinite, StopReason};
use super::tube::{frobenius_dot, row_norm, RowWeights, Tube};
use crate::data::Columns;

/// Rows per block of features.
const BLOCK: usize = 2048;

/// The feature rows of a reduced problem.
#[derive(Clone, Copy)]
pub enum FeatureRows<'a> {
    /// Stored features (n × r, or more rows of which `rows` lists the problem's).
    Stored {
        all: MatRef<'a, f64>,
        rows: Option<&'a [usize]>,
    },
    /// Computed from the map for each block of the scaled inputs' rows.
    Streamed {
        map: &'a NystromMap,
        x: &'a Columns,
        rows: Option<&'a [usize]>,
    },
}

impl FeatureRows<'_> {
    pub fn nrows(&self) -> usize {
        match *self {
            FeatureRows::Stored { all, rows } => rows.map_or(all.nrows(), <[usize]>::len),
            FeatureRows::Streamed { x, rows, .. } => rows.map_or(x.rows(), <[usize]>::len),
        }
    }

    pub fn width(&self) -> usize {
        match *self {
            FeatureRows::Stored { all, .. } => all.ncols(),
            FeatureRows::Streamed { map, .. } => map.width(),
        }
    }

    /// The features of the listed problem rows into `out` (rows.len() × r).
    fn gather(&self, listed: &[usize], mut out: MatMut<f64>, par: Par) {
        match *self {
            // Column by column: both matrices are column-major, so a row copy would stride
            // through memory at every element.
            FeatureRows::Stored { all, rows } => {
                for j in 0..all.ncols() {
                    let (from, mut to) = (all.col(j), out.rb_mut().col_mut(j));
                    for (a, &i) in listed.iter().enumerate() {
                        to[a] = from[stored_row(rows, i)];
                    }
                }
            }
            FeatureRows::Streamed { map, x, rows } => {
                let mapped: Vec<usize> = listed.iter().map(|&i| stored_row(rows, i)).collect();
                map.features_of(x, &mapped, out, par);
            }
        }
    }

    /// One pass over the listed rows' features (Φ̃ = [Φ 1]): Σᵢ cᵢ φ̃ᵢ φ̃ᵢᵀ added into the
    /// `gram`'s lower triangle ((r + 1)², all the step's Cholesky factor reads) with its sign,
    /// and Φ̃ᵀ T into the `rhs` ((r + 1) × q, T one row per listed row), each when asked.
    /// `listed` holds (row, cᵢ ≥ 0).
    fn accumulate(
        &self,
        listed: &[(usize, f64)],
        mut gram: Option<(f64, MatMut<f64>)>,
        mut rhs: Option<(MatRef<f64>, MatMut<f64>)>,
        par: Par,
    ) {
        let r = self.width();
        // Stored features: one product over all of them, the targets scattered to their rows,
        // instead of gathering the listed rows' features.
        if let FeatureRows::Stored { all, rows } = *self {
            if let Some((targets, rhs)) = rhs.take() {
                let mut scattered = Mat::<f64>::zeros(all.nrows(), targets.ncols());
                for (k, &(i, _)) in listed.iter().enumerate() {
                    let at = stored_row(rows, i);
                    for j in 0..targets.ncols() {
                        scattered[(at, j)] += targets[(k, j)];
                    }
                }
                let (mut top, mut last) = rhs.split_at_row_mut(r);
                matmul(
                    top.rb_mut(),
                    Accum::Add,
                    all.transpose(),
                    scattered.as_ref(),
                    1.0,
                    par,
                );
                for j in 0..targets.ncols() {
                    last[(0, j)] += targets.col(j).iter().sum::<f64>();
                }
            }
        }
        if gram.is_none() && rhs.is_none() {
            return;
        }
        let mut block = Mat::<f64>::zeros(BLOCK.min(listed.len()), r + 1);
        for (k, chunk) in listed.chunks(BLOCK).enumerate() {
            let rows: Vec<usize> = chunk.iter().map(|&(i, _)| i).collect();
            let mut b = block.as_mut().submatrix_mut(0, 0, chunk.len(), r + 1);
            self.gather(&rows, b.rb_mut().submatrix_mut(0, 0, chunk.len(), r), par);
            if let Some((targets, rhs)) = rhs.as_mut() {
                let t = targets.submatrix(k * BLOCK, 0, chunk.len(), targets.ncols());
                let features = b.rb().submatrix(0, 0, chunk.len(), r);
                matmul(
                    rhs.rb_mut().submatrix_mut(0, 0, r, t.ncols()),
                    Accum::Add,
                    features.transpose(),
                    t,
                    1.0,
                    par,
                );
                for j in 0..t.ncols() {
                    rhs[(r, j)] += t.col(j).iter().sum::<f64>();
                }
            }
            if let Some((sign, gram)) = gram.as_mut() {
                let scales: Vec<f64> = chunk.iter().map(|&(_, c)| c.sqrt()).collect();
                for j in 0..r {
                    let mut column = b.rb_mut().col_mut(j);
                    for (a, s) in scales.iter().enumerate() {
                        column[a] *= s;
                    }
                }
                for (a, s) in scales.iter().enumerate() {
                    b[(a, r)] = *s;
                }
                let b = b.into_const();
                triangular::matmul(
                    gram.rb_mut(),
                    BlockStructure::TriangularLower,
                    Accum::Add,
                    b.transpose(),
                    BlockStructure::Rectangular,
                    b,
                    BlockStructure::Rectangular,
                    *sign,
                    par,
                );
            }
        }
    }

    /// Φ̃ᵀWΦ̃ ((r + 1)², Φ̃ = [Φ 1], W the rows' weights) over the problem's rows: its lower
    /// triangle only (the upper triangle stays zero).
    pub fn gram(&self, weights: RowWeights, par: Par) -> Mat<f64> {
        let r = self.width();
        let all: Vec<(usize, f64)> = (0..self.nrows()).map(|i| (i, weights.of(i))).collect();
        let mut gram = Mat::<f64>::zeros(r + 1, r + 1);
        self.accumulate(&all, Some((1.0, gram.as_mut())), None, par);
        gram
    }

    /// Φ w for every row (n × q).
    fn times(&self, w: MatRef<f64>, par: Par) -> Mat<f64> {
        if let FeatureRows::Stored { all, rows } = *self {
            // Every stored row's product is cheaper than gathering the problem's rows.
            let every = all * w;
            return match rows {
                None => every,
                Some(rows) => Mat::from_fn(rows.len(), w.ncols(), |a, j| every[(rows[a], j)]),
            };
        }
        let (n, r) = (self.nrows(), self.width());
        let mut out = Mat::zeros(n, w.ncols());
        let mut block = Mat::<f64>::zeros(BLOCK.min(n), r);
        for start in (0..n).step_by(BLOCK) {
            let len = BLOCK.min(n - start);
            let rows: Vec<usize> = (start..start + len).collect();
            let mut b = block.as_mut().submatrix_mut(0, 0, len, r);
            self.gather(&rows, b.rb_mut(), par);
            matmul(
                out.as_mut().submatrix_mut(start, 0, len, w.ncols()),
                Accum::Replace,
                b.into_const(),
                w,
                1.0,
                par,
            );
        }
        out
    }
}

/// The row of the features (or inputs) that a problem's row `i` is: itself, or its entry in
/// the problem's list of `rows`.
fn stored_row(rows: Option<&[usize]>, i: usize) -> usize {
    rows.map_or(i, |rows| rows[i])
}

/// A reduced training problem.
#[derive(Clone, Copy)]
pub struct ReducedProblem<'a> {
    pub features: FeatureRows<'a>,
    /// Targets Y (n × q).
    pub targets: MatRef<'a, f64>,
    pub tube: Tube,
    /// Each row's weight in the loss.
    pub weights: RowWeights<'a>,
    /// Φ̃ᵀWΦ̃ over the problem's rows ([`FeatureRows::gram`] with the weights) when the caller
    /// has it (a search's folds share one per σ); computed by the solver otherwise.
    pub gram: Option<MatRef<'a, f64>>,
}

/// The reduced solver's result.
#[derive(Clone, Debug)]
pub struct ReducedSolution {
    /// Feature weights w (r × q).
    pub w: Mat<f64>,
    pub bias: Vec<f64>,
    pub objective: f64,
    pub iterations: usize,
    pub stop: StopReason,
    /// Rows outside the tube at the end (the exact model's support vectors would be these).
    pub outside: usize,
}

/// Solves from w = 0, b = mean(Y), stopping at a stop asked after `since`
/// ([`StopReason::Interrupted`]).
///
/// # Errors
/// [`NotPositiveDefinite`] when a step system cannot be factored (C beyond what f64 resolves).
pub fn solve(
    problem: &ReducedProblem,
    tol: f64,
    max_iter: usize,
    par: Par,
    since: crate::control::Since,
) -> Result<ReducedSolution, NotPositiveDefinite> {
    let (n, q) = problem.targets.shape();
    let (r, tube, y) = (problem.features.width(), problem.tube, problem.targets);
    assert_eq!(
        problem.features.nrows(),
        n,
        "one feature row per target row"
    );
    let computed;
    let gram = match problem.gram {
        Some(g) => g,
        None => {
            computed = problem.features.gram(problem.weights, par);
            computed.as_ref()
        }
    };

    let mut w = Mat::<f64>::zeros(r, q);
    let mut bias: Vec<f64> = (0..q)
        .map(|j| y.col(j).iter().sum::<f64>() / n as f64)
        .collect();
    let mut f = Mat::<f64>::zeros(n, q);
    let residuals =
        |f: &Mat<f64>, bias: &[f64]| Mat::from_fn(n, q, |i, j| y[(i, j)] - f[(i, j)] - bias[j]);
    let mut resid = residuals(&f, &bias);
    let mut objective = tube.data_term(resid.as_ref(), problem.weights);
    let mut iterations = 0;
    let stop = loop {
        if iterations == max_iter {
            break StopReason::IterationCap;
        }
        if since.stopped() {
            break StopReason::Interrupted;
        }
        iterations += 1;
        crate::control::iteration_done();
        // 1. Each row's weight and pulled-in target.
        let parts: Vec<Option<(f64, f64)>> = (0..n)
            .map(|i| tube.step_row(row_norm(resid.as_ref(), i), problem.weights.of(i)))
            .collect();
        // 2. The step target.
        let (w_star, bias_star) = step_target(problem, gram, &parts, resid.as_ref(), &bias, par)?;
        // 3. The line search.
        let f_star = problem.features.times(w_star.as_ref(), par);
        let delta = &w_star - &w;
        let g = Mat::from_fn(n, q, |i, j| {
            f_star[(i, j)] + bias_star[j] - f[(i, j)] - bias[j]
        });
        let quad = [
            frobenius_dot(w.as_ref(), w.as_ref()),
            frobenius_dot(w.as_ref(), delta.as_ref()),
            frobenius_dot(delta.as_ref(), delta.as_ref()),
        ];
        let previous = objective;
        let step = tube.step_along(resid.as_ref(), g.as_ref(), quad, objective, problem.weights);
        let Some((t, reached)) = step else {
            break StopReason::NoDescent;
        };
        w += faer::Scale(t) * &delta;
        for (j, b) in bias.iter_mut().enumerate() {
            *b += t * (bias_star[j] - *b);
        }
        f = Mat::from_fn(n, q, |i, j| f[(i, j)] + t * (f_star[(i, j)] - f[(i, j)]));
        resid = residuals(&f, &bias);
        objective = reached;
        if previous - objective <= tol * previous {
            break StopReason::Tolerance;
        }
    };
    let outside = (0..n)
        .filter(|&i| row_norm(resid.as_ref(), i) > tube.epsilon)
        .count();
    Ok(ReducedSolution {
        w,
        bias,
        objective,
        iterations,
        stop,
        outside,
    })
}

/// Step 2 of [`solve`]: the weights and bias that minimise the weighted quadratic model of the
/// loss, each row weighted and its target pulled in as `parts` say (`None` inside the tube);
/// `w = 0` and the bias kept when every row is inside.
fn step_target(
    problem: &ReducedProblem,
    gram: MatRef<'_, f64>,
    parts: &[Option<(f64, f64)>],
    resid: MatRef<'_, f64>,
    bias: &[f64],
    par: Par,
) -> Result<(Mat<f64>, Vec<f64>), NotPositiveDefinite> {
    let (r, tube, y) = (problem.features.width(), problem.tube, problem.targets);
    let q = y.ncols();
    // A quadratic row's weight as `Tube::step_row` computes it, so that such rows compare
    // equal: 2C wᵢ written otherwise can differ by a rounding, which made rows of the quadratic
    // zone count as leaving it with a negative share (NaN under its square root).
    let quadratic_weight = |i: usize| 1.0 / tube.quadratic_inverse_weight(problem.weights.of(i));
    let support: Vec<(usize, f64)> = parts
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.map(|(inv, _)| (i, 1.0 / inv)))
        .collect();
    if support.is_empty() {
        return Ok((Mat::zeros(r, q), bias.to_vec()));
    }
    let not_quadratic: Vec<(usize, f64)> = parts
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let a = p.map_or(0.0, |(inv, _)| 1.0 / inv);
            (a < quadratic_weight(i)).then_some((i, quadratic_weight(i) - a))
        })
        .collect();
    // Right-hand side Φ̃ᵀ A Y' over the support; the matrix from G and the rows outside the
    // quadratic zone when they are fewer, else in the same pass over the support.
    let targets = Mat::from_fn(support.len(), q, |a, j| {
        let (i, weight) = support[a];
        let (_, shrink) = parts[i].expect("support rows have a part");
        weight * (y[(i, j)] - shrink * resid[(i, j)])
    });
    let mut system = Mat::<f64>::zeros(r + 1, r + 1);
    let mut rhs = Mat::<f64>::zeros(r + 1, q);
    let features = &problem.features;
    if not_quadratic.len() < support.len() {
        system.copy_from(gram);
        system *= faer::Scale(2.0 * tube.c);
        features.accumulate(&not_quadratic, Some((-1.0, system.as_mut())), None, par);
        features.accumulate(&support, None, Some((targets.as_ref(), rhs.as_mut())), par);
    } else {
        features.accumulate(
            &support,
            Some((1.0, system.as_mut())),
            Some((targets.as_ref(), rhs.as_mut())),
            par,
        );
    }
    for j in 0..r {
        system[(j, j)] += 1.0;
    }
    let llt = system.llt(Side::Lower).map_err(|_| NotPositiveDefinite {
        pivot: 0,
        size: r + 1,
    })?;
    let solution = llt.solve(&rhs);
    Ok((
        solution.as_ref().submatrix(0, 0, r, q).to_owned(),
        (0..q).map(|j| solution[(r, j)]).collect::<Vec<f64>>(),
    ))
}
