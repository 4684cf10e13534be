//! The calibration files, read and written in one place: the stereo calibration (`calib.yml`),
//! the board description (`board.yml`), the synthetic rig's truth and the hand transform that
//! `triangulate` finds. All are OpenCV FileStorage YAML (`%YAML:1.0`), so `cv2.FileStorage` and
//! C++ read them; `calib/example_calib.yml` at the top of the repository is a commented example.
//!
//! # Keys
//!
//! | key | shape | meaning |
//! |---|---|---|
//! | `image_size` | [w, h] | pixels of both cameras |
//! | `K1`, `K2` | 3 × 3 | camera matrices, px: [fx 0 cx; 0 fy cy; 0 0 1] |
//! | `D1`, `D2` | 1 × 5 | distortion (k1, k2, p1, p2, k3), OpenCV's model |
//! | `R`, `T` | 3 × 3, 3 × 1 | right from left: p_right = R · p_left + T (mm) |
//! | `E`, `F` | 3 × 3 | essential (normalised coordinates) and fundamental (pixels) matrices |
//! | `R1`, `R2`, `P1`, `P2`, `Q` | | `stereoRectify`'s rectification (α = 0) |
//! | `rms_px`, `epipolar_px`, `per_view_rms_px` | | reprojection RMS, mean epipolar distance, per pair (left, right) |
//! | `views_used`, `views_rejected` | | pair names |
//! | `board_cols`, `board_rows`, `square_mm`, `detector`, `coverage` | | the board (inner corners) and how it was seen |
//! | `board`, `marker_mm`, `dictionary` | text, mm, text | the board as `--board` names it (`9x6`, `charuco:10x7`); a ChArUco board's markers |
//! | `board_neighbour_squares`, `board_planarity_rms_mm` | | the boards triangulated back |
//! | `coverage_cells_left`, `coverage_cells_right`, `tilt_sd_deg`, `advice` | | where the corners fell (8 × 6 cells, `#` seen), the boards' tilt spread about the left camera's x and y, what to capture next ([`super::guidance`]) |
//! | `baseline_mm` | | \|T\| |
//! | `forced` | | only in a calibration written with `--force` although it failed a gate: what failed ([`super::gates`]) |
//! | `validation_ratio`, `validation_disagreement_mm`, `validation_predicted_mm`, `validation_base_distance_mm`, `validation_warnings` | | with `--validate`: the halves' disagreement against their covariances' prediction ([`super::validate`]) |
//! | `K1_sd`, `D1_sd`, `K2_sd`, `D2_sd`, `T_sd`, `baseline_sd_mm`, `R_sd_deg`, `corner_sd_px` | | standard deviations beside each value ([`super::uncertainty`]; none for fixed intrinsics), `uncertainty` says how |
//! | `tip_sd_at_mm`, `tip_sd_at`, `tip_sd_mm`, `tip_move_sd_mm`, `tip_sd_marker_mm` | 3 × 1 | the tip's deviations at the finger: position and a 10 mm move from the calibration, and from 0.1 px of marker noise |
//! | `bootstrap_K1_sd` … `bootstrap_R_sd_deg` | | the same by `--bootstrap N` |
//! | `R_hand` | 3 × 3 | hand from left camera axes: p_hand = R_hand · p_left + t_hand |
//! | `t_hand` | 3 × 1 | the hand frame's translation (mm), where the origin is known (truth, `dataset_hand.yml`) |
//! | `hand_axes`, `handcap_version`, `command`, `seed` (of `--bootstrap`) | text | provenance |
//!
//! `board.yml`: `inner_corners_cols`, `inner_corners_rows`, `square_mm` for a chessboard;
//! `pattern: charuco`, `squares_x`, `squares_y`, `square_mm`, `marker_mm`, `dictionary` for a
//! ChArUco board.
//!
//! Reading checks what the geometry needs: `R` and `R_hand` must be rotations (orthonormal to
//! 1e-3, determinant > 0; [`crate::geometry::Transform::from_rows`]), camera matrices must have
//! positive focal lengths, every value must be finite.

mod anipose;
mod board;
mod json;
mod yaml;

pub use anipose::{
    anipose_toml, cameras_toml, read_anipose_toml, read_cameras_toml, AniposeCamera, ReadCamera,
};
pub use board::{
    board_yaml, default_board, read_board, read_board_text, BOARD_FILE, DEFAULT_BOARD_YAML,
};
pub use json::{calibration_json, cameras_json, read_calibration_json, read_cameras_covariance};
pub use yaml::{calibration_yaml, hand_yaml, read_calibration, read_intrinsics, write_rig};

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Vector3};

use super::StereoCalibration;
use crate::stereo::{StereoError, StereoRig};

/// A calibration file as `calibrate` writes it (and `synth` writes the truth).
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationFile {
    pub path: PathBuf,
    pub rig: StereoRig,
    /// Left camera → hand axes (`R_hand`), when the calibration had a reference pair.
    pub r_hand: Option<Rotation3<f64>>,
    /// The hand frame's translation (`t_hand`: p_hand = R_hand · p_left + t_hand), in files
    /// that know the origin (the synthetic truth, `triangulate`'s hand file).
    pub t_hand: Option<Vector3<f64>>,
}

/// How the `*_sd` keys were found, or why there are none.
pub fn uncertainty_note(cal: &StereoCalibration) -> &'static str {
    match &cal.uncertainty {
        Some(_) => "standard deviations (_sd) from the covariance of the joint reprojection problem, sigma^2 (J^T J)^-1 at the solution (handcap::calib::uncertainty); R_sd_deg about the left camera's x, y, z; at tip_sd_at_mm along the left camera's x, y, z: the tip's position (tip_sd_mm) and a 10 mm move of it (tip_move_sd_mm) from the calibration, its position from 0.1 px of marker noise in each image (tip_sd_marker_mm)",
        None => "no standard deviations: the problem has no unique solution or a fixed camera's distortion goes beyond k1, k2, p1, p2, k3",
    }
}

/// The standard deviations as (key, rows, cols, values), for the YAML and the JSON alike:
/// `K1_sd` (a 3 × 3 matrix with each deviation where its value is in `K1`), `D1_sd`, the same
/// for the right camera (only for solved intrinsics), `T_sd`, `baseline_sd_mm`, `R_sd_deg`,
/// `corner_sd_px`, `tip_sd_at_mm`, `tip_sd_mm`, `tip_move_sd_mm`, `tip_sd_marker_mm`; the
/// bootstrap's, when there is one, as `bootstrap_K1_sd` … `bootstrap_R_sd_deg`.
fn uncertainty_values(cal: &StereoCalibration) -> Vec<(String, usize, usize, Vec<f64>)> {
    let mut out = Vec::new();
    if let Some(u) = &cal.uncertainty {
        parameter_values("", &u.parameters, &mut out);
        for (key, rows, values) in [
            ("corner_sd_px", 1, vec![u.corner_sd_px]),
            ("tip_sd_at_mm", 3, u.at_mm.to_vec()),
            ("tip_sd_mm", 3, u.tip.position.to_vec()),
            ("tip_move_sd_mm", 3, u.tip.displacement.to_vec()),
            ("tip_sd_marker_mm", 3, u.tip.marker.to_vec()),
        ] {
            out.push((key.to_string(), rows, 1, values));
        }
    }
    if let Some(b) = &cal.bootstrap {
        parameter_values("bootstrap_", &b.parameters, &mut out);
    }
    out
}

fn parameter_values(
    prefix: &str,
    sd: &super::uncertainty::ParameterSd,
    out: &mut Vec<(String, usize, usize, Vec<f64>)>,
) {
    for (c, [k, d]) in [["K1_sd", "D1_sd"], ["K2_sd", "D2_sd"]]
        .into_iter()
        .enumerate()
    {
        if let Some([fx, fy, cx, cy, dist @ ..]) = sd.intrinsics[c] {
            out.push((
                prefix.to_string() + k,
                3,
                3,
                vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 0.0],
            ));
            out.push((prefix.to_string() + d, 1, 5, dist.to_vec()));
        }
    }
    out.push((
        prefix.to_string() + "T_sd",
        3,
        1,
        sd.translation_mm.to_vec(),
    ));
    out.push((
        prefix.to_string() + "baseline_sd_mm",
        1,
        1,
        vec![sd.baseline_mm],
    ));
    out.push((
        prefix.to_string() + "R_sd_deg",
        3,
        1,
        sd.rotation_deg.to_vec(),
    ));
}

/// Where [`anipose_toml`] is written beside the calibration file `out`: `OUT.toml`.
pub fn toml_path(out: &Path) -> PathBuf {
    out.with_extension("toml")
}

/// Where [`calibration_json`] is written beside the calibration file `out`: `OUT.json`.
pub fn json_path(out: &Path) -> PathBuf {
    out.with_extension("json")
}

/// A text calibration file's contents.
fn read_text(path: &Path) -> Result<String, StereoError> {
    std::fs::read_to_string(path).map_err(|e| StereoError::Unreadable {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// A camera matrix from a file's values (`name` for the message): nine values, fx and fy > 0,
/// K₃₃ = 1. With [`distortion_coefficients`], the one rule both calibration readers (OpenCV
/// YAML, Anipose TOML) apply.
fn camera_matrix(name: &str, k: Vec<f64>) -> Result<[f64; 9], String> {
    match <[f64; 9]>::try_from(k) {
        Ok(k) if k[0] > 0.0 && k[4] > 0.0 && k[8] == 1.0 => Ok(k),
        _ => Err(format!("{name} is not a camera matrix")),
    }
}

/// OpenCV distortion from a file's values: 4, 5, 8, 12 or 14 finite numbers.
fn distortion_coefficients(name: &str, d: Vec<f64>) -> Result<Vec<f64>, String> {
    if ![4, 5, 8, 12, 14].contains(&d.len()) || d.iter().any(|x| !x.is_finite()) {
        return Err(format!(
            "{name} has {} values; OpenCV distortion has 4, 5, 8, 12 or 14",
            d.len()
        ));
    }
    Ok(d)
}

/// The part of an OpenCV error message a user can act on, on one line: "Input file is invalid
/// in function 'open'" rather than the source location.
fn reason(e: &opencv::Error) -> String {
    let first = e.message.lines().next().unwrap_or_default();
    let text = first.rsplit_once("error: ").map_or(first, |(_, t)| t);
    text.split_once(") ")
        .map_or(text, |(_, t)| t)
        .trim()
        .to_string()
}
