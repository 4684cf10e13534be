//! The demo's checks against the virtual plant's truth: the calibration's parameters, each
//! triangulated tip, the inverse's pressures run through the plant.

use std::path::Path;

use nalgebra::Vector3;

use super::demo_summary::{CalibrationCheck, CameraCheck, CamerasCheck, InverseCheck, TipCheck};
use super::PipelineError;
use crate::calib::file::CalibrationFile;
use crate::calib::StereoCalibration;
use crate::data::{self, names};
use crate::model::interval::RowRadii;
use crate::model::inverse::{self, InverseOptions, PlannedTarget};
use crate::model::Differentiable;
use crate::synth::plant::Plant;
use crate::triangulate::Triangulation;

pub(super) fn feedforward(
    model: &dyn Differentiable,
    plant: &Plant,
    sources: &[Vec<f64>],
) -> Result<Vec<PlannedTarget>, PipelineError> {
    let options = InverseOptions::within_training_range(model, |_| Some((0.0, 250.0)));
    Ok(inverse::feedforward_check(
        model,
        |p| plant.tip([p[0], p[1], p[2]]).ok().map(|t| t.to_vec()),
        sources,
        &options,
    )?)
}

/// `radii`: the model's 90 % interval radius around each planned tip, whose coverage of the
/// plant's tips around the model's is measured.
pub(super) fn inverse_stats(
    model: &str,
    rows: &[PlannedTarget],
    radii: Option<RowRadii>,
) -> InverseCheck {
    let mut e: Vec<f64> = rows.iter().map(|r| r.plant_error).collect();
    let [median_mm, p90_mm, max_mm] =
        crate::stats::quantiles(&mut e, [0.5, 0.9, 1.0]).expect("targets were planned");
    InverseCheck {
        model: model.to_string(),
        targets: rows.len(),
        reached_by_model: rows.iter().filter(|r| r.solution.reached).count(),
        mean_mm: e.iter().sum::<f64>() / e.len() as f64,
        median_mm,
        p90_mm,
        max_mm,
        interval: radii.map(|r| {
            let within = rows
                .iter()
                .zip(&r.radii)
                .filter(|(t, radius)| {
                    let d2: f64 = t
                        .plant
                        .iter()
                        .zip(&t.solution.achieved)
                        .map(|(a, b)| (a - b).powi(2))
                        .sum();
                    d2.sqrt() <= **radius
                })
                .count();
            (r.radius, within as f64 / rows.len() as f64)
        }),
    }
}

pub(super) fn check_calibration(
    cal: &StereoCalibration,
    truth: &CalibrationFile,
) -> CalibrationCheck {
    let t = &truth.rig;
    let mut intrinsics = 0.0f64;
    for (got, want) in [(&cal.rig.left.k, &t.left.k), (&cal.rig.right.k, &t.right.k)] {
        for i in [0, 4, 2, 5] {
            intrinsics = intrinsics.max(100.0 * ((got[i] - want[i]) / want[i]).abs());
        }
    }
    let (got, want) = (&cal.rig.right_from_left, &t.right_from_left);
    let (gt, tt) = (got.translation, want.translation);
    CalibrationCheck {
        pairs_used: cal.used().count(),
        rms_px: cal.rms_px,
        epipolar_px: cal.epipolar_px,
        intrinsics_error_pct: intrinsics,
        baseline_error_pct: 100.0 * (gt.norm() - tt.norm()).abs() / tt.norm(),
        rotation_error_deg: (got.rotation.inverse() * want.rotation)
            .angle()
            .to_degrees(),
        hand_axes_error_deg: cal
            .hand_axes
            .zip(truth.r_hand)
            .map(|(g, w)| (g.inverse() * w).angle().to_degrees()),
        baseline_sd_pct: cal
            .uncertainty
            .as_ref()
            .map(|u| 100.0 * u.parameters.baseline_mm / gt.norm()),
        tip_sd: cal.uncertainty.as_ref().map(|u| u.tip),
        advice: cal.guidance.advice.clone(),
        validation: cal.validation.clone(),
    }
}

/// RMS and largest Euclidean error of the rows against `truth/tips.csv`, per phase and overall.
pub(super) fn check_tips(
    tri: &Triangulation,
    truth: &Path,
) -> Result<Vec<TipCheck>, PipelineError> {
    let column = |name: &str| tri.extra_columns.iter().position(|c| c == name);
    let (Some(step_col), Some(phase_col)) = (column("step"), column("phase")) else {
        return Err(PipelineError::Check(
            "the synthetic log has step and phase columns".into(),
        ));
    };
    let rows = tri.rows.iter().filter(|r| r.flags.is_empty()).map(|row| {
        (
            row.extra[step_col].clone(),
            row.extra[phase_col].clone(),
            row.tip_mm,
        )
    });
    tip_checks(rows, truth)
}

/// [`check_tips`] of more cameras' tips `found` in the steps of `log`.
pub(super) fn check_cameras_tips(
    found: &crate::triangulate::cameras::Found,
    log: &crate::session::pressures::PressureLog,
    truth: &Path,
) -> Result<Vec<TipCheck>, PipelineError> {
    let column = |name: &str| log.extra_columns.iter().position(|c| c == name);
    let (Some(step_col), Some(phase_col)) = (column("step"), column("phase")) else {
        return Err(PipelineError::Check(
            "the synthetic log has step and phase columns".into(),
        ));
    };
    let rows = found.tips.iter().map(|t| {
        let extra = &log.steps[t.step].extra;
        (
            extra[step_col].clone(),
            extra[phase_col].clone(),
            t.tip_mm.into(),
        )
    });
    tip_checks(rows, truth)
}

/// The virtual finger's tip at each step of `truth/tips.csv`.
fn true_tips(
    truth: &Path,
) -> Result<std::collections::HashMap<usize, Vector3<f64>>, PipelineError> {
    let tips = data::read_columns(truth, &names(&["step", "x_mm", "y_mm", "z_mm"]))?;
    Ok(tips
        .iter_rows()
        .map(|r| (r[0] as usize, Vector3::new(r[1], r[2], r[3])))
        .collect())
}

fn not_in(step: &str, truth: &Path) -> PipelineError {
    PipelineError::Check(format!("step {step} not in {}", truth.display()))
}

/// The tips' errors against `truth` (`truth/tips.csv`), per phase in the order they first
/// appear, then `all`.
fn tip_checks(
    rows: impl Iterator<Item = (String, String, [f64; 3])>,
    truth: &Path,
) -> Result<Vec<TipCheck>, PipelineError> {
    let tips = true_tips(truth)?;
    let mut by_phase: Vec<(String, Vec<[f64; 3]>)> = Vec::new();
    for (step, phase, tip) in rows {
        let t = step
            .parse::<usize>()
            .ok()
            .and_then(|k| tips.get(&k))
            .ok_or_else(|| not_in(&step, truth))?;
        let e: [f64; 3] = std::array::from_fn(|k| tip[k] - t[k]);
        match by_phase.iter_mut().find(|(p, _)| *p == phase) {
            Some((_, v)) => v.push(e),
            None => by_phase.push((phase, vec![e])),
        }
    }
    let all: Vec<[f64; 3]> = by_phase.iter().flat_map(|(_, v)| v.clone()).collect();
    by_phase.push(("all".into(), all));
    Ok(by_phase
        .into_iter()
        .map(|(phase, errors)| {
            let n = errors.len() as f64;
            let size: Vec<f64> = errors.iter().map(|e| Vector3::from(*e).norm()).collect();
            TipCheck {
                rows: errors.len(),
                rms_mm: (size.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
                max_mm: size.iter().copied().fold(0.0, f64::max),
                mean_mm: std::array::from_fn(|k| errors.iter().map(|e| e[k]).sum::<f64>() / n),
                phase,
            }
        })
        .collect())
}

/// More cameras' calibration `cal` against the rig `truth` they were rendered with
/// (`truth/cameras.toml`), and their tips `found` against `tips` (`truth/tips.csv`).
pub(super) fn check_cameras(
    cal: &crate::calib::cameras::GraphCalibration,
    truth: &Path,
    found: &crate::triangulate::cameras::Found,
    tips: &Path,
) -> Result<CamerasCheck, PipelineError> {
    let (rig, hand) = crate::calib::file::read_cameras_toml(truth)?;
    let cameras = cal
        .cameras
        .iter()
        .zip(&rig)
        .map(|(got, want)| {
            let pose = &got.pose.cam_from_world;
            CameraCheck {
                name: got.name.clone(),
                views: got.views,
                focal_error_pct: 100.0 * (got.pose.intrinsics.fx() - want.intrinsics.fx())
                    / want.intrinsics.fx(),
                rotation_error_deg: (pose.rotation * want.pose.rotation.inverse())
                    .angle()
                    .to_degrees(),
                centre_error_mm: (pose.centre() - want.pose.centre()).norm(),
                rotation_sd_deg: got.pose.rotation_sd_deg,
                position_sd_mm: got.pose.position_sd_mm,
            }
        })
        .collect();
    let true_tip = true_tips(tips)?;
    // χ² of 3 degrees of freedom at 0.95.
    let mut inside = 0;
    for t in &found.tips {
        let truth = true_tip
            .get(&t.step)
            .ok_or_else(|| not_in(&t.step.to_string(), tips))?;
        let e = t.tip_mm - truth;
        inside += usize::from(
            t.covariance_mm2
                .try_inverse()
                .is_some_and(|inverse| e.dot(&(inverse * e)) <= 7.815),
        );
    }
    let mut by_cameras: Vec<(usize, usize)> = Vec::new();
    for t in &found.tips {
        match by_cameras.iter_mut().find(|(n, _)| *n == t.used.len()) {
            Some((_, k)) => *k += 1,
            None => by_cameras.push((t.used.len(), 1)),
        }
    }
    by_cameras.sort_by_key(|&(n, _)| std::cmp::Reverse(n));
    let median_sd_mm = std::array::from_fn(|i| {
        let mut sd: Vec<f64> = found
            .tips
            .iter()
            .map(|t| t.covariance_mm2[(i, i)].max(0.0).sqrt())
            .collect();
        crate::stats::median(&mut sd).unwrap_or(f64::NAN)
    });
    Ok(CamerasCheck {
        cameras,
        rms_px: cal.rms_px,
        hand_axes_error_deg: cal
            .hand_axes
            .zip(hand)
            .map(|(g, w)| (g.inverse() * w).angle().to_degrees()),
        steps_with_tip: found.tips.len(),
        by_cameras,
        steps_with_left_out: found.tips.iter().filter(|t| !t.left_out.is_empty()).count(),
        ellipsoid_coverage: inside as f64 / found.tips.len().max(1) as f64,
        median_sd_mm,
        bead_noise_px: found.bead_noise_px,
    })
}
