//! Renders what a webcam of the virtual rig sees: a printed board (chessboard or ChArUco), or
//! the finger with its red tip bead, over an unevenly lit background.
//!
//! Every pixel is the mean of S × S samples (S = 4) inside it: anti-aliasing by supersampling. Each
//! sample's ray comes from inverting the lens distortion exactly (Newton, see `Camera::undistort`)
//! at the pixel corners and interpolating bilinearly inside the pixel — the distortion is so smooth
//! that this differs from inverting at every sample by under 2·10⁻⁴ px (a test checks it). Then, in
//! order ([`super::canvas::Canvas::develop`]): mild defocus (a Gaussian of σ = 0.7 px), the
//! exposure gain, sensor noise (read noise 0.4 DN plus shot noise, σ² = 0.4² + 0.004·I, drawn from
//! a counter-based hash of the seed, the image and the pixel, so parallel rendering is
//! deterministic), and rounding to 8 bits.
//!
//! Scene: the finger is a tube of radius 1.6 mm (the 5.0 × 2.6 mm section's mean half-size) along
//! the plant's centre line, pale silicone, with a rounded end; a matte red bead of radius 0.6 mm
//! sits on that end with its centre at the plant's tip, which is the point the pipeline tracks.
//! Shading is Lambertian under a light at the camera (a ring light), so the bead's image is
//! symmetric about its centre's projection. The board is printed black on white paper with a
//! one-square white margin (a ChArUco board's markers bit by bit, as OpenCV lays them). Paper,
//! finger and background share one illumination field (a horizontal gradient, a soft hot spot and
//! vignetting, drawn from the seed).

use std::sync::Mutex;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::camera::Camera;
use super::canvas::{splitmix, uniform, Canvas, Rect};
use super::scene::{ray_segment_gap, Board, Cell, Finger, BEAD, BEAD_RADIUS_MM, FINGER_RADIUS_MM};

/// Samples per pixel side.
pub const SUPERSAMPLING: usize = 4;

const BACKDROP: [f64; 3] = [0.47, 0.48, 0.50];
/// Ambient share of the lighting.
const AMBIENT: f64 = 0.35;

/// A camera prepared for rendering: its rays at every pixel corner, its illumination field and
/// what it sees behind the finger.
pub struct View {
    pub camera: Camera,
    /// Normalised undistorted (x, y) at pixel corners, (width + 1) × (height + 1), row-major.
    corners: Vec<[f64; 2]>,
    /// Illumination (0-255 for a white surface) at pixel centres.
    light: Vec<f32>,
    /// The background alone, RGB, as the camera sees it.
    backdrop: Vec<f32>,
    eye: Point3<f64>,
    specular: f64,
    /// Canvases developed and handed back ([`View::recycle`]): the next frames draw on them,
    /// restoring only what was drawn, instead of copying the whole backdrop each time.
    spare: Mutex<Vec<Canvas>>,
}

/// What a view shows besides the finger and the boards, and how the bead shines.
#[derive(Clone, Debug, Default)]
pub struct Surroundings {
    /// Albedo image (RGB, 0-1, row-major) of the wall behind the finger
    /// ([`super::clutter::wall`]); `None`: a plain grey backdrop.
    pub wall: Option<Vec<f64>>,
    /// Strength of the highlight a room lamp makes on the bead (0: matte).
    pub specular: f64,
}

/// Direction towards the room lamp that makes the bead's highlight (hand frame: above, in
/// front of the finger and to the right; the cameras look up at the finger from below).
const LAMP: [f64; 3] = [0.35, -0.75, 0.55];
/// Blinn-Phong exponent of the bead's highlight.
const SHININESS: i32 = 40;
/// Defocus of the wall (σ, px): it stands far behind the finger the cameras focus on.
const WALL_BLUR_PX: f64 = 3.5;

/// Parameters of the illumination field (drawn from the seed).
#[derive(Clone, Copy, Debug)]
pub struct Lighting {
    pub level: f64,
    pub gradient: f64,
    pub spot: [f64; 2],
    pub spot_gain: f64,
    pub vignetting: f64,
}

impl Lighting {
    pub fn from_seed(seed: u64) -> Self {
        let u = |k: u64| uniform(splitmix(seed ^ 0x4c49_4748), k);
        Lighting {
            level: 215.0 + 20.0 * u(0),
            gradient: 0.12 * (2.0 * u(1) - 1.0),
            spot: [0.2 + 0.6 * u(2), 0.2 + 0.6 * u(3)],
            spot_gain: 0.10 + 0.08 * u(4),
            vignetting: 0.22 + 0.08 * u(5),
        }
    }

    /// Illumination at normalised image position (s, t) ∈ [0, 1]².
    fn at(&self, s: f64, t: f64) -> f64 {
        let r2 = (s - 0.5).powi(2) + (t - 0.5).powi(2);
        let d2 = (s - self.spot[0]).powi(2) + (t - self.spot[1]).powi(2);
        self.level
            * (1.0 + self.gradient * (s - 0.5))
            * (1.0 + self.spot_gain * (-d2 / 0.08).exp())
            * (1.0 - self.vignetting * r2 * 2.0)
    }
}

impl View {
    pub fn new(camera: Camera, lighting: Lighting, surroundings: Surroundings) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let corners: Vec<[f64; 2]> = (0..(w + 1) * (h + 1))
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % (w + 1), k / (w + 1));
                let (x, y) = camera.intrinsics.undistort(i as f64 - 0.5, j as f64 - 0.5);
                [x, y]
            })
            .collect();
        let light: Vec<f32> = (0..w * h)
            .map(|k| {
                let (i, j) = (k % w, k / w);
                lighting.at((i as f64 + 0.5) / w as f64, (j as f64 + 0.5) / h as f64) as f32
            })
            .collect();
        let albedo = |k: usize, c: usize| match &surroundings.wall {
            Some(wall) => wall[3 * k + c],
            None => BACKDROP[c],
        };
        let mut backdrop = Canvas {
            width: w,
            height: h,
            rgb: (0..3 * w * h)
                .map(|i| (albedo(i / 3, i % 3) * f64::from(light[i / 3])) as f32)
                .collect(),
            detail: None,
        };
        if surroundings.wall.is_some() {
            // The finger's own defocus is added where it is drawn; the 0.7 px on top of the
            // wall's 1.5 px there is a 10 % wider blur of an already soft wall.
            backdrop.blur((0, 0, w - 1, h - 1), WALL_BLUR_PX);
        }
        let eye = camera.pose.centre();
        View {
            camera,
            corners,
            light,
            backdrop: backdrop.rgb,
            eye,
            specular: surroundings.specular,
            spare: Mutex::default(),
        }
    }

    fn width(&self) -> usize {
        self.camera.width as usize
    }

    fn height(&self) -> usize {
        self.camera.height as usize
    }

    /// Normalised undistorted coordinates of a point inside pixel (i, j) at fractions (a, b).
    fn sample(&self, i: usize, j: usize, a: f64, b: f64) -> [f64; 2] {
        let w = self.width() + 1;
        let c = |di: usize, dj: usize| self.corners[(j + dj) * w + i + di];
        let (p00, p10, p01, p11) = (c(0, 0), c(1, 0), c(0, 1), c(1, 1));
        std::array::from_fn(|k| {
            (1.0 - b) * ((1.0 - a) * p00[k] + a * p10[k]) + b * ((1.0 - a) * p01[k] + a * p11[k])
        })
    }

    fn ray(&self, i: usize, j: usize, a: f64, b: f64) -> Vector3<f64> {
        let [x, y] = self.sample(i, j, a, b);
        self.camera.ray_direction(x, y).into_inner()
    }

    /// The background alone: a spare canvas with what was drawn on it restored, or a copy.
    pub fn backdrop(&self) -> Canvas {
        let spare = self.spare.lock().map_or(None, |mut spare| spare.pop());
        let Some(mut canvas) = spare else {
            return Canvas {
                width: self.width(),
                height: self.height(),
                rgb: self.backdrop.clone(),
                detail: None,
            };
        };
        if let Some((x0, y0, x1, y1)) = canvas.detail.take() {
            let w = self.width();
            for y in y0..=y1 {
                let row = 3 * (y * w + x0)..3 * (y * w + x1 + 1);
                canvas.rgb[row.clone()].copy_from_slice(&self.backdrop[row]);
            }
        }
        canvas
    }

    /// Takes back a canvas of this view once developed, for a later frame to draw on.
    pub fn recycle(&self, canvas: Canvas) {
        if let Ok(mut spare) = self.spare.lock() {
            spare.push(canvas);
        }
    }

    /// A board over the background.
    pub fn board(&self, board: &Board) -> Canvas {
        let mut canvas = self.backdrop();
        let (w, h) = (self.width(), self.height());
        canvas.detail = Some((0, 0, w - 1, h - 1));
        // The board in camera coordinates: a ray (x, y, 1) meets its plane at t = n·o / n·ray.
        let cam_from_board = board.pose.then(&self.camera.pose);
        let (to_cam, origin) = (cam_from_board.rotation, cam_from_board.translation);
        let normal = to_cam * Vector3::z();
        let reach = normal.dot(&origin);
        let cell_of = |[x, y]: [f64; 2]| -> Option<Cell> {
            let ray = Vector3::new(x, y, 1.0);
            let t = reach / normal.dot(&ray);
            if !(t > 0.0 && t.is_finite()) {
                return None;
            }
            let local = to_cam.inverse() * (ray * t - origin);
            Some(board.cell(local.x, local.y))
        };
        // The cell under every pixel corner. A pixel whose four corners share a cell lies
        // inside it (cells are convex), so only pixels on an edge need their samples.
        let corners: Vec<Option<Cell>> = self.corners.par_iter().map(|&c| cell_of(c)).collect();
        canvas
            .rgb
            .par_chunks_mut(3 * w)
            .enumerate()
            .for_each(|(j, row)| {
                let at = |i: usize, dj: usize| corners[(j + dj) * (w + 1) + i];
                for i in 0..w {
                    let cell = at(i, 0);
                    let uniform = cell == at(i + 1, 0) && cell == at(i, 1) && cell == at(i + 1, 1);
                    let (albedo, share) = if uniform {
                        match cell.and_then(|c| board.albedo(c)) {
                            Some(albedo) => (albedo, 1.0),
                            None => continue,
                        }
                    } else {
                        let mut sum = [0.0; 3];
                        let mut hits = 0;
                        for_samples(|a, b| {
                            if let Some(albedo) =
                                cell_of(self.sample(i, j, a, b)).and_then(|c| board.albedo(c))
                            {
                                for k in 0..3 {
                                    sum[k] += albedo[k];
                                }
                                hits += 1;
                            }
                        });
                        if hits == 0 {
                            continue;
                        }
                        (
                            sum.map(|v| v / hits as f64),
                            hits as f64 / (SUPERSAMPLING * SUPERSAMPLING) as f64,
                        )
                    };
                    let light = f64::from(self.light[j * w + i]);
                    for k in 0..3 {
                        let px = &mut row[3 * i + k];
                        *px = (share * albedo[k] * light + (1.0 - share) * f64::from(*px)) as f32;
                    }
                }
            });
        canvas
    }

    /// The finger (tube along its axis, bead at its tip) over the background, moving through
    /// `poses` during the exposure: sample k of a pixel's S × S sees pose k mod `poses.len()`
    /// (motion blur; one pose for a still finger).
    pub fn finger(&self, poses: &[Finger]) -> Canvas {
        let mut canvas = self.backdrop();
        let boxes = self.piece_boxes(poses);
        let Some((x0, y0, x1, y1)) = self.region(&boxes) else {
            return canvas;
        };
        canvas.detail = Some((x0, y0, x1, y1));
        let w = self.width();
        let lamp = Vector3::from(LAMP).normalize();
        canvas.rgb[3 * w * y0..3 * w * (y1 + 1)]
            .par_chunks_mut(3 * w)
            .enumerate()
            .for_each(|(dj, row)| {
                let j = y0 + dj;
                let in_row = row_boxes(&boxes, j);
                let mut pieces: Vec<Vec<usize>> = vec![Vec::new(); poses.len()];
                for i in x0..=x1 {
                    let centre = self.ray(i, j, 0.5, 0.5);
                    let covered = self.pieces_near(poses, &in_row, i, &centre, &mut pieces);
                    if pieces.iter().all(Vec::is_empty) {
                        continue;
                    }
                    let (sum, hits) = self.seen(poses, &pieces, covered, &centre, [i, j], &lamp);
                    if hits == 0 {
                        continue;
                    }
                    let light = f64::from(self.light[j * w + i]);
                    let share = if covered {
                        1.0
                    } else {
                        hits as f64 / (SUPERSAMPLING * SUPERSAMPLING) as f64
                    };
                    for k in 0..3 {
                        let surface = sum[k] / hits as f64 * light;
                        let px = &mut row[3 * i + k];
                        *px = (share * surface + (1.0 - share) * f64::from(*px)) as f32;
                    }
                }
            });
        canvas
    }

    /// Per pose, the pixel box of every piece (capsules, then the bead): a sample tests only
    /// the pieces whose box holds its pixel.
    fn piece_boxes(&self, poses: &[Finger]) -> Vec<Vec<Option<[f64; 4]>>> {
        poses
            .iter()
            .map(|finger| {
                let mut b: Vec<Option<[f64; 4]>> = finger
                    .axis
                    .windows(2)
                    .map(|s| self.pixel_box(s, FINGER_RADIUS_MM))
                    .collect();
                b.push(self.pixel_box(&[finger.tip], BEAD_RADIUS_MM));
                b
            })
            .collect()
    }

    /// The pixels (x0, y0, x1, y1, inclusive) the boxes cover in the image; `None` when they
    /// miss it.
    fn region(&self, boxes: &[Vec<Option<[f64; 4]>>]) -> Option<(usize, usize, usize, usize)> {
        let bounds = boxes.iter().flatten().flatten().copied().reduce(|a, b| {
            [
                a[0].min(b[0]),
                a[1].min(b[1]),
                a[2].max(b[2]),
                a[3].max(b[3]),
            ]
        })?;
        let (w, h) = (self.width(), self.height());
        let clip = |v: f64, max: usize| v.clamp(0.0, max as f64 - 1.0) as usize;
        if bounds[2] < 0.0 || bounds[3] < 0.0 || bounds[0] >= w as f64 || bounds[1] >= h as f64 {
            return None;
        }
        Some((
            clip(bounds[0], w),
            clip(bounds[1], h),
            clip(bounds[2], w),
            clip(bounds[3], h),
        ))
    }

    /// Per pose, the pieces the pixel (`i`, its row's) may see, into `pieces`: a piece can be
    /// hit inside the pixel only if the pixel's centre ray passes within its radius plus the
    /// pixel's half-diagonal at that depth; every ray through the pixel hits it if the centre
    /// ray passes within its radius minus that. True when every ray sees the tube of every
    /// pose, away from the bead (the pixel is covered).
    fn pieces_near(
        &self,
        poses: &[Finger],
        in_row: &[Vec<(usize, [f64; 4])>],
        i: usize,
        centre: &Vector3<f64>,
        pieces: &mut [Vec<usize>],
    ) -> bool {
        let (left, right) = (i as f64 - 0.5, i as f64 + 0.5);
        let mut covered = true;
        for ((finger, in_row), pieces) in poses.iter().zip(in_row).zip(pieces) {
            let bead = finger.axis.len() - 1;
            let mut inside = false;
            let mut near = |k: usize| {
                let (a, b, r) = if k == bead {
                    (finger.tip, finger.tip, BEAD_RADIUS_MM)
                } else {
                    (finger.axis[k], finger.axis[k + 1], FINGER_RADIUS_MM)
                };
                let (gap, depth) = ray_segment_gap(&self.eye, centre, &a, &b);
                let margin = 1.2 * depth.max(0.0) / self.camera.intrinsics.fx();
                inside |= k != bead && gap <= r - margin;
                gap <= r + margin
            };
            pieces.clear();
            pieces.extend(
                in_row
                    .iter()
                    .filter(|(_, b)| b[0] <= right && b[2] >= left)
                    .map(|&(k, _)| k)
                    .filter(|&k| near(k)),
            );
            covered &= inside && !pieces.contains(&bead);
        }
        covered
    }

    /// The shaded colours the pixel's rays see of the finger, summed, and how many hit it: the
    /// centre ray of each pose for a covered pixel (the shading varies slowly there), else the S × S
    /// samples, sample k seeing pose k mod `poses.len()`.
    fn seen(
        &self,
        poses: &[Finger],
        pieces: &[Vec<usize>],
        covered: bool,
        centre: &Vector3<f64>,
        [i, j]: [usize; 2],
        lamp: &Vector3<f64>,
    ) -> ([f64; 3], usize) {
        // What one ray sees of the finger (tube or bead), shaded.
        let surface = |pose: usize, d: &Vector3<f64>| {
            let finger = &poses[pose];
            let bead = finger.axis.len() - 1;
            let (normal, albedo) = finger.hit(&self.eye, d, &pieces[pose], bead)?;
            let shade = AMBIENT + (1.0 - AMBIENT) * (-normal.dot(d)).max(0.0);
            let shine = if albedo == BEAD && self.specular > 0.0 {
                let half = (lamp - d).normalize();
                self.specular * normal.dot(&half).max(0.0).powi(SHININESS)
            } else {
                0.0
            };
            Some(albedo.map(|a| a * shade + shine))
        };
        let mut sum = [0.0; 3];
        let mut hits = 0;
        if covered {
            for pose in 0..poses.len() {
                if let Some(colour) = surface(pose, centre) {
                    for k in 0..3 {
                        sum[k] += colour[k];
                    }
                    hits += 1;
                }
            }
        } else {
            let mut sample = 0;
            for_samples(|a, b| {
                let pose = sample % poses.len();
                sample += 1;
                if let Some(colour) = surface(pose, &self.ray(i, j, a, b)) {
                    for k in 0..3 {
                        sum[k] += colour[k];
                    }
                    hits += 1;
                }
            });
        }
        (sum, hits)
    }

    /// Something passing between the camera and the bead (a gloved finger, a tool): a dark rod
    /// 24 px thick from the image's edge to 30 px beyond `through`, at `angle` (radians).
    pub fn occlude(&self, canvas: &mut Canvas, through: [f64; 2], angle: f64) {
        const GLOVE: [f64; 3] = [0.22, 0.25, 0.31];
        const RADIUS_PX: f64 = 12.0;
        let (w, h) = (self.width(), self.height());
        let dir = [angle.cos(), angle.sin()];
        let far = (w + h) as f64;
        let (a, b) = (
            [through[0] - 30.0 * dir[0], through[1] - 30.0 * dir[1]],
            [through[0] + far * dir[0], through[1] + far * dir[1]],
        );
        let gap = |x: f64, y: f64| {
            let t = ((x - a[0]) * dir[0] + (y - a[1]) * dir[1]).clamp(0.0, far + 30.0);
            (x - a[0] - t * dir[0]).hypot(y - a[1] - t * dir[1])
        };
        let clip = |v: f64, max: usize| v.clamp(0.0, max as f64 - 1.0) as usize;
        let (x0, x1) = (
            clip(a[0].min(b[0]) - RADIUS_PX - 1.0, w),
            clip(a[0].max(b[0]) + RADIUS_PX + 1.0, w),
        );
        let (y0, y1) = (
            clip(a[1].min(b[1]) - RADIUS_PX - 1.0, h),
            clip(a[1].max(b[1]) + RADIUS_PX + 1.0, h),
        );
        let mut drawn: Option<Rect> = None;
        for j in y0..=y1 {
            for i in x0..=x1 {
                if gap(i as f64, j as f64) > RADIUS_PX + 1.0 {
                    continue;
                }
                let mut cover = 0;
                for_samples(|sa, sb| {
                    cover +=
                        usize::from(gap(i as f64 - 0.5 + sa, j as f64 - 0.5 + sb) <= RADIUS_PX);
                });
                if cover == 0 {
                    continue;
                }
                let share = cover as f64 / (SUPERSAMPLING * SUPERSAMPLING) as f64;
                let light = f64::from(self.light[j * w + i]);
                let px = &mut canvas.rgb[3 * (j * w + i)..3 * (j * w + i) + 3];
                for (px, glove) in px.iter_mut().zip(GLOVE) {
                    *px = (share * glove * light + (1.0 - share) * f64::from(*px)) as f32;
                }
                drawn = Some(match drawn {
                    None => (i, j, i, j),
                    Some(r) => (r.0.min(i), r.1.min(j), r.2.max(i), r.3.max(j)),
                });
            }
        }
        if let Some(d) = drawn {
            canvas.detail = Some(match canvas.detail {
                None => d,
                Some(r) => (r.0.min(d.0), r.1.min(d.1), r.2.max(d.2), r.3.max(d.3)),
            });
        }
    }

    /// A pixel box [u0, v0, u1, v1] holding the image of the points swollen by `radius`; `None`
    /// when a point is behind the camera. The margin is generous (the radius projected at the
    /// nearest depth, × 1.5, + 2 px) so distortion and perspective cannot push a hit outside.
    fn pixel_box(&self, points: &[Point3<f64>], radius: f64) -> Option<[f64; 4]> {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for p in points {
            let [u, v] = self.camera.project(p)?;
            let depth = self.camera.pose.apply(p).z - radius;
            if depth <= 0.0 {
                return None;
            }
            let r = radius * self.camera.intrinsics.fx() / depth * 1.5 + 2.0;
            b = [
                b[0].min(u - r),
                b[1].min(v - r),
                b[2].max(u + r),
                b[3].max(v + r),
            ];
        }
        Some(b)
    }
}

/// Calls `f(a, b)` for the S × S sample positions inside a pixel (fractions of its width).
fn for_samples(mut f: impl FnMut(f64, f64)) {
    for sb in 0..SUPERSAMPLING {
        for sa in 0..SUPERSAMPLING {
            f(
                (sa as f64 + 0.5) / SUPERSAMPLING as f64,
                (sb as f64 + 0.5) / SUPERSAMPLING as f64,
            );
        }
    }
}

/// Per pose, the pieces whose boxes reach into pixel row `j`, with their boxes.
fn row_boxes(boxes: &[Vec<Option<[f64; 4]>>], j: usize) -> Vec<Vec<(usize, [f64; 4])>> {
    let (top, bottom) = (j as f64 - 0.5, j as f64 + 0.5);
    boxes
        .iter()
        .map(|boxes| {
            boxes
                .iter()
                .enumerate()
                .filter_map(|(k, b)| b.map(|b| (k, b)))
                .filter(|(_, b)| b[1] <= bottom && b[3] >= top)
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::camera::RigConfig;
    use crate::synth::scene::capsule;

    #[test]
    fn interpolated_rays_match_exact_undistortion() {
        let rig = RigConfig::default().build(3);
        let view = View::new(
            rig.left().clone(),
            Lighting::from_seed(3),
            Surroundings::default(),
        );
        let mut worst = 0.0f64;
        for &(i, j) in &[(0, 0), (1279, 719), (640, 360), (30, 700), (1200, 15)] {
            for &(a, b) in &[(0.125, 0.125), (0.625, 0.875), (0.375, 0.5)] {
                let [x, y] = view.sample(i, j, a, b);
                let (ex, ey) = rig
                    .left()
                    .intrinsics
                    .undistort(i as f64 - 0.5 + a, j as f64 - 0.5 + b);
                worst = worst.max((x - ex).abs().max((y - ey).abs()) * rig.left().intrinsics.fx());
            }
        }
        assert!(worst < 2e-4, "interpolation error {worst} px");
    }

    #[test]
    fn ray_segment_gap_is_the_closest_distance() {
        let o = Point3::origin();
        let d = Vector3::z();
        let (gap, t) = ray_segment_gap(
            &o,
            &d,
            &Point3::new(2.0, -1.0, 5.0),
            &Point3::new(2.0, 1.0, 5.0),
        );
        assert!((gap - 2.0).abs() < 1e-12 && (t - 5.0).abs() < 1e-12);
        // The closest segment point is an end.
        let (gap, _) = ray_segment_gap(
            &o,
            &d,
            &Point3::new(1.0, 1.0, 3.0),
            &Point3::new(4.0, 4.0, 3.0),
        );
        assert!((gap - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn capsule_hits_side_and_caps() {
        let a = Point3::new(0.0, 0.0, 0.0);
        let b = Point3::new(0.0, 0.0, 10.0);
        let o = Point3::new(0.0, -20.0, 5.0);
        let (t, n) = capsule(&o, &Vector3::y(), &a, &b, 1.0).unwrap();
        assert!((t - 19.0).abs() < 1e-12 && (n - (-Vector3::y())).norm() < 1e-12);
        // Above the segment: the rounded end.
        let o = Point3::new(0.0, -20.0, 10.5);
        let (t, _) = capsule(&o, &Vector3::y(), &a, &b, 1.0).unwrap();
        assert!((t - (20.0 - (0.75f64).sqrt())).abs() < 1e-12);
        let o = Point3::new(0.0, -20.0, 11.5);
        assert!(capsule(&o, &Vector3::y(), &a, &b, 1.0).is_none());
    }
}
