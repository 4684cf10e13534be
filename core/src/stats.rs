//! Medians, in one place and with their convention stated.
//!
//! [`median`] is the textbook median: the middle value, or the mean of the two middle values of
//! an even count. [`upper_median`] is the upper of the two middle values (`v[n / 2]` of the
//! sorted values): always one of the data, which a robust threshold or a reference element
//! needs. Both return `None` for no values, as do [`quantiles`] (nearest rank) for summaries
//! and [`mean_sd`].

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

/// The per-coordinate [`median`] of points; the origin for no points.
pub fn median_point(points: &[Vector3<f64>]) -> Vector3<f64> {
    let coordinate = |k: usize| {
        let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
        median(&mut v).unwrap_or(0.0)
    };
    Vector3::new(coordinate(0), coordinate(1), coordinate(2))
}

#[cfg(test)]
mod tests {
    use super::*;

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
