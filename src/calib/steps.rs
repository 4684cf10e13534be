//! The calibration's steps after the images are read ([`super::calibrate`] lists them): the
//! board in every image, the usable pairs, given intrinsics checked, the hand frame's axes,
//! and how sure the calibration is.

use std::path::Path;

use nalgebra::Rotation3;
use rayon::prelude::*;

use super::checks::{board_pose, hand_axes};
use super::detect::{self, check_sizes, Detector, Seen};
use super::fit::{self, bootstrap, single_camera};
use super::pairs::{self, ImagePair};
use super::{
    gates, guidance, uncertainty, validate, BoardSpec, Bootstrap, CalibError, CalibOptions, Found,
    PairCorners, PairReport, View, CLASSIC_SAMPLE,
};
use crate::geometry::CamFromBoard;

/// Step 2: the board in every image, by the detector that finds it in the most pairs; an
/// error naming the board and what was seen instead when it is in none.
pub(super) fn detect_boards(
    dir: &Path,
    grays: &[opencv::core::Mat],
    board: &BoardSpec,
    listing: &pairs::PairListing,
    options: &CalibOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(Detector, Vec<Found>), CalibError> {
    let done = std::sync::atomic::AtomicUsize::new(0);
    let detect_all = |detector: Detector| detect::find_all(grays, board, detector, &done, progress);
    let complete = |found: &[Found]| {
        found[..2 * listing.pairs.len()]
            .chunks(2)
            .filter(|p| p[0].1.is_some() && p[1].1.is_some())
            .count()
    };
    let mut detector = board.first_detector();
    let mut found = detect_all(detector)?;
    // A fallback (the classic chessboard detector) is slow to fail (about a second a 720p
    // image): when the first finds no board at all (a wrong --board, most often), it is first
    // tried on a few images spread over the set, and on all of them only if it finds the board
    // there.
    let fallback = board.pattern.kind().detectors().get(1).copied();
    let worth = |fallback: Detector| -> Result<bool, CalibError> {
        if found.iter().any(|f| f.1.is_some()) {
            return Ok(true);
        }
        let step = grays.len().div_ceil(CLASSIC_SAMPLE).max(1);
        let sample: Vec<&opencv::core::Mat> = grays.iter().step_by(step).collect();
        let seen = sample
            .par_iter()
            .map(|gray| detect::find_board(gray, board, fallback))
            .collect::<opencv::Result<Vec<_>>>()?;
        Ok(seen.iter().any(Option::is_some))
    };
    if let Some(fallback) = fallback {
        if complete(&found) < options.min_pairs && worth(fallback)? {
            let other = detect_all(fallback)?;
            if complete(&other) > complete(&found) {
                detector = fallback;
                found = other;
            }
        }
    }
    if found.iter().all(|f| f.1.is_none()) {
        return Err(CalibError::BoardNotFound {
            dir: dir.to_path_buf(),
            cols: board.cols,
            rows: board.rows,
            hint: board.pattern.kind().not_found_hint(board, grays),
        });
    }
    Ok((detector, found))
}

/// The images' one size, which given intrinsics must have been calibrated at.
pub(super) fn image_size(
    all: &[&ImagePair],
    found: &[Found],
    options: &CalibOptions,
) -> Result<[i32; 2], CalibError> {
    let size = check_sizes(all, found)?;
    for known in options.intrinsics.iter().flatten() {
        if known.image_size != size {
            return Err(CalibError::IntrinsicsSize {
                path: known.path.clone(),
                fw: known.image_size[0],
                fh: known.image_size[1],
                w: size[0],
                h: size[1],
            });
        }
    }
    Ok(size)
}

/// Step 3: a report per pair, and the corners of those with the board in both images.
pub(super) fn usable_pairs(
    board: &BoardSpec,
    listing: &pairs::PairListing,
    found: &[Found],
) -> (Vec<PairReport>, Vec<PairCorners>) {
    let mut reports = Vec::new();
    let mut usable: Vec<PairCorners> = Vec::new();
    for (k, pair) in listing.pairs.iter().enumerate() {
        let mut report = PairReport {
            name: pair.name.clone(),
            left: pair.left.clone(),
            right: pair.right.clone(),
            rms_px: None,
            rejected: None,
            note: None,
        };
        match (&found[2 * k].1, &found[2 * k + 1].1) {
            (Some(l), Some(r)) => match pairs::match_corners(board, l, r) {
                Ok((corners, note)) => {
                    report.note = note;
                    usable.push(PairCorners {
                        report: reports.len(),
                        ..corners
                    });
                }
                Err(why) => report.rejected = Some(why),
            },
            (None, None) => report.rejected = Some("board not found in either image".into()),
            (None, _) => report.rejected = Some("board not found in the left image".into()),
            (_, None) => report.rejected = Some("board not found in the right image".into()),
        }
        reports.push(report);
    }
    (reports, usable)
}

/// Step 4: what is implausible about given intrinsics under these images (nothing when none
/// are given).
pub(super) fn given_intrinsics(
    board: &BoardSpec,
    size: [i32; 2],
    usable: &[PairCorners],
    options: &CalibOptions,
) -> Result<Vec<String>, CalibError> {
    if options.intrinsics.iter().all(Option::is_none) {
        return Ok(Vec::new());
    }
    let side = |c: usize| -> Vec<View> { usable.iter().map(|u| u.view(c)).collect() };
    let (left, right) = (side(0), side(1));
    let own =
        |views: &[View]| -> Result<f64, CalibError> { Ok(single_camera(board, size, views)?.3) };
    gates::known_intrinsics(
        board,
        size,
        &options.intrinsics,
        [&left, &right],
        [own(&left)?, own(&right)?],
    )
}

/// Step 6: the hand frame's axes from the reference pair, and where they came from.
pub(super) fn reference_axes(
    board: &BoardSpec,
    rig: &fit::StereoFit,
    reference: Option<(&ImagePair, &Option<Seen>)>,
) -> Result<(Option<Rotation3<f64>>, String), CalibError> {
    Ok(match reference {
        Some((pair, Some(corners))) => (
            Some(hand_axes(board, rig, corners.into())?),
            format!(
                "from the reference pair {}: board x = hand x, board y = hand -z, board z = hand +y",
                pair.left.display()
            ),
        ),
        Some((pair, None)) => (
            None,
            format!("the board was not found in {}", pair.left.display()),
        ),
        None => (None, "no reference pair (left_ref/right_ref)".into()),
    })
}

/// Step 7's findings.
pub(super) struct HowSure {
    pub uncertainty: Option<uncertainty::Uncertainty>,
    pub validation: Option<validate::Validation>,
    pub bootstrap: Option<Bootstrap>,
    pub guidance: guidance::Guidance,
    /// The median distance of the boards' centres from the left camera (mm).
    pub median_distance_mm: f64,
}

/// Step 7: the calibration's standard deviations at the finger's distance (the reference
/// board's centre, the finger's base; else the median of the boards' centres), checked against
/// two halves of the pairs (`validate`) and by the bootstrap when asked, and what to capture
/// next.
pub(super) fn how_sure(
    board: &BoardSpec,
    size: [i32; 2],
    rig: &fit::StereoFit,
    usable: &[PairCorners],
    reference: Option<(&ImagePair, &Option<Seen>)>,
    options: &CalibOptions,
) -> Result<HowSure, CalibError> {
    let poses = uncertainty::board_poses(board, &rig.cams, usable)?;
    let centre = |pose: &CamFromBoard| pose.apply(&board.centre()).coords;
    let at = match reference {
        Some((_, Some(corners))) => (
            centre(&board_pose(board, &rig.cams.left, corners.into())?),
            "the reference board's centre".to_string(),
        ),
        _ => (
            crate::stats::median_point(&poses.iter().map(centre).collect::<Vec<_>>()),
            "the median of the boards' centres (no reference pair)".to_string(),
        ),
    };
    // Known intrinsics fix both cameras' (see [`stereo`]).
    let solved = options.intrinsics.iter().all(Option::is_none);
    let base = at.0;
    let uncertainty =
        uncertainty::estimate(board, &rig.cams, [solved, solved], usable, &poses, at)?;
    let validation = match (&uncertainty, options.validate) {
        (Some(u), true) => validate::validate(
            board,
            size,
            usable,
            &options.intrinsics,
            &validate::Full {
                rig: &rig.cams,
                uncertainty: u,
                poses: &poses,
                base,
            },
            options.seed,
        )?,
        _ => None,
    };
    let bootstrap = (options.bootstrap > 0)
        .then(|| bootstrap(board, size, usable, options, &rig.cams))
        .transpose()?;
    let guidance = guidance::advise(&rig.cams, usable, &poses, uncertainty.as_ref());
    let mut distances: Vec<f64> = poses.iter().map(|p| centre(p).norm()).collect();
    Ok(HowSure {
        uncertainty,
        validation,
        bootstrap,
        guidance,
        median_distance_mm: crate::stats::median(&mut distances).expect("pairs"),
    })
}
