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
pub(in crate::triangulate) fn of_rows(
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

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector, Point3};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    use super::*;
    use crate::calib::file::ReadCamera;
    use crate::calib::uncertainty::{intrinsic_mut, stepped};
    use crate::geometry::{relative, CamFromWorld};

    /// The calibration's share of each row, carried by central differences, against the rows'
    /// spread when the cameras are drawn from that covariance and the rows triangulated anew
    /// (Monte Carlo): the same within the draws' own error, and nothing at the rest tip.
    #[test]
    fn the_calibrations_share_matches_cameras_drawn_from_its_covariance() {
        let rig = crate::synth::camera::RigConfig {
            cameras: 3,
            ..Default::default()
        }
        .build(1);
        let first = rig.left().pose;
        let cameras: Vec<ReadCamera> = rig
            .cameras
            .iter()
            .enumerate()
            .map(|(i, cam)| {
                let pose = relative(&first, &cam.pose);
                ReadCamera {
                    name: format!("cam{}", i + 1),
                    size: [cam.width as i32, cam.height as i32],
                    intrinsics: cam.intrinsics.clone(),
                    pose: CamFromWorld::new(pose.rotation, pose.translation),
                }
            })
            .collect();
        // The rest tip and four tips around it (hand frame = the synth's world), in the world
        // of the cameras (the first camera's frame), seen without noise.
        let tips = [
            [0.0, 0.0, 0.0],
            [10.0, 0.0, 2.0],
            [-10.0, 5.0, 1.0],
            [0.0, -10.0, 2.0],
            [6.0, 8.0, 1.5],
        ];
        let world: Vec<Point3<f64>> = tips
            .iter()
            .map(|t| first.apply(&Point3::from(*t)))
            .collect();
        let pixels: Vec<Vec<(usize, [f64; 2])>> = world
            .iter()
            .map(|p| {
                (0..cameras.len())
                    .map(|c| {
                        let seen = cameras[c].pose.apply(p);
                        (c, cameras[c].intrinsics.pixel(&seen).unwrap())
                    })
                    .collect()
            })
            .collect();
        // A covariance of calibration-like size, correlated: 0.3 px on fx … cy, 1e-3 on the
        // distortion, 3e-4 rad and 0.05 mm on the poses.
        let per = 9;
        let k = per * 3 + 6 * 2;
        let scale: Vec<f64> = (0..k)
            .map(|j| match j {
                j if j < per * 3 && j % per < 4 => 0.3,
                j if j < per * 3 => 1e-3,
                j if (j - per * 3) % 6 < 3 => 3e-4,
                _ => 0.05,
            })
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let a = DMatrix::<f64>::from_fn(k, k, |_, _| StandardNormal.sample(&mut rng));
        let shape = DMatrix::<f64>::identity(k, k) * 0.5 + &a * a.transpose() * (0.5 / k as f64);
        let matrix = DMatrix::<f64>::from_fn(k, k, |i, j| scale[i] * shape[(i, j)] * scale[j]);
        let covariance = CameraCovariance {
            per_camera: per,
            matrix: (0..k)
                .map(|i| matrix.row(i).iter().copied().collect())
                .collect(),
        };
        let calibration = Calibration {
            cameras: cameras.clone(),
            hand: first.rotation.inverse(),
            covariance: Some(covariance.clone()),
        };
        let borrowed: Vec<&[(usize, [f64; 2])]> = pixels.iter().map(|p| &p[..]).collect();
        let carried = calibration_term(&borrowed, &[0], &calibration, &covariance);
        // The cameras drawn from the covariance; each draw's rows from the same pixels.
        let chol = matrix.clone().cholesky().unwrap().l();
        let draws = 600;
        let mut spread = vec![Matrix3::<f64>::zeros(); tips.len()];
        for _ in 0..draws {
            let z = DVector::<f64>::from_fn(k, |_, _| StandardNormal.sample(&mut rng));
            let delta = &chol * z;
            let mut moved = cameras.clone();
            for (c, camera) in moved.iter_mut().enumerate() {
                for i in 0..per {
                    *intrinsic_mut(&mut camera.intrinsics, i) += delta[per * c + i];
                }
                if c > 0 {
                    let at = per * 3 + 6 * (c - 1);
                    let step: Vec<f64> = (0..6).map(|q| delta[at + q]).collect();
                    camera.pose = stepped(&camera.pose, &step);
                }
            }
            let points: Vec<Vector3<f64>> = pixels
                .iter()
                .map(|seen| {
                    let views: Vec<View> = seen
                        .iter()
                        .map(|&(c, px)| {
                            let projection =
                                crate::geometry::projection(&moved[c].intrinsics, &moved[c].pose);
                            view_of(&moved[c].intrinsics, &projection, px)
                        })
                        .collect();
                    nview::through(&views).unwrap()
                })
                .collect();
            for (s, p) in points.iter().enumerate() {
                let e = calibration.hand * (p - points[0]) - Vector3::from(tips[s]);
                spread[s] += e * e.transpose() / draws as f64;
            }
        }
        for s in 1..tips.len() {
            for i in 0..3 {
                let (drawn, said) = (spread[s][(i, i)].sqrt(), carried[s][(i, i)].sqrt());
                assert!(
                    (said / drawn - 1.0).abs() < 0.15 && said > 1e-4,
                    "row {s}, axis {i}: carried {said:.6} mm, drawn {drawn:.6} mm"
                );
            }
        }
        assert!(carried[0].norm() < 1e-12 && spread[0].norm() < 1e-12);
    }
}
