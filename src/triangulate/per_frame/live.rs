//! The tips of frames as they arrive (`capture --view`): the per-frame steps 2-4 on the
//! frames of the last seconds, their candidates already found.

use std::path::Path;

use super::{locate_frames, ClockOffset, Tip, Track};
use crate::session::frames::FrameRecord;
use crate::stereo::{Side, StereoRig};
use crate::triangulate::{TriangulateError, TriangulateOptions};

/// The tips of frames as they arrive (`capture --view`): steps 2-4 on the frames `records`
/// whose candidates (or why none) are `centres[i]` and whose view of the still scene is
/// `scene[i]` (where measured), on the clock offset `clock` (measured from the motion when
/// `None`): each left frame in time order, and the clock offset used.
///
/// # Errors
/// [`TriangulateError`]: stamps going back.
pub fn tips_as_they_come(
    rig: &StereoRig,
    options: &TriangulateOptions,
    records: &[FrameRecord],
    centres: &[Result<Vec<[f64; 2]>, &'static str>],
    scene: &[Option<f64>],
    clock: Option<LiveClock>,
) -> Result<(Vec<LiveTip>, LiveClock), TriangulateError> {
    let index = Path::new("the frames as they came");
    let shift = options.latency_s.unwrap_or([0.0; 2]);
    let [left, right] = [(Side::Left, 0), (Side::Right, 1)]
        .map(|(side, k)| Track::of(records, side, shift[k], rig.camera(side).k[0], index));
    let (left, right) = (left?, right?);
    let centres = |i: usize| centres[i].clone();
    let (clock, _, located) =
        locate_frames(rig, options, [&left, &right], &centres, clock.map(|c| c.0))?;
    let (tracks, clocks) = ([&left, &right], [ClockOffset::default(), clock]);
    let tips = left
        .order
        .iter()
        .zip(&left.times)
        .zip(located)
        .map(|((&i, &t), found)| LiveTip {
            frame: records[i].index,
            time_s: t,
            tip: found.map(|f| (f.point.into(), f.reproj_px)),
            scene_px: super::rows::scene_near(records[i].index, t, &tracks, &clocks, scene),
        })
        .collect();
    Ok((tips, LiveClock(clock)))
}

/// A left frame [`tips_as_they_come`] located: its number, time (s), and tip in the left
/// camera (mm) with its reprojection residual (px).
pub struct LiveTip {
    pub frame: usize,
    pub time_s: f64,
    pub tip: Tip<([f64; 3], f64)>,
    /// How far each camera's view of the still scene moved, on a frame it is measured in
    /// (as `triangulate --per-frame`'s rows: each camera's measured frame nearest the row's
    /// instant on its own clock).
    pub scene_px: Vec<Option<f64>>,
}

/// The clock offset [`tips_as_they_come`] measured, to be given again.
#[derive(Clone, Copy, Debug)]
pub struct LiveClock(ClockOffset);

impl LiveClock {
    /// The right camera's stamps ahead of the left's (ms), and how many moving frames told it
    /// (0: not measured).
    pub fn offset_ms(&self) -> (f64, usize) {
        (1e3 * self.0.offset_s, self.0.frames)
    }

    /// The right camera's stamp of the left camera's instant `t` (s).
    pub fn right_instant(&self, t: f64) -> f64 {
        self.0.stamp_of(t)
    }
}
