//! The calibrated stereo pair as OpenCV models it: two pinhole cameras with (k1, k2, p1, p2, k3)
//! distortion and the left → right pose. Undistortion, triangulation and projection go through
//! OpenCV; `calibrate` checks its boards with them and `triangulate` finds the tip with them.
//!
//! Coordinates: pixels in each image; 3-D points in the left camera's frame (OpenCV's: x right,
//! y down, z forward, mm); `R`, `T` map left-camera points to the right camera's frame
//! (p_right = R · p_left + T), as `stereo_calibrate` returns them.

use std::path::PathBuf;

use nalgebra::{Matrix3, Vector3};
use opencv::calib3d;
use opencv::core::{self, Mat};
use opencv::prelude::*;

use crate::cv;
use crate::geometry::{Intrinsics, RightFromLeft};

/// An image point (x, y).
pub type Point2 = [f64; 2];

/// Which camera of the pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    Left,
    Right,
}

impl AsRef<str> for Side {
    fn as_ref(&self) -> &str {
        self.name()
    }
}

impl Side {
    /// The pair's camera at place `i` in its list (0 left, 1 right).
    pub fn of_index(i: usize) -> Side {
        [Side::Left, Side::Right][i]
    }

    /// `left` or `right`, as in file names.
    pub const fn name(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
        }
    }
}

/// The two cameras and the left → right pose.
#[derive(Clone, Debug, PartialEq)]
pub struct StereoRig {
    /// Width and height in pixels.
    pub image_size: [i32; 2],
    pub left: Intrinsics,
    pub right: Intrinsics,
    /// p_right = R · p_left + T (T in mm).
    pub right_from_left: RightFromLeft,
}

/// Errors of reading a calibration file or of the geometry.
#[derive(Debug, thiserror::Error)]
pub enum StereoError {
    #[error("{path}: not an OpenCV YAML/XML calibration file ({message}); pass the file `handcap calibrate` wrote")]
    Unreadable { path: PathBuf, message: String },
    #[error("{path}: {message}; pass the file `handcap calibrate` wrote")]
    Invalid { path: PathBuf, message: String },
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
}

#[cfg(test)]
impl StereoRig {
    /// Two identical 1280 × 720 cameras (f 900 px, no distortion), rectified, 60 mm apart.
    pub(crate) fn rectified_for_tests() -> StereoRig {
        let camera = Intrinsics::new(900.0, 900.0, 640.0, 360.0, vec![0.0; 5]);
        StereoRig {
            image_size: [1280, 720],
            left: camera.clone(),
            right: camera,
            right_from_left: RightFromLeft::new(
                nalgebra::Rotation3::identity(),
                Vector3::new(-60.0, 0.0, 0.0),
            ),
        }
    }
}

impl StereoRig {
    /// The intrinsics of one camera.
    pub fn camera(&self, side: Side) -> &Intrinsics {
        match side {
            Side::Left => &self.left,
            Side::Right => &self.right,
        }
    }

    /// The essential matrix \[T\]ₓ R (normalised coordinates: x̂_rightᵀ E x̂_left = 0).
    pub fn essential(&self) -> Matrix3<f64> {
        let pose = &self.right_from_left;
        pose.translation.cross_matrix() * pose.rotation.matrix()
    }

    /// The fundamental matrix K₂⁻ᵀ E K₁⁻¹ (undistorted pixels), scaled so that F₃₃ = 1.
    pub fn fundamental(&self) -> Matrix3<f64> {
        let inv = |k: &[f64; 9]| {
            Matrix3::from_row_slice(k)
                .try_inverse()
                .expect("a camera matrix is invertible")
        };
        let f = inv(&self.right.k).transpose() * self.essential() * inv(&self.left.k);
        f / f[(2, 2)]
    }

    /// Pixels of `side` undistorted to normalised image coordinates (x/z, y/z) by OpenCV's
    /// iterative undistortion, run to convergence.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn normalized(&self, side: Side, px: &[[f64; 2]]) -> opencv::Result<Vec<[f64; 2]>> {
        if px.is_empty() {
            return Ok(Vec::new());
        }
        let cam = self.camera(side);
        let mut out = Mat::default();
        calib3d::undistort_points_iter(
            &cv::points64(px)?,
            &mut out,
            &cv::mat(3, &cam.k)?,
            &cv::mat(1, &cam.dist)?,
            &core::no_array(),
            &core::no_array(),
            cv::criteria(100, 1e-12)?,
        )?;
        cv::pairs(&out)
    }

    /// Pixels of `side` undistorted to pixels of the same camera without distortion.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn undistorted(&self, side: Side, px: &[[f64; 2]]) -> opencv::Result<Vec<[f64; 2]>> {
        let k = &self.camera(side).k;
        Ok(self
            .normalized(side, px)?
            .into_iter()
            .map(|[x, y]| [k[0] * x + k[1] * y + k[2], k[4] * y + k[5]])
            .collect())
    }

    /// 3-D points (left camera, mm) from matching normalised coordinates, by OpenCV's
    /// `triangulate_points` (linear, in `f64`).
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn triangulate_normalized(
        &self,
        left: &[[f64; 2]],
        right: &[[f64; 2]],
    ) -> opencv::Result<Vec<Vector3<f64>>> {
        assert_eq!(left.len(), right.len(), "one right point per left point");
        if left.is_empty() {
            return Ok(Vec::new());
        }
        let (r, t) = (
            self.right_from_left.rotation_rows(),
            self.right_from_left.translation,
        );
        let p1 = cv::mat(3, &[1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0.])?;
        let p2 = cv::mat(
            3,
            &[
                r[0], r[1], r[2], t[0], r[3], r[4], r[5], t[1], r[6], r[7], r[8], t[2],
            ],
        )?;
        // 2 × N matrices of f64, so that OpenCV triangulates in f64.
        let rows = |p: &[[f64; 2]]| -> opencv::Result<Mat> {
            let mut flat: Vec<f64> = p.iter().map(|q| q[0]).collect();
            flat.extend(p.iter().map(|q| q[1]));
            cv::mat(2, &flat)
        };
        let mut x4 = Mat::default();
        calib3d::triangulate_points(&p1, &p2, &rows(left)?, &rows(right)?, &mut x4)?;
        let v = cv::values(&x4)?;
        let n = left.len();
        Ok((0..n)
            .map(|k| Vector3::new(v[k], v[n + k], v[2 * n + k]) / v[3 * n + k])
            .collect())
    }

    /// 3-D points (left camera, mm) from matching pixels: undistorted, then triangulated.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn triangulate(
        &self,
        left: &[[f64; 2]],
        right: &[[f64; 2]],
    ) -> opencv::Result<Vec<Vector3<f64>>> {
        self.triangulate_normalized(
            &self.normalized(Side::Left, left)?,
            &self.normalized(Side::Right, right)?,
        )
    }

    /// Hartley-Sturm optimal correction (`correct_matches`) of matching normalised coordinates:
    /// the nearest pair that satisfies the epipolar constraint exactly.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn correct_matches(
        &self,
        left: &[[f64; 2]],
        right: &[[f64; 2]],
    ) -> opencv::Result<(Vec<Point2>, Vec<Point2>)> {
        if left.is_empty() {
            return Ok((Vec::new(), Vec::new()));
        }
        let e = self.essential();
        let e: Vec<f64> = (0..9).map(|k| e[(k / 3, k % 3)]).collect();
        // 1 × N two-channel, the shape `correct_matches` asks for.
        let row = |p: &[[f64; 2]]| -> opencv::Result<Mat> {
            let flat: Vec<f64> = p.iter().flat_map(|q| [q[0], q[1]]).collect();
            Mat::from_slice(&flat)?.reshape(2, 1)?.try_clone()
        };
        let (mut a, mut b) = (Mat::default(), Mat::default());
        calib3d::correct_matches(&cv::mat(3, &e)?, &row(left)?, &row(right)?, &mut a, &mut b)?;
        Ok((cv::pairs(&a)?, cv::pairs(&b)?))
    }

    /// Pixels of `side` where the 3-D points (left camera, mm) appear, distortion included
    /// (OpenCV's `project_points`).
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn project(&self, side: Side, points: &[Vector3<f64>]) -> opencv::Result<Vec<[f64; 2]>> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let cam = self.camera(side);
        let (rvec, tvec) = match side {
            Side::Left => ([0.0; 3], [0.0; 3]),
            Side::Right => {
                let mut rvec = Mat::default();
                let pose = &self.right_from_left;
                calib3d::rodrigues(
                    &cv::mat(3, &pose.rotation_rows())?,
                    &mut rvec,
                    &mut core::no_array(),
                )?;
                (cv::fixed::<3>(&rvec)?, pose.translation_array())
            }
        };
        let flat: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        let object = Mat::from_slice(&flat)?
            .reshape(3, points.len() as i32)?
            .try_clone()?;
        let mut out = Mat::default();
        calib3d::project_points_def(
            &object,
            &cv::mat(3, &rvec)?,
            &cv::mat(3, &tvec)?,
            &cv::mat(3, &cam.k)?,
            &cv::mat(1, &cam.dist)?,
            &mut out,
        )?;
        cv::pairs(&out)
    }
}
