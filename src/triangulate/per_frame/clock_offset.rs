//! The offset between the cameras' clocks, from the motion itself (the module docs' step 3).

use nalgebra::Vector3;
use rayon::prelude::*;

use super::{lerp, Track, NEIGHBOUR_PX};
use crate::stats::Line;
use crate::stereo::{Side, StereoRig};
use crate::triangulate::{distance_px, TriangulateError};

/// Epipolar distances above this count as this in the clock's fit (px): detections gone wrong
/// must not pull it. This and [`MOVING_PX`] are multiples of a bead centre's noise (0.02-0.1 px
/// measured), which does not grow with the focal length: in pixels, unscaled.
const EPIPOLAR_CAP_PX: f64 = 2.0;
/// The tip must move at least this between two right frames (px) for the frame to tell the
/// clock offset.
const MOVING_PX: f64 = 0.3;
/// The largest clock offset looked for (s): two webcams' delays differ by tens of
/// milliseconds (one more than a frame period is common), a network camera's by more.
pub(super) const MAX_OFFSET_S: f64 = 0.5;
/// The fewest moving frames the session's offset is told by, and a run's.
const MIN_FRAMES: usize = 20;
const MIN_RUN_FRAMES: usize = 10;
/// Left frames per run whose clock offset is measured on its own, to see a drift (a second at
/// 30 fps), and the fewest runs that can show one.
const DRIFT_FRAMES: usize = 30;
const DRIFT_RUNS: usize = 5;
/// How far the refinement of a drift's line looks (s): a few times a run's error.
const REFINE_S: f64 = 0.02;

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

/// The offset between the cameras' clocks: a left instant `t` is [`Self::stamp_of`]`(t)` on
/// the right camera's clock.
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
    /// The other camera's stamp of the rows' camera's instant `t` (s): `t` plus the offset
    /// then.
    pub fn stamp_of(&self, t: f64) -> f64 {
        let offset = self.offset_s + self.drift * (t - self.mid_s);
        t + offset
    }
}

/// Per camera, per position in its track, the marker candidates found there (px).
pub(super) type Candidates = [Vec<Vec<[f64; 2]>>; 2];

/// The clock offset (see the module docs, step 3) from every candidate of every frame: one δ
/// for the whole session, then one for each run of [`DRIFT_FRAMES`] frames; a line through
/// those is the offset when its slope differs from 0 at the 1 % level (Student's t; a drift:
/// stamps from each camera's own clock, or videos whose frame rates are off).
pub(super) fn clock_offset(
    rig: &StereoRig,
    left: &Track,
    right: &Track,
    candidates: &Candidates,
) -> Result<ClockOffset, TriangulateError> {
    let undistort =
        |px: &[Vec<[f64; 2]>], side: Side| -> Result<Vec<Vec<[f64; 2]>>, TriangulateError> {
            let all: Vec<[f64; 2]> = px.iter().flatten().copied().collect();
            let mut undistorted = rig.undistorted(side, &all)?.into_iter();
            Ok(px
                .iter()
                .map(|c| c.iter().filter_map(|_| undistorted.next()).collect())
                .collect())
        };
    let clock = Epipolar {
        left,
        right,
        undistorted: [
            undistort(&candidates[0], Side::Left)?,
            undistort(&candidates[1], Side::Right)?,
        ],
        fundamental: rig.fundamental(),
    };
    let all: Vec<usize> = (0..left.times.len()).collect();
    let Some((delta, frames)) = clock.fit(&all, 0.0, MAX_OFFSET_S.max(right.period_s)) else {
        return Ok(ClockOffset::default());
    };
    let constant = ClockOffset {
        offset_s: delta,
        mid_s: 0.0,
        drift: 0.0,
        frames,
    };
    Ok(clock
        .drift(&all, delta)
        .map_or(constant, |(offset_s, mid_s, drift)| ClockOffset {
            offset_s,
            mid_s,
            drift,
            frames,
        }))
}

/// What tells the clock offset: the candidates undistorted, and the epipolar geometry.
struct Epipolar<'a> {
    left: &'a Track,
    right: &'a Track,
    undistorted: Candidates,
    fundamental: nalgebra::Matrix3<f64>,
}

/// The offset of a frame at time t for a scanned value x.
type Offset<'a> = &'a (dyn Fn(f64, f64) -> f64 + Sync);

/// The scans' steps (s): a millisecond, then a tenth of one.
const COARSE_S: f64 = 1e-3;
const FINE_S: f64 = 1e-4;

impl Epipolar<'_> {
    /// Left frame k's capped squared epipolar distance at offset δ, where the tip moves: the
    /// least over its candidates and the right frames' around the instant, each candidate of
    /// the one before taken with its nearest in the one after (one object), where that moved (a
    /// still red object is no clock; a candidate gone wrong costs the cap at most).
    fn frame_cost(&self, k: usize, delta: f64) -> Option<f64> {
        let (right, [ul, ur]) = (self.right, &self.undistorted);
        let (a, b, s) = right.around(self.left.times[k] + delta).ok()?;
        let nearest = |p: [f64; 2]| {
            let q = ur[b]
                .iter()
                .copied()
                .min_by(|&q, &r| distance_px(p, q).total_cmp(&distance_px(p, r)))?;
            (MOVING_PX..=right.px(NEIGHBOUR_PX))
                .contains(&distance_px(p, q))
                .then(|| lerp(p, q, s))
        };
        let moving: Vec<[f64; 2]> = ur[a].iter().filter_map(|&p| nearest(p)).collect();
        ul[k]
            .iter()
            .flat_map(|l| {
                let line = self.fundamental * Vector3::new(l[0], l[1], 1.0);
                let norm = line[0].hypot(line[1]);
                moving.iter().map(move |r| {
                    let d = (line[0] * r[0] + line[1] * r[1] + line[2]) / norm;
                    d.abs().min(EPIPOLAR_CAP_PX).powi(2)
                })
            })
            .min_by(f64::total_cmp)
    }

    /// The x within `reach` of `centre` that fits frames `ks` best, each at the offset
    /// `offset(t, x)` at its time t, and how many told it: a scan every `step`, then the
    /// parabola through the best and its neighbours (ties to the nearer `centre`).
    fn scan(
        &self,
        ks: &[usize],
        offset: Offset,
        centre: f64,
        reach: f64,
        step: f64,
    ) -> Option<(f64, usize)> {
        let least = if ks.len() > DRIFT_FRAMES {
            MIN_FRAMES
        } else {
            MIN_RUN_FRAMES
        };
        let reach = (reach / step).ceil() as i64;
        let scanned: Vec<(f64, f64, usize)> = (-reach..=reach)
            .into_par_iter()
            .map(|j| {
                let x = centre + j as f64 * step;
                let (sum, n) = ks
                    .iter()
                    .filter_map(|&k| self.frame_cost(k, offset(self.left.times[k], x)))
                    .fold((0.0, 0), |(sum, n), c| (sum + c, n + 1));
                let mean = if n >= least {
                    sum / n as f64
                } else {
                    f64::INFINITY
                };
                (x, mean, n)
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
        if !scanned[best].1.is_finite() {
            return None;
        }
        let mut x = scanned[best].0;
        if best > 0 && best + 1 < scanned.len() {
            let (a, b, c) = (scanned[best - 1].1, scanned[best].1, scanned[best + 1].1);
            let curvature = a - 2.0 * b + c;
            if curvature > 0.0 && a.is_finite() && c.is_finite() {
                x += step * 0.5 * (a - c) / curvature;
            }
        }
        Some((x, n))
    }

    /// The one offset for frames `ks` within `reach` of `centre`: a millisecond's scan, then
    /// tenths of one around its best.
    fn fit(&self, ks: &[usize], centre: f64, reach: f64) -> Option<(f64, usize)> {
        let (rough, _) = self.scan(ks, &|_, x| x, centre, reach, COARSE_S)?;
        self.scan(ks, &|_, x| x, rough, 2.0 * COARSE_S, FINE_S)
    }

    /// The drift, when the frames `all` (whose one offset is `delta`) show one: the offset at
    /// the middle, that middle, and the slope. Each run of [`DRIFT_FRAMES`] frames (those where
    /// the tip moves tell) is looked for over every offset first (a fast clock carries the
    /// stamps tens of milliseconds a second away from the session's δ); a line through those
    /// that a run which fits a wrong offset does not pull (Theil-Sen); each run again within a
    /// period of that line; their line tested, then refined on every frame.
    fn drift(&self, all: &[usize], delta: f64) -> Option<(f64, f64, f64)> {
        let (left, right) = (self.left, self.right);
        let runs: Vec<(f64, &[usize])> = all
            .chunks_exact(DRIFT_FRAMES)
            .map(|run| {
                let t = run.iter().map(|&k| left.times[k]).sum::<f64>() / run.len() as f64;
                (t, run)
            })
            .collect();
        let offsets = |centre: &dyn Fn(f64) -> f64, reach: f64| -> Vec<(f64, f64)> {
            runs.iter()
                .filter_map(|&(t, run)| Some((t, self.fit(run, centre(t), reach)?.0)))
                .collect()
        };
        let robust = theil_sen(&offsets(&|_| delta, MAX_OFFSET_S.max(right.period_s)))?;
        let runs = offsets(&robust, right.period_s);
        if runs.len() < DRIFT_RUNS {
            return None;
        }
        let line = Line::fit(&runs)?;
        let residual: f64 = runs.iter().map(|&(t, d)| (d - line.at(t)).powi(2)).sum();
        let slope_se = (residual / (runs.len() - 2) as f64 / line.sxx).sqrt();
        if line.slope.abs() <= student_t_995(runs.len() - 2) * slope_se {
            return None;
        }
        // Runs of a second, each off by a few ms where the tip starts, tell the line to some
        // ms: its offset, then its slope, refined on every frame to tenths of a millisecond at
        // the session's ends.
        let half_span = (left.times[left.times.len() - 1] - left.times[0]) / 2.0;
        let (mid, mut offset_s, mut drift) = (line.mean_x, line.mean_y, line.slope);
        for _ in 0..2 {
            let shift = |t: f64, x: f64| offset_s + x + drift * (t - mid);
            offset_s += self
                .scan(all, &shift, 0.0, REFINE_S, FINE_S)
                .map_or(0.0, |(x, _)| x);
            let tilt = |t: f64, x: f64| offset_s + x * (t - mid);
            let (reach, step) = (REFINE_S / half_span, FINE_S / half_span);
            drift = self
                .scan(all, &tilt, drift, reach, step)
                .map_or(drift, |(x, _)| x);
        }
        Some((offset_s, mid, drift))
    }
}

/// The Theil-Sen line through `points`: the median of the slopes between every two, through
/// the median of each point less that slope (`None` for fewer than [`DRIFT_RUNS`] points).
fn theil_sen(points: &[(f64, f64)]) -> Option<impl Fn(f64) -> f64> {
    if points.len() < DRIFT_RUNS {
        return None;
    }
    let mut slopes: Vec<f64> = points
        .iter()
        .enumerate()
        .flat_map(|(i, a)| points[i + 1..].iter().map(move |b| (a, b)))
        .filter(|(a, b)| a.0 != b.0)
        .map(|(a, b)| (b.1 - a.1) / (b.0 - a.0))
        .collect();
    let slope = crate::stats::upper_median(&mut slopes)?;
    let mut intercepts: Vec<f64> = points.iter().map(|p| p.1 - slope * p.0).collect();
    let intercept = crate::stats::upper_median(&mut intercepts)?;
    Some(move |x: f64| intercept + slope * x)
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

    #[test]
    fn the_robust_line_is_not_pulled_by_a_run_that_fit_a_wrong_offset() {
        let mut points: Vec<(f64, f64)> =
            (0..8).map(|i| (i as f64, 0.1 + 0.05 * i as f64)).collect();
        points[3].1 += 0.4;
        let line = theil_sen(&points).unwrap();
        assert!((line(0.0) - 0.1).abs() < 1e-12 && (line(10.0) - 0.6).abs() < 1e-12);
        assert!(theil_sen(&points[..DRIFT_RUNS - 1]).is_none());
    }
}
