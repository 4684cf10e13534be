//! The poses of any number of cameras from the board views they share (issue 59). OpenCV 4.6
//! calibrates one camera or a pair, not a graph of them, so this is handcap's:
//!
//! 1. Each sighting (one camera's view of the board at one instant) gives the board's pose in
//!    that camera (`solvePnP` with the camera's intrinsics, [`super::checks::board_pose`]).
//! 2. Two cameras that saw the board at the same instant are tied: camera b from camera a is
//!    T_b←board · T_a←board⁻¹. Of the instants they share, the one whose relative pose carries
//!    a's boards onto b's corners best, over every shared instant, is taken. The tree of the
//!    ties with the most shared instants (a maximum spanning tree from the first camera, the
//!    world) gives each camera its starting pose, and each instant's board starts from the
//!    camera that saw most of its corners.
//! 3. Every camera's intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3, from the ones given) and
//!    pose but the first's, and every board pose, are refined together by Levenberg-Marquardt
//!    over every corner's reprojection error, with the Huber loss (a corner more than
//!    [`HUBER_PX`] off counts linearly) by iteratively reweighted least squares; then the
//!    corners farther off than [`REJECT_SIGMAS`] times the corners' pixel noise (estimated from
//!    their median distance), and than [`MIN_REJECT_PX`], are left out as wrong detections, and
//!    everything refined again without them. The views only one camera saw inform its intrinsics. As a pair's
//!    `stereoCalibrate` does, the intrinsics move with the poses: held at each camera's own
//!    calibration, their errors (a principal point a pixel off) tilt the poses by several of
//!    the poses' own deviations.
//! 4. How sure each pose is: the covariance σ² (Jᵀ W J)⁻¹ at the solution (σ² the weighted
//!    residuals' variance; the intrinsics and board poses are nuisance parameters), its
//!    cameras' blocks as each camera's rotation (°) and position (mm) standard deviations.
//!
//! A camera tied to the others by fewer than [`MIN_SHARED`] instants is named as poorly tied;
//! one tied to none is refused, by name.

use std::collections::BTreeMap;

use faer::linalg::solvers::{DenseSolveCore, Solve};
use nalgebra::{Point3, Vector3};

use super::checks::board_pose;
use super::detect::Seen;
use super::uncertainty::{intrinsic_mut, intrinsic_step, moved, stepped, POSE_STEP};
use super::{BoardSpec, CalibError, View};
use crate::geometry::{frame, CamFromBoard, CamFromWorld, Intrinsics, Transform, WorldFromBoard};
use start::{starting_poses, transfer_cost};

/// A corner this far from where the poses put it (px) counts linearly, not squared.
pub const HUBER_PX: f64 = 1.0;
/// A corner farther from where the poses put it than this many times the corners' pixel
/// noise (per axis) is a wrong detection: with Gaussian noise, one corner in 3000 lies beyond.
pub const REJECT_SIGMAS: f64 = 4.0;
/// A corner is never called a wrong detection nearer than this (px): webcam JPEG corners err
/// with heavier tails than a Gaussian's (on the arc synth, 4σ was 0.13 px and left out 2 % of
/// the corners), while a wrong detection, a corner taken for its neighbour, is a square off.
pub const MIN_REJECT_PX: f64 = 1.0;
/// Fewer shared instants than this tie a camera poorly to the others.
pub const MIN_SHARED: usize = 3;
/// A sighting with fewer corners gives no pose.
const MIN_CORNERS: usize = 6;
/// Levenberg-Marquardt's iterations at most.
const MAX_ITERATIONS: usize = 100;

/// Whether the intrinsics move with the poses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Intrinsic {
    /// Refined with the poses, from the ones given (each camera's own calibration).
    Refined,
    /// Kept as given (known from an earlier calibration).
    Given,
}

/// One camera's view of the board at one instant.
#[derive(Clone, Debug)]
pub struct Sighting {
    pub camera: usize,
    pub instant: usize,
    pub seen: Seen,
}

/// A camera's intrinsics and pose in the graph and how sure the pose is.
#[derive(Clone, Debug)]
pub struct CameraPose {
    /// Refined with the poses (five distortion coefficients).
    pub intrinsics: Intrinsics,
    /// World (the first camera's frame) → this camera.
    pub cam_from_world: CamFromWorld,
    /// Standard deviation of the rotation (°, the largest about any axis) and of the
    /// camera's position (mm, the largest along any axis); zero for the first camera.
    pub rotation_sd_deg: f64,
    pub position_sd_mm: f64,
    /// The camera's corners' reprojection RMS (px) at the solution, wrong detections left out.
    pub rms_px: f64,
    /// The instants it shares with another camera.
    pub shared: usize,
}

/// The cameras' poses.
#[derive(Clone, Debug)]
pub struct Graph {
    pub cameras: Vec<CameraPose>,
    /// Every corner's reprojection RMS (px), wrong detections left out.
    pub rms_px: f64,
    /// Corners left out as wrong detections ([`REJECT_SIGMAS`]).
    pub outliers: usize,
    /// The distance beyond which they were (px).
    pub reject_px: f64,
    /// Cameras sharing fewer than [`MIN_SHARED`] instants with the others.
    pub poorly_tied: Vec<usize>,
    /// The board's pose at each instant a camera saw it: (instant, pose).
    pub boards: Vec<(usize, WorldFromBoard)>,
    /// The covariance of the cameras' unknowns at the solution, the boards' marginalised
    /// ([`CameraCovariance`]); none when the problem does not fix them.
    pub covariance: Option<CameraCovariance>,
}

/// The covariance σ²(JᵀWJ)⁻¹ of the cameras' unknowns: every camera's nine intrinsics in
/// [`super::uncertainty::INTRINSIC_NAMES`]' order when they were refined (`per_camera` 9, else
/// 0), then every camera's pose but the first's (the world) as [`stepped`] moves it (ω, rad,
/// then t, mm).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraCovariance {
    pub per_camera: usize,
    /// Rows of the matrix.
    pub matrix: Vec<Vec<f64>>,
}

/// Why the poses were not found.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    #[error("camera {camera} shares no board view with the others: show the board to it and to another camera at the same instant")]
    Untied { camera: usize },
    #[error(transparent)]
    Calib(#[from] CalibError),
}

/// One camera's frame → another's.
type CamFromCam = Transform<frame::Camera, frame::Camera>;

/// The problem: the sightings with their board corners, the instants, the corners left out.
struct Problem<'a> {
    sightings: Vec<(&'a Sighting, Vec<Point3<f64>>)>,
    /// The instants, in order; the board pose of `instants[i]` is unknown `i`.
    instants: Vec<usize>,
    /// Corners farther off than this (px) weigh nothing.
    reject_px: f64,
}

/// The unknowns: every camera's intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3) and pose (the
/// first's fixed: it is the world) and every instant's board pose, laid out in that order.
#[derive(Clone)]
struct State {
    /// The intrinsics' unknowns per camera: 9 when they are refined, 0 when given.
    per_camera: usize,
    intrinsics: Vec<Intrinsics>,
    cameras: Vec<CamFromWorld>,
    boards: Vec<WorldFromBoard>,
}

/// One unknown of a sighting: what it moves, and where it sits among all of them.
#[derive(Clone, Copy)]
enum Unknown {
    Intrinsic(usize),
    Camera(usize),
    Board(usize),
}

impl State {
    fn unknowns(&self) -> usize {
        let n = self.cameras.len();
        self.per_camera * n + 6 * (n - 1) + 6 * self.boards.len()
    }

    /// The column of camera `c`'s first pose unknown (c > 0).
    fn pose_column(&self, c: usize) -> usize {
        self.per_camera * self.cameras.len() + 6 * (c - 1)
    }

    /// The column of board `b`'s first unknown.
    fn board_column(&self, b: usize) -> usize {
        self.pose_column(self.cameras.len()) + 6 * b
    }

    /// The unknowns sighting (`camera`, board `b`) depends on, with their columns.
    fn columns(&self, camera: usize, b: usize) -> Vec<(usize, Unknown)> {
        let first = self.per_camera * camera;
        let mut out: Vec<(usize, Unknown)> = (0..self.per_camera)
            .map(|i| (first + i, Unknown::Intrinsic(i)))
            .collect();
        if camera > 0 {
            let at = self.pose_column(camera);
            out.extend((0..6).map(|j| (at + j, Unknown::Camera(j))));
        }
        let at = self.board_column(b);
        out.extend((0..6).map(|j| (at + j, Unknown::Board(j))));
        out
    }

    /// The step of central differences along an unknown.
    fn step_of(unknown: Unknown) -> f64 {
        match unknown {
            Unknown::Intrinsic(i) => intrinsic_step(i),
            Unknown::Camera(j) | Unknown::Board(j) => POSE_STEP[j],
        }
    }

    /// The state moved by the unknowns' step `delta`.
    fn moved(&self, delta: &[f64]) -> State {
        let mut next = self.clone();
        for (c, intrinsics) in next.intrinsics.iter_mut().enumerate() {
            for i in 0..self.per_camera {
                *intrinsic_mut(intrinsics, i) += delta[self.per_camera * c + i];
            }
        }
        for c in 1..self.cameras.len() {
            let at = self.pose_column(c);
            next.cameras[c] = stepped(&self.cameras[c], &delta[at..at + 6]);
        }
        for (b, board) in next.boards.iter_mut().enumerate() {
            let at = self.board_column(b);
            *board = stepped(board, &delta[at..at + 6]);
        }
        next
    }
}

impl Problem<'_> {
    fn board_index(&self, instant: usize) -> usize {
        self.instants
            .binary_search(&instant)
            .expect("an instant seen")
    }

    /// The residuals (px, u and v of each corner) of sighting `s` under `intrinsics`,
    /// `camera` and `board`.
    fn residuals(
        &self,
        s: usize,
        (intrinsics, camera, board): (&Intrinsics, &CamFromWorld, &WorldFromBoard),
        out: &mut Vec<f64>,
    ) {
        let (sighting, corners) = &self.sightings[s];
        out.clear();
        for (p, seen) in corners.iter().zip(&sighting.seen.px) {
            let at = intrinsics.pixel(&camera.apply(&board.apply(p)));
            let [u, v] = at.unwrap_or([f64::NAN; 2]);
            out.extend([u - f64::from(seen[0]), v - f64::from(seen[1])]);
        }
    }

    /// Sighting `s`'s residuals under `state`, with `change`'s unknown (if any) moved by its `h`.
    fn residuals_of(
        &self,
        s: usize,
        state: &State,
        change: Option<(Unknown, f64)>,
        out: &mut Vec<f64>,
    ) {
        let (sighting, _) = &self.sightings[s];
        let c = sighting.camera;
        let (mut intrinsics, mut camera, mut board) = (
            std::borrow::Cow::Borrowed(&state.intrinsics[c]),
            state.cameras[c],
            state.boards[self.board_index(sighting.instant)],
        );
        match change {
            None => {}
            Some((Unknown::Intrinsic(i), h)) => *intrinsic_mut(intrinsics.to_mut(), i) += h,
            Some((Unknown::Camera(j), h)) => camera = moved(&camera, j, h),
            Some((Unknown::Board(j), h)) => board = moved(&board, j, h),
        }
        self.residuals(s, (&intrinsics, &camera, &board), out);
    }

    /// Each corner's weight and loss from its residual's length: Huber's, nothing beyond
    /// `reject_px`.
    fn huber<'r>(&self, r: &'r [f64]) -> impl Iterator<Item = (f64, f64)> + 'r {
        let reject = self.reject_px;
        let loss = |d: f64| match d <= HUBER_PX {
            true => 0.5 * d * d,
            false => HUBER_PX * (d - 0.5 * HUBER_PX),
        };
        r.chunks(2).map(move |c| {
            let d = c[0].hypot(c[1]);
            match d {
                d if d > reject => (0.0, loss(reject)),
                d if d > HUBER_PX => (HUBER_PX / d, loss(d)),
                d => (1.0, loss(d)),
            }
        })
    }

    /// The robust cost of every corner under `state` (NaN where a corner falls behind its
    /// camera).
    fn cost(&self, state: &State) -> f64 {
        let mut r = Vec::new();
        (0..self.sightings.len())
            .map(|s| {
                self.residuals_of(s, state, None, &mut r);
                self.huber(&r).map(|(_, loss)| loss).sum::<f64>()
            })
            .sum()
    }

    /// The weighted normal matrix Jᵀ W J and gradient Jᵀ W r over every unknown, W the Huber
    /// weights; the weighted squared residuals and their count.
    fn normal(&self, state: &State) -> (faer::Mat<f64>, Vec<f64>, f64, usize) {
        let n = state.unknowns();
        let mut a = faer::Mat::<f64>::zeros(n, n);
        let mut g = vec![0.0; n];
        let (mut rss, mut m) = (0.0, 0);
        let (mut base, mut plus, mut minus) = (Vec::new(), Vec::new(), Vec::new());
        for s in 0..self.sightings.len() {
            let (sighting, _) = &self.sightings[s];
            self.residuals_of(s, state, None, &mut base);
            let weights: Vec<f64> = self.huber(&base).map(|(w, _)| w).collect();
            let b = self.board_index(sighting.instant);
            let columns: Vec<(usize, Vec<f64>)> = state
                .columns(sighting.camera, b)
                .into_iter()
                .map(|(column, unknown)| {
                    let h = State::step_of(unknown);
                    self.residuals_of(s, state, Some((unknown, h)), &mut plus);
                    self.residuals_of(s, state, Some((unknown, -h)), &mut minus);
                    let d = plus.iter().zip(&minus).map(|(p, q)| (p - q) / (2.0 * h));
                    (column, d.collect())
                })
                .collect();
            let weigh = |i: usize| weights[i / 2];
            for (c1, j1) in &columns {
                g[*c1] += j1
                    .iter()
                    .enumerate()
                    .map(|(i, x)| weigh(i) * x * base[i])
                    .sum::<f64>();
                for (c2, j2) in &columns {
                    a[(*c1, *c2)] += (0..j1.len()).map(|i| weigh(i) * j1[i] * j2[i]).sum::<f64>();
                }
            }
            rss += base
                .iter()
                .enumerate()
                .map(|(i, r)| weigh(i) * r * r)
                .sum::<f64>();
            m += 2 * weights.iter().filter(|&&w| w > 0.0).count();
        }
        (a, g, rss, m)
    }

    /// The corners' pixel noise per axis (px), robustly: the median distance of a corner
    /// from where `state` puts it is 1.1774 (√(2 ln 2)) times it under Gaussian noise.
    fn pixel_noise(&self, state: &State) -> f64 {
        let mut r = Vec::new();
        let mut distances: Vec<f64> = Vec::new();
        for s in 0..self.sightings.len() {
            self.residuals_of(s, state, None, &mut r);
            distances.extend(r.chunks(2).map(|c| c[0].hypot(c[1])));
        }
        crate::stats::median(&mut distances).unwrap_or(f64::NAN) / (2.0 * 2f64.ln()).sqrt()
    }

    /// Levenberg-Marquardt from `state` (module docs, step 3), on the unknowns scaled to the
    /// normal matrix's unit diagonal (a focal length moves a corner by a fraction of a pixel
    /// per pixel, k3 by hundreds).
    fn refine(&self, mut state: State) -> State {
        let mut cost = self.cost(&state);
        let mut lambda = 1e-3;
        for _ in 0..MAX_ITERATIONS {
            let (a, g, _, _) = self.normal(&state);
            let n = g.len();
            let scale: Vec<f64> = (0..n).map(|j| 1.0 / a[(j, j)].max(1e-30).sqrt()).collect();
            let mut improved = false;
            while lambda < 1e12 {
                let damped = faer::Mat::<f64>::from_fn(n, n, |i, j| {
                    scale[i] * a[(i, j)] * scale[j] + if i == j { lambda } else { 0.0 }
                });
                let Ok(llt) = damped.llt(faer::Side::Lower) else {
                    lambda *= 10.0;
                    continue;
                };
                let rhs = faer::Mat::<f64>::from_fn(n, 1, |j, _| -g[j] * scale[j]);
                let solved = llt.solve(&rhs);
                let delta: Vec<f64> = (0..n).map(|j| solved[(j, 0)] * scale[j]).collect();
                let moved = state.moved(&delta);
                let moved_cost = self.cost(&moved);
                if moved_cost < cost {
                    let gain = (cost - moved_cost) / cost.max(f64::MIN_POSITIVE);
                    (state, cost, lambda) = (moved, moved_cost, (lambda / 3.0).max(1e-9));
                    improved = gain > 1e-12;
                    break;
                }
                lambda *= 4.0;
            }
            if !improved {
                break;
            }
        }
        state
    }
}

/// The cameras' poses and intrinsics from their sightings of `board` (module docs); `cameras`
/// are the intrinsics to start from (each camera's own calibration) or to keep, as
/// `intrinsics` says, indexed by [`Sighting::camera`].
///
/// # Errors
/// [`GraphError::Untied`] for a camera tied to the first by no chain of shared instants;
/// an OpenCV failure.
pub fn calibrate(
    board: &BoardSpec,
    cameras: &[Intrinsics],
    intrinsics: Intrinsic,
    sightings: &[Sighting],
) -> Result<Graph, GraphError> {
    let used: Vec<&Sighting> = sightings
        .iter()
        .filter(|s| s.seen.ids.len() >= MIN_CORNERS && s.camera < cameras.len())
        .collect();
    let mut seen_in: Vec<CamFromBoard> = Vec::with_capacity(used.len());
    for s in &used {
        let view = View {
            ids: &s.seen.ids,
            px: &s.seen.px,
        };
        seen_in.push(board_pose(board, &cameras[s.camera], view)?);
    }
    // Each instant's sightings (indices into `used`), each camera at most once.
    let mut by_instant: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (i, s) in used.iter().enumerate() {
        by_instant.entry(s.instant).or_default().push(i);
    }
    let mut problem = Problem {
        sightings: by_instant
            .values()
            .flatten()
            .map(|&i| (used[i], board.corners_mm(&used[i].seen.ids)))
            .collect(),
        instants: by_instant.keys().copied().collect(),
        reject_px: f64::INFINITY,
    };
    let shared: Vec<usize> = (0..cameras.len())
        .map(|c| {
            let tied = |l: &&Vec<usize>| l.len() >= 2 && l.iter().any(|&i| used[i].camera == c);
            by_instant.values().filter(tied).count()
        })
        .collect();
    let mut start = starting_poses(cameras, &by_instant, &used, &seen_in, |a, b, pose| {
        transfer_cost(
            board,
            &cameras[b],
            &by_instant,
            &used,
            &seen_in,
            (a, b),
            pose,
        )
    })?;
    start.per_camera = match intrinsics {
        Intrinsic::Refined => 9,
        Intrinsic::Given => 0,
    };
    let state = problem.refine(start);
    problem.reject_px = (REJECT_SIGMAS * problem.pixel_noise(&state)).max(MIN_REJECT_PX);
    let state = problem.refine(state);
    Ok(summarise(&problem, &state, shared))
}

/// The graph's figures at the solution (module docs, step 4).
fn summarise(problem: &Problem<'_>, state: &State, shared: Vec<usize>) -> Graph {
    let n = state.cameras.len();
    let (a, _, rss, m) = problem.normal(state);
    let unknowns = state.unknowns();
    let sigma2 = rss / (m.saturating_sub(unknowns)).max(1) as f64;
    // (Jᵀ W J)⁻¹ through the matrix scaled to a unit diagonal, far better conditioned.
    let scale: Vec<f64> = (0..unknowns)
        .map(|j| 1.0 / a[(j, j)].max(1e-30).sqrt())
        .collect();
    let scaled =
        faer::Mat::<f64>::from_fn(unknowns, unknowns, |i, j| scale[i] * a[(i, j)] * scale[j]);
    let inverse = scaled.llt(faer::Side::Lower).ok().map(|llt| llt.inverse());
    let (mut squares, mut counts, mut outliers) = (vec![0.0; n], vec![0usize; n], 0);
    let mut r = Vec::new();
    for (s, (sighting, _)) in problem.sightings.iter().enumerate() {
        problem.residuals_of(s, state, None, &mut r);
        for c in r.chunks(2) {
            let d2 = c[0] * c[0] + c[1] * c[1];
            if d2 > problem.reject_px * problem.reject_px {
                outliers += 1;
            } else {
                squares[sighting.camera] += d2;
                counts[sighting.camera] += 1;
            }
        }
    }
    let covariance = inverse.as_ref().map(|inv| {
        let k = state.pose_column(n);
        CameraCovariance {
            per_camera: state.per_camera,
            matrix: (0..k)
                .map(|i| {
                    (0..k)
                        .map(|j| sigma2 * scale[i] * inv[(i, j)] * scale[j])
                        .collect()
                })
                .collect(),
        }
    });
    let cameras = (0..n)
        .map(|c| {
            let cam = state.cameras[c];
            let (rotation_sd_deg, position_sd_mm) = match (&inverse, c) {
                (Some(inv), c) if c > 0 => {
                    let o = state.pose_column(c);
                    let cov = |i: usize, j: usize| {
                        sigma2 * scale[o + i] * inv[(o + i, o + j)] * scale[o + j]
                    };
                    let sd = |i: usize| cov(i, i).max(0.0).sqrt();
                    let position = position_covariance(&cam, cov);
                    let largest = |v: [f64; 3]| v.into_iter().fold(0.0, f64::max);
                    (
                        largest([0, 1, 2].map(sd)).to_degrees(),
                        largest(position.map(|v| v.max(0.0).sqrt())),
                    )
                }
                _ => (0.0, 0.0),
            };
            CameraPose {
                intrinsics: state.intrinsics[c].clone(),
                cam_from_world: cam,
                rotation_sd_deg,
                position_sd_mm,
                rms_px: (squares[c] / counts[c].max(1) as f64).sqrt(),
                shared: shared[c],
            }
        })
        .collect();
    let total: f64 = squares.iter().sum();
    let count: usize = counts.iter().sum();
    Graph {
        cameras,
        rms_px: (total / count.max(1) as f64).sqrt(),
        outliers,
        reject_px: problem.reject_px,
        boards: problem
            .instants
            .iter()
            .copied()
            .zip(state.boards.iter().copied())
            .collect(),
        poorly_tied: (0..n).filter(|&c| shared[c] < MIN_SHARED).collect(),
        covariance,
    }
}

/// The variance of the camera centre's coordinates (mm²), first order from the pose's
/// covariance `cov` over (ω, t) as [`stepped`] moves them.
fn position_covariance(pose: &CamFromWorld, cov: impl Fn(usize, usize) -> f64) -> [f64; 3] {
    let centre = |p: &CamFromWorld| p.centre().coords;
    let base = centre(pose);
    let columns: Vec<Vector3<f64>> = (0..6)
        .map(|j| {
            let mut delta = [0.0; 6];
            delta[j] = POSE_STEP[j];
            (centre(&stepped(pose, &delta)) - base) / POSE_STEP[j]
        })
        .collect();
    std::array::from_fn(|k| {
        (0..6)
            .flat_map(|i| (0..6).map(move |j| (i, j)))
            .map(|(i, j)| columns[i][k] * cov(i, j) * columns[j][k])
            .sum()
    })
}

#[path = "graph/start.rs"]
mod start;

#[cfg(test)]
#[path = "graph/tests.rs"]
mod tests;
