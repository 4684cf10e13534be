//! The reduced basis: m centres among the scaled inputs and the Nyström feature map on them.
//!
//! Exact MSVR expands f in a kernel at every training row (n × n kernel). The reduced basis
//! expands it at m centres only: f(x) = Σⱼ K(x, cⱼ) βⱼ + b, with the regulariser ½ tr(βᵀ K_mm β)
//! (the subset of regressors). Written with the Nyström features φ(x) = L⁻¹ k_m(x), K_mm = L Lᵀ,
//! it is a linear model in m dimensions, f = φᵀw + b with β = L⁻ᵀ w and ½‖w‖² as regulariser,
//! which [`super::reduced`] fits in O(n m²) time and O(m²) memory besides the features.
//!
//! - **Centres** by k-means++ seeding (Arthur & Vassilvitskii 2007) on the scaled inputs: the
//!   first uniformly, each next one with probability ∝ its squared distance to the nearest
//!   centre chosen, with the given seed. They depend on the inputs only, not on σ nor the
//!   outputs, so every candidate of a search shares them. Rows already chosen (distance 0) are
//!   never chosen again: a design with fewer distinct rows than m gets fewer centres.
//! - **The map** by pivoted Cholesky of K_mm: a centre whose kernel column is, at this σ, within
//!   [`PIVOT_TOL`] of the span of those before it adds nothing but rounding, so it is dropped;
//!   the kept centres' factor is well conditioned, and the model file holds only them.

use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve;
use faer::reborrow::ReborrowMut;
use faer::{Accum, Mat, MatMut, MatRef, Par};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::kernel;
use crate::data::Columns;

/// A centre is dropped when its kernel column's residual after the centres before it is below
/// this (the kernel's diagonal is 1): its feature would carry 1/√tol of rounding.
pub const PIVOT_TOL: f64 = 1e-10;

/// Up to `m` centres among the rows of `x` (scaled inputs) by seeded k-means++ seeding: the
/// rows chosen, in the order chosen.
pub fn kmeans_pp(x: &Columns, m: usize, seed: u64) -> Vec<usize> {
    let n = x.rows();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut chosen = Vec::with_capacity(m.min(n));
    if n == 0 || m == 0 {
        return chosen;
    }
    let mut d2 = vec![f64::INFINITY; n];
    let mut next = rng.random_range(0..n);
    loop {
        chosen.push(next);
        if chosen.len() == m.min(n) {
            break;
        }
        let c = x.row(next);
        for (i, d) in d2.iter_mut().enumerate() {
            *d = d.min(kernel::squared_distance(x.row(i), c));
        }
        let total: f64 = d2.iter().sum();
        if total <= 0.0 {
            break; // every row coincides with a centre
        }
        let mut target = rng.random::<f64>() * total;
        next = d2
            .iter()
            .position(|&d| {
                target -= d;
                target < 0.0 && d > 0.0
            })
            .unwrap_or_else(|| d2.iter().rposition(|&d| d > 0.0).expect("total > 0"));
    }
    chosen
}

/// The Nyström feature map of a set of centres at one σ.
#[derive(Clone, Debug)]
pub struct NystromMap {
    /// The kept centres, scaled inputs (r × d).
    pub centres: Columns,
    pub sigma: f64,
    /// L, lower triangular with K among the kept centres = L Lᵀ (r × r).
    factor: Mat<f64>,
}

impl NystromMap {
    /// The map on the rows of `candidates` (in order of preference), dropping those the pivoted
    /// Cholesky finds redundant at this σ (module docs).
    pub fn new(candidates: &Columns, sigma: f64) -> Self {
        let m = candidates.rows();
        let k = kernel::rbf(candidates, candidates, sigma);
        // Pivoted Cholesky in the given order: greedy by largest residual diagonal, which keeps
        // the best-separated centres first.
        let mut diag: Vec<f64> = (0..m).map(|i| k[(i, i)]).collect();
        let mut taken = vec![false; m];
        let mut pivots: Vec<usize> = Vec::new();
        // The factor's columns over all m candidates: column c is L[:, c].
        let mut l = Mat::<f64>::zeros(m, m);
        while let Some((p, &best)) = diag
            .iter()
            .enumerate()
            .filter(|(i, _)| !taken[*i])
            .max_by(|a, b| a.1.total_cmp(b.1))
        {
            if best < PIVOT_TOL {
                break;
            }
            let c = pivots.len();
            let root = best.sqrt();
            // L[:, c] = (K[:, p] − L[:, ..c] L[p, ..c]ᵀ) / √d_p.
            let mut col = k.col(p).to_owned();
            matmul(
                col.as_mat_mut(),
                Accum::Add,
                l.as_ref().submatrix(0, 0, m, c),
                l.as_ref().submatrix(p, 0, 1, c).transpose(),
                -1.0,
                Par::Seq,
            );
            for i in 0..m {
                let v = col[i] / root;
                l[(i, c)] = v;
                diag[i] -= v * v;
            }
            taken[p] = true;
            pivots.push(p);
        }
        let r = pivots.len();
        let factor = Mat::from_fn(r, r, |i, j| if j <= i { l[(pivots[i], j)] } else { 0.0 });
        let centres = Columns::new(
            candidates.names.clone(),
            pivots
                .iter()
                .flat_map(|&p| candidates.row(p).to_vec())
                .collect(),
        );
        NystromMap {
            centres,
            sigma,
            factor,
        }
    }

    /// Kept centres r.
    pub fn width(&self) -> usize {
        self.centres.rows()
    }

    /// The features of the listed rows of `x` (scaled inputs) into `out` (rows.len() × r).
    fn features_into(&self, x: &Columns, rows: &[usize], mut out: MatMut<f64>) {
        let gamma = 1.0 / (2.0 * self.sigma * self.sigma);
        for j in 0..self.width() {
            let c = self.centres.row(j);
            for (a, &i) in rows.iter().enumerate() {
                out[(a, j)] = (-gamma * kernel::squared_distance(x.row(i), c)).exp();
            }
        }
        // φᵀ = L⁻¹ kᵀ for each row: solve L Φᵀ = Kᵀ, i.e. Φ Lᵀ = K.
        triangular_solve::solve_lower_triangular_in_place(
            self.factor.as_ref(),
            out.transpose_mut(),
            Par::Seq,
        );
    }

    /// The features of the listed rows of `x` into `out` (rows.len() × r): blocks of rows side
    /// by side unless `par` is sequential (a search's folds already run side by side).
    pub fn features_of(&self, x: &Columns, rows: &[usize], mut out: MatMut<f64>, par: Par) {
        const ROWS: usize = 256;
        if par == Par::Seq || rows.len() <= ROWS {
            return self.features_into(x, rows, out);
        }
        let blocks: Vec<Mat<f64>> = rows
            .par_chunks(ROWS)
            .map(|rows| {
                let mut m = Mat::zeros(rows.len(), self.width());
                self.features_into(x, rows, m.as_mut());
                m
            })
            .collect();
        for (k, m) in blocks.iter().enumerate() {
            out.rb_mut()
                .submatrix_mut(k * ROWS, 0, m.nrows(), m.ncols())
                .copy_from(m);
        }
    }

    /// Every row's features (n × r).
    pub fn features(&self, x: &Columns) -> Mat<f64> {
        let rows: Vec<usize> = (0..x.rows()).collect();
        let mut out = Mat::zeros(x.rows(), self.width());
        self.features_of(x, &rows, out.as_mut(), Par::rayon(0));
        out
    }

    /// The kernel coefficients β = L⁻ᵀ w of feature weights w (r × q).
    pub fn coefficients(&self, w: MatRef<f64>) -> Mat<f64> {
        let mut beta = w.to_owned();
        triangular_solve::solve_upper_triangular_in_place(
            self.factor.transpose(),
            beta.as_mut(),
            Par::Seq,
        );
        beta
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> Columns {
        let values = (0..n * n)
            .flat_map(|k| {
                [
                    (k / n) as f64 / (n - 1) as f64,
                    (k % n) as f64 / (n - 1) as f64,
                ]
            })
            .collect();
        Columns::new(vec!["a".into(), "b".into()], values)
    }

    #[test]
    fn kmeans_pp_is_seeded_and_never_repeats_a_point() {
        let x = grid(6);
        let a = kmeans_pp(&x, 10, 7);
        assert_eq!(a, kmeans_pp(&x, 10, 7));
        assert_ne!(a, kmeans_pp(&x, 10, 8));
        let mut sorted = a.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 10);
        // Duplicated rows: 3 distinct points give 3 centres whatever m asks.
        let dup = Columns::new(vec!["a".into()], vec![0.0, 1.0, 0.0, 2.0, 1.0, 2.0]);
        assert_eq!(kmeans_pp(&dup, 5, 1).len(), 3);
    }

    #[test]
    fn features_reproduce_the_kernel_among_centres() {
        // φ(cᵢ)ᵀ φ(cⱼ) = K(cᵢ, cⱼ) for kept centres, and kernel expansions agree:
        // φ(x)ᵀ w = k_m(x)ᵀ β with β = L⁻ᵀ w.
        let x = grid(5);
        let map = NystromMap::new(&x, 0.4);
        assert!(map.width() > 10, "{}", map.width());
        let phi = map.features(&map.centres);
        let k = kernel::rbf(&map.centres, &map.centres, 0.4);
        let gram = &phi * phi.transpose();
        for i in 0..map.width() {
            for j in 0..map.width() {
                assert!((gram[(i, j)] - k[(i, j)]).abs() < 1e-8, "{i},{j}");
            }
        }
        let w = Mat::from_fn(map.width(), 2, |i, j| ((i * 3 + j) as f64).sin());
        let beta = map.coefficients(w.as_ref());
        let phi_x = map.features(&x);
        let k_x = kernel::rbf(&x, &map.centres, 0.4);
        let (a, b) = (&phi_x * &w, &k_x * &beta);
        for i in 0..x.rows() {
            assert!((a[(i, 0)] - b[(i, 0)]).abs() < 1e-6 && (a[(i, 1)] - b[(i, 1)]).abs() < 1e-6);
        }
    }

    #[test]
    fn a_wide_kernel_drops_redundant_centres() {
        // At σ = 5 on the unit square the 25 kernel columns are numerically of low rank.
        let x = grid(5);
        let wide = NystromMap::new(&x, 5.0);
        assert!(wide.width() < 25, "{}", wide.width());
        assert_eq!(NystromMap::new(&x, 0.1).width(), 25);
    }
}
