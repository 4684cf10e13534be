//! Each row's covariance (module docs of [`super`], step 5): the beads' error in the tip and
//! in the origin, scaled up to what the session shows, and the calibration's.

use nalgebra::{Matrix3, Matrix3x4, Vector3};
use rayon::prelude::*;

use super::{view_of, Calibration, InWorld, BEAD_NOISE_PX, MIN_DOF};
use crate::calib::graph::CameraCovariance;
use crate::geometry::{CamFromWorld, Intrinsics};
use crate::triangulate::nview::{self, View};

/// Each row's covariance in the hand frame (mm²), the tips of `world` less the origin (the
/// median of the `rest` ones'), and the beads' error the steps' residuals show (px), when they
/// have [`MIN_DOF`] degrees of freedom or more.
pub(super) fn of_rows(
    world: &[InWorld],
    rest: &[usize],
    calibration: &Calibration,
) -> (Vec<Matrix3<f64>>, Option<f64>) {
    // The χ² of the steps' residuals over their degrees of freedom says how far
    // [`BEAD_NOISE_PX`] was from the beads' error. Never less: a bead's centre also errs the
    // same way in every camera (its shading), which no residual shows.
    let (chi2, dof) = world
        .iter()
        .fold((0.0, 0), |(c, d), w| (c + w.tip.chi2, d + w.tip.dof));
    let shown = (dof >= MIN_DOF).then(|| chi2 / dof as f64);
    let unit = shown.map_or(1.0, |unit| unit.max(1.0));
    let r: Matrix3<f64> = *calibration.hand.matrix();
    let origin: Matrix3<f64> = rest
        .iter()
        .map(|&i| world[i].tip.covariance)
        .sum::<Matrix3<f64>>()
        / (rest.len() * rest.len()) as f64;
    let from_calibration = match &calibration.covariance {
        Some(covariance) => {
            let pixels: Vec<&[(usize, [f64; 2])]> = world.iter().map(|w| &w.pixels[..]).collect();
            calibration_term(&pixels, rest, calibration, covariance)
        }
        None => vec![Matrix3::zeros(); world.len()],
    };
    let rows = world
        .iter()
        .zip(from_calibration)
        .map(|(w, calibrated)| r * (w.tip.covariance + origin) * r.transpose() * unit + calibrated)
        .collect();
    (rows, shown.map(|unit| BEAD_NOISE_PX * unit.sqrt()))
}

/// Each row's covariance from the calibration's `covariance` (module docs, step 5), in the
/// hand frame: the rows of `pixels` (each tip's views used) refitted, less the origin (the
/// median of the `rest` rows), with each camera unknown moved either way.
fn calibration_term(
    pixels: &[&[(usize, [f64; 2])]],
    rest: &[usize],
    calibration: &Calibration,
    covariance: &CameraCovariance,
) -> Vec<Matrix3<f64>> {
    use crate::calib::uncertainty::{intrinsic_mut, intrinsic_step, stepped, POSE_STEP};
    let (cameras, per) = (&calibration.cameras, covariance.per_camera);
    // The rows with the cameras as given.
    let rows = |intrinsics: &[Intrinsics], poses: &[CamFromWorld]| -> Vec<Vector3<f64>> {
        let projections: Vec<Matrix3x4<f64>> = intrinsics
            .iter()
            .zip(poses)
            .map(|(k, pose)| crate::geometry::projection(k, pose))
            .collect();
        let points: Vec<Vector3<f64>> = pixels
            .iter()
            .map(|seen| {
                let views: Vec<View> = seen
                    .iter()
                    .map(|&(c, px)| view_of(&intrinsics[c], &projections[c], px))
                    .collect();
                nview::through(&views).unwrap_or_else(|| Vector3::repeat(f64::NAN))
            })
            .collect();
        let at_rest: Vec<Vector3<f64>> = rest.iter().map(|&i| points[i]).collect();
        let origin = crate::stats::median_point(&at_rest);
        points
            .iter()
            .map(|p| calibration.hand * (p - origin))
            .collect()
    };
    let intrinsics: Vec<Intrinsics> = cameras.iter().map(|c| c.intrinsics.clone()).collect();
    let poses: Vec<CamFromWorld> = cameras.iter().map(|c| c.pose).collect();
    // Each row's derivative along each unknown.
    let derivatives: Vec<Vec<Vector3<f64>>> = (0..covariance.matrix.len())
        .into_par_iter()
        .map(|j| {
            let at = |sign: f64| {
                let (mut intrinsics, mut poses) = (intrinsics.clone(), poses.clone());
                let h = if j < per * cameras.len() {
                    let h = intrinsic_step(j % per);
                    *intrinsic_mut(&mut intrinsics[j / per], j % per) += sign * h;
                    h
                } else {
                    let (c, q) = (
                        1 + (j - per * cameras.len()) / 6,
                        (j - per * cameras.len()) % 6,
                    );
                    let mut delta = [0.0; 6];
                    delta[q] = sign * POSE_STEP[q];
                    poses[c] = stepped(&poses[c], &delta);
                    POSE_STEP[q]
                };
                (rows(&intrinsics, &poses), h)
            };
            let ((plus, h), (minus, _)) = (at(1.0), at(-1.0));
            plus.iter()
                .zip(&minus)
                .map(|(p, m)| {
                    let d = (p - m) / (2.0 * h);
                    if d.iter().all(|v| v.is_finite()) {
                        d
                    } else {
                        Vector3::zeros()
                    }
                })
                .collect()
        })
        .collect();
    let c = &covariance.matrix;
    (0..pixels.len())
        .map(|s| {
            let mut sum = Matrix3::zeros();
            for (j, dj) in derivatives.iter().enumerate() {
                let weighted: Vector3<f64> = derivatives
                    .iter()
                    .zip(&c[j])
                    .map(|(dl, &cjl)| dl[s] * cjl)
                    .sum();
                sum += dj[s] * weighted.transpose();
            }
            (sum + sum.transpose()) / 2.0
        })
        .collect()
}
