//! Anipose's `calibration.toml`, written and read.

use std::path::Path;

use nalgebra::{Rotation3, Vector3};

use super::{camera_matrix, distortion_coefficients, read_text, CalibrationFile};
use crate::calib::StereoCalibration;
use crate::geometry::{relative, CamFromWorld, Intrinsics, RightFromLeft};
use crate::stereo::{StereoError, StereoRig};

/// One camera as [`cameras_toml`] writes it.
pub struct AniposeCamera<'a> {
    pub name: &'a str,
    pub size: [i32; 2],
    pub intrinsics: &'a Intrinsics,
    /// World (the first camera's frame) → this camera.
    pub pose: CamFromWorld,
}

/// Cameras as Anipose/aniposelib's `calibration.toml` (what `CameraGroup.load` reads):
/// `[cam_0]`, `[cam_1]`, … in order, each with `name`, `size` [w, h], `matrix` (K, rows),
/// `distortions` (OpenCV's order), `rotation` and `translation` (Rodrigues vector and
/// translation taking points of the world, the first camera's frame, into this camera's, mm),
/// then `[metadata]` with the calibration's reprojection RMS (px) as `error` and, when known,
/// `hand_rotation`: the Rodrigues vector of the world → hand frame rotation (handcap's; Anipose
/// keeps what it does not read).
pub fn cameras_toml(
    cameras: &[AniposeCamera<'_>],
    error: f64,
    hand: Option<Rotation3<f64>>,
) -> String {
    #[derive(serde::Serialize)]
    struct Camera<'a> {
        name: &'a str,
        size: [i32; 2],
        matrix: Vec<&'a [f64]>,
        distortions: &'a [f64],
        rotation: [f64; 3],
        translation: [f64; 3],
    }
    #[derive(serde::Serialize)]
    struct Metadata {
        adjusted: bool,
        error: f64,
        #[serde(skip_serializing_if = "Option::is_none")]
        hand_rotation: Option<[f64; 3]>,
    }
    fn value(v: impl serde::Serialize) -> toml::Value {
        toml::Value::try_from(v).expect("numbers and names serialise as TOML")
    }
    let mut group = toml::Table::new();
    for (i, c) in cameras.iter().enumerate() {
        let camera = Camera {
            name: c.name,
            size: c.size,
            matrix: c.intrinsics.k.chunks(3).collect(),
            distortions: &c.intrinsics.dist,
            rotation: c.pose.rotation.scaled_axis().into(),
            translation: c.pose.translation_array(),
        };
        group.insert(format!("cam_{i}"), value(camera));
    }
    let metadata = Metadata {
        adjusted: false,
        error,
        hand_rotation: hand.map(|r| r.scaled_axis().into()),
    };
    group.insert("metadata".into(), value(metadata));
    toml::to_string(&group).expect("numbers and names serialise as TOML")
}

/// The pair's calibration as [`cameras_toml`]: `[cam_0]` the left camera (the world), `[cam_1]`
/// the right (its `R`, `T`).
pub fn anipose_toml(cal: &StereoCalibration) -> String {
    let pose = &cal.rig.right_from_left;
    let cameras = [
        AniposeCamera {
            name: "left",
            size: cal.rig.image_size,
            intrinsics: &cal.rig.left,
            pose: CamFromWorld::new(Rotation3::identity(), Vector3::zeros()),
        },
        AniposeCamera {
            name: "right",
            size: cal.rig.image_size,
            intrinsics: &cal.rig.right,
            pose: CamFromWorld::new(pose.rotation, pose.translation),
        },
    ];
    cameras_toml(&cameras, cal.rms_px, None)
}

/// A camera as [`read_cameras_toml`] reads it.
#[derive(Clone, Debug)]
pub struct ReadCamera {
    pub name: String,
    pub size: [i32; 2],
    pub intrinsics: Intrinsics,
    /// World (the first camera's frame, in Anipose's files) → this camera.
    pub pose: CamFromWorld,
}

/// The cameras of an Anipose/aniposelib `calibration.toml` (every `[cam_N]`, in N's order; a
/// camera without `name` is called `cam_N`), and `[metadata]`'s `hand_rotation` (world → hand
/// frame, a Rodrigues vector) when it has one ([`cameras_toml`] writes it).
///
/// # Errors
/// [`StereoError`] naming the file and the camera or key that is missing or malformed.
pub fn read_cameras_toml(
    path: &Path,
) -> Result<(Vec<ReadCamera>, Option<Rotation3<f64>>), StereoError> {
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
    let mut keys: Vec<(usize, &String)> = doc
        .keys()
        .filter_map(|k| Some((k.strip_prefix("cam_")?.parse().ok()?, k)))
        .collect();
    keys.sort();
    let mut cameras = Vec::new();
    for (_, cam) in keys {
        let Some(t) = doc[cam].as_table() else {
            return Err(invalid(format!("[{cam}] is not a table")));
        };
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
        cameras.push(ReadCamera {
            name: t
                .get("name")
                .and_then(toml::Value::as_str)
                .unwrap_or(cam)
                .to_string(),
            size: [size[0] as i32, size[1] as i32],
            intrinsics,
            pose: CamFromWorld::new(
                Rotation3::from_scaled_axis(Vector3::new(r[0], r[1], r[2])),
                Vector3::new(tr[0], tr[1], tr[2]),
            ),
        });
    }
    let hand = match doc.get("metadata").and_then(|m| m.get("hand_rotation")) {
        Some(v) => {
            let r = numbers("metadata", "hand_rotation", Some(v))?;
            if r.len() != 3 {
                return Err(invalid("[metadata] hand_rotation needs 3 numbers".into()));
            }
            Some(Rotation3::from_scaled_axis(Vector3::new(r[0], r[1], r[2])))
        }
        None => None,
    };
    Ok((cameras, hand))
}

/// Reads an Anipose/aniposelib `calibration.toml` of two cameras (as [`anipose_toml`] writes
/// it, or Anipose does): `cam_0` is taken as the left camera and the world, `cam_1` as the right.
/// The pose between them is [`relative`] of the two cameras' poses (R = R₁ R₀ᵀ, T = t₁ − R t₀).
/// It has no hand frame (`R_hand`): `triangulate` needs the YAML of a calibration with a
/// reference pair.
///
/// # Errors
/// [`StereoError`] naming the file and the camera or key that is missing or malformed.
pub fn read_anipose_toml(path: &Path) -> Result<CalibrationFile, StereoError> {
    let (cameras, _) = read_cameras_toml(path)?;
    let [left, right] = &cameras[..] else {
        return Err(StereoError::Invalid {
            path: path.to_path_buf(),
            message: format!(
                "handcap needs exactly two cameras, [cam_0] (left) and [cam_1] (right); the file has {}",
                cameras.len()
            ),
        });
    };
    if left.size != right.size {
        return Err(StereoError::Invalid {
            path: path.to_path_buf(),
            message: format!(
                "the cameras' sizes differ ({:?} and {:?}); both must capture at the same size",
                left.size, right.size
            ),
        });
    }
    Ok(CalibrationFile {
        path: path.to_path_buf(),
        rig: left.pair_with(right),
        r_hand: None,
        t_hand: None,
    })
}

impl ReadCamera {
    /// This camera as a stereo pair's left, `right` its right (the image size this one's).
    pub fn pair_with(&self, right: &ReadCamera) -> StereoRig {
        let between = relative(&self.pose, &right.pose);
        StereoRig {
            image_size: self.size,
            left: self.intrinsics.clone(),
            right: right.intrinsics.clone(),
            right_from_left: RightFromLeft::new(between.rotation, between.translation),
        }
    }
}
