//! The Gaussian (RBF) kernel K(x, x') = exp(−‖x − x'‖² / (2σ²)).
//!
//! The distance is squared once (some public MSVR ports square it twice, which is not this kernel).

use faer::{Mat, MatRef};
use rayon::prelude::*;

use crate::data::Columns;

/// Fills `out[i, j] = f(i, j)` column by column, columns in parallel.
fn fill_by_column(rows: usize, cols: usize, f: impl Fn(usize, &mut [f64]) + Sync) -> Mat<f64> {
    let mut out = Mat::zeros(rows, cols);
    out.par_col_iter_mut().enumerate().for_each(|(j, col)| {
        let col = col
            .try_as_col_major_mut()
            .expect("a fresh matrix is column-major");
        f(j, col.as_slice_mut());
    });
    out
}

/// ‖a − b‖².
pub fn squared_distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Squared distances ‖aᵢ − bⱼ‖² (`a.rows() × b.rows()`), computed in parallel.
///
/// # Panics
/// If `a` and `b` differ in width.
pub fn squared_distances(a: &Columns, b: &Columns) -> Mat<f64> {
    assert_eq!(a.width(), b.width(), "points of different dimension");
    fill_by_column(a.rows(), b.rows(), |j, col| {
        let bj = b.row(j);
        for (o, ai) in col.iter_mut().zip(a.iter_rows()) {
            *o = squared_distance(ai, bj);
        }
    })
}

/// The kernel from the squared distances of a set of points with themselves (`d2` symmetric):
/// exp(−d² / (2σ²)) on and above the diagonal, mirrored below (half the exponentials; d² is
/// symmetric to the bit, so the matrix is [`rbf`]`(a, a, σ)` to the bit).
pub fn rbf_from_squared(d2: MatRef<f64>, sigma: f64) -> Mat<f64> {
    assert_eq!(
        d2.nrows(),
        d2.ncols(),
        "a square matrix of squared distances"
    );
    let gamma = 1.0 / (2.0 * sigma * sigma);
    let mut out = fill_by_column(d2.nrows(), d2.ncols(), |j, col| {
        for (o, d) in col[..=j].iter_mut().zip(d2.col(j).iter()) {
            *o = (-gamma * d).exp();
        }
    });
    mirror_upper(&mut out);
    out
}

/// The kernel matrix of the rows of `a` with themselves (symmetric: half the exponentials of
/// [`rbf`]`(a, a, σ)`, the same matrix).
pub fn rbf_gram(a: &Columns, sigma: f64) -> Mat<f64> {
    let gamma = 1.0 / (2.0 * sigma * sigma);
    let rows: Vec<&[f64]> = a.iter_rows().collect();
    let mut out = fill_by_column(a.rows(), a.rows(), |j, col| {
        for (o, ai) in col[..=j].iter_mut().zip(&rows) {
            *o = (-gamma * squared_distance(ai, rows[j])).exp();
        }
    });
    mirror_upper(&mut out);
    out
}

/// Copies the upper triangle of a square matrix onto the lower one.
fn mirror_upper(m: &mut Mat<f64>) {
    for j in 0..m.ncols() {
        for i in j + 1..m.nrows() {
            m[(i, j)] = m[(j, i)];
        }
    }
}

/// The kernel matrix between the rows of `a` and of `b`.
///
/// # Panics
/// If `a` and `b` differ in width.
pub fn rbf(a: &Columns, b: &Columns, sigma: f64) -> Mat<f64> {
    assert_eq!(a.width(), b.width(), "points of different dimension");
    let gamma = 1.0 / (2.0 * sigma * sigma);
    fill_by_column(a.rows(), b.rows(), |j, col| {
        let bj = b.row(j);
        for (o, ai) in col.iter_mut().zip(a.iter_rows()) {
            *o = (-gamma * squared_distance(ai, bj)).exp();
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_of_the_distance_squared_once() {
        let a = Columns::new(vec!["u".into(), "v".into()], vec![0.0, 0.0, 3.0, 4.0]);
        let k = rbf(&a, &a, 2.0);
        assert_eq!(k[(0, 0)], 1.0);
        let expected = (-25.0f64 / 8.0).exp();
        assert!((k[(0, 1)] - expected).abs() < 1e-15 && k[(1, 0)] == k[(0, 1)]);
        let via_squared = rbf_from_squared(squared_distances(&a, &a).as_ref(), 2.0);
        assert_eq!(via_squared, k);
    }

    #[test]
    fn the_symmetric_kernels_are_the_full_one_to_the_bit() {
        let n = 37;
        let values = (0..3 * n)
            .map(|k| ((k * 7919) % 101) as f64 / 101.0)
            .collect();
        let a = Columns::new(vec!["u".into(), "v".into(), "w".into()], values);
        let full = rbf(&a, &a, 0.3);
        assert_eq!(rbf_gram(&a, 0.3), full);
        assert_eq!(
            rbf_from_squared(squared_distances(&a, &a).as_ref(), 0.3),
            full
        );
    }
}
