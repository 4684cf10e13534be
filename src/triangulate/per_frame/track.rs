//! One camera's track: its frames in time order on their own clock, the tip interpolated
//! between them (a spline at the frames' times), how sure the track is of the tip between two
//! frames, and the track smoothed where the tip moves smoothly.

use std::path::Path;

use super::Centres;
use crate::session::frames::FrameRecord;
use crate::stereo::Side;
use crate::triangulate::{distance_px, TriangulateError};

/// The longest a right frame may be from its neighbour for the track to be interpolated
/// between them, in frame periods: one frame dropped (a webcam under load drops some; across
/// one the spline still holds: a PNG session dropping one right frame in 20 gives 38 more rows
/// and 0.0196 mm RMS over all, against 0.0184 without them).
pub(super) const MAX_GAP_PERIODS: f64 = 2.5;
/// The pixel limits below are a tip's motion in the image, measured on the synth's default rig
/// (1280 × 720, 78° diagonal: a C920's focal length, [`REFERENCE_FOCAL_PX`]); a track scales them
/// by its camera's focal length ([`Track::px`]), so that they mean the same motion of the finger
/// at another resolution or lens (checked at 640 × 480 with 90° and 1920 × 1080 with 55°).
pub(super) const REFERENCE_FOCAL_PX: f64 = 906.8;
/// The most a track may be unsure of the tip between two frames ([`track_spread_px`], px):
/// 1.4 × the most seen on dynamic sessions (0.70 px at 150 commands/s; 0.3-0.7 over seven
/// sessions, either camera), a tenth of what a step whose line and lag are shorter than a frame
/// gives (up to 15 px).
pub(super) const MAX_SPREAD_PX: f64 = 1.0;
/// How far a frame's candidate may be from its neighbour's for the track's spread to be
/// measured through it (px): a step that jumps within a frame moves the tip tens of pixels.
const JUMP_PX: f64 = 3.0 * NEIGHBOUR_PX;
/// The farthest the tip may move from one right frame to the next to be taken for the same
/// candidate (px).
pub(super) const NEIGHBOUR_PX: f64 = 30.0;

/// One camera's frames in time order: their records' indices and times (s).
pub(super) struct Track {
    pub order: Vec<usize>,
    /// On the camera's own regular clock, when its stamps lie on one.
    pub times: Vec<f64>,
    pub period_s: f64,
    /// The stamps' RMS about the regular clock (s), when they lie on one.
    pub jitter_s: Option<f64>,
    /// The camera's focal length over [`REFERENCE_FOCAL_PX`].
    pub px_scale: f64,
}

impl Track {
    /// `side`'s frames, their stamps shifted by `shift_s`, for a camera of focal length
    /// `focal_px`; `index` names the frame list in messages.
    pub(super) fn of(
        records: &[FrameRecord],
        side: Side,
        shift_s: f64,
        focal_px: f64,
        index: &Path,
    ) -> Result<Track, TriangulateError> {
        let mut order: Vec<usize> = (0..records.len())
            .filter(|&i| records[i].camera == side)
            .collect();
        order.sort_by_key(|&i| records[i].index);
        for w in order.windows(2) {
            let (a, b) = (&records[w[0]], &records[w[1]]);
            if b.time_s <= a.time_s {
                return Err(TriangulateError::Input(crate::data::DataError::Input {
                    path: index.to_path_buf(),
                    line: b.line,
                    message: format!(
                        "{} frame {} is stamped {} s, not after frame {} ({} s, line {}): a camera's stamps must increase; check the capture's clock",
                        side.name(),
                        b.index,
                        b.time_s,
                        a.index,
                        a.time_s,
                        a.line
                    ),
                }));
            }
        }
        let stamps: Vec<f64> = order.iter().map(|&i| records[i].time_s - shift_s).collect();
        Ok(Track::of_stamps(order, stamps, focal_px))
    }

    /// A camera's frames `order` (indices of its records, in frame order) stamped `stamps`
    /// (increasing), for a camera of focal length `focal_px`.
    pub(super) fn of_stamps(order: Vec<usize>, stamps: Vec<f64>, focal_px: f64) -> Track {
        let period_s = crate::frame_times::period(&stamps);
        let (times, jitter_s) = match crate::frame_times::regular(&stamps, period_s) {
            Some((times, rms)) => (times, Some(rms)),
            None => (stamps, None),
        };
        Track {
            order,
            times,
            period_s,
            jitter_s,
            px_scale: focal_px / REFERENCE_FOCAL_PX,
        }
    }

    /// A pixel limit measured on the reference rig, in this camera's pixels.
    pub(super) fn px(&self, reference_px: f64) -> f64 {
        reference_px * self.px_scale
    }

    /// The frames just before and after `t` (positions in the track) and where `t` lies
    /// between them (0-1), when both exist and lie close enough together.
    pub(super) fn around(&self, t: f64) -> Result<(usize, usize, f64), &'static str> {
        let after = self.times.partition_point(|&s| s <= t);
        if after == 0 || after == self.times.len() {
            return Err("gap");
        }
        let (a, b) = (after - 1, after);
        if !self.close(a, b) {
            return Err("gap");
        }
        Ok((a, b, (t - self.times[a]) / (self.times[b] - self.times[a])))
    }

    /// Of its frames within `within` positions of the one nearest `t`, the value `of` the one
    /// nearest `t` that has one.
    pub(super) fn nearest_with<T>(
        &self,
        t: f64,
        within: usize,
        of: &dyn Fn(&Track, usize) -> Option<T>,
    ) -> Option<T> {
        let near = self.times.partition_point(|&s| s <= t);
        let span = near.saturating_sub(within + 1)..(near + within + 1).min(self.times.len());
        span.filter_map(|pos| Some(((self.times[pos] - t).abs(), of(self, pos)?)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, v)| v)
    }

    /// The times of its first and last frames, when it has any.
    pub(super) fn span_s(&self) -> Option<(f64, f64)> {
        Some((*self.times.first()?, *self.times.last()?))
    }

    /// How long it films from its first frame to its last (s; 0 without frames).
    pub(super) fn length_s(&self) -> f64 {
        self.span_s().map_or(0.0, |(a, b)| b - a)
    }

    /// What `between` makes of its frames `a` and `b` (those around an instant); when that
    /// is nothing, of the frames either side with one of the two left out, as if dropped (the
    /// bead hidden in it, or the frame unreadable), where exactly one of the two ways gives
    /// something (both giving is no frame hidden but a jump); else `between(a, b)`'s flag.
    pub(super) fn around_or_dropped<T>(
        &self,
        (a, b): (usize, usize),
        between: impl Fn(usize, usize) -> Result<T, &'static str>,
    ) -> Result<T, &'static str> {
        let flag = match between(a, b) {
            Ok(found) => return Ok(found),
            Err(flag) => flag,
        };
        let wider = [
            a.checked_sub(1).map(|o| (o, b)),
            Some(b + 1)
                .filter(|&r| r < self.times.len())
                .map(|r| (a, r)),
        ];
        let mut found = wider
            .into_iter()
            .flatten()
            .filter(|&(a, b)| self.close(a, b))
            .filter_map(|(a, b)| between(a, b).ok());
        match (found.next(), found.next()) {
            (Some(found), None) => Ok(found),
            _ => Err(flag),
        }
    }

    /// How many frame periods apart the frames at `a` and `b` are.
    pub(super) fn periods_apart(&self, a: usize, b: usize) -> f64 {
        (self.times[b] - self.times[a]) / self.period_s
    }

    /// Whether the frames at `a` and `b` are close enough for the track to be interpolated
    /// between them ([`MAX_GAP_PERIODS`]).
    pub(super) fn close(&self, a: usize, b: usize) -> bool {
        self.periods_apart(a, b) <= MAX_GAP_PERIODS
    }

    /// The candidate of the frame at `pos` nearest `to`, when one is within [`JUMP_PX`]: a
    /// neighbour farther than [`NEIGHBOUR_PX`] is no pair to interpolate between but still
    /// tells a jump.
    pub(super) fn nearest(
        &self,
        pos: usize,
        to: [f64; 2],
        centres: &Centres<'_>,
    ) -> Option<[f64; 2]> {
        centres(*self.order.get(pos)?)
            .ok()?
            .into_iter()
            .map(|c| (distance_px(c, to), c))
            .filter(|(d, _)| *d <= self.px(JUMP_PX))
            .min_by(|x, y| x.0.total_cmp(&y.0))
            .map(|(_, c)| c)
    }

    /// How unsure the track is around its frame at `pos`, seen at `at` ([`jerk_px`] over the
    /// two frames on either side, their candidates nearest `at`); `None` without them.
    pub(super) fn jerk_around(
        &self,
        pos: usize,
        at: [f64; 2],
        centres: &Centres<'_>,
    ) -> Option<f64> {
        let first = pos.checked_sub(2)?;
        let points: Option<Vec<[f64; 2]>> = (first..first + 5)
            .map(|j| {
                if j == pos {
                    Some(at)
                } else {
                    self.nearest(j, at, centres)
                }
            })
            .collect();
        let times = self.times.get(first..first + 5)?;
        Some(jerk_px(&points?, times))
    }

    /// The times of the frames `a - 1`, `a`, `b`, `b + 1` for a spline between `a` and `b`,
    /// when the outer two exist and lie close enough.
    pub(super) fn knots(&self, a: usize, b: usize) -> Option<[f64; 4]> {
        let (o, r) = (
            a.checked_sub(1)?,
            Some(b + 1).filter(|&r| r < self.times.len())?,
        );
        (self.close(o, a) && self.close(b, r)).then(|| [o, a, b, r].map(|k| self.times[k]))
    }
}

/// Each camera's track smoothed where the first pass saw the tip in five frames in a row,
/// evenly spaced: the Savitzky-Golay filter of a parabola through the five (weights −3, 12,
/// 17, 12, −3 over 35), exact for a tip moving at constant acceleration, which averages out
/// the frame-to-frame error of a moving bead's JPEG chroma. Keyed by frame record.
pub(super) fn smoothed_tracks(
    tracks: &[&Track],
    seen: &[Vec<Option<[f64; 2]>>],
) -> std::collections::HashMap<usize, [f64; 2]> {
    const WEIGHTS: [f64; 5] = [-3.0, 12.0, 17.0, 12.0, -3.0];
    let mut out = std::collections::HashMap::new();
    for (track, seen) in tracks.iter().zip(seen) {
        for k in 2..track.times.len().saturating_sub(2) {
            let window: Option<Vec<[f64; 2]>> = (k - 2..=k + 2).map(|j| seen[j]).collect();
            let even = (k - 2..k + 2).all(|j| (track.periods_apart(j, j + 1) - 1.0).abs() <= 0.25);
            let smooth = |w: &Vec<[f64; 2]>| {
                jerk_px(w, &track.times[k - 2..=k + 2]) <= track.px(MAX_SPREAD_PX)
            };
            let Some(w) = window.filter(|w| even && smooth(w)) else {
                continue;
            };
            let c = std::array::from_fn(|a| {
                w.iter().zip(WEIGHTS).map(|(p, wt)| wt * p[a]).sum::<f64>() / 35.0
            });
            out.insert(track.order[k], c);
        }
    }
    out
}

/// How unsure a track is of the tip between its middle two `points` (at times `knots`): how far
/// apart the parabolas through the first three and through the last three pass midway between
/// the two (px). Where the tip moves smoothly they agree to the error of a moving bead's centre;
/// where it jumps between frames (a pressure step whose line and lag are shorter than a frame)
/// they part by pixels, and neither the frames' centres (smeared over the jump) nor any curve
/// through them says where the tip was.
pub(super) fn track_spread_px(points: [[f64; 2]; 4], knots: [f64; 4]) -> f64 {
    let mid = 0.5 * (knots[1] + knots[2]);
    let parabola = |first: usize| -> [f64; 2] {
        let weight = |i: usize| {
            (first..first + 3)
                .filter(|&j| j != i)
                .fold(1.0, |w, j| w * (mid - knots[j]) / (knots[i] - knots[j]))
        };
        std::array::from_fn(|axis| {
            (first..first + 3)
                .map(|i| weight(i) * points[i][axis])
                .sum()
        })
    };
    distance_px(parabola(0), parabola(1))
}

/// How unsure a track of five frames is around the middle one: the larger
/// [`track_spread_px`] of the two intervals beside it.
fn jerk_px(points: &[[f64; 2]], times: &[f64]) -> f64 {
    (0..2)
        .map(|k| {
            let four = |v: &[[f64; 2]]| std::array::from_fn(|i| v[k + i]);
            track_spread_px(four(points), std::array::from_fn(|i| times[k + i]))
        })
        .fold(0.0, f64::max)
}

/// The Catmull-Rom spline through four points at times `knots`, at `t` between the middle
/// two (Barry and Goldman's pyramid of linear interpolations): exact for a track of constant
/// acceleration, where a straight line between two frames 33 ms apart misses a turning tip by a
/// good share of the error budget; the times need not be even (a frame dropped on either side).
pub(super) fn catmull_rom(points: [[f64; 2]; 4], knots: [f64; 4], t: f64) -> [f64; 2] {
    let blend = |p: [f64; 2], q: [f64; 2], i: usize, j: usize| {
        lerp(p, q, (t - knots[i]) / (knots[j] - knots[i]))
    };
    let [p0, p1, p2, p3] = points;
    let (a1, a2, a3) = (
        blend(p0, p1, 0, 1),
        blend(p1, p2, 1, 2),
        blend(p2, p3, 2, 3),
    );
    let (b1, b2) = (blend(a1, a2, 0, 2), blend(a2, a3, 1, 3));
    blend(b1, b2, 1, 2)
}

pub(super) fn lerp(p: [f64; 2], q: [f64; 2], s: f64) -> [f64; 2] {
    [p[0] + (q[0] - p[0]) * s, p[1] + (q[1] - p[1]) * s]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spline_follows_a_tip_of_constant_acceleration_across_uneven_frames() {
        // Frames at 0, 1, 3 and 4 periods (one dropped between the middle two); the tip
        // accelerating, as a pressure step drives it.
        let tip = |t: f64| [1.0 + 2.0 * t + 0.5 * t * t, 3.0 - t - 0.25 * t * t];
        let knots = [0.0, 1.0, 3.0, 4.0];
        for t in [1.0, 1.5, 2.0, 2.7, 3.0] {
            let [x, y] = catmull_rom(knots.map(tip), knots, t);
            let [tx, ty] = tip(t);
            assert!(
                (x - tx).abs() < 1e-9 && (y - ty).abs() < 1e-9,
                "{t}: {x}, {y}"
            );
        }
        // Evenly spaced, the textbook Catmull-Rom: halfway is (−p0 + 9 p1 + 9 p2 − p3) / 16.
        let p = [[0.0, 0.0], [1.0, 2.0], [3.0, 1.0], [4.0, 5.0]];
        let [x, y] = catmull_rom(p, [0.0, 1.0, 2.0, 3.0], 1.5);
        assert!(
            (x - 2.0).abs() < 1e-12 && (y - 1.375).abs() < 1e-12,
            "{x}, {y}"
        );
    }
}
