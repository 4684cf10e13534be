//! A pair's tip in 3-D: its candidates undistorted and triangulated by OpenCV, reprojected,
//! and the one consistent combination kept; the used pairs' epipolar residual.

use std::path::PathBuf;

use nalgebra::Vector3;
use rayon::prelude::*;

use super::distance_px;
use super::marker::{self, Markers};
use super::pairing::{self, Placement};
use super::{
    median_95_max, FrameRef, FrameResult, PairRecord, PairStatus, TriangulateError,
    TriangulateOptions,
};
use crate::session::frames::FrameRecord;
use crate::session::pressures::PressureLog;
use crate::stereo::{Side, StereoRig};

/// Each pair of `pairs` (indices into `records`) placed in the log's steps (`guard_s` before
/// each command, see [`pairing::place`]) and, when in one, its tip located.
#[allow(clippy::too_many_arguments)]
pub(super) fn locate_pairs(
    records: &[FrameRecord],
    paths: &[Option<PathBuf>],
    pairs: &[(usize, usize)],
    results: &[FrameResult],
    log: &PressureLog,
    rig: &StereoRig,
    options: &TriangulateOptions,
    guard_s: f64,
) -> Result<Vec<PairRecord>, TriangulateError> {
    let frame_ref = |i: usize| FrameRef {
        index: records[i].index,
        time_s: records[i].time_s,
        path: paths[i].clone(),
    };
    pairs
        .par_iter()
        .map(|&(l, r)| {
            let mut record = PairRecord {
                left: frame_ref(l),
                right: frame_ref(r),
                step: None,
                status: PairStatus::Skipped,
                candidates: 0,
                centres_px: None,
                point_left_mm: None,
                reprojected_px: None,
                reproj_px: None,
                fitted: [false; 2],
            };
            let (a, b) = (records[l].time_s, records[r].time_s);
            match pairing::place(log, a, b, options.settle_s, guard_s) {
                Placement::Step(k) => record.step = Some(k),
                Placement::OutsideLog => record.status = PairStatus::OutsideLog,
                Placement::Settling => record.status = PairStatus::Settling,
                Placement::Straddles => record.status = PairStatus::Straddles,
            }
            if record.step.is_some() {
                locate(rig, &results[l], &results[r], options, &mut record)?;
            }
            Ok(record)
        })
        .collect()
}

/// Triangulates a pair's candidates and keeps the one consistent combination, if there is one.
fn locate(
    rig: &StereoRig,
    left: &FrameResult,
    right: &FrameResult,
    options: &TriangulateOptions,
    record: &mut PairRecord,
) -> Result<(), TriangulateError> {
    let (l, r) = match (left, right) {
        (FrameResult::Skipped, _) | (_, FrameResult::Skipped) => {
            record.status = PairStatus::Skipped;
            return Ok(());
        }
        (FrameResult::Markers(l), FrameResult::Markers(r)) => (l, r),
        _ => {
            record.status = PairStatus::NoImage;
            return Ok(());
        }
    };
    record.status = match (l.blobs.is_empty(), r.blobs.is_empty()) {
        (true, true) => PairStatus::NoMarkerBoth,
        (true, false) => PairStatus::NoMarkerLeft,
        (false, true) => PairStatus::NoMarkerRight,
        (false, false) => PairStatus::Reprojection,
    };
    if l.blobs.is_empty() || r.blobs.is_empty() {
        return Ok(());
    }
    let centres = |m: &Markers| -> Vec<[f64; 2]> {
        m.blobs
            .iter()
            .take(marker::MAX_CANDIDATES)
            .map(|b| b.centre_px)
            .collect()
    };
    let (cl, cr) = (centres(l), centres(r));
    let combos = combinations(rig, &cl, &cr, options)?;
    let consistent: Vec<&Combination> = combos.iter().filter(|c| c.consistent).collect();
    record.candidates = combos.len();
    match consistent.as_slice() {
        [] => {}
        [c] => {
            record.status = if combos.len() > 1 {
                PairStatus::Resolved
            } else {
                PairStatus::Used
            };
            record.centres_px = Some([cl[c.left], cr[c.right]]);
            record.fitted = [l.blobs[c.left].fitted, r.blobs[c.right].fitted];
            record.point_left_mm = Some(c.point);
            record.reprojected_px = Some(c.reprojected_px);
            record.reproj_px = Some(c.reproj_px);
        }
        _ => record.status = PairStatus::Ambiguous,
    }
    if record.centres_px.is_none() && combos.len() == 1 {
        // Keep what was seen, for the figures.
        let c = &combos[0];
        record.centres_px = Some([cl[0], cr[0]]);
        record.reprojected_px = Some(c.reprojected_px);
        record.reproj_px = Some(c.reproj_px);
    }
    Ok(())
}

/// One left × right combination of candidate centres, triangulated.
pub(super) struct Combination {
    /// Indices into the left and right candidates.
    pub left: usize,
    pub right: usize,
    /// The point in the left camera (mm).
    pub point: Vector3<f64>,
    /// Its reprojections (left, right), px.
    pub reprojected_px: [[f64; 2]; 2],
    /// The larger of the two reprojection errors (px).
    pub reproj_px: f64,
    /// Both errors within `max_reproj_px`, the point in front of both cameras.
    pub consistent: bool,
}

/// Every combination of the candidate centres `cl` × `cr` (px), left-major: undistorted and
/// triangulated by OpenCV (after Hartley-Sturm correction when asked), reprojected, and judged.
pub(super) fn combinations(
    rig: &StereoRig,
    cl: &[[f64; 2]],
    cr: &[[f64; 2]],
    options: &TriangulateOptions,
) -> Result<Vec<Combination>, TriangulateError> {
    let (nl, nr) = (
        rig.normalized(Side::Left, cl)?,
        rig.normalized(Side::Right, cr)?,
    );
    let combos: Vec<(usize, usize)> = (0..cl.len())
        .flat_map(|i| (0..cr.len()).map(move |j| (i, j)))
        .collect();
    let (mut a, mut b): (Vec<[f64; 2]>, Vec<[f64; 2]>) =
        combos.iter().map(|&(i, j)| (nl[i], nr[j])).unzip();
    if options.correct_matches {
        (a, b) = rig.correct_matches(&a, &b)?;
    }
    let points = rig.triangulate_normalized(&a, &b)?;
    let (pl, pr) = (
        rig.project(Side::Left, &points)?,
        rig.project(Side::Right, &points)?,
    );
    Ok(combos
        .iter()
        .enumerate()
        .map(|(k, &(i, j))| {
            let p = points[k];
            let err = distance_px(pl[k], cl[i]).max(distance_px(pr[k], cr[j]));
            Combination {
                left: i,
                right: j,
                point: p,
                reprojected_px: [pl[k], pr[k]],
                reproj_px: err,
                consistent: err <= options.max_reproj_px
                    && p.z > 0.0
                    && rig.right_from_left.apply(&p.into()).z > 0.0,
            }
        })
        .collect())
}

/// Mean, standard deviation and 95th percentile of the size of the pairs' signed distance of
/// the right centre from the left centre's epipolar line (undistorted px).
pub(super) fn epipolar_residuals(
    rig: &StereoRig,
    pairs: &[&PairRecord],
) -> Result<[f64; 3], TriangulateError> {
    let centres: Vec<[[f64; 2]; 2]> = pairs.iter().filter_map(|p| p.centres_px).collect();
    if centres.is_empty() {
        return Ok([0.0; 3]);
    }
    let side = |k: usize| centres.iter().map(|c| c[k]).collect::<Vec<_>>();
    let (left, right) = (
        rig.undistorted(Side::Left, &side(0))?,
        rig.undistorted(Side::Right, &side(1))?,
    );
    let f = rig.fundamental();
    let d: Vec<f64> = left
        .iter()
        .zip(&right)
        .map(|(l, r)| {
            let line = f * Vector3::new(l[0], l[1], 1.0);
            (line[0] * r[0] + line[1] * r[1] + line[2]) / line[0].hypot(line[1])
        })
        .collect();
    let (mean, sd) = crate::stats::mean_sd(&d).unwrap_or_default();
    Ok([
        mean,
        sd,
        median_95_max(d.iter().map(|v| v.abs()).collect())[1],
    ])
}
