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
//! | `board_cols`, `board_rows`, `square_mm`, `detector`, `coverage` | | the board and how it was seen |
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
//! `board.yml`: `inner_corners_cols`, `inner_corners_rows`, `square_mm`.
//!
//! Reading checks what the geometry needs: `R` and `R_hand` must be rotations (orthonormal to
//! 1e-3, determinant > 0; [`crate::geometry::Transform::from_rows`]), camera matrices must have
//! positive focal lengths, every value must be finite.

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Vector3};
use opencv::core;
use opencv::prelude::*;

use super::{BoardSpec, CalibError, KnownIntrinsics, PairReport, StereoCalibration};
use crate::cv;
use crate::geometry::{
    relative, rotation_from_rows, rotation_rows, CamFromWorld, HandFromLeft, Intrinsics,
    RightFromLeft,
};
use crate::opencv_yaml::FileStorage;
use crate::provenance::Provenance;
use crate::stereo::{StereoError, StereoRig};

/// The board description's file name inside a calibration directory.
pub const BOARD_FILE: &str = "board.yml";

/// The repository's `calib/board.yml`: the printed board handcap assumes when a calibration
/// directory has no `board.yml` and no flags say otherwise.
pub const DEFAULT_BOARD_YAML: &str = include_str!("../../calib/board.yml");

/// [`DEFAULT_BOARD_YAML`] read.
pub fn default_board() -> BoardSpec {
    read_board_text(DEFAULT_BOARD_YAML).expect("calib/board.yml is a board description")
}

/// Reads a board description from its text.
///
/// # Errors
/// As [`read_board`].
pub fn read_board_text(text: &str) -> Result<BoardSpec, CalibError> {
    let mode = core::FileStorage_Mode::READ as i32 | core::FileStorage_Mode::MEMORY as i32;
    board_from(text, mode, Path::new("(built-in board.yml)"))
}

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

/// Writes `image_size`, `K1`, `D1`, `K2`, `D2`, `R`, `T`: the keys [`read_calibration`] reads
/// back.
pub fn write_rig<'a>(fs: &'a mut FileStorage, rig: &StereoRig) -> &'a mut FileStorage {
    fs.ints(
        "image_size",
        &[rig.image_size[0].into(), rig.image_size[1].into()],
    )
    .matrix("K1", 3, 3, &rig.left.k)
    .matrix("D1", 1, rig.left.dist.len(), &rig.left.dist)
    .matrix("K2", 3, 3, &rig.right.k)
    .matrix("D2", 1, rig.right.dist.len(), &rig.right.dist)
    .matrix("R", 3, 3, &rig.right_from_left.rotation_rows())
    .matrix("T", 3, 1, &rig.right_from_left.translation_array())
}

/// The calibration file `calibrate` writes (the keys in the module docs).
pub fn calibration_yaml(cal: &StereoCalibration, provenance: &Provenance) -> String {
    let mut fs = FileStorage::new();
    write_rig(&mut fs, &cal.rig)
        .matrix("E", 3, 3, &cal.e)
        .matrix("F", 3, 3, &cal.f)
        .matrix("R1", 3, 3, &cal.r1)
        .matrix("R2", 3, 3, &cal.r2)
        .matrix("P1", 3, 4, &cal.p1)
        .matrix("P2", 3, 4, &cal.p2)
        .matrix("Q", 4, 4, &cal.q)
        .real("rms_px", cal.rms_px)
        .real("epipolar_px", cal.epipolar_px);
    let used: Vec<&PairReport> = cal.used().collect();
    let per_view: Vec<f64> = used
        .iter()
        .flat_map(|p| p.rms_px.unwrap_or([f64::NAN; 2]))
        .collect();
    fs.matrix("per_view_rms_px", used.len(), 2, &per_view)
        .strings(
            "views_used",
            &used.iter().map(|p| p.name.clone()).collect::<Vec<_>>(),
        )
        .strings(
            "views_rejected",
            &cal.rejected().map(|p| p.name.clone()).collect::<Vec<_>>(),
        )
        .int("board_cols", cal.board.cols as i64)
        .int("board_rows", cal.board.rows as i64)
        .real("square_mm", cal.board.square_mm)
        .string("detector", cal.detector.name())
        .reals("coverage", &cal.guidance.coverage())
        .strings("coverage_cells_left", &cal.guidance.map(0))
        .strings("coverage_cells_right", &cal.guidance.map(1))
        .reals("tilt_sd_deg", &cal.guidance.tilt_sd_deg)
        .strings("advice", &cal.guidance.advice)
        .real(
            "board_neighbour_squares",
            cal.board_check.neighbour_mean_squares,
        )
        .real("board_planarity_rms_mm", cal.board_check.planarity_rms_mm)
        .real("baseline_mm", cal.rig.right_from_left.translation.norm());
    for (key, rows, cols, data) in uncertainty_values(cal) {
        match data.as_slice() {
            [x] => fs.real(&key, *x),
            _ => fs.matrix(&key, rows, cols, &data),
        };
    }
    if let Some(u) = &cal.uncertainty {
        fs.string("tip_sd_at", &u.at);
    }
    fs.string("uncertainty", uncertainty_note(cal));
    if let Some(axes) = &cal.hand_axes {
        fs.matrix("R_hand", 3, 3, &rotation_rows(axes));
    }
    if !cal.implausible.is_empty() {
        fs.strings("forced", &cal.implausible);
    }
    if let Some(v) = &cal.validation {
        fs.real("validation_ratio", v.ratio)
            .reals("validation_disagreement_mm", &v.disagreement_mm)
            .reals("validation_predicted_mm", &v.predicted_mm)
            .real("validation_base_distance_mm", v.base_distance_mm)
            .strings("validation_warnings", &v.warnings);
    }
    fs.string("hand_axes", &cal.hand_axes_note)
        .string("handcap_version", &provenance.handcap_version)
        .string("command", &provenance.command.join(" "));
    if let Some(seed) = provenance.seed {
        fs.int("seed", seed as i64);
    }
    fs.text().to_string()
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

/// The cameras and the hand axes as JSON, for tools that read JSON rather than OpenCV YAML
/// (Python's `json` + `numpy.array`, MATLAB's `jsondecode`, JavaScript): the YAML's keys and
/// meanings, matrices as lists of rows. What [`read_calibration`] needs (`image_size`, `K1`,
/// `D1`, `K2`, `D2`, `R`, `T`, `R_hand` when known) and the derived matrices (`E`, `F`,
/// `R1`, `R2`, `P1`, `P2`, `Q`) and quality (`rms_px`, `epipolar_px`).
pub fn calibration_json(cal: &StereoCalibration) -> String {
    let rows =
        |m: &[f64], cols: usize| -> Vec<Vec<f64>> { m.chunks(cols).map(<[f64]>::to_vec).collect() };
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

/// The calibration as Anipose/aniposelib's `calibration.toml` (what `CameraGroup.load` reads):
/// `[cam_0]` (the left camera, `name = "left"`) and `[cam_1]` (`"right"`), each with `size`
/// [w, h], `matrix` (K, rows), `distortions` (OpenCV's order), `rotation` and `translation`
/// (Rodrigues vector and translation taking points of the first camera's frame, the world, into
/// this camera's: the left camera's are zero, the right's are `R`, `T`, mm), then `[metadata]`
/// with the calibration's reprojection RMS (px) as `error`.
pub fn anipose_toml(cal: &StereoCalibration) -> String {
    let list = |v: &[f64]| {
        let items: Vec<String> = v.iter().map(|x| format!("{x:?}")).collect();
        format!("[{}]", items.join(", "))
    };
    let pose = &cal.rig.right_from_left;
    let cameras = [
        ("left", &cal.rig.left, [0.0; 3], [0.0; 3]),
        (
            "right",
            &cal.rig.right,
            pose.rotation.scaled_axis().into(),
            pose.translation_array(),
        ),
    ];
    let mut out = String::new();
    for (k, (name, cam, rotation, translation)) in cameras.iter().enumerate() {
        let rows: Vec<String> = cam.k.chunks(3).map(list).collect();
        out += &format!(
            "[cam_{k}]\nname = \"{name}\"\nsize = [{}, {}]\nmatrix = [{}]\ndistortions = {}\nrotation = {}\ntranslation = {}\n\n",
            cal.rig.image_size[0],
            cal.rig.image_size[1],
            rows.join(", "),
            list(&cam.dist),
            list(rotation),
            list(translation),
        );
    }
    out + &format!("[metadata]\nadjusted = false\nerror = {:?}\n", cal.rms_px)
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

/// Reads an Anipose/aniposelib `calibration.toml` of two cameras (as [`anipose_toml`] writes
/// it, or Anipose does): `cam_0` is taken as the left camera and the world, `cam_1` as the right.
/// The pose between them is [`relative`] of the two cameras' poses (R = R₁ R₀ᵀ, T = t₁ − R t₀). It has no hand frame (`R_hand`): `triangulate` needs the YAML of a calibration
/// with a reference pair.
///
/// # Errors
/// [`StereoError`] naming the file and the camera or key that is missing or malformed.
pub fn read_anipose_toml(path: &Path) -> Result<CalibrationFile, StereoError> {
    let invalid = |message: String| StereoError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let text = read_text(path)?;
    let doc: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| StereoError::Unreadable {
            path: path.to_path_buf(),
            message: format!("not TOML: {}", e.message()),
        })?;
    let numbers =
        |cam: &str, key: &str, v: Option<&toml::Value>| -> Result<Vec<f64>, StereoError> {
            let bad = || invalid(format!("[{cam}] {key} is missing or not a list of numbers"));
            let mut out = Vec::new();
            let mut push = |x: &toml::Value| -> Result<(), StereoError> {
                let f = x
                    .as_float()
                    .or(x.as_integer().map(|i| i as f64))
                    .ok_or_else(bad)?;
                if !f.is_finite() {
                    return Err(bad());
                }
                out.push(f);
                Ok(())
            };
            for item in v.and_then(toml::Value::as_array).ok_or_else(bad)? {
                match item.as_array() {
                    Some(row) => row.iter().try_for_each(&mut push)?,
                    None => push(item)?,
                }
            }
            Ok(out)
        };
    let cameras: Vec<&str> = ["cam_0", "cam_1"]
        .into_iter()
        .filter(|c| doc.get(*c).is_some_and(toml::Value::is_table))
        .collect();
    if cameras.len() < 2 || doc.keys().filter(|k| k.starts_with("cam_")).count() != 2 {
        return Err(invalid(format!(
            "handcap needs exactly two cameras, [cam_0] (left) and [cam_1] (right); the file has {}",
            doc.keys().filter(|k| k.starts_with("cam_")).count()
        )));
    }
    // Each camera: intrinsics, size, and its pose in the world (the first camera's frame).
    type Camera = (Intrinsics, [f64; 2], CamFromWorld);
    let camera = |cam: &str| -> Result<Camera, StereoError> {
        let t = &doc[cam];
        let size = numbers(cam, "size", t.get("size"))?;
        let k = numbers(cam, "matrix", t.get("matrix"))?;
        let dist = numbers(cam, "distortions", t.get("distortions"))?;
        let r = numbers(cam, "rotation", t.get("rotation"))?;
        let tr = numbers(cam, "translation", t.get("translation"))?;
        if size.len() != 2 || k.len() != 9 || r.len() != 3 || tr.len() != 3 {
            return Err(invalid(format!(
                "[{cam}]: size needs 2 numbers, matrix 3 × 3, rotation and translation 3 each"
            )));
        }
        let intrinsics = Intrinsics {
            k: camera_matrix(&format!("[{cam}] matrix"), k).map_err(invalid)?,
            dist: distortion_coefficients(&format!("[{cam}] distortions"), dist)
                .map_err(invalid)?,
        };
        Ok((
            intrinsics,
            [size[0], size[1]],
            CamFromWorld::new(
                Rotation3::from_scaled_axis(Vector3::new(r[0], r[1], r[2])),
                Vector3::new(tr[0], tr[1], tr[2]),
            ),
        ))
    };
    let (left, left_size, left_pose) = camera("cam_0")?;
    let (right, right_size, right_pose) = camera("cam_1")?;
    if left_size != right_size {
        return Err(invalid(format!(
            "the cameras' sizes differ ({left_size:?} and {right_size:?}); both must capture at the same size"
        )));
    }
    let between = relative(&left_pose, &right_pose);
    Ok(CalibrationFile {
        path: path.to_path_buf(),
        rig: StereoRig {
            image_size: left_size.map(|v| v as i32),
            left,
            right,
            right_from_left: RightFromLeft::new(between.rotation, between.translation),
        },
        r_hand: None,
        t_hand: None,
    })
}

/// `board.yml`: the printed board's inner corners and square size.
pub fn board_yaml(board: &BoardSpec) -> String {
    let mut fs = FileStorage::new();
    fs.int("inner_corners_cols", board.cols as i64)
        .int("inner_corners_rows", board.rows as i64)
        .real("square_mm", board.square_mm);
    fs.text().to_string()
}

/// Reads `board.yml`.
///
/// # Errors
/// [`CalibError::BadBoard`] naming the file and what is missing.
pub fn read_board(path: &Path) -> Result<BoardSpec, CalibError> {
    let bad = |what: String| board_error(path, &what);
    if !path.is_file() {
        return Err(bad("no such file".into()));
    }
    let name = path
        .to_str()
        .ok_or_else(|| bad("the path is not UTF-8".into()))?;
    board_from(name, core::FileStorage_Mode::READ as i32, path)
}

/// A board description that cannot be used, and what to do instead.
fn board_error(path: &Path, what: &str) -> CalibError {
    CalibError::BadBoard(format!(
        "{}: {what}; pass --board COLSxROWS --square-mm MM, or write the file (see calib/board.yml)",
        path.display()
    ))
}

/// Reads a board description from a file name or, with the MEMORY flag, the text itself.
fn board_from(source: &str, mode: i32, path: &Path) -> Result<BoardSpec, CalibError> {
    let bad = |what: String| board_error(path, &what);
    let fs = core::FileStorage::new(source, mode, "").map_err(|e| bad(reason(&e)))?;
    let number = |key: &str| -> Result<f64, CalibError> {
        let node = fs.get(key).map_err(|e| bad(reason(&e)))?;
        if node.empty().unwrap_or(true)
            || !node.is_real().unwrap_or(false) && !node.is_int().unwrap_or(false)
        {
            return Err(bad(format!("no number for {key}")));
        }
        node.to_f64().map_err(|e| bad(reason(&e)))
    };
    let count = |key: &str| -> Result<usize, CalibError> {
        let v = number(key)?;
        if v.fract() != 0.0 || v < 0.0 {
            return Err(bad(format!("{key} is {v}, not a whole number")));
        }
        Ok(v as usize)
    };
    Ok(BoardSpec {
        cols: count("inner_corners_cols")?,
        rows: count("inner_corners_rows")?,
        square_mm: number("square_mm")?,
    })
}

/// The hand transform `triangulate` writes beside its dataset (`dataset_hand.yml`).
pub fn hand_yaml(
    hand: &HandFromLeft,
    origin_left_mm: &[f64; 3],
    origin_pairs: usize,
    provenance: &Provenance,
) -> String {
    let mut fs = FileStorage::new();
    fs.matrix("R_hand", 3, 3, &hand.rotation_rows())
        .matrix("t_hand", 3, 1, &hand.translation_array())
        .matrix("origin_left_mm", 3, 1, origin_left_mm)
        .int("origin_pairs", origin_pairs as i64)
        .string(
            "convention",
            "p_hand = R_hand * p_left + t_hand (mm); origin: median tip at zero pressure",
        )
        .string("handcap_version", &provenance.handcap_version)
        .string("command", &provenance.command.join(" "));
    fs.text().to_string()
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

/// Reads the cameras (`image_size`, `K1`, `D1`, `K2`, `D2`, `R`, `T`) and, when present, the
/// hand frame (`R_hand`, `t_hand`) of an OpenCV FileStorage file.
///
/// # Errors
/// [`StereoError`] naming the file and the key that is missing or malformed.
pub fn read_calibration(path: &Path) -> Result<CalibrationFile, StereoError> {
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_lowercase);
    match extension.as_deref() {
        Some("toml") => return read_anipose_toml(path),
        Some("json") => return read_calibration_json(path),
        _ => {}
    }
    let file = YamlFile::open(path)?;
    let image_size = file
        .size_pair("image_size")?
        .ok_or_else(|| file.invalid("no image_size [width, height]".into()))?;
    let rig = StereoRig {
        image_size,
        left: file.camera("K1", "D1")?,
        right: file.camera("K2", "D2")?,
        right_from_left: RightFromLeft::from_rows(
            &file.required("R", 9)?.try_into().expect("nine values"),
            file.required("T", 3)?.try_into().expect("three values"),
        )
        .map_err(|e| file.invalid(format!("R is {e}")))?,
    };
    let r_hand = file
        .optional("R_hand", 9)?
        .map(|v| rotation_from_rows(&v.try_into().expect("nine values")))
        .transpose()
        .map_err(|e| file.invalid(format!("R_hand is {e}")))?;
    Ok(CalibrationFile {
        path: path.to_path_buf(),
        rig,
        r_hand,
        t_hand: file
            .optional("t_hand", 3)?
            .map(|v| Vector3::from_row_slice(&v)),
    })
}

/// One camera's intrinsics from an earlier single-camera calibration (`calibrate --intrinsics`):
/// OpenCV YAML/XML with `camera_matrix` and `distortion_coefficients` and the image size as
/// `image_width` and `image_height` (what OpenCV's calibration sample writes), or `K`, `D` and
/// `image_size` [w, h].
///
/// # Errors
/// [`StereoError`] naming the file and the key that is missing or malformed.
pub fn read_intrinsics(path: &Path) -> Result<KnownIntrinsics, StereoError> {
    let file = YamlFile::open(path)?;
    let image_size = match (file.node("image_width")?, file.node("image_height")?) {
        (Some(w), Some(h)) => Some([w.to_i32()?, h.to_i32()?]),
        _ => file.size_pair("image_size")?,
    }
    .ok_or_else(|| {
        file.invalid("no image size (image_width and image_height, or image_size [w, h])".into())
    })?;
    let intrinsics = if file.node("camera_matrix")?.is_some() {
        file.camera("camera_matrix", "distortion_coefficients")?
    } else if file.node("K")?.is_some() {
        file.camera("K", "D")?
    } else {
        return Err(file.invalid(
            "no camera matrix (camera_matrix and distortion_coefficients, or K and D)".into(),
        ));
    };
    Ok(KnownIntrinsics {
        path: path.to_path_buf(),
        image_size,
        intrinsics,
    })
}

/// An OpenCV FileStorage file opened for reading, and the key readers with one error rule.
struct YamlFile {
    path: PathBuf,
    fs: core::FileStorage,
}

impl YamlFile {
    fn open(path: &Path) -> Result<Self, StereoError> {
        let unreadable = |message: String| StereoError::Unreadable {
            path: path.to_path_buf(),
            message,
        };
        if !path.is_file() {
            return Err(unreadable("no such file".into()));
        }
        if std::fs::metadata(path).is_ok_and(|m| m.len() == 0) {
            return Err(unreadable("the file is empty".into()));
        }
        let name = path
            .to_str()
            .ok_or_else(|| unreadable("the path is not UTF-8".into()))?;
        let fs = core::FileStorage::new(name, core::FileStorage_Mode::READ as i32, "")
            .map_err(|e| unreadable(reason(&e)))?;
        if !fs.is_opened()? {
            return Err(unreadable("OpenCV cannot open it".into()));
        }
        Ok(YamlFile {
            path: path.to_path_buf(),
            fs,
        })
    }

    fn invalid(&self, message: String) -> StereoError {
        StereoError::Invalid {
            path: self.path.clone(),
            message,
        }
    }

    /// The key's node, `None` when the key is absent.
    fn node(&self, key: &str) -> Result<Option<core::FileNode>, StereoError> {
        let node = self.fs.get(key)?;
        Ok((!(node.empty()? || node.is_none()?)).then_some(node))
    }

    /// A [width, height] sequence, `None` when the key is absent or not one.
    fn size_pair(&self, key: &str) -> Result<Option<[i32; 2]>, StereoError> {
        match self.node(key)? {
            Some(node) if node.is_seq()? && node.size()? == 2 => {
                Ok(Some([node.at(0)?.to_i32()?, node.at(1)?.to_i32()?]))
            }
            _ => Ok(None),
        }
    }

    /// A matrix of `len` finite values, `None` when the key is absent.
    fn optional(&self, key: &str, len: usize) -> Result<Option<Vec<f64>>, StereoError> {
        let Some(node) = self.node(key)? else {
            return Ok(None);
        };
        let m = node
            .mat()
            .map_err(|e| self.invalid(format!("{key}: {}", e.message)))?;
        let v = cv::values(&m)?;
        if v.len() != len || v.iter().any(|x| !x.is_finite()) {
            return Err(self.invalid(format!(
                "{key} has {} values (finite: {}), expected {len}",
                v.len(),
                v.iter().all(|x| x.is_finite())
            )));
        }
        Ok(Some(v))
    }

    fn required(&self, key: &str, len: usize) -> Result<Vec<f64>, StereoError> {
        self.optional(key, len)?
            .ok_or_else(|| self.invalid(format!("no {key}")))
    }

    /// The camera of matrix key `k` and distortion key `d`.
    fn camera(&self, k: &str, d: &str) -> Result<Intrinsics, StereoError> {
        let k = camera_matrix(k, self.required(k, 9)?).map_err(|e| self.invalid(e))?;
        let node = self
            .node(d)?
            .ok_or_else(|| self.invalid(format!("no {d}")))?;
        let dist =
            distortion_coefficients(d, cv::values(&node.mat()?)?).map_err(|e| self.invalid(e))?;
        Ok(Intrinsics { k, dist })
    }
}
