//! What a run counted and found, for the user and `dataset_summary.json`.

use serde::Serialize;

use super::{clock, latency, FrameResult};
use crate::session::frames::{self, FrameRecord};
use crate::stereo::Side;

/// Counts per camera: [left, right].
pub type PerCamera = [usize; 2];

/// What happened to the frames.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FrameCounts {
    pub listed: PerCamera,
    pub no_file: PerCamera,
    pub unreadable: PerCamera,
    pub marker_missing: PerCamera,
    pub several_candidates: PerCamera,
    /// Red regions that failed the marker's limits, all frames.
    pub discarded_regions: usize,
    pub skipped: PerCamera,
    /// Frames stamped late ([`FrameRecord::late_s`]), left out of the pairs, and the latest of
    /// them (ms).
    pub stamped_late: PerCamera,
    pub late_max_ms: f64,
    /// The first unreadable frame and why (`frames.csv` line: reason), for the user to look at.
    pub first_unreadable: Option<String>,
}

/// How the hand frame's origin was found.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Origin {
    /// The tip at zero pressure, in the left camera (mm).
    pub left_mm: [f64; 3],
    pub zero_steps: usize,
    pub pairs: usize,
    /// RMS distance of those pairs' tips from the origin (mm).
    pub spread_mm: f64,
}

/// Counts of everything, for the user and the summary file.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    pub frames: FrameCounts,
    pub pairs_formed: usize,
    pub unpaired: PerCamera,
    /// Pairs per [`super::PairStatus`] name.
    pub pairs: std::collections::BTreeMap<&'static str, usize>,
    pub steps_logged: usize,
    pub rows: usize,
    pub rows_flagged: usize,
    /// Log rows (0-based) with no used pair.
    pub steps_without_tip: Vec<usize>,
    /// Reprojection error of the used pairs (px): median, 95th percentile, largest.
    pub reproj_px: [f64; 3],
    /// The used pairs' signed distance of the right centre from the left centre's epipolar
    /// line (undistorted px): mean, standard deviation, 95th percentile of its size. Without
    /// truth a detector's sub-pixel bias cannot be seen in one image; across the two it shows
    /// here: a mean away from 0 (a bias in one camera, or a calibration that drifted) or a
    /// spread wider than the frames' noise (a bias that moves with the marker).
    pub epipolar_px: [f64; 3],
    /// Used pairs per camera whose centre came from the region's centroid because the
    /// sub-pixel fit did not settle (`subpixel::refine`).
    pub centroid_only: PerCamera,
    /// Per camera, the codec of a video that OpenCV decoded (not Motion-JPEG, so the fit
    /// cannot undo its colour's sampling and quantisation).
    pub decoded_video: [Option<String>; 2],
    /// Per camera, a video that ended before the frames `frames.csv` lists for it.
    pub video_ended: [Option<frames::VideoEnd>; 2],
    /// The rows' spread (largest distance of a step's pairs from their median, mm): median,
    /// 95th percentile, largest.
    pub step_spread_mm: [f64; 3],
    /// What the timestamps say: skew, drift, dropped frames, steps filmed while settling.
    pub clock: clock::ClockCheck,
    /// Each camera's delay from the tip's motion, and whether the times were corrected by it.
    pub latency: latency::Latency,
    pub origin: Origin,
    pub interrupted: bool,
}

/// Counts what became of each frame into `c`.
pub(super) fn count_frames(records: &[FrameRecord], results: &[FrameResult], c: &mut FrameCounts) {
    for (f, r) in records.iter().zip(results) {
        let cam = usize::from(f.camera == Side::Right);
        c.listed[cam] += 1;
        if let Some(late_s) = f.late_s {
            c.stamped_late[cam] += 1;
            c.late_max_ms = c.late_max_ms.max(1e3 * late_s);
        }
        match r {
            FrameResult::NoFile => c.no_file[cam] += 1,
            FrameResult::Unreadable(why) => {
                c.unreadable[cam] += 1;
                c.first_unreadable.get_or_insert_with(|| {
                    format!(
                        "{} frame {} (frames.csv line {}): {why}",
                        f.camera.name(),
                        f.index,
                        f.line
                    )
                });
            }
            FrameResult::Skipped => c.skipped[cam] += 1,
            FrameResult::Markers(m) => {
                c.discarded_regions += m.discarded;
                match m.blobs.len() {
                    0 => c.marker_missing[cam] += 1,
                    1 => {}
                    _ => c.several_candidates[cam] += 1,
                }
            }
        }
    }
}
