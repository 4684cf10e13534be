//! A pair's tip in 3-D: its candidates undistorted and triangulated by OpenCV, reprojected,
//! and the one consistent combination kept; the used pairs' epipolar residual.

use std::path::PathBuf;

use nalgebra::Vector3;
use rayon::prelude::*;

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
    let (nl, nr) = (
        rig.normalized(Side::Left, &cl)?,
        rig.normalized(Side::Right, &cr)?,
    );
    // Every combination, left-major.
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
    let right_from_left = &rig.right_from_left;
    let dist = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
    let consistent: Vec<(usize, f64)> = combos
        .iter()
        .enumerate()
        .map(|(k, &(i, j))| (k, dist(pl[k], cl[i]).max(dist(pr[k], cr[j]))))
        .filter(|&(k, err)| {
            let p = points[k];
            err <= options.max_reproj_px && p.z > 0.0 && right_from_left.apply(&p.into()).z > 0.0
        })
        .collect();
    record.candidates = combos.len();
    match consistent.as_slice() {
        [] => {}
        [(k, err)] => {
            let (i, j) = combos[*k];
            record.status = if combos.len() > 1 {
                PairStatus::Resolved
            } else {
                PairStatus::Used
            };
            record.centres_px = Some([cl[i], cr[j]]);
            record.fitted = [l.blobs[i].fitted, r.blobs[j].fitted];
            record.point_left_mm = Some(points[*k]);
            record.reprojected_px = Some([pl[*k], pr[*k]]);
            record.reproj_px = Some(*err);
        }
        _ => record.status = PairStatus::Ambiguous,
    }
    if record.centres_px.is_none() && combos.len() == 1 {
        // Keep what was seen, for the figures.
        record.centres_px = Some([cl[0], cr[0]]);
        record.reprojected_px = Some([pl[0], pr[0]]);
        record.reproj_px = Some(dist(pl[0], cl[0]).max(dist(pr[0], cr[0])));
    }
    Ok(())
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
