//! Per-frame triangulation with more than two cameras (issue 59): one row per frame of the
//! first camera that lists frames (the rows' camera), as a pair's rows are its left frames.
//!
//! 1. Every frame of every camera searched for the marker ([`super::super::cameras::examine`]);
//!    each camera's frames in time order, their stamps increasing.
//! 2. Each other camera's clock offset from the rows' camera, from the motion, as a pair's
//!    right camera's from its left ([`super::clock_offset`], on the two cameras as a pair);
//!    none with the clocks measured.
//! 3. Each row's instant on each camera's clock: the rows' camera its frame's candidates
//!    (those around which its own track is sure of the tip), every other camera its track's
//!    candidates interpolated to the instant between the two frames around it
//!    ([`Track::at_instant`]: a spline; one of the two frames left out, as if dropped, where
//!    they give nothing). A camera without a point there is no view; a row with fewer than two
//!    is flagged (`fast` when a camera's track was too unsure of the tip, else `unseen`).
//! 4. The row's tip from one candidate per camera, as a held step's
//!    ([`super::super::cameras::agreed`]): the χ² gate in units of each view's pixel error,
//!    the choice the most cameras agree on, then the least χ² (`reprojection` when no two
//!    agree). Each camera's track then smoothed where the rows saw the tip in five frames in a
//!    row, and the rows located again, as a pair's.
//! 5. The pressures in force, the origin (the median tip over the log's first rest hold), the
//!    hand frame's axes from the calibration, `reach` and `centroid` flags, as a pair's rows.
//! 6. Each row's covariance as a held step's: the beads' error, scaled up to what the rows'
//!    residuals show, in the tip and the origin, and the calibration's.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use nalgebra::Matrix3;
use rayon::prelude::*;
use serde::Serialize;

mod locate;
mod output;

use super::clock_offset::{clock_offset, ClockOffset, MAX_OFFSET_S};
use super::track::{smoothed_tracks, Track};
use super::{rows, Centres, FrameRow, Tip, CENTROID};
use crate::geometry::HandFromLeft;
use crate::session::pressures::PressureLog;
use crate::triangulate::cameras::{
    covariance, examine, Calibration, CamerasError, Examined, Frame, InWorld,
};
use crate::triangulate::marker::MAX_CANDIDATES;
use crate::triangulate::{nview, scene, TriangulateError, TriangulateOptions};
use locate::{Located, Locator};

/// One row: a frame of the rows' camera.
#[derive(Clone, Debug)]
pub struct CamerasRow {
    /// Its frame, time, step, tip (hand frame), the largest reprojection residual of the views
    /// used and flags.
    pub row: FrameRow,
    /// The cameras used and left out by the gate (indices into the calibration's).
    pub used: Vec<usize>,
    pub left_out: Vec<usize>,
    pub chi2: f64,
    /// The tip's covariance in the hand frame (mm²), when it has a tip.
    pub covariance_mm2: Option<Matrix3<f64>>,
}

/// What one camera showed, and its clock against the rows' camera's.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CameraTrack {
    pub name: String,
    pub listed: usize,
    pub without_marker: usize,
    pub unreadable: usize,
    /// Its stamps run this far ahead of the rows' camera's (ms), as the motion shows, at the
    /// middle of the moving frames; how much that grows over the rows (ms); from how many
    /// moving frames (0: not measured, taken as 0).
    pub clock_offset_ms: f64,
    pub clock_drift_ms: f64,
    pub clock_frames: usize,
    /// The RMS of its stamps about its regular frame clock (ms), when they lie on one.
    pub stamp_jitter_ms: Option<f64>,
    /// The rows whose tip it is in.
    pub rows_used: usize,
}

/// What a per-frame run with more cameras counted and measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CamerasSummary {
    /// The rows' camera.
    pub rows_camera: String,
    pub cameras: Vec<CameraTrack>,
    pub clocks_measured: bool,
    pub rows: usize,
    /// Rows with a tip and no flag.
    pub good_rows: usize,
    /// Rows per flag.
    pub flagged: BTreeMap<&'static str, usize>,
    /// Rows with a tip per number of cameras in it.
    pub by_cameras: BTreeMap<usize, usize>,
    /// The origin in the world (the first camera's frame, mm), from this many rows, and their
    /// RMS distance from it (mm).
    pub origin_world_mm: [f64; 3],
    pub origin_rows: usize,
    pub origin_spread_mm: f64,
    /// The beads' pixel error the rows' residuals show (px).
    pub bead_noise_px: Option<f64>,
    pub calibration_in_covariance: bool,
    pub interrupted: bool,
}

/// The result of a per-frame run with more cameras.
#[derive(Clone, Debug)]
pub struct PerFrameCameras {
    pub rows: Vec<CamerasRow>,
    pub summary: CamerasSummary,
}

/// Runs the per-frame triangulation of `frames` (module docs) seen by the cameras of
/// `calibration`, against `log`; `index` is the frame list's file, for messages;
/// `progress(done, total)` counts frames examined; once `interrupt` is set the frames not yet
/// examined are left out (the rows still made, `interrupted` said).
///
/// # Errors
/// [`CamerasError`]: a frame of another size than its camera's calibration, stamps going back,
/// fewer than two cameras with frames, a camera's frames apart in time from the rows', no tip
/// in the first rest hold.
pub fn triangulate_per_frame_cameras(
    frames: &[Frame],
    calibration: &Calibration,
    log: &PressureLog,
    options: &TriangulateOptions,
    index: &Path,
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &AtomicBool,
) -> Result<PerFrameCameras, CamerasError> {
    let cameras = &calibration.cameras;
    // 1. Each camera's track, every frame's candidates.
    let tracks = tracks(frames, calibration, index)?;
    let Some(first) = tracks.iter().position(|t| !t.order.is_empty()) else {
        unreachable!("frames.csv lists frames of a calibrated camera")
    };
    let seeing = tracks.iter().filter(|t| !t.order.is_empty()).count();
    if seeing < 2 {
        return Err(TriangulateError::Unpaired {
            index: index.to_path_buf(),
            why: format!(
                "lists frames of camera {} alone: a tip takes two cameras' frames",
                cameras[first].name
            ),
        }
        .into());
    }
    let (examined, scene) = examine_all(frames, cameras, options, progress, interrupt);
    let mut summary = CamerasSummary {
        rows_camera: cameras[first].name.clone(),
        clocks_measured: options.clocks_measured,
        interrupted: interrupt.load(Ordering::SeqCst),
        ..CamerasSummary::default()
    };
    summary.cameras = count(frames, &examined, calibration, &tracks)?;
    let centres = |i: usize| -> Result<Vec<[f64; 2]>, &'static str> {
        match &examined[i] {
            Examined::Markers(blobs) => Ok(blobs
                .iter()
                .take(MAX_CANDIDATES)
                .map(|b| b.centre_px)
                .collect()),
            Examined::Skipped => Err("skipped"),
            _ => Err("no_image"),
        }
    };

    // 2. Each camera's clock against the rows' camera's.
    let clocks = clocks(calibration, &tracks, first, &centres, options, index)?;
    let rows_track = &tracks[first];
    for (camera, clock) in summary.cameras.iter_mut().zip(&clocks) {
        camera.clock_offset_ms = 1e3 * clock.offset_s;
        camera.clock_drift_ms = 1e3 * clock.drift * rows_track.length_s();
        camera.clock_frames = clock.frames;
    }

    // 3-4. Each row's tip, twice: the second time on the tracks smoothed.
    let locator = Locator {
        calibration,
        tracks: &tracks,
        clocks: &clocks,
        first,
        projections: cameras
            .iter()
            .map(|c| crate::geometry::projection(&c.intrinsics, &c.pose))
            .collect(),
    };
    let pass = locator.locate_all(&centres);
    let mut seen: Vec<Vec<Option<[f64; 2]>>> =
        tracks.iter().map(|t| vec![None; t.order.len()]).collect();
    for found in pass.iter().flatten() {
        for &(c, pos, px) in &found.frames {
            seen[c][pos] = Some(px);
        }
    }
    let track_refs: Vec<&Track> = tracks.iter().collect();
    let smoothed = smoothed_tracks(&track_refs, &seen);
    let chosen = |i: usize| match smoothed.get(&i) {
        Some(c) => Ok(vec![*c]),
        None => centres(i),
    };
    let located = locator.locate_all(&chosen);

    // 5. The rows, the origin, the hand frame.
    let centroid_only = centroid_only(&tracks, &examined, &seen, &located);
    let (mut rows, points) = rows::frame_rows(
        rows_track,
        |i| frames[i].index,
        log,
        located.iter().map(|f| {
            f.as_ref()
                .map(|f| (f.tip.point, worst_px(&f.tip)))
                .map_err(|e| *e)
        }),
    );
    for (row, _) in rows.iter_mut().zip(&centroid_only).filter(|(_, c)| **c) {
        row.flags.push(CENTROID);
    }
    rows::with_scene(&mut rows, &track_refs, &clocks, &scene);
    let origin = rows::rest_origin(&rows, &points, log, options)?;
    summary.origin_world_mm = origin.point.into();
    summary.origin_rows = origin.rows;
    summary.origin_spread_mm = origin.spread_mm;
    let hand = calibration.hand;
    let hand_from_world = HandFromLeft::new(hand, -(hand * origin.point));
    rows::in_hand_frame(&mut rows, &points, &hand_from_world, options);

    // 6. Each row's covariance.
    let (rows, bead_noise_px) = with_covariances(rows, located, calibration, log, options);
    summary.bead_noise_px = bead_noise_px;
    summary.calibration_in_covariance = calibration.covariance.is_some();
    summarise(&mut summary, &rows);
    Ok(PerFrameCameras { rows, summary })
}

/// Every frame examined ([`examine`]), in parallel; `progress(done, total)` counts them; once
/// `interrupt` is set the rest are skipped. And, in the frames whose number is a multiple of
/// [`scene::EVERY`], how far the view of the still scene lies from its camera's first such
/// frame's (px).
fn examine_all(
    frames: &[Frame],
    cameras: &[crate::calib::file::ReadCamera],
    options: &TriangulateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &AtomicBool,
) -> (Vec<Examined>, Vec<Option<f64>>) {
    let measured = |f: &Frame| f.index.is_multiple_of(scene::EVERY);
    let mut first = scene::FirstFrames::default();
    for camera in 0..cameras.len() {
        let mut of_camera: Vec<&Frame> = (frames.iter())
            .filter(|f| f.camera == camera && measured(f))
            .collect();
        of_camera.sort_by_key(|f| f.index);
        // The first that reads, at the camera's size.
        let first_read = of_camera
            .iter()
            .find_map(|f| examine(f, cameras, options, true).1);
        if let Some(thumbnail) = first_read {
            first.offer(camera, &thumbnail);
        }
    }
    let done = AtomicUsize::new(0);
    frames
        .par_iter()
        .map(|f| {
            if interrupt.load(Ordering::Relaxed) {
                return (Examined::Skipped, None);
            }
            let (e, thumbnail) = examine(f, cameras, options, measured(f));
            progress(done.fetch_add(1, Ordering::SeqCst) + 1, frames.len());
            (e, thumbnail.and_then(|t| first.shift(f.camera, &t)))
        })
        .unzip()
}

/// Per row of `located`, whether a frame a camera it used saw it in was seen, by the first
/// pass (`seen`: the second's centres may be smoothed), as a region whose sub-pixel fit did not
/// settle (the row's flag [`CENTROID`]), as a pair's rows are flagged.
fn centroid_only(
    tracks: &[Track],
    examined: &[Examined],
    seen: &[Vec<Option<[f64; 2]>>],
    located: &[Tip<Located>],
) -> Vec<bool> {
    let unfitted = |c: usize, pos: usize| {
        let (Some(px), Examined::Markers(blobs)) = (seen[c][pos], &examined[tracks[c].order[pos]])
        else {
            return false;
        };
        blobs.iter().any(|b| b.centre_px == px && !b.fitted)
    };
    located
        .iter()
        .map(|found| {
            found.as_ref().is_ok_and(|f| {
                f.frames
                    .iter()
                    .filter(|(c, _, _)| f.tip.used.contains(c))
                    .any(|&(c, pos, _)| unfitted(c, pos))
            })
        })
        .collect()
}

/// Each calibrated camera's frames of `frames` as a track, in frame order.
///
/// # Errors
/// A camera's stamps not increasing, naming the frames (`index`, the frame list).
fn tracks(
    frames: &[Frame],
    calibration: &Calibration,
    index: &Path,
) -> Result<Vec<Track>, TriangulateError> {
    let cameras = &calibration.cameras;
    (0..cameras.len())
        .map(|c| {
            let mut order: Vec<usize> = (0..frames.len())
                .filter(|&i| frames[i].camera == c)
                .collect();
            order.sort_by_key(|&i| frames[i].index);
            if let Some(w) = order
                .windows(2)
                .find(|w| frames[w[1]].time_s <= frames[w[0]].time_s)
            {
                let (a, b) = (&frames[w[0]], &frames[w[1]]);
                return Err(TriangulateError::Unpaired {
                    index: index.to_path_buf(),
                    why: format!(
                        "{} frame {} is stamped {} s, not after frame {} ({} s): a camera's stamps must increase; check the capture's clock",
                        cameras[c].name, b.index, b.time_s, a.index, a.time_s
                    ),
                });
            }
            let stamps = order.iter().map(|&i| frames[i].time_s).collect();
            Ok(Track::of_stamps(order, stamps, cameras[c].intrinsics.fx()))
        })
        .collect()
}

/// Each camera's frames listed, without a marker and unreadable; an image of another size
/// than its camera's calibration refused.
fn count(
    frames: &[Frame],
    examined: &[Examined],
    calibration: &Calibration,
    tracks: &[Track],
) -> Result<Vec<CameraTrack>, CamerasError> {
    let cameras = &calibration.cameras;
    let mut counted: Vec<CameraTrack> = cameras
        .iter()
        .zip(tracks)
        .map(|(c, t)| CameraTrack {
            name: c.name.clone(),
            listed: t.order.len(),
            stamp_jitter_ms: t.jitter_s.map(|s| 1e3 * s),
            ..CameraTrack::default()
        })
        .collect();
    for (f, e) in frames.iter().zip(examined) {
        let camera = &mut counted[f.camera];
        match e {
            Examined::Markers(blobs) => camera.without_marker += usize::from(blobs.is_empty()),
            Examined::Unreadable(_) => camera.unreadable += 1,
            Examined::WrongSize(got) => {
                return Err(CamerasError::wrong_size(f, &cameras[f.camera], *got))
            }
            Examined::Skipped => {}
        }
    }
    Ok(counted)
}

/// Each camera's clock against the rows' camera `first` (module docs, step 2).
///
/// # Errors
/// A camera whose frames lie farther from the rows' camera's in time than the offset is looked
/// for within.
fn clocks(
    calibration: &Calibration,
    tracks: &[Track],
    first: usize,
    centres: &Centres<'_>,
    options: &TriangulateOptions,
    index: &Path,
) -> Result<Vec<ClockOffset>, TriangulateError> {
    let cameras = &calibration.cameras;
    let candidates = |t: &Track| -> Vec<Vec<[f64; 2]>> {
        t.order
            .iter()
            .map(|&i| centres(i).unwrap_or_default())
            .collect()
    };
    let reference = candidates(&tracks[first]);
    (0..cameras.len())
        .map(|c| {
            let (Some(l), Some(r)) = (tracks[first].span_s(), tracks[c].span_s()) else {
                return Ok(ClockOffset::default());
            };
            let gap = (r.0 - l.1).max(l.0 - r.1);
            if gap > MAX_OFFSET_S {
                return Err(TriangulateError::Unpaired {
                    index: index.to_path_buf(),
                    why: format!(
                        "camera {}'s frames ({:.3}-{:.3} s) do not overlap camera {}'s ({:.3}-{:.3} s) in time, by more than the {MAX_OFFSET_S} s the clock offset is looked for within: check each camera's clock",
                        cameras[c].name, r.0, r.1, cameras[first].name, l.0, l.1
                    ),
                });
            }
            if c == first || options.clocks_measured {
                return Ok(ClockOffset::default());
            }
            let pair = cameras[first].pair_with(&cameras[c]);
            clock_offset(
                &pair,
                &tracks[first],
                &tracks[c],
                &[reference.clone(), candidates(&tracks[c])],
            )
        })
        .collect()
}

/// The largest reprojection residual of a tip's views used (px).
fn worst_px(tip: &nview::Triangulated) -> f64 {
    tip.residuals_px.iter().copied().fold(0.0, f64::max)
}

/// The rows with their cameras and covariances (module docs, step 6), and the beads' error
/// the rows' residuals show.
fn with_covariances(
    rows: Vec<FrameRow>,
    located: Vec<Tip<Located>>,
    calibration: &Calibration,
    log: &PressureLog,
    options: &TriangulateOptions,
) -> (Vec<CamerasRow>, Option<f64>) {
    let rest_steps = rows::rest_steps(log, options);
    let mut world = Vec::new();
    let mut rest = Vec::new();
    let mut of_row = Vec::with_capacity(rows.len());
    for (k, (row, found)) in rows.iter().zip(located).enumerate() {
        let Ok(found) = found else {
            of_row.push(None);
            continue;
        };
        if row.step.is_some_and(|s| s < rest_steps) {
            rest.push(world.len());
        }
        of_row.push(Some(world.len()));
        world.push(InWorld {
            step: k,
            tip: found.tip,
            frames: found.frames.len(),
            pixels: found.pixels,
        });
    }
    let (covariances, bead_noise_px) = covariance::of_rows(&world, &rest, calibration);
    let rows = rows
        .into_iter()
        .zip(of_row)
        .map(|(row, w)| match w {
            Some(w) => CamerasRow {
                row,
                used: world[w].tip.used.clone(),
                left_out: world[w].tip.left_out.clone(),
                chi2: world[w].tip.chi2,
                covariance_mm2: Some(covariances[w]),
            },
            None => CamerasRow {
                row,
                used: Vec::new(),
                left_out: Vec::new(),
                chi2: f64::NAN,
                covariance_mm2: None,
            },
        })
        .collect();
    (rows, bead_noise_px)
}

/// The rows' counts into `summary`.
fn summarise(summary: &mut CamerasSummary, rows: &[CamerasRow]) {
    summary.rows = rows.len();
    summary.good_rows = rows.iter().filter(|r| r.row.flags.is_empty()).count();
    for f in rows.iter().flat_map(|r| &r.row.flags) {
        *summary.flagged.entry(f).or_default() += 1;
    }
    for r in rows.iter().filter(|r| r.row.tip_mm.is_some()) {
        *summary.by_cameras.entry(r.used.len()).or_default() += 1;
        for &c in &r.used {
            summary.cameras[c].rows_used += 1;
        }
    }
}
