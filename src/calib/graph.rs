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
//! 3. Every camera's pose but the first's and every board pose are refined together by
//!    Levenberg-Marquardt over every corner's reprojection error, with the Huber loss (a corner
//!    more than [`HUBER_PX`] off counts linearly) by iteratively reweighted least squares; then
//!    the corners farther off than [`REJECT_SIGMAS`] times the corners' pixel noise (estimated
//!    from their median distance) are left out as wrong detections, and the poses refined
//!    again without them. The intrinsics stay as given.
//! 4. How sure each pose is: the covariance σ² (Jᵀ W J)⁻¹ at the solution (σ² the weighted
//!    residuals' variance; the board poses are nuisance parameters), its cameras' blocks as
//!    each camera's rotation (°) and position (mm) standard deviations.
//!
//! A camera tied to the others by fewer than [`MIN_SHARED`] instants is named as poorly tied;
//! one tied to none is refused, by name.

use std::collections::BTreeMap;

use faer::linalg::solvers::{DenseSolveCore, Solve};
use nalgebra::{Point3, Rotation3, Vector3};

use super::checks::board_pose;
use super::detect::Seen;
use super::{BoardSpec, CalibError, View};
use crate::geometry::{
    frame, relative, CamFromBoard, CamFromWorld, Intrinsics, Transform, WorldFromBoard,
};

/// A corner this far from where the poses put it (px) counts linearly, not squared.
pub const HUBER_PX: f64 = 1.0;
/// A corner farther from where the poses put it than this many times the corners' pixel
/// noise (per axis) is a wrong detection: with Gaussian noise, one corner in 3000 lies beyond.
pub const REJECT_SIGMAS: f64 = 4.0;
/// Fewer shared instants than this tie a camera poorly to the others.
pub const MIN_SHARED: usize = 3;
/// A sighting with fewer corners gives no pose.
const MIN_CORNERS: usize = 6;
/// Levenberg-Marquardt's iterations at most.
const MAX_ITERATIONS: usize = 100;

/// One camera's view of the board at one instant.
#[derive(Clone, Debug)]
pub struct Sighting {
    pub camera: usize,
    pub instant: usize,
    pub seen: Seen,
}

/// A camera's pose in the graph and how sure it is.
#[derive(Clone, Debug)]
pub struct CameraPose {
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
}

/// Why the poses were not found.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    #[error("camera {camera} shares no board view with the others: show the board to it and to another camera at the same instant")]
    Untied { camera: usize },
    #[error(transparent)]
    Calib(#[from] CalibError),
}

/// A pose moved by δ = (ω, t): the rotation by exp(ω) on its right, the translation by t.
fn stepped<To, From>(pose: &Transform<To, From>, delta: &[f64]) -> Transform<To, From> {
    Transform::new(
        pose.rotation * Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])),
        pose.translation + Vector3::new(delta[3], delta[4], delta[5]),
    )
}

/// One camera's frame → another's.
type CamFromCam = Transform<frame::Camera, frame::Camera>;

const STEP: [f64; 6] = [1e-7, 1e-7, 1e-7, 1e-5, 1e-5, 1e-5];

/// The problem: the cameras, the sightings with their board corners, the unknowns' layout.
struct Problem<'a> {
    cameras: &'a [Intrinsics],
    sightings: Vec<(&'a Sighting, Vec<Point3<f64>>)>,
    /// The instants, in order; the board pose of `instants[i]` is unknown `i`.
    instants: Vec<usize>,
    /// Corners farther off than this (px) weigh nothing.
    reject_px: f64,
}

/// The unknowns: every camera's pose (the first's fixed) and every instant's board pose.
#[derive(Clone)]
struct Poses {
    cameras: Vec<CamFromWorld>,
    boards: Vec<WorldFromBoard>,
}

impl Problem<'_> {
    fn unknowns(&self) -> usize {
        6 * (self.cameras.len() - 1 + self.instants.len())
    }

    fn board_index(&self, instant: usize) -> usize {
        self.instants
            .binary_search(&instant)
            .expect("an instant seen")
    }

    /// The residuals (px, u and v of each corner) of sighting `s` under `camera` and `board`.
    fn residuals(
        &self,
        s: usize,
        camera: &CamFromWorld,
        board: &WorldFromBoard,
        out: &mut Vec<f64>,
    ) {
        let (sighting, corners) = &self.sightings[s];
        let intrinsics = &self.cameras[sighting.camera];
        out.clear();
        for (p, seen) in corners.iter().zip(&sighting.seen.px) {
            let at = intrinsics.pixel(&camera.apply(&board.apply(p)));
            let [u, v] = at.unwrap_or([f64::NAN; 2]);
            out.extend([u - f64::from(seen[0]), v - f64::from(seen[1])]);
        }
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

    /// The robust cost of every corner under `poses` (NaN where a corner falls behind its
    /// camera).
    fn cost(&self, poses: &Poses) -> f64 {
        let mut r = Vec::new();
        (0..self.sightings.len())
            .map(|s| {
                let (sighting, _) = &self.sightings[s];
                let board = &poses.boards[self.board_index(sighting.instant)];
                self.residuals(s, &poses.cameras[sighting.camera], board, &mut r);
                self.huber(&r).map(|(_, loss)| loss).sum::<f64>()
            })
            .sum()
    }

    /// The weighted normal matrix Jᵀ W J and gradient Jᵀ W r over every unknown, W the Huber
    /// weights; the weighted squared residuals and their count.
    fn normal(&self, poses: &Poses) -> (faer::Mat<f64>, Vec<f64>, f64, usize) {
        let n = self.unknowns();
        let mut a = faer::Mat::<f64>::zeros(n, n);
        let mut g = vec![0.0; n];
        let (mut rss, mut m) = (0.0, 0);
        let (mut base, mut plus, mut minus) = (Vec::new(), Vec::new(), Vec::new());
        for s in 0..self.sightings.len() {
            let (sighting, _) = &self.sightings[s];
            let b = self.board_index(sighting.instant);
            let (camera, board) = (&poses.cameras[sighting.camera], &poses.boards[b]);
            self.residuals(s, camera, board, &mut base);
            let weights: Vec<f64> = self.huber(&base).map(|(w, _)| w).collect();
            // The sighting's columns: its camera's six (none for the first), its board's six.
            let mut columns: Vec<(usize, Vec<f64>)> = Vec::new();
            for (j, &h) in STEP.iter().enumerate() {
                let mut delta = [0.0; 6];
                if sighting.camera > 0 {
                    delta[j] = h;
                    self.residuals(s, &stepped(camera, &delta), board, &mut plus);
                    delta[j] = -h;
                    self.residuals(s, &stepped(camera, &delta), board, &mut minus);
                    let col = plus.iter().zip(&minus).map(|(p, q)| (p - q) / (2.0 * h));
                    columns.push((6 * (sighting.camera - 1) + j, col.collect()));
                }
                delta[j] = h;
                self.residuals(s, camera, &stepped(board, &delta), &mut plus);
                delta[j] = -h;
                self.residuals(s, camera, &stepped(board, &delta), &mut minus);
                let col = plus.iter().zip(&minus).map(|(p, q)| (p - q) / (2.0 * h));
                columns.push((6 * (self.cameras.len() - 1 + b) + j, col.collect()));
            }
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
    /// from where `poses` put it is 1.1774 (√(2 ln 2)) times it under Gaussian noise.
    fn pixel_noise(&self, poses: &Poses) -> f64 {
        let mut r = Vec::new();
        let mut distances: Vec<f64> = Vec::new();
        for (s, (sighting, _)) in self.sightings.iter().enumerate() {
            let board = &poses.boards[self.board_index(sighting.instant)];
            self.residuals(s, &poses.cameras[sighting.camera], board, &mut r);
            distances.extend(r.chunks(2).map(|c| c[0].hypot(c[1])));
        }
        crate::stats::median(&mut distances).unwrap_or(f64::NAN) / (2.0 * 2f64.ln()).sqrt()
    }

    /// `poses` moved by the unknowns' step `delta`.
    fn step(&self, poses: &Poses, delta: &[f64]) -> Poses {
        let k = self.cameras.len() - 1;
        Poses {
            cameras: (0..poses.cameras.len())
                .map(|c| match c {
                    0 => poses.cameras[0],
                    c => stepped(&poses.cameras[c], &delta[6 * (c - 1)..6 * c]),
                })
                .collect(),
            boards: (0..poses.boards.len())
                .map(|b| stepped(&poses.boards[b], &delta[6 * (k + b)..6 * (k + b + 1)]))
                .collect(),
        }
    }

    /// Levenberg-Marquardt from `poses` (module docs, step 3).
    fn refine(&self, mut poses: Poses) -> Poses {
        let mut cost = self.cost(&poses);
        let mut lambda = 1e-3;
        for _ in 0..MAX_ITERATIONS {
            let (a, g, _, _) = self.normal(&poses);
            let n = g.len();
            let mut improved = false;
            while lambda < 1e12 {
                let mut damped = a.clone();
                for j in 0..n {
                    damped[(j, j)] += lambda * a[(j, j)].max(1e-12);
                }
                let Ok(llt) = damped.llt(faer::Side::Lower) else {
                    lambda *= 10.0;
                    continue;
                };
                let rhs = faer::Mat::<f64>::from_fn(n, 1, |j, _| -g[j]);
                let delta = llt.solve(&rhs);
                let delta: Vec<f64> = (0..n).map(|j| delta[(j, 0)]).collect();
                let moved = self.step(&poses, &delta);
                let moved_cost = self.cost(&moved);
                if moved_cost < cost {
                    let gain = (cost - moved_cost) / cost.max(f64::MIN_POSITIVE);
                    (poses, cost, lambda) = (moved, moved_cost, (lambda / 3.0).max(1e-9));
                    improved = gain > 1e-12;
                    break;
                }
                lambda *= 4.0;
            }
            if !improved {
                break;
            }
        }
        poses
    }
}

/// The cameras' poses from their sightings of `board` (module docs); `cameras` are the
/// intrinsics, indexed by [`Sighting::camera`].
///
/// # Errors
/// [`GraphError::Untied`] for a camera tied to the first by no chain of shared instants;
/// an OpenCV failure.
pub fn calibrate(
    board: &BoardSpec,
    cameras: &[Intrinsics],
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
    by_instant.retain(|_, list| list.len() >= 2);
    let problem = Problem {
        cameras,
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
            by_instant
                .values()
                .filter(|l| l.iter().any(|&i| used[i].camera == c))
                .count()
        })
        .collect();
    let start = starting_poses(cameras.len(), &by_instant, &used, &seen_in, |a, b, pose| {
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
    let mut problem = problem;
    let poses = problem.refine(start);
    problem.reject_px = REJECT_SIGMAS * problem.pixel_noise(&poses);
    let poses = problem.refine(poses);
    Ok(summarise(&problem, &poses, shared))
}

/// How far the corners camera `b` saw lie (px², summed) from a's boards carried by `b_from_a`,
/// over every instant both saw.
fn transfer_cost(
    board: &BoardSpec,
    camera_b: &Intrinsics,
    by_instant: &BTreeMap<usize, Vec<usize>>,
    used: &[&Sighting],
    seen_in: &[CamFromBoard],
    (a, b): (usize, usize),
    b_from_a: &CamFromCam,
) -> f64 {
    let mut sum = 0.0;
    for list in by_instant.values() {
        let find = |c: usize| list.iter().copied().find(|&i| used[i].camera == c);
        let (Some(i), Some(j)) = (find(a), find(b)) else {
            continue;
        };
        let carried = seen_in[i].then(b_from_a);
        let corners = board.corners_mm(&used[j].seen.ids);
        for (p, seen) in corners.iter().zip(&used[j].seen.px) {
            let [u, v] = camera_b
                .pixel(&carried.apply(p))
                .unwrap_or([f64::INFINITY; 2]);
            sum += (u - f64::from(seen[0])).powi(2) + (v - f64::from(seen[1])).powi(2);
        }
    }
    sum
}

/// The starting poses (module docs, step 2): each camera from the first along the tree of the
/// ties with the most shared instants, each tie's relative pose the shared instant's that
/// `cost` (a, b, b_from_a) finds best; each board from the camera that saw most corners of it.
fn starting_poses(
    n: usize,
    by_instant: &BTreeMap<usize, Vec<usize>>,
    used: &[&Sighting],
    seen_in: &[CamFromBoard],
    cost: impl Fn(usize, usize, &CamFromCam) -> f64,
) -> Result<Poses, GraphError> {
    let mut ties = vec![vec![0usize; n]; n];
    for list in by_instant.values() {
        for &i in list {
            for &j in list {
                ties[used[i].camera][used[j].camera] += usize::from(i != j);
            }
        }
    }
    let mut cameras: Vec<Option<CamFromWorld>> = vec![None; n];
    cameras[0] = Some(CamFromWorld::new(Rotation3::identity(), Vector3::zeros()));
    for _ in 1..n {
        // The strongest tie from a camera placed to one not yet placed.
        let best = (0..n)
            .filter(|&a| cameras[a].is_some())
            .flat_map(|a| {
                (0..n)
                    .filter(|&b| cameras[b].is_none())
                    .map(move |b| (a, b))
            })
            .filter(|&(a, b)| ties[a][b] > 0)
            .max_by_key(|&(a, b)| (ties[a][b], std::cmp::Reverse(b)));
        let Some((a, b)) = best else {
            let camera = (0..n).find(|&c| cameras[c].is_none()).expect("one left");
            return Err(GraphError::Untied { camera });
        };
        let candidates = by_instant.values().filter_map(|list| {
            let find = |c: usize| list.iter().copied().find(|&i| used[i].camera == c);
            Some(relative(&seen_in[find(a)?], &seen_in[find(b)?]))
        });
        let b_from_a = candidates
            .map(|pose| (cost(a, b, &pose), pose))
            .min_by(|x, y| x.0.total_cmp(&y.0))
            .expect("a shared instant")
            .1;
        cameras[b] = Some(cameras[a].expect("placed").then(&b_from_a));
    }
    let cameras: Vec<CamFromWorld> = cameras.into_iter().map(|c| c.expect("placed")).collect();
    let boards = by_instant
        .values()
        .map(|list| {
            let &i = list
                .iter()
                .max_by_key(|&&i| used[i].seen.ids.len())
                .expect("sighted");
            seen_in[i].then(&cameras[used[i].camera].inverse())
        })
        .collect();
    Ok(Poses { cameras, boards })
}

/// The graph's figures at the solution (module docs, step 4).
fn summarise(problem: &Problem<'_>, poses: &Poses, shared: Vec<usize>) -> Graph {
    let n = problem.cameras.len();
    let (a, _, rss, m) = problem.normal(poses);
    let sigma2 = rss / (m.saturating_sub(problem.unknowns())).max(1) as f64;
    let inverse = a.llt(faer::Side::Lower).ok().map(|llt| llt.inverse());
    let (mut squares, mut counts, mut outliers) = (vec![0.0; n], vec![0usize; n], 0);
    let mut r = Vec::new();
    for (s, (sighting, _)) in problem.sightings.iter().enumerate() {
        let board = &poses.boards[problem.board_index(sighting.instant)];
        problem.residuals(s, &poses.cameras[sighting.camera], board, &mut r);
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
    let cameras = (0..n)
        .map(|c| {
            let cam = poses.cameras[c];
            let (rotation_sd_deg, position_sd_mm) = match (&inverse, c) {
                (Some(inv), c) if c > 0 => {
                    let o = 6 * (c - 1);
                    let cov = |i: usize, j: usize| sigma2 * inv[(o + i, o + j)];
                    let sd = |i: usize| cov(i, i).max(0.0).sqrt();
                    let position = position_covariance(&cam, cov);
                    let rot = (0..3).map(sd).fold(0.0, f64::max).to_degrees();
                    (
                        rot,
                        (0..3)
                            .map(|i| position[i].max(0.0).sqrt())
                            .fold(0.0, f64::max),
                    )
                }
                _ => (0.0, 0.0),
            };
            CameraPose {
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
        poorly_tied: (0..n).filter(|&c| shared[c] < MIN_SHARED).collect(),
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
            delta[j] = STEP[j];
            (centre(&stepped(pose, &delta)) - base) / STEP[j]
        })
        .collect();
    std::array::from_fn(|k| {
        (0..6)
            .flat_map(|i| (0..6).map(move |j| (i, j)))
            .map(|(i, j)| columns[i][k] * cov(i, j) * columns[j][k])
            .sum()
    })
}

#[cfg(test)]
#[path = "graph/tests.rs"]
mod tests;
