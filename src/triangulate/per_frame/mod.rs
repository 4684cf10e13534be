//! Per-frame triangulation (`triangulate --per-frame`): one row per left frame instant, for a
//! finger in motion.
//!
//! # Steps
//!
//! 1. Every frame is searched for the marker (as for steps; a moving bead's smear is found as
//!    one region, its centroid the bead at mid-exposure).
//! 2. Each camera's frames in time order: their stamps must increase (frames.csv named
//!    otherwise).
//! 3. The clock offset between the cameras, from the motion itself: the right track
//!    interpolated to the left frames' instants shifted by δ, the δ (within ±0.5 s: two
//!    webcams' delays often differ by more than a frame) whose interpolated points lie closest
//!    to their epipolar lines (a robust sum of squared distances, undistorted px, over the
//!    frames where the tip moves; each frame's best over its candidates, a right candidate
//!    taken with its nearest in the next frame, so that a still red object tells nothing and
//!    no earlier pass chooses which frames count). Without motion δ = 0. The same in each
//!    second of frames, looked for over every offset: when the δ of five seconds or more lie on
//!    a line (Theil-Sen, then each second again near it) whose slope differs from 0 at the
//!    1 % level, the stamps drift apart and δ follows that line, refined on every frame (a
//!    camera clock 5 % fast: 698.6 ms found for 700 over 14 s).
//! 4. Each left frame: the right camera's two frames around its instant (less δ) and the tip
//!    in them interpolated in time to it (a Catmull-Rom spline through them and the frames on
//!    either side, at their own times, so across a dropped frame too; linearly where a side
//!    has no such frame) — never the nearest frame, which at tens of mm/s is off by more than
//!    the error budget. Every combination of candidates (left × right before × right after,
//!    the two right ones within 30 px of each other, at a C920's focal length, scaled by the
//!    camera's: one object) is triangulated and
//!    reprojected as for a step's pair; exactly one consistent → the row's tip. None: one of
//!    the two right frames left out as if dropped (the bead hidden in it), the frames on
//!    either side taken instead, where exactly one of the two ways gives tips. Several (a
//!    faint red fleck beside the bead on its epipolar line, a red object seen by both
//!    cameras): the one within 1 mm of where the frames around it put the tip (interpolated
//!    between the neighbours with one tip each, or extrapolated from two on one side). Else
//!    the row is flagged, its tip left empty: `no_image`, `no_marker_left`,
//!    `no_marker_right`, `gap` (no right frame within two and a half periods on one side: two
//!    dropped in a row), `reprojection`, `ambiguous`, `fast` (the tip jumped between frames:
//!    where the parabolas through either camera's frames around the instant part by more than
//!    1 px, as when a pressure step's line and lag are shorter than a frame, no curve through
//!    the frames says where it was, and a smeared frame's centre is not its instant's; such
//!    tracks are not smoothed either).
//! 5. The pressures in force at the row's time: the log's command held until the next
//!    (the last held on), or what a streaming regulator measured while it held, where the log
//!    has that (`P1_measured_kpa`, …); a row before the first command, or after the last
//!    one's hold (its `hold_s`, or the log's median step where the log does not say), is
//!    flagged `outside_log`.
//! 6. The hand frame: axes from the calibration, origin the median tip over the rows in the
//!    log's first rest hold (the steps at 0, 0, 0 kPa before anything else: the finger rested
//!    before the session; later rest holds still creep). A tip beyond the finger's reach is
//!    flagged `reach`; a tip that rests on a region's plain centroid in a frame it used (the
//!    sub-pixel fit did not settle there) `centroid`. Both keep their tips.

mod cameras;
mod clock_offset;
mod live;
mod output;
mod rows;
pub(in crate::triangulate) use output::write_rows;
mod track;

pub use cameras::{
    triangulate_per_frame_cameras, CameraTrack, CamerasRow, CamerasSummary, PerFrameCameras,
};
pub use live::{tips_as_they_come, LiveClock, LiveTip};
pub use output::errors_against;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use nalgebra::Vector3;
use serde::Serialize;

use clock_offset::{clock_offset, Candidates, ClockOffset};
use track::{
    catmull_rom, lerp, smoothed_tracks, track_spread_px, Track, MAX_SPREAD_PX, NEIGHBOUR_PX,
};

use super::locate::combinations;
use super::marker::MAX_CANDIDATES;
use super::summary::{count_frames, FrameCounts};
use super::{distance_px, find_all_markers, FrameResult, TriangulateError, TriangulateOptions};
use crate::calib::file::CalibrationFile;
use crate::geometry::HandFromLeft;
use crate::session::frames::FrameList;
use crate::session::pressures::PressureLog;
use crate::stereo::{Side, StereoRig};

/// A frame record's marker candidates (px), or why it has none.
pub(super) type Centres<'a> = dyn Fn(usize) -> Result<Vec<[f64; 2]>, &'static str> + Sync + 'a;

/// Of several consistent tips in a frame, the one within this of where the frames around it put
/// the tip is taken (mm): a frame moves the tip at most a few mm, an interpolation between
/// its neighbours far less, and a false candidate along the epipolar line lies many mm away.
const TRACK_MM: f64 = 1.0;

/// One row: a left frame's instant.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRow {
    /// The left frame's number.
    pub frame: usize,
    /// Its timestamp on the log's clock (s).
    pub time_s: f64,
    /// The log step in force then.
    pub step: Option<usize>,
    /// The tip in the hand frame (mm), when found.
    pub tip_mm: Option<[f64; 3]>,
    pub reproj_px: Option<f64>,
    /// How far each camera's view of the still scene lies from its first frame's (px; per
    /// camera: the rows' camera's frame, the others' measured nearest in time), on the rows
    /// whose frame was measured ([`crate::triangulate::scene`]: one in
    /// [`crate::triangulate::scene::EVERY`]); empty on the others.
    pub scene_px: Vec<Option<f64>>,
    pub flags: Vec<&'static str>,
}

/// What a per-frame run counted and measured.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PerFrameSummary {
    pub frames: FrameCounts,
    pub rows: usize,
    /// Rows with a tip and no flag.
    pub good_rows: usize,
    /// Rows per flag.
    pub flagged: BTreeMap<&'static str, usize>,
    /// The right camera's stamps run this far ahead of the left's (ms), as the motion shows, at
    /// the middle of the moving frames.
    pub clock_offset_ms: f64,
    /// How much that offset grows from the first left frame to the last (ms): 0 unless the
    /// motion shows the stamps drifting apart.
    pub clock_drift_ms: f64,
    /// How many moving frames told the offset (0: not measured, taken as 0).
    pub clock_frames: usize,
    /// Each camera's delay from exposure to stamp taken out of its stamps (ms), when given or
    /// measured by `capture`; with `clocks_measured` (an LED both cameras filmed) nothing is
    /// measured from the motion.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delays_ms: Option<[f64; 2]>,
    pub clocks_measured: bool,
    /// Per camera, the RMS of its stamps about its regular frame clock (ms), when they lie on
    /// one: the times used are the clock's (`None`: the stamps as they are).
    pub stamp_jitter_ms: [Option<f64>; 2],
    /// The origin: the tip at rest in the left camera (mm), from this many rows, and their RMS
    /// distance from it (mm).
    pub origin_left_mm: [f64; 3],
    pub origin_rows: usize,
    pub origin_spread_mm: f64,
    /// Reprojection error of the rows with a tip (px): median, 95th percentile, largest.
    pub reproj_px: [f64; 3],
    pub interrupted: bool,
}

/// The result of a per-frame run.
#[derive(Clone, Debug)]
pub struct PerFrame {
    pub rows: Vec<FrameRow>,
    pub summary: PerFrameSummary,
    pub hand_from_left: HandFromLeft,
    pub options: TriangulateOptions,
}

/// Runs the per-frame triangulation; `progress(done, total)` counts frames examined,
/// `interrupt` stops the frame search (the rows of the frames examined are still made).
///
/// # Errors
/// [`TriangulateError`]: bad inputs (each naming the file and line or frame), no hand axes,
/// stamps going back, no tip in the first rest hold. `index` is the frame list's file, for
/// messages.
#[allow(clippy::too_many_arguments)]
pub fn triangulate_per_frame(
    frames: &FrameList,
    index: &Path,
    calibration: &CalibrationFile,
    log: &PressureLog,
    options: &TriangulateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &AtomicBool,
) -> Result<PerFrame, TriangulateError> {
    let r_hand = super::hand_axes(calibration)?;
    let rig = &calibration.rig;
    let records = &frames.records;
    let shift = options.latency_s.unwrap_or([0.0; 2]);
    let (left, right) = (
        Track::of(records, Side::Left, shift[0], rig.left.k[0], index)?,
        Track::of(records, Side::Right, shift[1], rig.right.k[0], index)?,
    );
    let unpaired = |why: String| TriangulateError::Unpaired {
        index: index.to_path_buf(),
        why,
    };
    if let Some(why) = apart(&left, &right) {
        return Err(unpaired(why));
    }
    let found = find_all_markers(frames, rig, options, true, progress, interrupt)?;
    let results = &found.results;
    let mut summary = PerFrameSummary {
        interrupted: interrupt.load(Ordering::SeqCst),
        ..PerFrameSummary::default()
    };
    count_frames(records, results, &mut summary.frames);
    let c = &summary.frames;
    let unread = |k: usize| c.no_file[k] + c.unreadable[k];
    if let Some(cam) = (0..2).find(|&k| c.listed[k] > 0 && unread(k) == c.listed[k]) {
        let name = [Side::Left, Side::Right][cam].name();
        return Err(unpaired(format!(
            "none of the {} {name} frames it lists can be read ({} missing, {} unreadable): check the folder and the file names ({name}_NNNNN.EXT)",
            c.listed[cam], c.no_file[cam], c.unreadable[cam]
        )));
    }

    let centres = |i: usize| -> Result<Vec<[f64; 2]>, &'static str> {
        match &results[i] {
            FrameResult::Markers(m) => Ok(m
                .blobs
                .iter()
                .take(MAX_CANDIDATES)
                .map(|b| b.centre_px)
                .collect()),
            FrameResult::Skipped => Err("skipped"),
            _ => Err("no_image"),
        }
    };
    summary.stamp_jitter_ms = [&left, &right].map(|t| t.jitter_s.map(|s| 1e3 * s));

    // 3-4. The clock offset, each left frame's tip.
    let (clock, seen, located) = locate_frames(rig, options, [&left, &right], &centres, None)?;
    summary.clock_offset_ms = 1e3 * clock.offset_s;
    summary.clock_drift_ms = 1e3 * clock.drift * left.length_s();
    summary.clock_frames = clock.frames;
    summary.delays_ms = options.latency_s.map(|s| s.map(|s| 1e3 * s));
    summary.clocks_measured = options.clocks_measured;

    // 5. Each left frame's step.
    let centroid_only = centroid_only(&left, &right, &seen, results, &located);
    let (mut rows, points) = rows::frame_rows(
        &left,
        |i| records[i].index,
        log,
        located
            .into_iter()
            .map(|f| f.map(|f| (f.point, f.reproj_px))),
    );
    for (row, _) in rows.iter_mut().zip(centroid_only).filter(|(_, c)| *c) {
        row.flags.push(CENTROID);
    }
    let clocks = [ClockOffset::default(), clock];
    rows::with_scene(&mut rows, &[&left, &right], &clocks, &found.scene);

    // 6. The hand frame from the first rest hold.
    let origin = rows::rest_origin(&rows, &points, log, options)?;
    summary.origin_left_mm = origin.point.into();
    summary.origin_rows = origin.rows;
    summary.origin_spread_mm = origin.spread_mm;
    let hand_from_left = HandFromLeft::new(r_hand, -(r_hand * origin.point));
    rows::in_hand_frame(&mut rows, &points, &hand_from_left, options);
    summary.rows = rows.len();
    summary.good_rows = rows.iter().filter(|r| r.flags.is_empty()).count();
    for f in rows.iter().flat_map(|r| &r.flags) {
        *summary.flagged.entry(f).or_default() += 1;
    }
    summary.reproj_px = super::median_95_max(rows.iter().filter_map(|r| r.reproj_px).collect());
    Ok(PerFrame {
        rows,
        summary,
        hand_from_left,
        options: options.clone(),
    })
}

/// A left frame's tip, or the flag saying why it has none.
pub type Tip<T> = Result<T, &'static str>;

/// Steps 3-4: the clock offset between the cameras (`clock` when given; none when the clocks
/// are measured; else from every candidate in every frame), the pass at it that chooses each
/// frame's centre, and each left frame's tip (left camera) from the tracks smoothed.
fn locate_frames(
    rig: &StereoRig,
    options: &TriangulateOptions,
    [left, right]: [&Track; 2],
    centres: &Centres<'_>,
    clock: Option<ClockOffset>,
) -> Result<(ClockOffset, Seen, Vec<Tip<Located>>), TriangulateError> {
    let clock = match (clock, options.clocks_measured) {
        (Some(clock), _) => clock,
        (None, true) => ClockOffset::default(),
        (None, false) => {
            let candidates: Candidates = [left, right].map(|t| {
                t.order
                    .iter()
                    .map(|&i| centres(i).unwrap_or_default())
                    .collect()
            });
            clock_offset(rig, left, right, &candidates)?
        }
    };
    let pass = locate_all(rig, options, left, right, centres, &clock);
    let seen = seen_in(left, right, &pass);
    let smoothed = smoothed_tracks(&[left, right], &seen);
    let chosen = |i: usize| match smoothed.get(&i) {
        Some(c) => Ok(vec![*c]),
        None => centres(i),
    };
    let located = locate_all(rig, options, left, right, &chosen, &clock);
    Ok((clock, seen, located))
}

/// Why the two tracks cannot make pairs, if they cannot: a camera without frames, or their
/// times apart by more than the clock offset is looked for within.
fn apart(left: &Track, right: &Track) -> Option<String> {
    let (Some(l), Some(r)) = (left.span_s(), right.span_s()) else {
        let missing = match left.span_s() {
            None => Side::Left.name(),
            Some(_) => Side::Right.name(),
        };
        return Some(format!(
            "lists no {missing} frames: a per-frame session needs both cameras'"
        ));
    };
    let gap = (r.0 - l.1).max(l.0 - r.1);
    (gap > clock_offset::MAX_OFFSET_S).then(|| format!(
        "the cameras' frames do not overlap in time (left {:.3}-{:.3} s, right {:.3}-{:.3} s), more than the {} s the clock offset is looked for within: check each camera's clock, or give their delays (--latency-ms)",
        l.0, l.1, r.0, r.1, clock_offset::MAX_OFFSET_S
    ))
}

/// Per camera, per position in its track, the centre a pass chose there (left, right).
pub(super) type Seen = [Vec<Option<[f64; 2]>>; 2];

/// The flag of a row whose tip rests on a region's plain centroid in either camera (the
/// sub-pixel fit did not settle there: ≈ 0.2 px of JPEG chroma bias). Its tip is written all
/// the same, for a user who would rather have it.
pub const CENTROID: &str = "centroid";

/// Per row of `located`, whether a frame it was seen in (the left frame, the right frames
/// around its instant) was seen as a region whose sub-pixel fit did not settle.
fn centroid_only(
    left: &Track,
    right: &Track,
    seen: &Seen,
    results: &[FrameResult],
    located: &[Result<Located, &'static str>],
) -> Vec<bool> {
    let unfitted = |track: &Track, camera: usize, pos: usize| {
        let (Some(Some(px)), Some(FrameResult::Markers(m))) = (
            seen[camera].get(pos),
            track.order.get(pos).and_then(|&i| results.get(i)),
        ) else {
            return false;
        };
        m.blobs.iter().any(|b| b.centre_px == *px && !b.fitted)
    };
    located
        .iter()
        .enumerate()
        .map(|(k, found)| match found {
            Ok(found) => {
                unfitted(left, 0, k) || found.right.iter().any(|&(p, _)| unfitted(right, 1, p))
            }
            Err(_) => false,
        })
        .collect()
}

/// The centres the located frames were seen as, in each track.
fn seen_in(left: &Track, right: &Track, located: &[Result<Located, &'static str>]) -> Seen {
    let mut seen: Seen = [vec![None; left.times.len()], vec![None; right.times.len()]];
    for (k, found) in located.iter().enumerate() {
        if let Ok(found) = found {
            seen[0][k] = Some(found.left_px);
            for (pos, px) in found.right {
                seen[1][pos] = Some(px);
            }
        }
    }
    seen
}

/// A left frame's tip, and the candidates it was seen as.
struct Located {
    /// In the left camera (mm).
    point: Vector3<f64>,
    reproj_px: f64,
    /// The left centre, and the right track's frames around the instant (positions in the
    /// track) with their centres (px).
    left_px: [f64; 2],
    right: [(usize, [f64; 2]); 2],
}

/// Every left frame's tip at its instant on the right camera's clock (`clock`), in
/// parallel; or the flag saying why there is none.
fn locate_all(
    rig: &StereoRig,
    options: &TriangulateOptions,
    left: &Track,
    right: &Track,
    centres: &Centres<'_>,
    clock: &ClockOffset,
) -> Vec<Result<Located, &'static str>> {
    use rayon::prelude::*;
    let found: Vec<Result<Vec<Located>, &'static str>> = left
        .order
        .par_iter()
        .zip(&left.times)
        .map(|(&i, &t)| locate_at(rig, options, right, centres, i, clock.stamp_of(t)))
        .collect();
    // The single tip of each frame, for its neighbours to be told by.
    let single: Vec<Option<Vector3<f64>>> = found
        .iter()
        .map(|f| match f.as_deref() {
            Ok([only]) => Some(only.point),
            _ => None,
        })
        .collect();
    found
        .into_iter()
        .enumerate()
        .map(|(k, f)| {
            let mut tips = f?;
            let tip = if tips.len() == 1 {
                tips.remove(0)
            } else {
                let expected = expected_tip(&left.times, &single, k).ok_or("ambiguous")?;
                let mut near = tips
                    .into_iter()
                    .filter(|c| (c.point - expected).norm() <= TRACK_MM);
                match (near.next(), near.next()) {
                    (Some(c), None) => c,
                    _ => return Err("ambiguous"),
                }
            };
            // The left frame's centre, smeared over a jump, is no better than the right's.
            match left.jerk_around(k, tip.left_px, centres) {
                Some(jerk) if jerk > left.px(MAX_SPREAD_PX) => Err("fast"),
                _ => Ok(tip),
            }
        })
        .collect()
}

/// Where the tip of left frame `k` should be, from the frames on either side with a single
/// tip (interpolated in time), or the two before or after it (extrapolated); `None` without.
fn expected_tip(times: &[f64], single: &[Option<Vector3<f64>>], k: usize) -> Option<Vector3<f64>> {
    let at = |j: usize| Some((times[j], (*single.get(j)?)?));
    let line = |(ta, a): (f64, Vector3<f64>), (tb, b): (f64, Vector3<f64>)| {
        a + (b - a) * ((times[k] - ta) / (tb - ta))
    };
    let before = k.checked_sub(1).and_then(at);
    let after = at(k + 1);
    match (before, after) {
        (Some(a), Some(b)) => Some(line(a, b)),
        (Some(a), None) => Some(line(at(k.checked_sub(2)?)?, a)),
        (None, Some(b)) => Some(line(b, at(k + 2)?)),
        (None, None) => None,
    }
}

/// The tips at left frame `i` and its instant `t` on the right camera's clock: every
/// consistent combination of candidates (one or more), from the right frames around `t`; when
/// those give none, from the frames around `t` with one of the two left out, as if dropped
/// (the bead hidden in it, or the frame unreadable), where exactly one of the two ways gives
/// tips.
fn locate_at(
    rig: &StereoRig,
    options: &TriangulateOptions,
    right: &Track,
    centres: &Centres<'_>,
    i: usize,
    t: f64,
) -> Result<Vec<Located>, &'static str> {
    let cl = centres(i)?;
    let (a, b, _) = right.around(t)?;
    if cl.is_empty() {
        return Err("no_marker_left");
    }
    right.around_or_dropped((a, b), |a, b| {
        locate_between(rig, options, right, centres, &cl, a, b, t)
    })
}

/// The consistent tips of the left candidates `cl` with the right track between its frames
/// `a` and `b`, at `t`.
#[allow(clippy::too_many_arguments)]
fn locate_between(
    rig: &StereoRig,
    options: &TriangulateOptions,
    right: &Track,
    centres: &Centres<'_>,
    cl: &[[f64; 2]],
    a: usize,
    b: usize,
    t: f64,
) -> Result<Vec<Located>, &'static str> {
    let (points, unused) = right.at_instant(centres, a, b, t)?;
    let (pairs, cr): (Vec<_>, Vec<_>) = points.into_iter().unzip();
    let combos = combinations(rig, cl, &cr, options).map_err(|_| "reprojection")?;
    let consistent: Vec<Located> = combos
        .iter()
        .filter(|c| c.consistent)
        .map(|c| Located {
            point: c.point,
            reproj_px: c.reproj_px,
            left_px: cl[c.left],
            right: [(a, pairs[c.right].0), (b, pairs[c.right].1)],
        })
        .collect();
    if consistent.is_empty() {
        return Err(unused.unwrap_or("reprojection"));
    }
    Ok(consistent)
}

/// Pairs of candidates of two frames taken for one object, each with its point at an instant
/// between them, and the flag of the pairs left out, if any ([`Track::at_instant`]).
type AtInstant = (Vec<(([f64; 2], [f64; 2]), [f64; 2])>, Option<&'static str>);

impl Track {
    /// The candidates of this track's frames `a` and `b` (positions) taken for one object, each
    /// pair with its point at `t` between them: on the spline where the track is sure enough
    /// of the tip between the two frames, on their line where a side has no frame to bend it
    /// (never across a frame left out: nothing would say the tip did not jump there). The flag
    /// when none: `no_marker_right` (a frame without candidates, or none near enough to be
    /// one object), `fast` (the track unsure of the tip), `gap` (a frame left out and no frame
    /// beyond to bend it); the flag of the pairs left out beside those kept.
    fn at_instant(
        &self,
        centres: &Centres<'_>,
        a: usize,
        b: usize,
        t: f64,
    ) -> Result<AtInstant, &'static str> {
        let (ca, cb) = (centres(self.order[a])?, centres(self.order[b])?);
        // The candidates in the two frames taken for one object: those near enough to be (a
        // red object in one frame and the bead in the next, interpolated, would lie anywhere
        // between them, and on the epipolar line when the bead is about to appear).
        let pairs: Vec<([f64; 2], [f64; 2])> = ca
            .iter()
            .flat_map(|&p| cb.iter().map(move |&q| (p, q)))
            .filter(|&(p, q)| distance_px(p, q) <= self.px(NEIGHBOUR_PX))
            .collect();
        if pairs.is_empty() {
            return Err("no_marker_right");
        }
        let s = (t - self.times[a]) / (self.times[b] - self.times[a]);
        let (before, after) = (
            a.checked_sub(1),
            Some(b + 1).filter(|&k| k < self.times.len()),
        );
        let wide = self.periods_apart(a, b) > 1.5;
        let nearest = |pos: Option<usize>, to: [f64; 2]| self.nearest(pos?, to, centres);
        let at_t = |(p, q): ([f64; 2], [f64; 2])| -> Result<[f64; 2], &'static str> {
            match (nearest(before, p), nearest(after, q), self.knots(a, b)) {
                (Some(o), Some(r), Some(knots)) => {
                    let points = [o, p, q, r];
                    if track_spread_px(points, knots) <= self.px(MAX_SPREAD_PX) {
                        Ok(catmull_rom(points, knots, t))
                    } else {
                        Err("fast")
                    }
                }
                _ if wide => Err("gap"),
                _ => Ok(lerp(p, q, s)),
            }
        };
        let tried: Vec<_> = pairs.into_iter().map(|pair| (pair, at_t(pair))).collect();
        // Why a pair was not used, to name a row that has no point for it.
        let unused = tried.iter().find_map(|(_, c)| c.err());
        let points: Vec<_> = tried
            .into_iter()
            .filter_map(|(pair, c)| Some((pair, c.ok()?)))
            .collect();
        if points.is_empty() {
            return Err(unused.unwrap_or("no_marker_right"));
        }
        Ok((points, unused))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERIOD: f64 = 1.0 / 30.0;

    /// Every left frame's tip from `locate_all` on the stamps as they are (no clock offset).
    fn locate_on_stamps(
        rig: &StereoRig,
        left: &Track,
        right: &Track,
        centres: &Centres<'_>,
    ) -> Vec<Result<Located, &'static str>> {
        let options = TriangulateOptions::default();
        locate_all(rig, &options, left, right, centres, &ClockOffset::default())
    }

    /// `count` frames of one camera, records `first`…, at (k + `phase`) periods.
    fn regular_track(first: usize, count: usize, phase: f64) -> Track {
        Track {
            order: (first..first + count).collect(),
            times: (0..count).map(|k| (k as f64 + phase) * PERIOD).collect(),
            period_s: PERIOD,
            jitter_s: None,
            px_scale: 1.0,
        }
    }

    /// Issue 61: a row whose tip rests on a region's plain centroid (the sub-pixel fit did not
    /// settle in one of the frames it used) was written as any other, with no flag and no count.
    #[test]
    fn a_tip_on_a_plain_centroid_is_flagged_centroid() {
        let rig = StereoRig::rectified_for_tests();
        let tip = Vector3::new(5.0, 10.0, 300.0);
        let px = |side| rig.project(side, &[tip]).unwrap()[0];
        let (left_px, right_px) = (px(Side::Left), px(Side::Right));
        // Records: five left frames (0-4), then six right frames (5-10), all on one clock;
        // right frame 6 (track position 1) was not fitted.
        let (left, right) = (regular_track(0, 5, 0.0), regular_track(5, 6, 0.0));
        let blob = |centre_px, fitted| super::super::marker::Blob {
            centre_px,
            fitted,
            area_px: 30,
            peak: 100.0,
            elongation: 1.0,
        };
        let results: Vec<FrameResult> = (0..11)
            .map(|i| {
                let blobs = match i {
                    0..5 => vec![blob(left_px, true)],
                    _ => vec![blob(right_px, i != 6)],
                };
                FrameResult::Markers(super::super::marker::Markers {
                    blobs,
                    discarded: 0,
                })
            })
            .collect();
        let centres = |i: usize| -> Result<Vec<[f64; 2]>, &'static str> {
            Ok(vec![if i < 5 { left_px } else { right_px }])
        };
        let located = locate_on_stamps(&rig, &left, &right, &centres);
        assert!(located.iter().all(Result::is_ok));
        let seen = seen_in(&left, &right, &located);
        let flagged = centroid_only(&left, &right, &seen, &results, &located);
        // Each row uses the right frames around its instant: the first uses frame 6, the last
        // does not.
        let uses_6: Vec<bool> = located
            .iter()
            .map(|f| f.as_ref().unwrap().right.iter().any(|&(p, _)| p == 1))
            .collect();
        assert_eq!(flagged, uses_6);
        assert!(flagged[0] && !flagged[4], "{flagged:?}");
    }

    #[test]
    fn a_right_frame_that_lost_the_bead_is_left_out_not_paired_with_another_red_object() {
        // Rectified cameras 60 mm apart; the tip 300 mm ahead. In the right camera a red
        // object 20 px below the tip's epipolar line is seen in every frame, the tip in all
        // but the one just before the left frame's instant (hidden). Interpolated 98 % of the
        // way from the object to the tip, the right point lies 0.4 px off the epipolar line
        // and 7.7 px off the tip along it: a consistent pair, 5 mm deep in error, that an
        // earlier version returned. The hidden frame is left out instead, as if dropped, and
        // the tip comes from the frames on either side of it; hidden in two frames in a row, the
        // row has no tip.
        let rig = StereoRig::rectified_for_tests();
        let tip = Vector3::new(5.0, 10.0, 300.0);
        let [left_px] = rig.project(Side::Left, &[tip]).unwrap()[..] else {
            unreachable!()
        };
        let [right_px] = rig.project(Side::Right, &[tip]).unwrap()[..] else {
            unreachable!()
        };
        let other = [right_px[0] + 384.0, right_px[1] + 20.0];
        // Records: the left frame (0), then six right frames 1/30 s apart (1-6).
        let right = regular_track(1, 6, 0.0);
        let hidden_in = |frames: &'static [usize]| {
            move |i: usize| -> Result<Vec<[f64; 2]>, &'static str> {
                Ok(match i {
                    0 => vec![left_px],
                    i if frames.contains(&i) => vec![other],
                    _ => vec![right_px, other],
                })
            }
        };
        let t = (2.0 + 0.98) * PERIOD;
        let options = TriangulateOptions::default();
        let found = locate_at(&rig, &options, &right, &hidden_in(&[3]), 0, t).expect("the tip");
        assert_eq!(found.len(), 1);
        assert!((found[0].point - tip).norm() < 0.01, "{:?}", found[0].point);
        assert_eq!([found[0].right[0].0, found[0].right[1].0], [1, 3]);
        let found = locate_at(&rig, &options, &right, &hidden_in(&[3, 4]), 0, t);
        assert!(
            found.is_err(),
            "a tip at {:?}",
            found.map(|f| f.iter().map(|c| c.point).collect::<Vec<_>>())
        );
        // With the tip seen in both frames around the instant, it is found from them.
        let found = locate_at(&rig, &options, &right, &hidden_in(&[]), 0, t).expect("the tip");
        assert_eq!(found.len(), 1);
        assert!((found[0].point - tip).norm() < 0.01, "{:?}", found[0].point);
        assert_eq!([found[0].right[0].0, found[0].right[1].0], [2, 3]);
    }

    #[test]
    fn a_tip_that_jumps_between_frames_is_flagged_fast_not_interpolated() {
        // A pressure step whose line and lag are shorter than a frame: the tip, 300 mm ahead of
        // rectified cameras, jumps 4 mm (12 px) along x with τ = 5 ms just before the third
        // left frame. Frames catch it exactly (no blur); the right camera's half a period
        // earlier. No curve through the right frames says where the tip was mid-jump: the rows
        // beside the jump are `fast`, the others right. Without the spread check the second
        // row's tip is 1.2 mm off.
        let rig = StereoRig::rectified_for_tests();
        let jump = 1.9 * PERIOD;
        let tip = |t: f64| {
            let moved = if t > jump {
                1.0 - (-(t - jump) / 0.005).exp()
            } else {
                0.0
            };
            Vector3::new(5.0 + 4.0 * moved, 10.0, 300.0)
        };
        let project = |side: Side, t: f64| rig.project(side, &[tip(t)]).unwrap()[0];
        // Records 0-5: left frames; 6-12: right frames half a period earlier.
        let (left, right) = (regular_track(0, 6, 0.0), regular_track(6, 7, -0.5));
        let centres = |i: usize| -> Result<Vec<[f64; 2]>, &'static str> {
            Ok(vec![match i {
                0..=5 => project(Side::Left, left.times[i]),
                _ => project(Side::Right, right.times[i - 6]),
            }])
        };
        let found = locate_on_stamps(&rig, &left, &right, &centres);
        for (k, row) in found.iter().enumerate() {
            match row {
                Ok(c) => {
                    let error = (c.point - tip(left.times[k])).norm();
                    assert!(error < 0.05, "row {k}: {error} mm off");
                }
                Err(flag) => assert_eq!(*flag, "fast", "row {k}"),
            }
        }
        assert_eq!(found[2].as_ref().err(), Some(&"fast"));
        let flags: Vec<_> = found.iter().map(|r| r.as_ref().err()).collect();
        assert!(found[0].is_ok() && found[5].is_ok(), "{flags:?}");
    }

    #[test]
    fn a_fleck_beside_the_bead_on_its_epipolar_line_is_told_apart_by_the_frames_around() {
        // The tip moves at 30 mm/s along x, 300 mm ahead of rectified cameras. The middle of
        // three left frames also shows a faint red fleck 10 px to the bead's right, on its
        // row and so on its epipolar line: a second consistent tip, 17 mm deeper.
        let rig = StereoRig::rectified_for_tests();
        let tip = |t: f64| Vector3::new(5.0 + 30.0 * t, 10.0, 300.0);
        let project = |side: Side, t: f64| rig.project(side, &[tip(t)]).unwrap()[0];
        // Records 0-2: left frames; 3-6: right frames half a period earlier.
        let (left, right) = (regular_track(0, 3, 0.0), regular_track(3, 4, -0.5));
        let centres = |i: usize| -> Result<Vec<[f64; 2]>, &'static str> {
            Ok(match i {
                0..=2 => {
                    let bead = project(Side::Left, left.times[i]);
                    if i == 1 {
                        vec![bead, [bead[0] + 10.0, bead[1]]]
                    } else {
                        vec![bead]
                    }
                }
                _ => vec![project(Side::Right, right.times[i - 3])],
            })
        };
        let found = locate_on_stamps(&rig, &left, &right, &centres);
        let middle = found[1].as_ref().expect("the bead, not `ambiguous`");
        assert!(
            (middle.point - tip(PERIOD)).norm() < 0.01,
            "{:?} against {:?}",
            middle.point,
            tip(PERIOD)
        );
        // Alone, the middle frame has two consistent tips.
        let both = locate_at(
            &rig,
            &TriangulateOptions::default(),
            &right,
            &centres,
            1,
            PERIOD,
        )
        .unwrap();
        assert_eq!(both.len(), 2);
        assert!(both.iter().any(|c| (c.point - tip(PERIOD)).norm() > 5.0));
    }
}
