//! The settings of a triangulation run and their ranges.

use serde::Serialize;

use super::marker::MarkerOptions;

/// How far beyond the finger's length a tip may lie from its base before its row is flagged
/// `reach` (mm): the rest position's own error and the hand axes' tilt.
pub const REACH_MARGIN_MM: f64 = 1.0;

/// Settings of a run.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TriangulateOptions {
    pub marker: MarkerOptions,
    /// Largest left/right timestamp difference of a pair (s).
    pub max_dt_s: f64,
    /// Frames earlier than this into their step are skipped (s).
    pub settle_s: f64,
    /// Largest reprojection error of a used pair, in either image (px).
    pub max_reproj_px: f64,
    /// Hartley-Sturm correction of the matches before triangulating.
    pub correct_matches: bool,
    /// Rows with fewer pairs are flagged.
    pub min_frames: usize,
    /// Rows whose pairs are further apart are flagged (mm).
    pub max_spread_mm: f64,
    /// A step is at zero pressure when all three are at most this (kPa).
    pub zero_kpa: f64,
    /// The finger's length (mm): its base is this far up the hand frame's z axis from the tip
    /// at rest, and a tip further than this (plus [`REACH_MARGIN_MM`]) from the base is out of
    /// its reach, its row flagged.
    pub finger_mm: f64,
    /// For videos without `frames.csv`: when each video's first frame was taken on the log's
    /// clock (s); the frames' times are then the videos' own timestamps after it.
    pub video_start_s: Option<[f64; 2]>,
    /// Each camera's delay from exposure to timestamp (s), when known; `None` measures it
    /// from the tip's motion ([`super::latency`]).
    pub latency_s: Option<[f64; 2]>,
    /// `latency_s` was measured for both cameras at once (an LED both filmed): `--per-frame`
    /// takes the clocks as they say instead of measuring their offset from the motion.
    pub clocks_measured: bool,
}

impl TriangulateOptions {
    /// Every limit within its range; the message names the flag.
    ///
    /// # Errors
    /// What is wrong, e.g. "--marker-area-px 10,5: the smallest area must be at least 1 and
    /// not above the largest".
    pub fn check(&self) -> Result<(), String> {
        let m = &self.marker;
        let rules = [
            (
                m.min_area_px >= 1 && m.min_area_px <= m.max_area_px,
                format!(
                    "--marker-area-px {},{}: the smallest area must be at least 1 and not above the largest",
                    m.min_area_px, m.max_area_px
                ),
            ),
            (
                self.max_dt_s > 0.0 && self.max_dt_s.is_finite(),
                format!("--max-dt-ms {}: must be a positive number", 1e3 * self.max_dt_s),
            ),
            (
                self.settle_s >= 0.0 && self.settle_s.is_finite(),
                format!("--settle-s {}: must be a number ≥ 0", self.settle_s),
            ),
            (
                self.max_reproj_px > 0.0 && self.max_reproj_px.is_finite(),
                format!("--max-reproj-px {}: must be a positive number", self.max_reproj_px),
            ),
            (
                self.min_frames >= 1,
                "--min-frames 0: a row needs at least one frame pair".to_string(),
            ),
            (
                self.max_spread_mm > 0.0 && self.max_spread_mm.is_finite(),
                format!("--max-spread-mm {}: must be a positive number", self.max_spread_mm),
            ),
            (
                m.max_elongation >= 1.0 && m.min_chroma.is_finite() && m.min_redness.is_finite(),
                "the marker limits must be finite, the elongation at least 1".to_string(),
            ),
            (
                self.finger_mm > 0.0 && self.finger_mm.is_finite(),
                format!("--finger-mm {}: must be a positive length", self.finger_mm),
            ),
            (
                self.zero_kpa >= 0.0 && self.zero_kpa.is_finite(),
                format!("zero pressure threshold {} kPa: must be ≥ 0", self.zero_kpa),
            ),
            (
                self.video_start_s
                    .is_none_or(|s| s.iter().all(|t| t.is_finite())),
                "--video-start-s: give finite times (s)".to_string(),
            ),
            (
                self.latency_s
                    .is_none_or(|s| s.iter().all(|t| (0.0..10.0).contains(t))),
                "--latency-ms: give each camera's delay from 0 up to 10 000 ms".to_string(),
            ),
        ];
        match rules.into_iter().find(|(ok, _)| !ok) {
            Some((_, why)) => Err(why),
            None => Ok(()),
        }
    }
}

impl Default for TriangulateOptions {
    fn default() -> Self {
        TriangulateOptions {
            marker: MarkerOptions::default(),
            max_dt_s: 0.020,
            settle_s: 0.1,
            max_reproj_px: 1.0,
            correct_matches: true,
            min_frames: 2,
            max_spread_mm: 0.5,
            zero_kpa: 1.0,
            finger_mm: 50.0,
            video_start_s: None,
            latency_s: None,
            clocks_measured: false,
        }
    }
}
