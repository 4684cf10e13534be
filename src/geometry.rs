//! The nouns of handcap's geometry: the frames, the rigid transforms between them, and the
//! pinhole camera with OpenCV's distortion that synth, calib and stereo share.
//!
//! A transform is named after what it does to a point: a [`RightFromLeft`] takes a point in the
//! left camera's frame to the right camera's (p_right = R · p_left + T, OpenCV's `R`, `T`). Both
//! frames are in the type, so a transform is inverted ([`Transform::inverse`] returns the
//! opposite type) or composed ([`Transform::then`]) only in a direction that makes sense, and a
//! [`HandFromLeft`] cannot be passed where a [`RightFromLeft`] is expected.
//!
//! Frames (OpenCV's camera convention: x right, y down, z forward; millimetres):
//! - [`frame::Left`], [`frame::Right`]: the two cameras of the stereo pair;
//! - [`frame::Hand`]: the micro-hand's frame (README: z along the finger towards its base);
//! - [`frame::Camera`], [`frame::World`]: any one camera and the scene it sees (synth's world is
//!   the hand frame);
//! - [`frame::Board`]: a chessboard (x along its rows, y along its columns, z into the board).

use std::marker::PhantomData;

use nalgebra::{Matrix3, Matrix3x4, Point3, Rotation3, Vector3};

/// The coordinate frames, as types without values.
pub mod frame {
    /// The left camera of the stereo pair.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum Left {}
    /// The right camera of the stereo pair.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum Right {}
    /// The micro-hand's frame.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum Hand {}
    /// Any one camera.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum Camera {}
    /// The scene a camera sees.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum World {}
    /// A calibration chessboard.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum Board {}
}

/// A rigid transform taking points of frame `From` to frame `To`:
/// p_To = rotation · p_From + translation (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform<To, From> {
    pub rotation: Rotation3<f64>,
    pub translation: Vector3<f64>,
    frames: PhantomData<(To, From)>,
}

/// Left camera → right camera (OpenCV's stereo `R`, `T`).
pub type RightFromLeft = Transform<frame::Right, frame::Left>;
/// Left camera → hand frame (`R_hand`, `t_hand` of the calibration and hand files).
pub type HandFromLeft = Transform<frame::Hand, frame::Left>;
/// World → camera (a camera's pose, as OpenCV's `rvec`, `tvec`).
pub type CamFromWorld = Transform<frame::Camera, frame::World>;
/// Board → camera (one calibration view's board pose).
pub type CamFromBoard = Transform<frame::Camera, frame::Board>;
/// Board → world (where synth places a board).
pub type WorldFromBoard = Transform<frame::World, frame::Board>;

/// A 3 × 3 matrix that is not a rotation (not orthonormal, or a reflection).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("not a rotation matrix (‖R Rᵀ − I‖ = {orthogonality:.2e}, det = {det:.4})")]
pub struct NotARotation {
    pub orthogonality: f64,
    pub det: f64,
}

impl<To, From> Transform<To, From> {
    pub fn new(rotation: Rotation3<f64>, translation: Vector3<f64>) -> Self {
        Transform {
            rotation,
            translation,
            frames: PhantomData,
        }
    }

    /// From a row-major rotation matrix and a translation as files store them. The matrix is
    /// kept exactly (no re-orthonormalisation, so a file read and written is unchanged) once
    /// it is a rotation to within 1e-3 (a matrix printed with six decimals passes; a zero,
    /// scaled or mirrored one does not).
    ///
    /// # Errors
    /// [`NotARotation`].
    pub fn from_rows(r: &[f64; 9], t: [f64; 3]) -> Result<Self, NotARotation> {
        Ok(Self::new(rotation_from_rows(r)?, Vector3::from(t)))
    }

    /// The rotation, row-major (as OpenCV's files and `Mat`s store it).
    pub fn rotation_rows(&self) -> [f64; 9] {
        rotation_rows(&self.rotation)
    }

    /// The translation as an array.
    pub fn translation_array(&self) -> [f64; 3] {
        self.translation.into()
    }

    /// The point `p` (in `From`) expressed in `To`.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * p.coords + self.translation)
    }

    /// The opposite transform: `To` → `From`.
    pub fn inverse(&self) -> Transform<From, To> {
        let rotation = self.rotation.inverse();
        Transform::new(rotation, -(rotation * self.translation))
    }

    /// This transform followed by `next`: `From` → `Next`.
    pub fn then<Next>(&self, next: &Transform<Next, To>) -> Transform<Next, From> {
        Transform::new(
            next.rotation * self.rotation,
            next.rotation * self.translation + next.translation,
        )
    }
}

impl CamFromWorld {
    /// The camera centre in world coordinates.
    pub fn centre(&self) -> Point3<f64> {
        Point3::from(-(self.rotation.inverse() * self.translation))
    }
}

/// Two transforms from one frame `From` (say two cameras' poses seen from the same world, or
/// the same board): the transform from the first's frame to the second's,
/// R = R_b · R_aᵀ, t = t_b − R · t_a.
pub fn relative<A, B, From>(a: &Transform<A, From>, b: &Transform<B, From>) -> Transform<B, A> {
    let rotation = b.rotation * a.rotation.inverse();
    Transform::new(rotation, b.translation - rotation * a.translation)
}

/// K [R | t]: world points to the undistorted pixels of a camera with intrinsics `camera` and
/// pose `pose` (the projection a calibration's K and undistorted points describe).
pub fn projection(camera: &Intrinsics, pose: &CamFromWorld) -> Matrix3x4<f64> {
    let mut rt = Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(pose.rotation.matrix());
    rt.set_column(3, &pose.translation);
    Matrix3::from_row_slice(&camera.k) * rt
}

/// A rotation's matrix, row-major.
pub fn rotation_rows(r: &Rotation3<f64>) -> [f64; 9] {
    let m = r.matrix();
    std::array::from_fn(|k| m[(k / 3, k % 3)])
}

/// A row-major 3 × 3 rotation, checked as [`Transform::from_rows`] says.
///
/// # Errors
/// [`NotARotation`].
pub fn rotation_from_rows(r: &[f64; 9]) -> Result<Rotation3<f64>, NotARotation> {
    let m = Matrix3::from_row_slice(r);
    let orthogonality = (m * m.transpose() - Matrix3::identity()).norm();
    let det = m.determinant();
    if !(orthogonality < 1e-3 && det > 0.0) {
        return Err(NotARotation { orthogonality, det });
    }
    Ok(Rotation3::from_matrix_unchecked(m))
}

/// One camera's intrinsics as OpenCV models them: K (row-major 3 × 3) and the distortion
/// coefficients (k1, k2, p1, p2\[, k3\[, k4, k5, k6\[, …\]\]\]).
///
/// Pixel (0, 0) is the centre of the top-left pixel; the pure-Rust projection here
/// ([`Intrinsics::pixel`], [`Intrinsics::undistort`]) models the first five coefficients,
/// which is what handcap's synthetic cameras and `calibrate` use; `stereo` goes through
/// OpenCV for every model.
#[derive(Clone, Debug, PartialEq)]
pub struct Intrinsics {
    pub k: [f64; 9],
    pub dist: Vec<f64>,
}

impl Intrinsics {
    /// A camera without skew: focal lengths and principal point (pixels), distortion.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, dist: Vec<f64>) -> Self {
        Intrinsics {
            k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            dist,
        }
    }

    pub fn fx(&self) -> f64 {
        self.k[0]
    }

    pub fn fy(&self) -> f64 {
        self.k[4]
    }

    pub fn cx(&self) -> f64 {
        self.k[2]
    }

    pub fn cy(&self) -> f64 {
        self.k[5]
    }

    /// k1, k2, p1, p2, k3, zero where the file has fewer.
    fn five(&self) -> [f64; 5] {
        std::array::from_fn(|i| self.dist.get(i).copied().unwrap_or(0.0))
    }

    /// Normalised → distorted normalised coordinates:
    /// r² = x² + y², x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²),
    /// y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.five();
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Pixel of a point in the camera's frame; `None` behind the camera.
    pub fn pixel(&self, p: &Point3<f64>) -> Option<[f64; 2]> {
        if p.z <= 1e-9 {
            return None;
        }
        let (xd, yd) = self.distort(p.x / p.z, p.y / p.z);
        Some([self.fx() * xd + self.cx(), self.fy() * yd + self.cy()])
    }

    /// Normalised undistorted coordinates of a pixel: the inverse of [`Intrinsics::distort`]
    /// by Newton's method (to 1e-12; converges in a few steps for webcam-sized distortion).
    pub fn undistort(&self, u: f64, v: f64) -> (f64, f64) {
        let (xd, yd) = ((u - self.cx()) / self.fx(), (v - self.cy()) / self.fy());
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let (fx, fy) = self.distort(x, y);
            let (rx, ry) = (fx - xd, fy - yd);
            if rx.abs().max(ry.abs()) < 1e-13 {
                break;
            }
            // Jacobian by central differences (the map is smooth and nearly the identity).
            let h = 1e-7;
            let (ax, ay) = self.distort(x + h, y);
            let (bx, by) = self.distort(x - h, y);
            let (cx, cy) = self.distort(x, y + h);
            let (dx, dy) = self.distort(x, y - h);
            let (j11, j21) = ((ax - bx) / (2.0 * h), (ay - by) / (2.0 * h));
            let (j12, j22) = ((cx - dx) / (2.0 * h), (cy - dy) / (2.0 * h));
            let det = j11 * j22 - j12 * j21;
            x -= (j22 * rx - j12 * ry) / det;
            y -= (j11 * ry - j21 * rx) / det;
        }
        (x, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn rotation(a: f64, b: f64, c: f64) -> Rotation3<f64> {
        Rotation3::from_euler_angles(a, b, c)
    }

    fn webcam() -> Intrinsics {
        Intrinsics::new(
            907.0,
            905.0,
            641.0,
            358.0,
            vec![0.09, -0.2, 6e-4, -4e-4, 0.08],
        )
    }

    proptest! {
        #[test]
        fn a_transform_then_its_inverse_is_the_identity(
            a in -3.0..3.0f64, b in -1.5..1.5f64, c in -3.0..3.0f64,
            t in prop::array::uniform3(-200.0..200.0f64),
            p in prop::array::uniform3(-100.0..100.0f64),
        ) {
            let x = RightFromLeft::new(rotation(a, b, c), Vector3::from(t));
            let p = Point3::from(p);
            let back = x.inverse().apply(&x.apply(&p));
            prop_assert!((back - p).norm() < 1e-9);
            let round = x.then(&x.inverse());
            prop_assert!((round.rotation.matrix() - Matrix3::identity()).norm() < 1e-12);
            prop_assert!(round.translation.norm() < 1e-9);
            // The inverse of the inverse is the transform.
            let twice = x.inverse().inverse();
            prop_assert!((twice.translation - x.translation).norm() < 1e-9);
        }

        #[test]
        fn relative_poses_compose_back(
            a in prop::array::uniform3(-1.0..1.0f64),
            b in prop::array::uniform3(-1.0..1.0f64),
            ta in prop::array::uniform3(-100.0..100.0f64),
            tb in prop::array::uniform3(-100.0..100.0f64),
            p in prop::array::uniform3(-50.0..50.0f64),
        ) {
            let left = CamFromWorld::new(rotation(a[0], a[1], a[2]), Vector3::from(ta));
            let right = CamFromWorld::new(rotation(b[0], b[1], b[2]), Vector3::from(tb));
            let between = relative(&left, &right);
            let p = Point3::from(p);
            prop_assert!((between.apply(&left.apply(&p)) - right.apply(&p)).norm() < 1e-9);
            // `then` agrees: world → left → right is world → right.
            let through = left.then(&between);
            prop_assert!((through.apply(&p) - right.apply(&p)).norm() < 1e-9);
        }

        #[test]
        fn undistort_inverts_the_projection_across_a_webcam_image(
            u in 0.0..1280.0f64, v in 0.0..720.0f64,
        ) {
            let cam = webcam();
            let (x, y) = cam.undistort(u, v);
            let [u2, v2] = cam.pixel(&Point3::new(x, y, 1.0)).unwrap();
            prop_assert!((u2 - u).abs() < 1e-9 && (v2 - v).abs() < 1e-9, "{u},{v} → {u2},{v2}");
        }

        #[test]
        fn rows_round_trip_exactly(a in prop::array::uniform3(-3.0..3.0f64)) {
            let r = rotation(a[0], a[1], a[2]);
            let x = HandFromLeft::new(r, Vector3::new(1.0, 2.0, 3.0));
            let back = HandFromLeft::from_rows(&x.rotation_rows(), x.translation_array()).unwrap();
            prop_assert_eq!(back, x);
        }
    }

    #[test]
    fn matrices_that_are_not_rotations_are_refused() {
        let mirror = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0];
        assert!(rotation_from_rows(&mirror).is_err());
        assert!(rotation_from_rows(&[0.0; 9]).is_err());
        let scaled = [2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0];
        assert!(rotation_from_rows(&scaled).is_err());
        // Six printed decimals still read.
        let r = rotation(0.3, -0.2, 1.1);
        let printed: [f64; 9] =
            std::array::from_fn(|k| (r.matrix()[(k / 3, k % 3)] * 1e6).round() / 1e6);
        assert!(rotation_from_rows(&printed).is_ok());
    }

    #[test]
    fn points_behind_the_camera_have_no_pixel() {
        assert_eq!(webcam().pixel(&Point3::new(0.0, 0.0, -1.0)), None);
        let [u, v] = webcam().pixel(&Point3::new(0.0, 0.0, 100.0)).unwrap();
        assert_eq!([u, v], [641.0, 358.0]);
    }
}
