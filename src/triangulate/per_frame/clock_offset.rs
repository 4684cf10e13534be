//! The offset between the cameras' clocks, from the motion itself (the module docs' step 3).

use nalgebra::Vector3;

use super::{lerp, Seen, Track};
use crate::stats::Line;
use crate::stereo::{Side, StereoRig};
use crate::triangulate::{distance_px, TriangulateError};

/// Epipolar distances above this count as this in the clock's fit (px): detections gone wrong
/// must not pull it.
const EPIPOLAR_CAP_PX: f64 = 2.0;
/// The tip must move at least this between two right frames (px) for the frame to tell the
/// clock offset.
const MOVING_PX: f64 = 0.3;
/// The largest clock offset looked for (s): two webcams' delays differ by tens of
/// milliseconds (one more than a frame period is common), a network camera's by more.
pub(super) const MAX_OFFSET_S: f64 = 0.5;
/// Moving frames per run whose clock offset is measured on its own, to see a drift (one
/// second of motion; a run's δ needs 20), and the fewest runs that can show one.
const DRIFT_FRAMES: usize = 30;
const DRIFT_RUNS: usize = 5;

/// Student's t at 99.5 % (a two-sided test at 1 %) for 1-30 degrees of freedom; beyond, the
/// normal's 2.576 plus the first term of the Cornish-Fisher expansion.
fn student_t_995(dof: usize) -> f64 {
    const T: [f64; 30] = [
        63.657, 9.925, 5.841, 4.604, 4.032, 3.707, 3.499, 3.355, 3.250, 3.169, 3.106, 3.055, 3.012,
        2.977, 2.947, 2.921, 2.898, 2.878, 2.861, 2.845, 2.831, 2.819, 2.807, 2.797, 2.787, 2.779,
        2.771, 2.763, 2.756, 2.750,
    ];
    match dof {
        0 => f64::INFINITY,
        1..=30 => T[dof - 1],
        _ => 2.576 + 5.2 / dof as f64,
    }
}

/// The offset between the cameras' clocks: a left instant `t` is `t + at(t)` on the right
/// camera's clock.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct ClockOffset {
    /// The offset at `mid_s` (s).
    pub offset_s: f64,
    pub mid_s: f64,
    /// How fast the offset grows (s per s): the stamps of one camera drift against the other's.
    pub drift: f64,
    /// How many moving frames told it (0: not measured, no offset).
    pub frames: usize,
}

impl ClockOffset {
    pub fn at(&self, t: f64) -> f64 {
        self.offset_s + self.drift * (t - self.mid_s)
    }
}

/// The clock offset (see the module docs, step 3) from the centres a pass without an offset
/// saw: one δ for the whole session, then one for each run of [`DRIFT_FRAMES`] moving frames;
/// a line through those is the offset when its slope differs from 0 at the 1 % level (Student's
/// t; a drift: stamps from each camera's own clock, or videos whose frame rates are off).
pub(super) fn clock_offset(
    rig: &StereoRig,
    left: &Track,
    right: &Track,
    seen: &Seen,
) -> Result<ClockOffset, TriangulateError> {
    // The centres seen, undistorted once: the left frame's, and the right track's frames'.
    let [left_px, right_px] = seen;
    let undistort =
        |px: &[Option<[f64; 2]>], side: Side| -> Result<Vec<Option<[f64; 2]>>, TriangulateError> {
            let seen: Vec<[f64; 2]> = px.iter().flatten().copied().collect();
            let mut undistorted = rig.undistorted(side, &seen)?.into_iter();
            Ok(px
                .iter()
                .map(|p| p.and_then(|_| undistorted.next()))
                .collect())
        };
    let (ul, ur) = (
        undistort(left_px, Side::Left)?,
        undistort(right_px, Side::Right)?,
    );
    let f = rig.fundamental();
    // Left frame k's capped squared epipolar distance at offset δ, where the tip moves.
    let frame_cost = |k: usize, delta: f64| -> Option<f64> {
        let l = ul[k]?;
        let (a, b, s) = right.around(left.times[k] + delta).ok()?;
        let (p, q) = (ur[a]?, ur[b]?);
        if distance_px(p, q) < MOVING_PX {
            return None;
        }
        let r = lerp(p, q, s);
        let line = f * Vector3::new(l[0], l[1], 1.0);
        let d = (line[0] * r[0] + line[1] * r[1] + line[2]) / line[0].hypot(line[1]);
        Some(d.abs().min(EPIPOLAR_CAP_PX).powi(2))
    };
    // The δ within `reach` of `centre` that fits frames `ks` best, and how many told it: a
    // scan every `step`, then the parabola through the best and its neighbours (ties to the
    // nearer `centre`).
    let scan = |ks: &[usize], centre: f64, reach: f64, step: f64| -> Option<(f64, usize)> {
        let reach = (reach / step).ceil() as i64;
        let scanned: Vec<(f64, f64, usize)> = (-reach..=reach)
            .map(|j| {
                let delta = centre + j as f64 * step;
                let (sum, n) = ks
                    .iter()
                    .filter_map(|&k| frame_cost(k, delta))
                    .fold((0.0, 0), |(sum, n), c| (sum + c, n + 1));
                let mean = if n > 0 { sum / n as f64 } else { f64::INFINITY };
                (delta, mean, n)
            })
            .collect();
        let best = (0..scanned.len()).min_by(|&a, &b| {
            let near = |x: f64| (x - centre).abs();
            scanned[a]
                .1
                .total_cmp(&scanned[b].1)
                .then(near(scanned[a].0).total_cmp(&near(scanned[b].0)))
        })?;
        let n = scanned[best].2;
        if n < 20 || !scanned[best].1.is_finite() {
            return None;
        }
        let mut delta = scanned[best].0;
        if best > 0 && best + 1 < scanned.len() {
            let (a, b, c) = (scanned[best - 1].1, scanned[best].1, scanned[best + 1].1);
            let curvature = a - 2.0 * b + c;
            if curvature > 0.0 && a.is_finite() && c.is_finite() {
                delta += step * 0.5 * (a - c) / curvature;
            }
        }
        Some((delta, n))
    };
    // A millisecond's scan over every offset looked for, then tenths of one around its best.
    let (fine, coarse) = (1e-4, 1e-3);
    let fit = |ks: &[usize], centre: f64, reach: f64| -> Option<(f64, usize)> {
        let (rough, _) = scan(ks, centre, reach, coarse)?;
        scan(ks, rough, 2.0 * coarse, fine)
    };
    let all: Vec<usize> = (0..ul.len()).collect();
    let Some((delta, frames)) = fit(&all, 0.0, MAX_OFFSET_S.max(right.period_s)) else {
        return Ok(ClockOffset::default());
    };
    let constant = ClockOffset {
        offset_s: delta,
        mid_s: 0.0,
        drift: 0.0,
        frames,
    };
    // The offset in runs of moving frames, and the line through them.
    let moving: Vec<usize> = all
        .into_iter()
        .filter(|&k| frame_cost(k, delta).is_some())
        .collect();
    let runs: Vec<(f64, f64)> = moving
        .chunks_exact(DRIFT_FRAMES)
        .filter_map(|run| {
            let (d, _) = fit(run, delta, right.period_s)?;
            let t = run.iter().map(|&k| left.times[k]).sum::<f64>() / run.len() as f64;
            Some((t, d))
        })
        .collect();
    if runs.len() < DRIFT_RUNS {
        return Ok(constant);
    }
    let Some(line) = Line::fit(&runs) else {
        return Ok(constant);
    };
    let residual: f64 = runs.iter().map(|&(t, d)| (d - line.at(t)).powi(2)).sum();
    let slope_se = (residual / (runs.len() - 2) as f64 / line.sxx).sqrt();
    if line.slope.abs() <= student_t_995(runs.len() - 2) * slope_se {
        return Ok(constant);
    }
    Ok(ClockOffset {
        offset_s: line.mean_y,
        mid_s: line.mean_x,
        drift: line.slope,
        frames,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_t_quantile_falls_with_the_degrees_of_freedom_towards_the_normals() {
        let t: Vec<f64> = (1..=200).map(student_t_995).collect();
        assert!(t.windows(2).all(|w| w[1] < w[0]), "{t:?}");
        assert!((t[9] - 3.169).abs() < 1e-9);
        assert!(t[199] > 2.576 && t[199] < 2.61, "{}", t[199]);
        assert_eq!(student_t_995(0), f64::INFINITY);
    }
}
