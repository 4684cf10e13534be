//! How sure the calibration is: the standard deviation of every camera parameter, and what it
//! means for a triangulated tip.
//!
//! # Method
//! The stereo calibration minimises the reprojection error of every corner in both images over
//! θ = (the left camera's fx, fy, cx, cy, k1, k2, p1, p2, k3; the right camera's; the left → right
//! rotation and translation; each board's pose). At the minimum, with corner errors independent
//! and of one variance σ², θ's covariance is σ² (JᵀJ)⁻¹, J the Jacobian of the residuals and
//! σ² = RSS / (m − n) (m residuals, n parameters): what OpenCV's `calibrateCameraExtended`
//! reports for one camera and MATLAB's stereo app for two. OpenCV 4.6's `stereoCalibrate`
//! reports nothing of the kind, so it is computed here from the calibration it returns:
//!
//! 1. each board's pose in the left camera: `solvePnP`, then Gauss-Newton over both images'
//!    corners with the cameras fixed (`stereoCalibrate` solves the poses but does not return
//!    them);
//! 2. J by central differences of handcap's projection ([`Intrinsics::pixel`], the
//!    five-coefficient model `calibrate` fits), each rotation perturbed on its right
//!    (R = R₀ · exp(\[ω\]ₓ)), so the rotation's ω is about the left camera's axes;
//! 3. JᵀJ inverted by faer's Cholesky; the cameras' block of the inverse is their marginal
//!    covariance (the board poses are nuisance parameters).
//!
//! A camera whose intrinsics `--intrinsics` fixed has none in θ. The baseline's deviation is
//! the translation's projected on its direction. The tip's ([`PointSd`]), at the finger's
//! distance: the marker's pixels in both images held where they are and triangulated again as
//! the camera parameters move (first order, Σ = G Σ_cam Gᵀ), for the position and for a
//! displacement of 10 mm (the dataset's tips are taken from the rest position, so an error
//! common to both cancels: mostly the principal points'); and, separately, the marker's own
//! noise of 0.1 px in each image through the same triangulation. The calibration's part is the
//! same error in every frame of a session; the marker's differs from frame to frame.

use faer::linalg::solvers::DenseSolveCore;
use nalgebra::{Matrix6, Point3, Rotation3, Vector3, Vector6};
use serde::Serialize;

use super::checks::board_pose;
use super::{BoardSpec, CalibError, PairCorners};
use crate::geometry::{CamFromBoard, Intrinsics, RightFromLeft, Transform};
use crate::stereo::StereoRig;

/// The intrinsic parameters, in the order of [`ParameterSd::intrinsics`].
pub const INTRINSIC_NAMES: [&str; 9] = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"];

/// Where fx, fy, cx, cy sit in the row-major camera matrix.
const IN_K: [usize; 4] = [0, 4, 2, 5];

/// Intrinsic parameter `i` (in [`INTRINSIC_NAMES`]' order) of a camera whose distortion has
/// at least five coefficients.
pub(crate) fn intrinsic_mut(camera: &mut Intrinsics, i: usize) -> &mut f64 {
    match i {
        0..4 => &mut camera.k[IN_K[i]],
        _ => &mut camera.dist[i - 4],
    }
}

/// The step of central differences along intrinsic parameter `i`: 10⁻³ px for fx, fy, cx,
/// cy, 10⁻⁶ for a distortion coefficient.
pub(crate) fn intrinsic_step(i: usize) -> f64 {
    if i < 4 {
        1e-3
    } else {
        1e-6
    }
}

/// Intrinsic parameter `i` of a camera, zero for a distortion coefficient it does not have.
pub(super) fn intrinsic(camera: &Intrinsics, i: usize) -> f64 {
    match i {
        0..4 => camera.k[IN_K[i]],
        _ => camera.dist.get(i - 4).copied().unwrap_or(0.0),
    }
}

/// Pixels of marker noise the frame-to-frame tip deviation is given for.
pub const MARKER_NOISE_PX: f64 = 0.1;

/// Standard deviations of the cameras' parameters, however found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParameterSd {
    /// Each camera's fx, fy, cx, cy (px), k1, k2, p1, p2, k3; `None` for a camera whose
    /// intrinsics were fixed.
    pub intrinsics: [Option<[f64; 9]>; 2],
    /// T's components (mm).
    pub translation_mm: [f64; 3],
    /// The baseline |T| (mm).
    pub baseline_mm: f64,
    /// The left → right rotation about the left camera's x, y, z axes (degrees).
    pub rotation_deg: [f64; 3],
}

/// The calibration's standard deviations (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Uncertainty {
    pub parameters: ParameterSd,
    /// The corners' noise as the fit sees it: √(RSS / (m − n)), px.
    pub corner_sd_px: f64,
    /// Where the tip's deviation is evaluated (left camera, mm) …
    pub at_mm: [f64; 3],
    /// … and what that point is.
    pub at: String,
    /// The tip's deviations there.
    pub tip: PointSd,
    /// The camera parameters' covariance (free intrinsics, then ω, T), row-major.
    #[serde(skip)]
    covariance: Vec<f64>,
}

/// The parameters of the joint problem, and which cameras' intrinsics are in it.
#[derive(Clone)]
struct Params {
    cameras: [Intrinsics; 2],
    free: [bool; 2],
    rotation: Rotation3<f64>,
    translation: Vector3<f64>,
}

impl Params {
    fn new(rig: &StereoRig, free: [bool; 2]) -> Self {
        let five = |c: &Intrinsics| Intrinsics {
            k: c.k,
            dist: (4..9).map(|i| intrinsic(c, i)).collect(),
        };
        Params {
            cameras: [five(&rig.left), five(&rig.right)],
            free,
            rotation: rig.right_from_left.rotation,
            translation: rig.right_from_left.translation,
        }
    }

    /// How many camera parameters are free: 9 per free camera, then ω and T.
    fn len(&self) -> usize {
        9 * self.free.iter().filter(|&&f| f).count() + 6
    }

    /// Step for a central difference of parameter `j`.
    fn step(&self, j: usize) -> f64 {
        match self.locate(j) {
            Slot::Intrinsic(_, i) => intrinsic_step(i),
            Slot::Rotation(_) => 1e-7,
            Slot::Translation(_) => 1e-5,
        }
    }

    fn locate(&self, j: usize) -> Slot {
        let mut j = j;
        for (c, &free) in self.free.iter().enumerate() {
            if free {
                if j < 9 {
                    return Slot::Intrinsic(c, j);
                }
                j -= 9;
            }
        }
        if j < 3 {
            Slot::Rotation(j)
        } else {
            Slot::Translation(j - 3)
        }
    }

    /// These parameters with parameter `j` moved by `h`.
    fn moved(&self, j: usize, h: f64) -> Params {
        let mut p = self.clone();
        match self.locate(j) {
            Slot::Intrinsic(c, i) => *intrinsic_mut(&mut p.cameras[c], i) += h,
            Slot::Rotation(a) => {
                let mut w = Vector3::zeros();
                w[a] = h;
                p.rotation = self.rotation * Rotation3::new(w);
            }
            Slot::Translation(a) => p.translation[a] += h,
        }
        p
    }

    fn rig(&self, image_size: [i32; 2]) -> StereoRig {
        StereoRig {
            image_size,
            left: self.cameras[0].clone(),
            right: self.cameras[1].clone(),
            right_from_left: RightFromLeft::new(self.rotation, self.translation),
        }
    }

    /// Predicted minus observed corners of one view, left (x, y …) then right.
    fn residuals(
        &self,
        object: &[Point3<f64>],
        pose: &CamFromBoard,
        corners: [&[[f32; 2]]; 2],
        out: &mut Vec<f64>,
    ) {
        out.clear();
        for (side, observed) in corners.iter().enumerate() {
            for (p, c) in object.iter().zip(observed.iter()) {
                let mut x = pose.apply(p);
                if side == 1 {
                    x = Point3::from(self.rotation * x.coords + self.translation);
                }
                let px = self.cameras[side].pixel(&x).unwrap_or([f64::NAN; 2]);
                out.push(px[0] - f64::from(c[0]));
                out.push(px[1] - f64::from(c[1]));
            }
        }
    }
}

/// Where parameter j of [`Params`] sits.
enum Slot {
    Intrinsic(usize, usize),
    Rotation(usize),
    Translation(usize),
}

/// A pose moved by δ = (ω, t): its rotation by exp(ω) on its right (about its own `From`
/// axes), its translation by t. The pose steps of every least-squares fit of poses here.
pub(crate) fn stepped<To, From>(pose: &Transform<To, From>, delta: &[f64]) -> Transform<To, From> {
    Transform::new(
        pose.rotation * Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])),
        pose.translation + Vector3::new(delta[3], delta[4], delta[5]),
    )
}

/// A pose moved by `h` along its parameter `j` (ω then t, as [`stepped`]).
pub(super) fn moved<To, From>(pose: &Transform<To, From>, j: usize, h: f64) -> Transform<To, From> {
    let mut delta = [0.0; 6];
    delta[j] = h;
    stepped(pose, &delta)
}

/// The steps of central differences along a pose's parameters (rad, mm).
pub(crate) const POSE_STEP: [f64; 6] = [1e-7, 1e-7, 1e-7, 1e-5, 1e-5, 1e-5];

/// Each view's board pose in the left camera: `solvePnP` on the left corners, then Gauss-Newton
/// on both images' corners with the cameras as calibrated.
///
/// # Errors
/// An OpenCV failure.
pub fn board_poses(
    board: &BoardSpec,
    rig: &StereoRig,
    pairs: &[PairCorners],
) -> Result<Vec<CamFromBoard>, CalibError> {
    let params = Params::new(rig, [false, false]);
    let (mut r0, mut r1) = (Vec::new(), Vec::new());
    pairs
        .iter()
        .map(|pair| {
            let object = board.corners_mm(&pair.ids);
            let (l, r) = (pair.left.as_slice(), pair.right.as_slice());
            let mut pose = board_pose(board, &rig.left, pair.view(0))?;
            for _ in 0..10 {
                params.residuals(&object, &pose, [l, r], &mut r0);
                let mut jtj = Matrix6::zeros();
                let mut jtr = Vector6::zeros();
                let columns: Vec<Vec<f64>> = (0..6)
                    .map(|j| {
                        let h = POSE_STEP[j];
                        params.residuals(&object, &moved(&pose, j, h), [l, r], &mut r1);
                        let plus = r1.clone();
                        params.residuals(&object, &moved(&pose, j, -h), [l, r], &mut r1);
                        plus.iter()
                            .zip(&r1)
                            .map(|(a, b)| (a - b) / (2.0 * h))
                            .collect()
                    })
                    .collect();
                for a in 0..6 {
                    jtr[a] = dot(&columns[a], &r0);
                    for b in 0..6 {
                        jtj[(a, b)] = dot(&columns[a], &columns[b]);
                    }
                }
                let Some(step) = jtj.cholesky().map(|c| c.solve(&(-jtr))) else {
                    break;
                };
                pose = stepped(&pose, step.as_slice());
                if step.norm() < 1e-10 {
                    break;
                }
            }
            Ok(pose)
        })
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The calibration's standard deviations (module docs), the tip's at `at` (left camera, mm,
/// described by `what`). `free` says which cameras' intrinsics were solved. `None` when the
/// problem has no unique solution (JᵀJ singular) or a fixed camera's distortion is beyond the
/// five coefficients handcap's projection models.
///
/// # Errors
/// An OpenCV failure.
#[allow(clippy::too_many_arguments)]
pub fn estimate(
    board: &BoardSpec,
    rig: &StereoRig,
    free: [bool; 2],
    pairs: &[PairCorners],
    poses: &[CamFromBoard],
    at: (Vector3<f64>, String),
) -> Result<Option<Uncertainty>, CalibError> {
    if [&rig.left, &rig.right]
        .iter()
        .any(|c| c.dist.iter().skip(5).any(|&d| d != 0.0))
    {
        return Ok(None);
    }
    let params = Params::new(rig, free);
    let nc = params.len();
    let n = nc + 6 * poses.len();
    // Each view's first residual's row: four per corner both images show.
    let mut first_row = vec![0];
    for pair in pairs {
        first_row.push(first_row.last().expect("row") + 4 * pair.ids.len());
    }
    let m = *first_row.last().expect("row");
    if m <= n {
        return Ok(None);
    }
    let mut jacobian = faer::Mat::<f64>::zeros(m, n);
    let (mut base, mut plus, mut minus) = (Vec::new(), Vec::new(), Vec::new());
    let mut rss = 0.0;
    for (v, (pose, pair)) in poses.iter().zip(pairs).enumerate() {
        let object = board.corners_mm(&pair.ids);
        let corners = [pair.left.as_slice(), pair.right.as_slice()];
        let row = first_row[v];
        params.residuals(&object, pose, corners, &mut base);
        rss += dot(&base, &base);
        let mut column = |j: usize, plus: &[f64], minus: &[f64], h: f64| {
            for (i, (a, b)) in plus.iter().zip(minus).enumerate() {
                jacobian[(row + i, j)] = (a - b) / (2.0 * h);
            }
        };
        for j in 0..nc {
            let h = params.step(j);
            params
                .moved(j, h)
                .residuals(&object, pose, corners, &mut plus);
            params
                .moved(j, -h)
                .residuals(&object, pose, corners, &mut minus);
            column(j, &plus, &minus, h);
        }
        for (j, &h) in POSE_STEP.iter().enumerate() {
            params.residuals(&object, &moved(pose, j, h), corners, &mut plus);
            params.residuals(&object, &moved(pose, j, -h), corners, &mut minus);
            column(nc + 6 * v + j, &plus, &minus, h);
        }
    }
    if !rss.is_finite() {
        return Ok(None);
    }
    let sigma2 = rss / (m - n) as f64;
    // Columns scaled to unit length first: fx moves a corner by a fraction of a pixel per
    // pixel, k3 by hundreds; the scaled normal matrix is far better conditioned.
    let scale: Vec<f64> = (0..n)
        .map(|j| 1.0 / jacobian.col(j).norm_l2().max(f64::MIN_POSITIVE))
        .collect();
    for (j, s) in scale.iter().enumerate() {
        for i in 0..m {
            jacobian[(i, j)] *= s;
        }
    }
    let normal = jacobian.transpose() * &jacobian;
    let Ok(llt) = normal.llt(faer::Side::Lower) else {
        return Ok(None);
    };
    let inverse = llt.inverse();
    let covariance: Vec<f64> = (0..nc * nc)
        .map(|k| {
            let (a, b) = (k / nc, k % nc);
            sigma2 * scale[a] * inverse[(a, b)] * scale[b]
        })
        .collect();
    let sd = |j: usize| covariance[j * nc + j].max(0.0).sqrt();

    let mut intrinsics = [None, None];
    let mut offset = 0;
    for (c, slot) in intrinsics.iter_mut().enumerate() {
        if free[c] {
            *slot = Some(std::array::from_fn(|i| sd(offset + i)));
            offset += 9;
        }
    }
    let t = params.translation;
    let g = t / t.norm();
    let mut baseline_var = 0.0;
    for a in 0..3 {
        for b in 0..3 {
            baseline_var += g[a] * g[b] * covariance[(offset + 3 + a) * nc + offset + 3 + b];
        }
    }
    let mut uncertainty = Uncertainty {
        parameters: ParameterSd {
            intrinsics,
            translation_mm: std::array::from_fn(|a| sd(offset + 3 + a)),
            baseline_mm: baseline_var.max(0.0).sqrt(),
            rotation_deg: std::array::from_fn(|a| sd(offset + a).to_degrees()),
        },
        corner_sd_px: sigma2.sqrt(),
        at_mm: at.0.into(),
        at: at.1,
        tip: PointSd {
            position: [0.0; 3],
            displacement: [0.0; 3],
            marker: [0.0; 3],
        },
        covariance,
    };
    uncertainty.tip = uncertainty.point_sd(rig, &at.0)?;
    Ok(Some(uncertainty))
}

/// A triangulated point's standard deviations along the left camera's x, y, z (mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PointSd {
    /// Its position, from the calibration: the same error in every frame.
    pub position: [f64; 3],
    /// Its displacement from a point [`DISPLACEMENT_MM`] away (the largest over the three
    /// axes' directions), from the calibration: what the dataset's tips, taken from the rest
    /// position, inherit.
    pub displacement: [f64; 3],
    /// Its position, from [`MARKER_NOISE_PX`] of noise in each image's marker: frame to frame.
    pub marker: [f64; 3],
}

/// The displacement [`PointSd::displacement`] is given for (mm): about the finger's reach.
pub const DISPLACEMENT_MM: f64 = 10.0;

impl Uncertainty {
    /// A triangulated point's standard deviations at `point` (left camera, mm).
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn point_sd(&self, rig: &StereoRig, point: &Vector3<f64>) -> Result<PointSd, CalibError> {
        let free = self.parameters.intrinsics.map(|c| c.is_some());
        let params = Params::new(rig, free);
        let nc = params.len();
        let seen = |p: &Vector3<f64>| {
            let p = Point3::from(*p);
            [
                rig.left.pixel(&p),
                rig.right.pixel(&rig.right_from_left.apply(&p)),
            ]
            .map(|px| px.unwrap_or([f64::NAN; 2]))
        };
        let locate = |rig: &StereoRig, px: &[[f64; 2]; 2]| -> Result<Vector3<f64>, CalibError> {
            Ok(rig.triangulate(&[px[0]], &[px[1]])?[0])
        };
        // The point's derivative along each camera parameter, its pixels held.
        let gradient = |p: &Vector3<f64>| -> Result<Vec<Vector3<f64>>, CalibError> {
            let pixels = seen(p);
            (0..nc)
                .map(|j| {
                    let h = params.step(j);
                    let a = locate(&params.moved(j, h).rig(rig.image_size), &pixels)?;
                    let b = locate(&params.moved(j, -h).rig(rig.image_size), &pixels)?;
                    Ok((a - b) / (2.0 * h))
                })
                .collect()
        };
        let sd = |g: &[Vector3<f64>]| -> [f64; 3] {
            std::array::from_fn(|axis| {
                let mut var = 0.0;
                for i in 0..nc {
                    for j in 0..nc {
                        var += g[i][axis] * self.covariance[i * nc + j] * g[j][axis];
                    }
                }
                var.max(0.0).sqrt()
            })
        };
        let here = gradient(point)?;
        let mut displacement = [0.0f64; 3];
        for direction in 0..3 {
            let mut away = *point;
            away[direction] += DISPLACEMENT_MM;
            let there = gradient(&away)?;
            let moved: Vec<Vector3<f64>> = there.iter().zip(&here).map(|(a, b)| a - b).collect();
            for (d, s) in displacement.iter_mut().zip(sd(&moved)) {
                *d = d.max(s);
            }
        }
        // And along each pixel coordinate, the camera parameters held.
        let pixels = seen(point);
        let h = 1e-3;
        let mut marker = [0.0f64; 3];
        for k in 0..4 {
            let (mut a, mut b) = (pixels, pixels);
            a[k / 2][k % 2] += h;
            b[k / 2][k % 2] -= h;
            let g = (locate(rig, &a)? - locate(rig, &b)?) / (2.0 * h);
            for (m, g) in marker.iter_mut().zip(g.iter()) {
                *m += (MARKER_NOISE_PX * g).powi(2);
            }
        }
        Ok(PointSd {
            position: sd(&here),
            displacement,
            marker: marker.map(f64::sqrt),
        })
    }
}
