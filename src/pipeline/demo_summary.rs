//! What the demo found, each stage against the virtual capture's truth: the contents of
//! `summary.json`, which [`super::demo`] fills and `demo_report` shows.

use serde::Serialize;

use crate::model::Errors;
use crate::provenance::Provenance;
use crate::report::IntervalReport;
use crate::select::family::{Family, FamilyDecision};
use crate::synth::capture::Realism;

/// Calibration against the truth.
#[derive(Clone, Serialize)]
pub struct CalibrationCheck {
    pub pairs_used: usize,
    pub rms_px: f64,
    pub epipolar_px: f64,
    /// Largest relative error of fx, fy, cx, cy over both cameras (%).
    pub intrinsics_error_pct: f64,
    pub baseline_error_pct: f64,
    pub rotation_error_deg: f64,
    pub hand_axes_error_deg: Option<f64>,
    /// The calibration's own standard deviation of the baseline (%), and of the tip.
    pub baseline_sd_pct: Option<f64>,
    pub tip_sd: Option<crate::calib::uncertainty::PointSd>,
    /// What the calibration advises capturing next.
    pub advice: Vec<String>,
    /// Its stated uncertainty checked against two halves of the pairs.
    pub validation: Option<crate::calib::validate::Validation>,
}

/// More than two cameras' calibration and tips against the truth.
#[derive(Clone, Serialize)]
pub struct CamerasCheck {
    pub cameras: Vec<CameraCheck>,
    /// Every corner's reprojection RMS in the joint refinement (px).
    pub rms_px: f64,
    pub hand_axes_error_deg: Option<f64>,
    /// Steps with a tip, and how many of them by each number of cameras (n, steps).
    pub steps_with_tip: usize,
    pub by_cameras: Vec<(usize, usize)>,
    /// Steps with a camera left out by the gate.
    pub steps_with_left_out: usize,
    /// The share of rows whose true tip lies inside the row's 95 % ellipsoid, and the rows'
    /// median standard deviations along x, y, z (mm).
    pub ellipsoid_coverage: f64,
    pub median_sd_mm: [f64; 3],
    /// The beads' error the steps' residuals show (px).
    pub bead_noise_px: Option<f64>,
}

/// One camera of more, against the rig it was rendered with.
#[derive(Clone, Serialize)]
pub struct CameraCheck {
    pub name: String,
    pub views: usize,
    pub focal_error_pct: f64,
    pub rotation_error_deg: f64,
    pub centre_error_mm: f64,
    /// What the calibration states of its pose.
    pub rotation_sd_deg: f64,
    pub position_sd_mm: f64,
}

/// Triangulated tips against the truth, per phase.
#[derive(Clone, Serialize)]
pub struct TipCheck {
    pub phase: String,
    pub rows: usize,
    pub rms_mm: f64,
    pub max_mm: f64,
    /// The mean error (x, y, z mm): what every row shares, mostly the rest position's own
    /// error, since each tip is measured from it.
    pub mean_mm: [f64; 3],
}

/// One model × test file.
#[derive(Serialize)]
pub struct Score {
    pub trained_on: String,
    pub model: String,
    pub test: String,
    pub errors: Errors,
}

impl Score {
    /// The `model` of the rows of `handcap model`'s default pick, `family`.
    pub fn auto_model(family: Family) -> String {
        format!("auto: {family}")
    }
}

/// Planned pressures run through the plant.
#[derive(Serialize)]
pub struct InverseCheck {
    pub model: String,
    pub targets: usize,
    pub reached_by_model: usize,
    pub mean_mm: f64,
    pub median_mm: f64,
    pub p90_mm: f64,
    pub max_mm: f64,
    /// The model's 90 % interval radius, and the share of planned tips whose plant tip lies
    /// within it of the model's (when the model has intervals).
    pub interval: Option<(f64, f64)>,
}

/// One model's prediction intervals and their coverage on the test files.
#[derive(Serialize)]
pub struct IntervalCheck {
    pub trained_on: String,
    #[serde(flatten)]
    pub intervals: IntervalReport,
}

/// Everything the demo checked, as `summary.json` holds it.
#[derive(Serialize)]
pub struct Summary {
    pub seed: u64,
    pub quick: bool,
    /// What the virtual lab added to the frames.
    pub realism: Realism,
    /// A pair's calibration, or more cameras' calibration and tips.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationCheck>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cameras: Option<CamerasCheck>,
    pub triangulation: Vec<TipCheck>,
    pub scores: Vec<Score>,
    pub intervals: Vec<IntervalCheck>,
    /// The family `handcap model`'s defaults picked on the triangulated rows, and why (its
    /// scores are among `scores`, its model `auto: <family>`).
    pub auto: FamilyDecision,
    pub inverse: Vec<InverseCheck>,
    /// The finger in motion (a pair's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dynamic: Option<super::demo_dynamic::DynamicCheck>,
    pub provenance: Provenance,
}
