//! Gates: a calibration that cannot be right is refused, never written as if it were.
//!
//! Each gate is a plain physical check whose failure has one cause a user can act on:
//! - given intrinsics (`--intrinsics`) are checked against the images before the stereo fit:
//!   the principal point must lie inside the image, the boards must reproject with them about
//!   as well as with the camera's own fit from the same images, and the two files must not fit
//!   the other camera's images better (left and right swapped);
//! - the fitted rig: a reprojection RMS above [`MAX_RMS_PX`] (a sharp board calibrates below
//!   0.5 px; pairs whose images were not taken together give tens of pixels), boards that do
//!   not triangulate back to their printed squares (spacing or flatness), and a baseline more
//!   than [`MAX_BASELINE_DISTANCES`] times the boards' distance (two cameras that far apart
//!   cannot both see a board's face).
//!
//! `calibrate --force` writes a calibration that fails a gate, with the failures in its
//! `forced` key.

use super::checks::board_pose;
use super::{BoardCheck, BoardSpec, CalibError, KnownIntrinsics, View};
use crate::geometry::{CamFromBoard, Intrinsics};

/// Reprojection RMS above which a calibration is refused (px).
pub const MAX_RMS_PX: f64 = 2.0;
/// Triangulated boards' neighbour spacing: mean further than this from 1 square …
pub const MAX_SPACING_ERROR: f64 = 0.02;
/// … or spread (sd) above this share of a square.
pub const MAX_SPACING_SD: f64 = 0.05;
/// Triangulated boards' off-plane RMS above this share of a square.
pub const MAX_PLANARITY_SQUARES: f64 = 0.1;
/// Baseline above this many times the boards' median distance from the left camera.
pub const MAX_BASELINE_DISTANCES: f64 = 3.0;
/// Given intrinsics fit the images when the boards reproject within this × the camera's own
/// fit plus [`INTRINSICS_SLACK_PX`].
pub const INTRINSICS_RATIO: f64 = 2.0;
pub const INTRINSICS_SLACK_PX: f64 = 0.1;

/// `value` above `limit`, or not a number.
pub(super) fn exceeds(value: f64, limit: f64) -> bool {
    value.is_nan() || value > limit
}

/// RMS (px) of the boards reprojected by `camera`, each at its best pose (solvePnP).
pub(super) fn reprojection_rms(
    board: &BoardSpec,
    camera: &Intrinsics,
    views: &[View],
) -> Result<f64, CalibError> {
    let (mut sum, mut n) = (0.0, 0usize);
    for view in views {
        let pose: CamFromBoard = board_pose(board, camera, *view)?;
        for (p, c) in board.corners_mm(view.ids).iter().zip(view.px) {
            let Some(px) = camera.pixel(&pose.apply(p)) else {
                return Ok(f64::INFINITY); // a corner behind the camera
            };
            sum += (px[0] - f64::from(c[0])).powi(2) + (px[1] - f64::from(c[1])).powi(2);
            n += 1;
        }
    }
    Ok((sum / n.max(1) as f64).sqrt())
}

/// Whether given intrinsics that reproject a camera's boards at `given` px are not that
/// camera's, its own fit from the same images reprojecting them at `own` px.
pub(super) fn given_implausible(given: f64, own: f64) -> bool {
    given > INTRINSICS_RATIO * own + INTRINSICS_SLACK_PX
}

/// What is wrong with the given intrinsics, checked against each camera's views of the boards
/// (`views[0]` left, `views[1]` right) and `own_rms`, the RMS of each camera's own fit.
pub(super) fn known_intrinsics(
    board: &BoardSpec,
    size: [i32; 2],
    known: &[Option<KnownIntrinsics>; 2],
    views: [&[View]; 2],
    own_rms: [f64; 2],
) -> Result<Vec<String>, CalibError> {
    let mut problems = Vec::new();
    let sides = ["left", "right"];
    let mut rms = [None, None];
    for (c, k) in known.iter().enumerate() {
        let Some(k) = k else { continue };
        let (cx, cy) = (k.intrinsics.cx(), k.intrinsics.cy());
        if !(cx > 0.0 && cx < f64::from(size[0]) && cy > 0.0 && cy < f64::from(size[1])) {
            problems.push(format!(
                "{}: the principal point ({cx:.1}, {cy:.1}) lies outside the {}×{} image; give this camera's own intrinsics file",
                k.path.display(),
                size[0],
                size[1]
            ));
            continue;
        }
        rms[c] = Some(reprojection_rms(board, &k.intrinsics, views[c])?);
    }
    if let [Some(l), Some(r)] = known {
        // Each file on the other camera's images: better there means swapped.
        let crossed = [
            reprojection_rms(board, &r.intrinsics, views[0])?,
            reprojection_rms(board, &l.intrinsics, views[1])?,
        ];
        if let [Some(a), Some(b)] = rms {
            if crossed[0] + crossed[1] < 0.5 * (a + b) {
                problems.push(format!(
                    "--intrinsics {},{} look swapped: the boards reproject at {:.3}/{:.3} px with them as given and {:.3}/{:.3} px the other way round; give the left camera's file first",
                    l.path.display(),
                    r.path.display(),
                    a,
                    b,
                    crossed[0],
                    crossed[1]
                ));
                return Ok(problems);
            }
        }
    }
    for (c, k) in known.iter().enumerate() {
        let (Some(k), Some(given)) = (k, rms[c]) else {
            continue;
        };
        let own = own_rms[c];
        if given_implausible(given, own) {
            problems.push(format!(
                "{}: the {} camera's boards reproject at {given:.3} px with these intrinsics and at {own:.3} px with the camera's own fit from the same images (focal length {:.1} px given); they are not this camera's at this zoom and focus: calibrate it again, or leave it to be solved (`-`)",
                k.path.display(),
                sides[c],
                k.intrinsics.fx()
            ));
        }
    }
    Ok(problems)
}

/// What is wrong with a fitted rig: its RMS (px), the boards triangulated back, its baseline
/// and the boards' median distance from the left camera (mm).
pub(super) fn fitted(
    board: &BoardSpec,
    rms_px: f64,
    check: &BoardCheck,
    baseline_mm: f64,
    board_distance_mm: f64,
) -> Vec<String> {
    let mut problems = Vec::new();
    if exceeds(rms_px, MAX_RMS_PX) {
        problems.push(format!(
            "reprojection RMS {rms_px:.2} px (a sharp board calibrates below 0.5 px): a pair's two images were not taken together while the board moved, or the board is not the one given; hold the board still for each pair (`capture --calib` waits for it) and check --board"
        ));
    }
    let spacing = check.neighbour_mean_squares;
    let flat = MAX_PLANARITY_SQUARES * board.square_mm;
    if exceeds((spacing - 1.0).abs(), MAX_SPACING_ERROR)
        || exceeds(check.neighbour_sd_squares, MAX_SPACING_SD)
        || exceeds(check.planarity_rms_mm, flat)
    {
        problems.push(format!(
            "the boards triangulate to {spacing:.3} ± {:.3} squares apart and {:.2} mm off their plane (a right rig gives 1 square and well below {flat:.2} mm): pairs not simultaneous, wrong intrinsics, or a camera moved between pairs",
            check.neighbour_sd_squares, check.planarity_rms_mm
        ));
    }
    if exceeds(baseline_mm, MAX_BASELINE_DISTANCES * board_distance_mm) {
        problems.push(format!(
            "a baseline of {baseline_mm:.0} mm with the boards {board_distance_mm:.0} mm away: two cameras that far apart cannot both see a board's face; the pairs do not show the board at one moment"
        ));
    }
    problems
}
