//! Medians, in one place and with their convention stated.
//!
//! [`median`] is the textbook median: the middle value, or the mean of the two middle values of
//! an even count. [`upper_median`] is the upper of the two middle values (`v[n / 2]` of the
//! sorted values): always one of the data, which a robust threshold or a reference element
//! needs. Both return `None` for no values, as do [`quantiles`] (nearest rank) for summaries
//! and [`mean_sd`]. [`quantile_upper_bound`] bounds a quantile from above with a stated
//! confidence. [`paired_difference`] compares two models' scores on the same folds.
//! [`Line`] is the least-squares line through points. [`chi_square_quantile`]
//! is the χ² distribution's quantile, for gates on sums of squared normalized residuals.

use std::cmp::Ordering;

use nalgebra::Vector3;

/// The upper median by `compare`: the element that sorts to position `n / 2`. Reorders
/// `values`.
pub fn upper_median_by<T: Copy>(
    values: &mut [T],
    compare: impl FnMut(&T, &T) -> Ordering,
) -> Option<T> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    Some(*values.select_nth_unstable_by(mid, compare).1)
}

/// The upper median of numbers (ordered by `total_cmp`). Reorders `values`.
pub fn upper_median(values: &mut [f64]) -> Option<f64> {
    upper_median_by(values, f64::total_cmp)
}

/// The median: the middle value, or the mean of the two middle values. Reorders `values`.
pub fn median(values: &mut [f64]) -> Option<f64> {
    let n = values.len();
    let upper = upper_median(values)?;
    if n % 2 == 1 {
        return Some(upper);
    }
    // After the selection, the lower middle value is the largest of the first half.
    let lower = values[..n / 2]
        .iter()
        .copied()
        .max_by(f64::total_cmp)
        .expect("n ≥ 2");
    Some((lower + upper) / 2.0)
}

/// The values at fractions `q` of the sorted values (nearest rank: position round((n − 1) q),
/// so 0.5 gives the upper median and 1 the largest). Sorts `values`; `None` for no values.
pub fn quantiles<const N: usize>(values: &mut [f64], q: [f64; N]) -> Option<[f64; N]> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let last = (values.len() - 1) as f64;
    Some(q.map(|q| values[(last * q).round() as usize]))
}

/// An upper confidence bound of the `q` quantile of the distribution the `values` are drawn
/// from (independently): the smallest order statistic that lies at or above that quantile with
/// probability `confidence` whatever the distribution. The k-th smallest of n does so with
/// probability P(Binomial(n, q) ≤ k − 1), so k − 1 is that binomial's `confidence` quantile.
/// `None` when n values are too few for any (q^n > 1 − `confidence`: 22 values for 0.9 and
/// 0.9). Sorts `values`.
pub fn quantile_upper_bound(values: &mut [f64], q: f64, confidence: f64) -> Option<f64> {
    let n = values.len();
    // P(Binomial(n, q) = j) summed up from j = 0, each term from the last in logarithms.
    let odds = (q / (1.0 - q)).ln();
    let mut log_pmf = n as f64 * (1.0 - q).ln();
    let mut cdf = 0.0;
    for j in 0..n {
        cdf += log_pmf.exp();
        if cdf >= confidence {
            values.sort_by(f64::total_cmp);
            return Some(values[j]);
        }
        log_pmf += ((n - j) as f64 / (j + 1) as f64).ln() + odds;
    }
    None
}

/// The mean of `a` less `b`, fold by fold (each fold's score weighed by its `weights`, e.g.
/// its held-out values: for per-fold MAEs the pooled MAEs' difference), and its standard error
/// over the folds (0 for one fold).
pub fn paired_difference(a: &[f64], b: &[f64], weights: &[usize]) -> (f64, f64) {
    let w: Vec<f64> = weights.iter().map(|&v| v as f64).collect();
    let total: f64 = w.iter().sum();
    let d: Vec<f64> = a.iter().zip(b).map(|(a, b)| a - b).collect();
    let mean = d.iter().zip(&w).map(|(d, w)| d * w).sum::<f64>() / total;
    let k = d.len() as f64;
    if d.len() < 2 {
        return (mean, 0.0);
    }
    let spread: f64 = d
        .iter()
        .zip(&w)
        .map(|(d, w)| (w * (d - mean)).powi(2))
        .sum();
    (mean, (spread * k / (k - 1.0)).sqrt() / total)
}

/// Mean and standard deviation (population: divided by n) of `values`; `None` for none.
pub fn mean_sd(values: &[f64]) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    Some((mean, var.sqrt()))
}

/// The least-squares line through points (x, y): it passes through their means.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Line {
    pub mean_x: f64,
    pub mean_y: f64,
    pub slope: f64,
    /// Σ (x − x̄)², for the slope's standard error.
    pub sxx: f64,
}

impl Line {
    /// The line through `points`; `None` for fewer than two or when every x is the same.
    pub fn fit(points: &[(f64, f64)]) -> Option<Line> {
        if points.len() < 2 {
            return None;
        }
        let n = points.len() as f64;
        let mean_x = points.iter().map(|p| p.0).sum::<f64>() / n;
        let mean_y = points.iter().map(|p| p.1).sum::<f64>() / n;
        let sxx: f64 = points.iter().map(|p| (p.0 - mean_x).powi(2)).sum();
        let sxy: f64 = points.iter().map(|p| (p.0 - mean_x) * (p.1 - mean_y)).sum();
        (sxx > 0.0).then(|| Line {
            mean_x,
            mean_y,
            slope: sxy / sxx,
            sxx,
        })
    }

    /// The line's y at `x`.
    pub fn at(&self, x: f64) -> f64 {
        self.mean_y + self.slope * (x - self.mean_x)
    }
}

/// The per-coordinate [`median`] of points; the origin for no points.
pub fn median_point(points: &[Vector3<f64>]) -> Vector3<f64> {
    let coordinate = |k: usize| {
        let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
        median(&mut v).unwrap_or(0.0)
    };
    Vector3::new(coordinate(0), coordinate(1), coordinate(2))
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, nine terms: 15 significant digits).
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x) Γ(1 − x) = π / sin(πx).
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let sum = G[1..]
        .iter()
        .enumerate()
        .fold(G[0], |s, (i, g)| s + g / (x + i as f64 + 1.0));
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + sum.ln()
}

/// The regularized lower incomplete gamma function P(a, x): its series below a + 1, its
/// continued fraction (modified Lentz) above.
fn gamma_p(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let front = (a * x.ln() - x - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut term, mut sum, mut n) = (1.0 / a, 1.0 / a, a);
        while term.abs() > sum.abs() * 1e-16 {
            n += 1.0;
            term *= x / n;
            sum += term;
        }
        return sum * front;
    }
    let tiny = 1e-300;
    let mut b = x + 1.0 - a;
    let (mut c, mut d) = (1.0 / tiny, 1.0 / b);
    let mut h = d;
    for i in 1..500 {
        let an = -(i as f64) * (i as f64 - a);
        b += 2.0;
        d = an * d + b;
        d = if d.abs() < tiny { tiny } else { d };
        c = b + an / c;
        c = if c.abs() < tiny { tiny } else { c };
        d = 1.0 / d;
        let step = d * c;
        h *= step;
        if (step - 1.0).abs() < 1e-16 {
            break;
        }
    }
    1.0 - front * h
}

/// The `p` quantile of the χ² distribution with `dof` degrees of freedom (`dof` ≥ 1, `p` in
/// (0, 1)): the value a sum of `dof` squared standard normals stays below with probability `p`
/// (bisection on the CDF to 1e-12 relative).
pub fn chi_square_quantile(dof: usize, p: f64) -> f64 {
    let k = dof.max(1) as f64;
    let cdf = |x: f64| gamma_p(k / 2.0, x / 2.0);
    let (mut lo, mut hi) = (0.0, k.max(1.0));
    while cdf(hi) < p {
        hi *= 2.0;
    }
    while hi - lo > 1e-12 * hi {
        let mid = 0.5 * (lo + hi);
        if cdf(mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    #[test]
    fn chi_square_quantiles_are_the_tables() {
        // Tabulated χ² quantiles (dof, p, value).
        for (dof, p, value) in [
            (1, 0.99, 6.634_897),
            (1, 0.5, 0.454_936),
            (2, 0.95, 5.991_465),
            (3, 0.99, 11.344_867),
            (5, 0.99, 15.086_272),
            (9, 0.999, 27.877_165),
            (30, 0.01, 14.953_457),
        ] {
            let got = super::chi_square_quantile(dof, p);
            assert!((got - value).abs() < 1e-5 * value, "dof {dof} p {p}: {got}");
        }
    }

    use super::*;

    #[test]
    fn a_quantiles_upper_bound_is_the_binomials_order_statistic_and_holds_its_confidence() {
        // scipy.stats.binom.ppf(0.9, n, 0.9) + 1 is the 1-based rank: 113 of 120, 549+1 of 600.
        for (n, rank) in [(22, 22), (30, 30), (60, 58), (120, 113), (600, 550)] {
            let mut v: Vec<f64> = (1..=n).rev().map(|i| i as f64).collect();
            let got = quantile_upper_bound(&mut v, 0.9, 0.9);
            assert_eq!(got, Some(rank as f64), "n = {n}");
        }
        assert_eq!(quantile_upper_bound(&mut [1.0; 21], 0.9, 0.9), None);
        assert_eq!(quantile_upper_bound(&mut [], 0.9, 0.9), None);
        // Uniform draws: the 0.9 quantile is 0.9; the bound lies above it in about 90 % of
        // samples of 120 (binomial: 0.9 ± 0.03 over 1000 samples).
        let mut state = 12345u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let held = (0..1000)
            .filter(|_| {
                let mut v: Vec<f64> = (0..120).map(|_| uniform()).collect();
                quantile_upper_bound(&mut v, 0.9, 0.9).unwrap() >= 0.9
            })
            .count();
        assert!((870..=930).contains(&held), "{held} of 1000");
    }

    #[test]
    fn a_line_goes_through_the_means_with_the_least_squares_slope() {
        let line = Line::fit(&[(0.0, 1.0), (1.0, 3.0), (2.0, 5.0), (3.0, 7.5)]).unwrap();
        assert!((line.slope - 2.15).abs() < 1e-12, "{line:?}");
        assert!((line.at(1.5) - 4.125).abs() < 1e-12, "{line:?}");
        assert!((line.sxx - 5.0).abs() < 1e-12);
        assert_eq!(Line::fit(&[(1.0, 2.0)]), None);
        assert_eq!(Line::fit(&[(1.0, 2.0), (1.0, 3.0)]), None);
    }

    #[test]
    fn conventions() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(upper_median(&mut [4.0, 1.0, 3.0, 2.0]), Some(3.0));
        assert_eq!(upper_median_by(&mut [5, -1, 2], i32::cmp), Some(2));
        assert_eq!(median(&mut []), None);
        let p = median_point(&[Vector3::new(0.0, 1.0, 9.0), Vector3::new(2.0, 3.0, 1.0)]);
        assert_eq!(p, Vector3::new(1.0, 2.0, 5.0));
    }
}
