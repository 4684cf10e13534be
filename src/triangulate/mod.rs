//! From frames to a dataset: the red tip in every frame, its 3-D position from each left/right
//! pair, and one row per pressure step of the regulator's log.
//!
//! # Steps
//!
//! 1. Every frame listed in `frames.csv` is decoded and searched for the marker, in parallel
//!    ([`marker`]): zero candidates → the marker is missing from that frame.
//! 2. Frames pair by timestamp ([`crate::session::frames::pair_frames`]; frames stamped late
//!    take no part), pairs fall into the log's steps, pairs in a step's settling time are
//!    skipped ([`pairing`]).
//! 3. Each pair's candidates (usually one per image) are undistorted and triangulated by OpenCV
//!    ([`crate::stereo`]), optionally after Hartley-Sturm correction (`correct_matches`), and
//!    reprojected into both images with the distortion. A combination is consistent when both
//!    reprojection errors are at most `max_reproj_px` and the point is in front of both
//!    cameras. Exactly one consistent combination → the pair is used (when there were several
//!    candidates, the epipolar constraint resolved them); none → rejected for its reprojection
//!    error; several → ambiguous, rejected. Nothing is guessed (`locate`).
//! 4. A step's row is flagged (`flag` column, `;`-separated) when it has fewer than
//!    `min_frames` pairs (`few_frames`), its pairs disagree by more than `max_spread_mm`
//!    (`spread`), its step lasted over 1.5 times its `hold_s` (the log's median step where the
//!    log has no `hold_s`) (`long_step`: a gap in the log, so frames of an unlogged step may
//!    be in it), or (after the hand frame) its
//!    tip lies further from the finger's base than the finger is long (`reach`: the base
//!    `finger_mm` up the z axis from the rest tip). `handcap model` leaves flagged rows out.
//! 5. The hand frame: axes `R_hand` from the calibration (its reference pair), origin the
//!    median tip over the unflagged zero-pressure steps (all three pressures ≤ `zero_kpa`):
//!    p_hand = R_hand · (p_left − origin).
//! 6. One row per step with at least one used pair: the per-coordinate median of its pairs,
//!    with `n_frames` (pairs), `spread_mm` (largest distance of a pair from the median),
//!    `reproj_px` (largest reprojection error) and `dt_ms` (largest left/right time
//!    difference).

pub mod cameras;
pub mod clock;
pub mod latency;
mod locate;
pub mod marker;
pub mod nview;
pub mod options;
pub mod output;
pub mod pairing;
pub mod per_frame;
pub mod scene;
mod steps;
pub mod subpixel;
pub mod summary;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;

use crate::calib::file::CalibrationFile;
use crate::geometry::HandFromLeft;
use crate::image::{Buffers, RgbImage};
use crate::session::frames::{self, FrameList, FrameRecord};
use crate::session::pressures::PressureLog;
use crate::stereo::StereoRig;
use locate::{epipolar_residuals, locate_pairs};
use marker::Markers;
pub use options::TriangulateOptions;
use steps::{hand_frame, nothing_used, Steps};
use summary::{count_frames, Summary};

/// Errors of triangulating.
#[derive(Debug, thiserror::Error)]
pub enum TriangulateError {
    #[error(transparent)]
    Input(#[from] crate::data::DataError),
    #[error("{path} has no R_hand: calibrate with a reference pair (left_ref/right_ref, the board at the finger's base) so the hand frame's axes are known")]
    NoHandAxes { path: PathBuf },
    #[error("{path} is Anipose's camera file, which cannot hold the hand frame; give --calib {yaml}, the calibration `handcap calibrate` wrote beside it")]
    AniposeFile { path: PathBuf, yaml: PathBuf },
    #[error("{frame} is {width}×{height} but the calibration is for {cw}×{ch}; capture frames at the calibration's size")]
    WrongSize {
        frame: PathBuf,
        width: usize,
        height: usize,
        cw: i32,
        ch: i32,
    },
    #[error("no tip found in a zero-pressure step ({zero} steps with all pressures ≤ {zero_kpa} kPa in the log; the hand frame's origin is the tip at zero pressure): {why}")]
    NoOrigin {
        zero: usize,
        zero_kpa: f64,
        /// What became of those steps' frames ([`no_origin_cause`]).
        why: String,
    },
    #[error("no frame pair gave a tip position: {0}")]
    NothingUsed(String),
    /// Per frame: the two cameras' frames cannot make pairs at all (one camera's frames none or
    /// unreadable, or their times far apart); said before any row blames the rest hold.
    #[error("{index}: {why}")]
    Unpaired { index: PathBuf, why: String },
    #[error(transparent)]
    Stereo(#[from] crate::stereo::StereoError),
    #[error(transparent)]
    Session(#[from] crate::session::SessionError),
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    #[error("writing {path}: {message}")]
    Write { path: PathBuf, message: String },
}

/// What became of one frame.
#[derive(Clone, Debug, PartialEq)]
enum FrameResult {
    Markers(Markers),
    NoFile,
    Unreadable(String),
    /// Not examined: the run was interrupted.
    Skipped,
}

/// What became of a frame pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PairStatus {
    Used,
    /// Used, after the epipolar constraint chose among several candidates.
    Resolved,
    OutsideLog,
    Settling,
    Straddles,
    NoMarkerLeft,
    NoMarkerRight,
    NoMarkerBoth,
    /// An image missing or unreadable.
    NoImage,
    /// No candidate combination reprojects within the limit.
    Reprojection,
    /// Several candidate combinations do.
    Ambiguous,
    /// Not examined: the run was interrupted.
    Skipped,
}

impl PairStatus {
    pub fn used(self) -> bool {
        matches!(self, PairStatus::Used | PairStatus::Resolved)
    }

    pub fn name(self) -> &'static str {
        match self {
            PairStatus::Used => "used",
            PairStatus::Resolved => "resolved",
            PairStatus::OutsideLog => "outside_log",
            PairStatus::Settling => "settling",
            PairStatus::Straddles => "straddles",
            PairStatus::NoMarkerLeft => "no_marker_left",
            PairStatus::NoMarkerRight => "no_marker_right",
            PairStatus::NoMarkerBoth => "no_marker_both",
            PairStatus::NoImage => "no_image",
            PairStatus::Reprojection => "reprojection",
            PairStatus::Ambiguous => "ambiguous",
            PairStatus::Skipped => "skipped",
        }
    }
}

/// One left/right pair and what became of it.
#[derive(Clone, Debug, PartialEq)]
pub struct PairRecord {
    pub left: FrameRef,
    pub right: FrameRef,
    pub step: Option<usize>,
    pub status: PairStatus,
    /// Candidate combinations examined.
    pub candidates: usize,
    /// The chosen centroids (left, right), px.
    pub centres_px: Option<[[f64; 2]; 2]>,
    /// The tip in the left camera (mm) and its reprojections (left, right), px.
    pub point_left_mm: Option<Vector3<f64>>,
    pub reprojected_px: Option<[[f64; 2]; 2]>,
    /// The larger of the two reprojection errors (px).
    pub reproj_px: Option<f64>,
    /// Whether each chosen centre is the sub-pixel fit's (else the region's centroid).
    pub fitted: [bool; 2],
}

/// A frame by camera, number and timestamp.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRef {
    pub index: usize,
    pub time_s: f64,
    pub path: Option<PathBuf>,
}

/// One dataset row: a pressure step and its tip.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Row {
    /// Row of the log (0-based).
    pub step: usize,
    pub pressures_kpa: [f64; 3],
    /// Tip in the hand frame (mm).
    pub tip_mm: [f64; 3],
    pub n_frames: usize,
    pub spread_mm: f64,
    pub reproj_px: f64,
    pub dt_ms: f64,
    /// The log row's other columns.
    pub extra: Vec<String>,
    pub flags: Vec<&'static str>,
}

/// The result of a run.
#[derive(Clone, Debug)]
pub struct Triangulation {
    pub rows: Vec<Row>,
    pub pairs: Vec<PairRecord>,
    pub summary: Summary,
    /// p_hand = R_hand · p_left + t_hand, the origin at the median zero-pressure tip.
    pub hand_from_left: HandFromLeft,
    /// Names of the log's other columns, copied into each row.
    pub extra_columns: Vec<String>,
    pub options: TriangulateOptions,
}

/// Runs the whole triangulation; `progress(done, total)` counts frames examined, `interrupt`
/// stops the frame search (the pairs examined so far are still used).
///
/// # Errors
/// [`TriangulateError`]: bad inputs (each naming the file and line or frame), no hand axes, no
/// zero-pressure tip, no usable pair at all.
pub fn triangulate(
    frames: &FrameList,
    calibration: &CalibrationFile,
    log: &PressureLog,
    options: &TriangulateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &AtomicBool,
) -> Result<Triangulation, TriangulateError> {
    let r_hand = hand_axes(calibration)?;
    let rig = &calibration.rig;
    // 1. Markers in every frame.
    let found = find_all_markers(frames, rig, options, false, progress, interrupt)?;
    let mut summary = Summary {
        interrupted: interrupt.load(Ordering::SeqCst),
        steps_logged: log.steps.len(),
        decoded_video: found.decoded_video,
        video_ended: found.video_ended,
        ..Summary::default()
    };
    count_frames(&frames.records, &found.results, &mut summary.frames);
    // 2-3. Pairs, their steps and their tips.
    let (pairs, records) =
        pair_and_locate(frames, &found.results, log, rig, options, &mut summary)?;
    let used: Vec<&PairRecord> = pairs.iter().filter(|p| p.status.used()).collect();
    if used.is_empty() {
        return Err(nothing_used(&pairs, &records, &summary, log, options));
    }
    summary.reproj_px = median_95_max(used.iter().filter_map(|p| p.reproj_px).collect());
    summary.epipolar_px = epipolar_residuals(rig, &used)?;
    for cam in 0..2 {
        summary.centroid_only[cam] = used.iter().filter(|p| !p.fitted[cam]).count();
    }
    // 4. Each step's pairs and whether its row is doubtful.
    let steps = Steps::of(&used, log, options);
    // 5. The hand frame.
    let hand_from_left = hand_frame(r_hand, &steps, &pairs, &records, log, options, &mut summary)?;
    // 6. One row per step.
    let rows = steps.rows(&hand_from_left, log, options, &mut summary);
    Ok(Triangulation {
        rows,
        pairs,
        summary,
        hand_from_left,
        extra_columns: log.extra_columns.clone(),
        options: options.clone(),
    })
}

/// Steps 2-3: the frames paired by time, each pair placed in the log's steps and located; then
/// again on the frames' times less each camera's delay when the frames show it (or it is
/// given). Returns the pairs and the frames' records on the times they were paired by; the
/// summary gets the latency, the clock check and the pairs' counts.
fn pair_and_locate(
    frames: &FrameList,
    results: &[FrameResult],
    log: &PressureLog,
    rig: &StereoRig,
    options: &TriangulateOptions,
    summary: &mut Summary,
) -> Result<(Vec<PairRecord>, Vec<FrameRecord>), TriangulateError> {
    let located = |records: &[FrameRecord], guard_s: f64| {
        let pairing = frames::pair_frames(records, options.max_dt_s);
        let pairs = locate_pairs(
            records,
            &frames.paths,
            &pairing.pairs,
            results,
            log,
            rig,
            options,
            guard_s,
        )?;
        let clock = clock::check(records, &pairing.pairs, log, options.settle_s, guard_s);
        Ok::<_, TriangulateError>((pairing, pairs, clock))
    };
    let mut records = frames.records.clone();
    let (mut pairing, mut pairs, mut clock) = located(&records, 0.0)?;
    let periods = clock.period_ms.map(|p| p / 1e3);
    summary.latency = match options.latency_s {
        Some(s) => latency::Latency::given(s.map(|s| 1e3 * s)),
        None => latency::measure(&records, results, &pairs, log, periods),
    };
    // The cut cannot tell a delay from one a whole step longer when the steps are even; the
    // pairs can: of the left/right offsets a few steps apart, the one with the most pairs
    // that agree in 3-D is kept.
    if summary.latency.corrected {
        let measured = summary.latency.clone();
        let tries: &[i32] = if measured.given {
            &[0]
        } else {
            &latency::STEPS_APART
        };
        let mut most = None;
        for &steps in tries {
            let candidate = measured.steps_apart(steps, log.median_step_s);
            let shifts = candidate.shifts_s();
            let shifted: Vec<FrameRecord> = frames
                .records
                .iter()
                .map(|r| FrameRecord {
                    time_s: r.time_s - shifts[r.camera as usize],
                    ..r.clone()
                })
                .collect();
            let found = located(&shifted, candidate.guard_s())?;
            let used = found.1.iter().filter(|p| p.status.used()).count();
            if most.is_none_or(|m| used > m) {
                most = Some(used);
                (pairing, pairs, clock) = found;
                records = shifted;
                summary.latency = candidate;
            }
        }
    }
    summary.clock = clock;
    summary.pairs_formed = pairing.pairs.len();
    summary.unpaired = pairing.unpaired;
    for p in &pairs {
        *summary.pairs.entry(p.status.name()).or_default() += 1;
    }
    Ok((pairs, records))
}

/// The hand frame's axes from the calibration, or why it has none.
fn hand_axes(calibration: &CalibrationFile) -> Result<nalgebra::Rotation3<f64>, TriangulateError> {
    calibration.r_hand.ok_or_else(|| {
        let path = calibration.path.clone();
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
        {
            let yaml = path.with_extension("yml");
            TriangulateError::AniposeFile { path, yaml }
        } else {
            TriangulateError::NoHandAxes { path }
        }
    })
}

/// What the search of every frame found.
struct Found {
    /// Per frame record.
    results: Vec<FrameResult>,
    /// Per frame record, when asked for: how far its camera's view of the still scene moved
    /// since the camera's first frame read ([`scene`]; px).
    scene: Vec<Option<f64>>,
    decoded_video: [Option<String>; 2],
    video_ended: [Option<frames::VideoEnd>; 2],
}

/// The marker candidates in every frame: handed out in order (a video is read front to back) a
/// chunk at a time, examined in parallel; `interrupt` leaves the rest [`FrameResult::Skipped`].
/// With `scene`, also how far the view of the still scene lies from its camera's first frame
/// read (in the reading order: a video's, or frames.csv's, which lists a camera's frames
/// in time order as capture writes it), in one frame in
/// [`scene::EVERY`].
fn find_all_markers(
    frames: &FrameList,
    rig: &StereoRig,
    options: &TriangulateOptions,
    scene: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &AtomicBool,
) -> Result<Found, TriangulateError> {
    let records = &frames.records;
    let done = AtomicUsize::new(0);
    let mut results: Vec<FrameResult> = vec![FrameResult::Skipped; records.len()];
    let mut shifts = vec![None; if scene { records.len() } else { 0 }];
    let mut first = scene::FirstFrames::default();
    let mut reader = frames.reader()?;
    let decoded_video = reader.decoded_codecs();
    for chunk in frames.reading_order().chunks(256) {
        if interrupt.load(Ordering::SeqCst) {
            break;
        }
        let data = chunk
            .iter()
            .map(|&i| Ok((i, reader.read(i)?)))
            .collect::<Result<Vec<_>, TriangulateError>>()?;
        let examined: Vec<(
            usize,
            Result<FrameResult, TriangulateError>,
            Option<scene::Thumbnail>,
        )> = data
            .into_par_iter()
            .map_init(
                || (RgbImage::default(), Buffers::default()),
                |(image, buffers), (i, data)| {
                    let result = examine(&data, frames, i, rig, options, interrupt, image, buffers);
                    let seen = matches!(result, Ok(FrameResult::Markers(_)));
                    let measured = scene && seen && records[i].index.is_multiple_of(scene::EVERY);
                    let thumbnail = measured.then(|| scene::Thumbnail::of(image).ok()).flatten();
                    progress(done.fetch_add(1, Ordering::SeqCst) + 1, records.len());
                    (i, result, thumbnail)
                },
            )
            .collect();
        let mut thumbnails = Vec::new();
        for (i, result, thumbnail) in examined {
            results[i] = result?;
            if let Some(thumbnail) = thumbnail {
                let camera = records[i].camera as usize;
                first.offer(camera, &thumbnail);
                thumbnails.push((i, camera, thumbnail));
            }
        }
        let moved: Vec<(usize, Option<f64>)> = thumbnails
            .into_par_iter()
            .map(|(i, camera, thumbnail)| (i, first.shift(camera, &thumbnail)))
            .collect();
        for (i, shift) in moved {
            shifts[i] = shift;
        }
    }
    Ok(Found {
        results,
        scene: shifts,
        decoded_video,
        video_ended: reader.ended(),
    })
}

/// Decodes record `i`'s frame (into the worker's buffers) and finds its marker candidates.
#[allow(clippy::too_many_arguments)]
fn examine(
    data: &frames::FrameData,
    list: &FrameList,
    i: usize,
    rig: &StereoRig,
    options: &TriangulateOptions,
    interrupt: &AtomicBool,
    image: &mut RgbImage,
    buffers: &mut Buffers,
) -> Result<FrameResult, TriangulateError> {
    if interrupt.load(Ordering::SeqCst) {
        return Ok(FrameResult::Skipped);
    }
    if let frames::FrameData::Missing = data {
        return Ok(FrameResult::NoFile);
    }
    if let Err(why) = frames::decode_frame(data, image, buffers) {
        return Ok(FrameResult::Unreadable(why));
    }
    let [cw, ch] = rig.image_size;
    if (image.width, image.height) != (cw as usize, ch as usize) {
        return Err(TriangulateError::WrongSize {
            frame: data.name(list, i),
            width: image.width,
            height: image.height,
            cw,
            ch,
        });
    }
    Ok(FrameResult::Markers(marker::find_markers(
        image,
        &options.marker,
    )))
}

/// The distance between two image points (px).
fn distance_px(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Median, 95th percentile and largest of `values` (zeros for none).
fn median_95_max(mut values: Vec<f64>) -> [f64; 3] {
    crate::stats::quantiles(&mut values, [0.5, 0.95, 1.0]).unwrap_or([0.0; 3])
}

/// The hand frame's origin from the tips seen at rest: their median, and their RMS distance
/// from it (mm), how still they were. `points` is not empty.
fn origin_of(points: &[Vector3<f64>]) -> (Vector3<f64>, f64) {
    let origin = crate::stats::median_point(points);
    let spread = (points
        .iter()
        .map(|p| (p - origin).norm_squared())
        .sum::<f64>()
        / points.len() as f64)
        .sqrt();
    (origin, spread)
}

/// The largest distance of a point from the points' median (mm); 0 for no points.
fn spread(points: &[Vector3<f64>]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let centre = crate::stats::median_point(points);
    points
        .iter()
        .map(|p| (p - centre).norm())
        .fold(0.0, f64::max)
}
