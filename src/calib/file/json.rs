//! The calibration as JSON, for tools that read JSON rather than OpenCV YAML.

use std::path::Path;

use super::{
    camera_matrix, distortion_coefficients, read_text, uncertainty_note, uncertainty_values,
    CalibrationFile,
};
use crate::calib::StereoCalibration;
use crate::geometry::{rotation_from_rows, rotation_rows, Intrinsics, RightFromLeft};
use crate::stereo::{StereoError, StereoRig};

/// A row-major matrix of `cols` columns as a list of its rows.
fn rows(m: &[f64], cols: usize) -> Vec<Vec<f64>> {
    m.chunks(cols).map(<[f64]>::to_vec).collect()
}

/// The cameras and the hand axes as JSON, for tools that read JSON rather than OpenCV YAML
/// (Python's `json` + `numpy.array`, MATLAB's `jsondecode`, JavaScript): the YAML's keys and
/// meanings, matrices as lists of rows. What [`super::read_calibration`] needs (`image_size`, `K1`,
/// `D1`, `K2`, `D2`, `R`, `T`, `R_hand` when known) and the derived matrices (`E`, `F`,
/// `R1`, `R2`, `P1`, `P2`, `Q`) and quality (`rms_px`, `epipolar_px`).
pub fn calibration_json(cal: &StereoCalibration) -> String {
    let rig = &cal.rig;
    let mut doc = serde_json::json!({
        "format": "handcap stereo calibration: the keys of calib.yml, matrices as rows; lengths in mm, image coordinates in px",
        "image_size": rig.image_size,
        "K1": rows(&rig.left.k, 3),
        "D1": rig.left.dist,
        "K2": rows(&rig.right.k, 3),
        "D2": rig.right.dist,
        "R": rows(&rig.right_from_left.rotation_rows(), 3),
        "T": rig.right_from_left.translation_array(),
        "E": rows(&cal.e, 3),
        "F": rows(&cal.f, 3),
        "R1": rows(&cal.r1, 3),
        "R2": rows(&cal.r2, 3),
        "P1": rows(&cal.p1, 4),
        "P2": rows(&cal.p2, 4),
        "Q": rows(&cal.q, 4),
        "rms_px": cal.rms_px,
        "epipolar_px": cal.epipolar_px,
    });
    if let Some(axes) = &cal.hand_axes {
        doc["R_hand"] = serde_json::json!(rows(&rotation_rows(axes), 3));
    }
    for (key, r, cols, data) in uncertainty_values(cal) {
        doc[&key] = match (r, cols) {
            (1, 1) => serde_json::json!(data[0]),
            (1, _) | (_, 1) => serde_json::json!(data),
            _ => serde_json::json!(rows(&data, cols)),
        };
    }
    doc["uncertainty"] = serde_json::json!(uncertainty_note(cal));
    doc["advice"] = serde_json::json!(cal.guidance.advice);
    if !cal.implausible.is_empty() {
        doc["forced"] = serde_json::json!(cal.implausible);
    }
    if let Some(v) = &cal.validation {
        doc["validation"] = serde_json::json!(v);
    }
    let mut text = serde_json::to_string_pretty(&doc).expect("numbers and strings serialise");
    text.push('\n');
    text
}

/// More than two cameras' calibration ([`crate::calib::cameras`]) as JSON: `cameras`, each
/// with `name`, `image_size`, `K` (rows), `D`, `R` (rows) and `T` (the world, the first
/// camera's frame, into this camera's: p_cam = R p_world + T, mm), `rotation_sd_deg`,
/// `position_sd_mm`, `rms_px` (its corners in the joint fit), `intrinsics_rms_px` (its own
/// calibration), `views` of `images` with the board, `shared_instants`; then `rms_px`,
/// `outliers`, `reject_px`, `poorly_tied`, `R_hand` (world → hand frame rows) when known,
/// `covariance` (`per_camera` and `matrix`: [`crate::calib::graph::CameraCovariance`], what
/// `triangulate` carries into each tip's), and `forced`: the gates it failed, when `--force`
/// wrote it.
pub fn cameras_json(cal: &crate::calib::cameras::GraphCalibration) -> String {
    let cameras: Vec<serde_json::Value> = cal
        .cameras
        .iter()
        .map(|c| {
            let pose = &c.pose;
            serde_json::json!({
                "name": c.name,
                "image_size": c.size,
                "K": rows(&pose.intrinsics.k, 3),
                "D": pose.intrinsics.dist,
                "R": rows(&pose.cam_from_world.rotation_rows(), 3),
                "T": pose.cam_from_world.translation_array(),
                "rotation_sd_deg": pose.rotation_sd_deg,
                "position_sd_mm": pose.position_sd_mm,
                "rms_px": pose.rms_px,
                "intrinsics_rms_px": c.intrinsics_rms_px,
                "views": c.views,
                "images": c.images,
                "shared_instants": pose.shared,
            })
        })
        .collect();
    let mut doc = serde_json::json!({
        "format": "handcap calibration of more cameras: the world is the first camera's frame; matrices as rows; lengths in mm, image coordinates in px",
        "cameras": cameras,
        "rms_px": cal.rms_px,
        "outliers": cal.outliers,
        "reject_px": cal.reject_px,
        "poorly_tied": cal.poorly_tied,
        "hand_axes_note": cal.hand_axes_note,
    });
    if let Some(axes) = &cal.hand_axes {
        doc["R_hand"] = serde_json::json!(rows(&rotation_rows(axes), 3));
    }
    if let Some(c) = &cal.covariance {
        doc["covariance"] = serde_json::json!({
            "unknowns": "each camera's fx, fy, cx, cy, k1, k2, p1, p2, k3 (when refined: per_camera 9), then each camera's pose but the first's: a rotation vector applied on the right (rad), then the translation (mm); the board poses marginalised",
            "per_camera": c.per_camera,
            "matrix": c.matrix,
        });
    }
    if let Some(c) = &cal.covariance {
        doc["covariance"] = serde_json::json!({
            "unknowns": "each camera's fx, fy, cx, cy, k1, k2, p1, p2, k3 (when refined: per_camera 9), then each camera's pose but the first's: a rotation vector applied on the right (rad), then the translation (mm); the board poses marginalised",
            "per_camera": c.per_camera,
            "matrix": c.matrix,
        });
    }
    if !cal.implausible.is_empty() {
        doc["forced"] = serde_json::json!(cal.implausible);
    }
    serde_json::to_string_pretty(&doc).expect("numbers and names serialise as JSON")
}

/// The covariance of the cameras' unknowns in a JSON [`cameras_json`] wrote for `cameras`
/// cameras; `None` when it has none, or not one of that size.
///
/// # Errors
/// [`StereoError`] when the file cannot be read or is not JSON.
pub fn read_cameras_covariance(
    path: &Path,
    cameras: usize,
) -> Result<Option<crate::calib::graph::CameraCovariance>, StereoError> {
    #[derive(serde::Deserialize)]
    struct Keys {
        covariance: Option<Covariance>,
    }
    #[derive(serde::Deserialize)]
    struct Covariance {
        per_camera: usize,
        matrix: Vec<Vec<f64>>,
    }
    let text = read_text(path)?;
    let keys: Keys = serde_json::from_str(&text).map_err(|e| StereoError::Invalid {
        path: path.to_path_buf(),
        message: format!("not a handcap calibration JSON ({e})"),
    })?;
    Ok(keys.covariance.and_then(|c| {
        let k = c.per_camera * cameras + 6 * (cameras - 1);
        let square = c.matrix.len() == k && c.matrix.iter().all(|row| row.len() == k);
        (square && matches!(c.per_camera, 0 | 9)).then_some(crate::calib::graph::CameraCovariance {
            per_camera: c.per_camera,
            matrix: c.matrix,
        })
    }))
}

/// Reads a calibration written by [`calibration_json`].
///
/// # Errors
/// [`StereoError`] naming the file and the key that is missing or malformed.
pub fn read_calibration_json(path: &Path) -> Result<CalibrationFile, StereoError> {
    #[derive(serde::Deserialize)]
    #[allow(non_snake_case)]
    struct Keys {
        image_size: [i32; 2],
        K1: [[f64; 3]; 3],
        D1: Vec<f64>,
        K2: [[f64; 3]; 3],
        D2: Vec<f64>,
        R: [[f64; 3]; 3],
        T: [f64; 3],
        R_hand: Option<[[f64; 3]; 3]>,
    }
    let invalid = |message: String| StereoError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let text = read_text(path)?;
    let keys: Keys = serde_json::from_str(&text)
        .map_err(|e| invalid(format!("not a handcap calibration JSON ({e})")))?;
    let flat = |m: [[f64; 3]; 3]| -> [f64; 9] { std::array::from_fn(|k| m[k / 3][k % 3]) };
    let camera = |k: [[f64; 3]; 3], d: Vec<f64>, kn: &str, dn: &str| {
        Ok::<_, StereoError>(Intrinsics {
            k: camera_matrix(kn, flat(k).to_vec()).map_err(invalid)?,
            dist: distortion_coefficients(dn, d).map_err(invalid)?,
        })
    };
    let rotation = |m: [[f64; 3]; 3], name: &str| {
        rotation_from_rows(&flat(m)).map_err(|e| invalid(format!("{name}: {e}")))
    };
    if keys.image_size.iter().any(|&v| v <= 0) || keys.T.iter().any(|v| !v.is_finite()) {
        return Err(invalid("image_size must be positive and T finite".into()));
    }
    Ok(CalibrationFile {
        path: path.to_path_buf(),
        rig: StereoRig {
            image_size: keys.image_size,
            left: camera(keys.K1, keys.D1, "K1", "D1")?,
            right: camera(keys.K2, keys.D2, "K2", "D2")?,
            right_from_left: RightFromLeft::new(rotation(keys.R, "R")?, keys.T.into()),
        },
        r_hand: keys.R_hand.map(|m| rotation(m, "R_hand")).transpose()?,
        t_hand: None,
    })
}
