//! The virtual rig: two OpenCV pinhole cameras with radial/tangential distortion (a stereo
//! pair), or more on an arc around the finger.
//!
//! Conventions are OpenCV's: camera frame x right, y down, z forward; pixel (0, 0) is the
//! centre of the top-left pixel; distortion coefficients (k1, k2, p1, p2, k3) act on normalised
//! coordinates (x, y) = (X/Z, Y/Z):
//! r² = x² + y², x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²),
//! y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y, u = fx x_d + cx, v = fy y_d + cy.
//!
//! # The default rig
//!
//! Two webcams of the Logitech C920 class (1280×720, 78° diagonal field of view, so
//! f = 734 px / tan 39° ≈ 907 px; k1 ≈ 0.09, k2 ≈ −0.2, small tangential terms), 60 mm apart,
//! 160 mm from the finger's tip region and 40° below it, both turned towards the aim point
//! (0, 0, 8) mm of the hand frame. Looking up at the tip keeps the red bead on the finger's end
//! in view whichever way the finger bends. A seed varies the focal lengths (±1 %), principal
//! points (±8 px), distortion (±15 %) and mounting (±2 mm, ±1°) of each camera, as two units of
//! one webcam model and a hand-built rig differ.
//!
//! # More cameras
//!
//! Three or more cameras ([`RigConfig::cameras`]), named `cam1` … `camN`, stand on an arc
//! around the hand's z axis, [`ARC_STEP_DEG`] apart and centred on the pair's direction (the
//! hand's −y side), each at the pair's distance and elevation, turned towards the aim point,
//! varied by the seed as the pair is.

use nalgebra::{Matrix3, Matrix3x4, Point3, Rotation3, Unit, Vector3};

use crate::geometry::{relative, CamFromWorld, Intrinsics, RightFromLeft};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// One virtual camera: image size, intrinsics and pose.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub intrinsics: Intrinsics,
    pub pose: CamFromWorld,
}

impl Camera {
    /// Pixel of a world point; `None` behind the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<[f64; 2]> {
        self.intrinsics.pixel(&self.pose.apply(p))
    }

    /// K [R | t]: world points to undistorted pixels (the projection a calibration's K and
    /// undistorted points describe).
    pub fn projection(&self) -> Matrix3x4<f64> {
        crate::geometry::projection(&self.intrinsics, &self.pose)
    }

    /// World-space direction (unit) of the ray through normalised coordinates (x, y).
    pub fn ray_direction(&self, x: f64, y: f64) -> Unit<Vector3<f64>> {
        Unit::new_normalize(self.pose.rotation.inverse() * Vector3::new(x, y, 1.0))
    }
}

/// A camera at `eye` looking at `target`, with image-up as close to `up` as possible.
pub fn looking_at(eye: Point3<f64>, target: Point3<f64>, up: Vector3<f64>) -> CamFromWorld {
    let z = (target - eye).normalize();
    let x = z.cross(&up).normalize(); // x = y × z with y ≈ −up
    let y = z.cross(&x);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        x.transpose(),
        y.transpose(),
        z.transpose(),
    ]));
    CamFromWorld::new(rotation, -(rotation * eye.coords))
}

/// The rig's cameras: a stereo pair (`left`, `right`), or more (`cam1` … `camN`).
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    pub cameras: Vec<Camera>,
}

/// Azimuth between neighbouring cameras of a rig of more than two (degrees).
pub const ARC_STEP_DEG: f64 = 30.0;

impl Rig {
    /// The first camera (a pair's left).
    pub fn left(&self) -> &Camera {
        &self.cameras[0]
    }

    /// The second camera (a pair's right).
    pub fn right(&self) -> &Camera {
        &self.cameras[1]
    }

    /// The cameras' names, in order, as in file names: `left`, `right` for two, else `cam1`
    /// … `camN`.
    pub fn names(&self) -> Vec<String> {
        match self.cameras.len() {
            2 => vec!["left".into(), "right".into()],
            n => (1..=n).map(|i| format!("cam{i}")).collect(),
        }
    }

    /// The right camera's pose relative to the left: p_right = R p_left + T (OpenCV's R, T).
    pub fn right_from_left(&self) -> RightFromLeft {
        let between = relative(&self.left().pose, &self.right().pose);
        RightFromLeft::new(between.rotation, between.translation)
    }

    /// The pair as OpenCV describes it (what a perfect calibration would return).
    pub fn stereo(&self) -> crate::stereo::StereoRig {
        crate::stereo::StereoRig {
            image_size: [self.left().width as i32, self.left().height as i32],
            left: self.left().intrinsics.clone(),
            right: self.right().intrinsics.clone(),
            right_from_left: self.right_from_left(),
        }
    }
}

/// What the virtual rig looks like (see the module docs for the defaults).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RigConfig {
    pub width: u32,
    pub height: u32,
    /// Diagonal field of view (degrees).
    pub fov_diag_deg: f64,
    /// k1, k2, p1, p2, k3 of the nominal lens.
    pub dist: [f64; 5],
    pub baseline_mm: f64,
    /// Distance from the midpoint between the cameras to the aim point (mm).
    pub distance_mm: f64,
    /// How far below the aim point the cameras sit (degrees).
    pub elevation_deg: f64,
    /// The point both cameras look at (hand frame, mm).
    pub aim_mm: [f64; 3],
    /// Scale of the per-camera variation the seed draws (1 = the documented ranges, 0 = none).
    pub variation: f64,
    /// How many cameras: 2, a stereo pair `baseline_mm` apart; more, on an arc (module docs).
    pub cameras: usize,
}

impl Default for RigConfig {
    fn default() -> Self {
        RigConfig {
            width: 1280,
            height: 720,
            fov_diag_deg: 78.0,
            dist: [0.09, -0.2, 0.0006, -0.0004, 0.08],
            baseline_mm: 60.0,
            distance_mm: 160.0,
            elevation_deg: 40.0,
            aim_mm: [0.0, 0.0, 8.0],
            variation: 1.0,
            cameras: 2,
        }
    }
}

impl RigConfig {
    /// Builds the rig, varied by `seed`. The cameras sit on the hand's −y side (a pair) or
    /// around it (more), below the aim point, image x along the rig's bar or arc and image up
    /// towards the hand's +z (the base).
    pub fn build(&self, seed: u64) -> Rig {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5249_4721);
        let aim = Point3::from(self.aim_mm);
        let elevation = self.elevation_deg.to_radians();
        let forward = Vector3::new(0.0, elevation.cos(), elevation.sin());
        let centre = aim - forward * self.distance_mm;
        // The bar holding the cameras runs along hand x; each camera turns towards the aim
        // about the rig's own up direction, so the pair's relative rotation is a toe-in.
        let rig_up = Vector3::x().cross(&forward);
        let f = (f64::from(self.width).hypot(f64::from(self.height)) / 2.0)
            / (self.fov_diag_deg.to_radians() / 2.0).tan();
        let v = self.variation;
        // A camera at `place`, image up as near `up` as its aim allows.
        let mut camera = |place: Point3<f64>, up: Vector3<f64>| {
            let mut jitter = |range: f64| v * range * rng.random_range(-1.0..=1.0);
            let eye = place + Vector3::new(jitter(2.0), jitter(2.0), jitter(2.0));
            let look = looking_at(eye, aim, up);
            let tweak = Rotation3::from_euler_angles(
                jitter(1f64.to_radians()),
                jitter(1f64.to_radians()),
                jitter(1f64.to_radians()),
            );
            let rotation = tweak * look.rotation;
            let focal = f * (1.0 + jitter(0.01));
            Camera {
                width: self.width,
                height: self.height,
                intrinsics: Intrinsics::new(
                    focal,
                    focal * (1.0 + jitter(0.002)),
                    f64::from(self.width) / 2.0 - 0.5 + jitter(8.0),
                    f64::from(self.height) / 2.0 - 0.5 + jitter(8.0),
                    self.dist.map(|d| d * (1.0 + jitter(0.15))).to_vec(),
                ),
                pose: CamFromWorld::new(rotation, -(rotation * eye.coords)),
            }
        };
        let half = Vector3::new(self.baseline_mm / 2.0, 0.0, 0.0);
        let cameras = match self.cameras {
            2 => vec![camera(centre - half, rig_up), camera(centre + half, rig_up)],
            n => (0..n)
                .map(|i| {
                    let azimuth = (i as f64 - (n - 1) as f64 / 2.0) * ARC_STEP_DEG;
                    let turn = Rotation3::from_axis_angle(&Vector3::z_axis(), azimuth.to_radians());
                    camera(aim + turn * (centre - aim), turn * rig_up)
                })
                .collect(),
        };
        Rig { cameras }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_rig_is_a_converging_c920_pair() {
        let rig = RigConfig::default().build(2020);
        let aim = Point3::new(0.0, 0.0, 8.0);
        for cam in &rig.cameras {
            assert!((cam.intrinsics.fx() - 907.0).abs() < 15.0);
            // The aim point lands near the image centre.
            let [u, v] = cam.project(&aim).unwrap();
            assert!(
                (u - 640.0).abs() < 60.0 && (v - 360.0).abs() < 60.0,
                "{u},{v}"
            );
            // Image up is the hand's +z: the base projects above the tip.
            let base = cam.project(&Point3::new(0.0, 0.0, 50.0)).unwrap();
            assert!(base[1] < v);
        }
        let t = rig.right_from_left().translation;
        assert!((t.norm() - 60.0).abs() < 5.0, "{t}");
        assert!(
            t.x < 0.0,
            "the left camera sits at −x in the right camera's frame: {t}"
        );
        // Same seed, same rig; another seed, another rig.
        assert_eq!(rig, RigConfig::default().build(2020));
        assert_ne!(rig, RigConfig::default().build(7));
    }
}
