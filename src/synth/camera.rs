//! The virtual stereo rig: two OpenCV pinhole cameras with radial/tangential distortion.
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

use nalgebra::{Matrix3, Point3, Rotation3, Unit, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Camera pose: p_cam = rotation · p_world + translation (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CamFromWorld {
    pub rotation: Rotation3<f64>,
    pub translation: Vector3<f64>,
}

impl CamFromWorld {
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * p.coords + self.translation)
    }

    /// The camera centre in world coordinates.
    pub fn centre(&self) -> Point3<f64> {
        Point3::from(-(self.rotation.inverse() * self.translation))
    }

    /// A camera at `eye` looking at `target`, with image-up as close to `up` as possible.
    pub fn looking_at(eye: Point3<f64>, target: Point3<f64>, up: Vector3<f64>) -> Self {
        let z = (target - eye).normalize();
        let x = z.cross(&up).normalize(); // x = y × z with y ≈ −up
        let y = z.cross(&x);
        let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
            x.transpose(),
            y.transpose(),
            z.transpose(),
        ]));
        CamFromWorld {
            rotation,
            translation: -(rotation * eye.coords),
        }
    }
}

/// One camera: intrinsics, distortion, image size and pose.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// k1, k2, p1, p2, k3 (OpenCV order).
    pub dist: [f64; 5],
    pub pose: CamFromWorld,
}

impl Camera {
    /// Camera matrix K, row-major.
    pub fn k(&self) -> [f64; 9] {
        [self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0]
    }

    /// Normalised → distorted normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Pixel of a point in the camera frame; `None` behind the camera.
    pub fn project_cam(&self, p: &Point3<f64>) -> Option<[f64; 2]> {
        if p.z <= 1e-9 {
            return None;
        }
        let (xd, yd) = self.distort(p.x / p.z, p.y / p.z);
        Some([self.fx * xd + self.cx, self.fy * yd + self.cy])
    }

    /// Pixel of a world point; `None` behind the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<[f64; 2]> {
        self.project_cam(&self.pose.apply(p))
    }

    /// Normalised undistorted coordinates of a pixel: the inverse of [`Camera::distort`] by
    /// Newton's method (to 1e-12; converges in a few steps for webcam-sized distortion).
    pub fn undistort(&self, u: f64, v: f64) -> (f64, f64) {
        let (xd, yd) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
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

    /// World-space direction (unit) of the ray through normalised coordinates (x, y).
    pub fn ray_direction(&self, x: f64, y: f64) -> Unit<Vector3<f64>> {
        Unit::new_normalize(self.pose.rotation.inverse() * Vector3::new(x, y, 1.0))
    }
}

/// The two cameras of a stereo pair.
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    pub left: Camera,
    pub right: Camera,
}

impl Rig {
    /// The right camera's pose relative to the left: p_right = R p_left + T (OpenCV's R, T).
    pub fn right_from_left(&self) -> CamFromWorld {
        let (l, r) = (&self.left.pose, &self.right.pose);
        let rotation = r.rotation * l.rotation.inverse();
        CamFromWorld {
            rotation,
            translation: r.translation - rotation * l.translation,
        }
    }

    /// The rig as OpenCV describes it (what a perfect calibration would return).
    pub fn stereo(&self) -> crate::stereo::StereoRig {
        let rl = self.right_from_left();
        let r = rl.rotation.matrix();
        let cam = |c: &Camera| crate::stereo::Intrinsics {
            k: c.k(),
            dist: c.dist.to_vec(),
        };
        crate::stereo::StereoRig {
            image_size: [self.left.width as i32, self.left.height as i32],
            left: cam(&self.left),
            right: cam(&self.right),
            r: std::array::from_fn(|k| r[(k / 3, k % 3)]),
            t: rl.translation.into(),
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
        }
    }
}

impl RigConfig {
    /// Builds the rig, varied by `seed`. The cameras sit on the hand's −y side, below the aim
    /// point, image x along hand +x and image up towards the hand's +z (the base).
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
        let mut camera = |side: f64| {
            let mut jitter = |range: f64| v * range * rng.random_range(-1.0..=1.0);
            let eye = centre
                + Vector3::new(side * self.baseline_mm / 2.0, 0.0, 0.0)
                + Vector3::new(jitter(2.0), jitter(2.0), jitter(2.0));
            let look = CamFromWorld::looking_at(eye, aim, rig_up);
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
                fx: focal,
                fy: focal * (1.0 + jitter(0.002)),
                cx: f64::from(self.width) / 2.0 - 0.5 + jitter(8.0),
                cy: f64::from(self.height) / 2.0 - 0.5 + jitter(8.0),
                dist: self.dist.map(|d| d * (1.0 + jitter(0.15))),
                pose: CamFromWorld {
                    rotation,
                    translation: -(rotation * eye.coords),
                },
            }
        };
        let left = camera(-1.0);
        let right = camera(1.0);
        Rig { left, right }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistort_inverts_distort_across_the_image() {
        let rig = RigConfig::default().build(1);
        let cam = &rig.left;
        for &(u, v) in &[(0.0, 0.0), (1279.0, 719.0), (640.0, 360.0), (100.0, 600.0)] {
            let (x, y) = cam.undistort(u, v);
            let (xd, yd) = cam.distort(x, y);
            let (u2, v2) = (cam.fx * xd + cam.cx, cam.fy * yd + cam.cy);
            assert!((u2 - u).abs() < 1e-9 && (v2 - v).abs() < 1e-9, "{u},{v}");
        }
    }

    #[test]
    fn default_rig_is_a_converging_c920_pair() {
        let rig = RigConfig::default().build(2020);
        let aim = Point3::new(0.0, 0.0, 8.0);
        for cam in [&rig.left, &rig.right] {
            assert!((cam.fx - 907.0).abs() < 15.0, "{}", cam.fx);
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
