//! Two cameras' frame times: each one's period and the frames it dropped, and how far apart the
//! two are; one definition for `capture`'s live line and summary and `triangulate`'s clock
//! report and messages.
//!
//! The period is the median interval between consecutive frames. The frames dropped in a run of
//! frames are those its span should hold and it does not: round(span / period) + 1 − frames. A
//! frame stamped late (jitter) lengthens one interval and shortens the next, so it changes
//! neither the span's count nor the result; counting long intervals instead (over 1.5 periods)
//! takes such a frame for a drop.

/// The median interval between consecutive `times` (sorted, s); 0 with fewer than two.
pub fn period(times: &[f64]) -> f64 {
    let mut gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    crate::stats::median(&mut gaps).unwrap_or(0.0)
}

/// Frames missing from a run of `times` (sorted, s) taken every `period` s.
pub fn dropped(times: &[f64], period: f64) -> usize {
    match (times.first(), times.last()) {
        (Some(first), Some(last)) if period > 0.0 => {
            let expected = ((last - first) / period).round() as usize + 1;
            expected.saturating_sub(times.len())
        }
        _ => 0,
    }
}

/// The median distance (s) from each `left` time to the nearest `right` time (both sorted); 0
/// when either is empty.
pub fn skew(left: &[f64], right: &[f64]) -> f64 {
    if right.is_empty() {
        return 0.0;
    }
    let mut d: Vec<f64> = left
        .iter()
        .map(|t| {
            let k = right.partition_point(|r| r < t);
            [k.checked_sub(1), Some(k)]
                .into_iter()
                .flatten()
                .filter_map(|k| right.get(k))
                .map(|r| (r - t).abs())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    crate::stats::median(&mut d).unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn late_frames_are_not_drops_and_missing_ones_are() {
        let p = 1.0 / 30.0;
        let mut times: Vec<f64> = (0..90).map(|k| k as f64 * p).collect();
        // Frame 10 stamped 60 % of a period late: one long and one short interval.
        times[10] += 0.6 * p;
        assert!((period(&times) - p).abs() < 1e-12);
        assert_eq!(dropped(&times, p), 0);
        // Frames 40-42 lost.
        times.drain(40..43);
        assert_eq!(dropped(&times, period(&times)), 3);
        assert_eq!(dropped(&[], p), 0);
        assert_eq!(dropped(&[1.0], 0.0), 0);
    }

    #[test]
    fn skew_is_the_median_distance_to_the_nearest_partner() {
        let left = [0.0, 1.0, 2.0];
        let right = [0.01, 0.97, 2.5];
        assert!((skew(&left, &right) - 0.03).abs() < 1e-12);
        assert_eq!(skew(&left, &[]), 0.0);
    }
}
