//! The OpenCV YAML files: the calibration, the hand transform, and single-camera intrinsics.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use opencv::core;
use opencv::prelude::*;

use super::{
    camera_matrix, distortion_coefficients, read_anipose_toml, read_calibration_json, reason,
    uncertainty_note, uncertainty_values, CalibrationFile,
};
use crate::calib::{KnownIntrinsics, PairReport, StereoCalibration};
use crate::cv;
use crate::geometry::{rotation_from_rows, rotation_rows, HandFromLeft, Intrinsics, RightFromLeft};
use crate::opencv_yaml::FileStorage;
use crate::provenance::Provenance;
use crate::stereo::{StereoError, StereoRig};

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
    fs.string("board", &cal.board.layout().to_string());
    cal.board.pattern.kind().calibration_keys(&mut fs);
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
