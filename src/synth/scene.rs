//! The virtual scene's objects and their ray intersections: the printed board (a chessboard,
//! or a ChArUco board with its markers bit by bit) and the finger (a tube along the plant's centre line with a rounded end and the red bead). The
//! renderer ([`super::render`]) shades what these return.

use std::sync::Arc;

use nalgebra::{Point3, Vector3};

use crate::calib::{BoardSpec, Marker};
use crate::geometry::WorldFromBoard;

/// Radius of the finger's tube (mm).
pub const FINGER_RADIUS_MM: f64 = 1.6;
/// Radius of the red tip bead (mm).
pub const BEAD_RADIUS_MM: f64 = 0.6;

/// The objects' colours (linear reflectance, RGB): the finger's silicone, the bead's red, the
/// board's paper and ink.
pub(super) const SILICONE: [f64; 3] = [0.93, 0.89, 0.82];
pub(super) const BEAD: [f64; 3] = [0.80, 0.10, 0.09];
pub(super) const PAPER: [f64; 3] = [0.92, 0.92, 0.90];
pub(super) const INK: [f64; 3] = [0.08, 0.08, 0.09];

/// A printed board placed in the world.
#[derive(Clone, Debug, PartialEq)]
pub struct Board {
    pub spec: BoardSpec,
    /// Board frame → world: the origin at the first inner corner, x along a row of corners,
    /// y down the columns, z into the board.
    pub pose: WorldFromBoard,
    /// A ChArUco board's markers (none for a chessboard), shared by every pose.
    pub markers: Arc<Markers>,
}

/// A ChArUco board's markers, by square.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Markers {
    list: Vec<Marker>,
    /// The marker in each square of the board (row by row, `cols + 1` a row).
    at: Vec<Option<usize>>,
    squares_x: i64,
}

impl Markers {
    /// `spec`'s markers where OpenCV places them.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn of(spec: &BoardSpec) -> opencv::Result<Self> {
        let list = spec.markers()?;
        let squares_x = spec.cols as i64 + 1;
        let mut at = vec![None; (spec.cols + 1) * (spec.rows + 1)];
        for (k, m) in list.iter().enumerate() {
            // Squares −1 … n − 1 in cells (module docs of [`Board::cell`]).
            let (x, y) = (m.square.0 + 1, m.square.1 + 1);
            at[(y * squares_x + x) as usize] = Some(k);
        }
        Ok(Markers {
            list,
            at,
            squares_x,
        })
    }

    /// What of a marker lies under board point (x, y) mm in square (cx, cy): a bit's index
    /// (plus 1 000 when white); off the bits, which of the eight rectangles around the marker
    /// (−2 … −10); −1 in a square without a marker. Each value's region is convex.
    fn part(&self, cx: i64, cy: i64, x: f64, y: f64) -> i32 {
        let (sx, sy) = (cx + 1, cy + 1);
        let marker = (sx >= 0 && sy >= 0 && sx < self.squares_x)
            .then(|| self.at.get((sy * self.squares_x + sx) as usize).copied())
            .flatten()
            .flatten();
        let Some(m) = marker.map(|k| &self.list[k]) else {
            return -1;
        };
        let [c0, c1, _, c3] = m.corners;
        let u = (x - c0[0]) / (c1[0] - c0[0]);
        let v = (y - c0[1]) / (c3[1] - c0[1]);
        let band = |t: f64| i32::from(t >= 0.0) + i32::from(t >= 1.0);
        let (bu, bv) = (band(u), band(v));
        if (bu, bv) != (1, 1) {
            return -2 - (3 * bv + bu);
        }
        let n = m.side;
        let k = ((v * n as f64) as usize).min(n - 1) * n + ((u * n as f64) as usize).min(n - 1);
        k as i32 + if m.white[k] { 1000 } else { 0 }
    }
}

/// Where a board point lies: its square-sized cell, and what of a marker it falls on
/// ([`Markers::part`]).
pub(super) type Cell = (i64, i64, i32);

impl Board {
    /// The cell holding board coordinates (mm): cell (0, 0) has the first inner corner at its
    /// top-left. Squares, margin and paper edge all follow cell boundaries; a ChArUco board's
    /// markers divide their cells into bits.
    pub(super) fn cell(&self, x: f64, y: f64) -> Cell {
        let s = self.spec.square_mm;
        let (cx, cy) = ((x / s).floor() as i64, (y / s).floor() as i64);
        (cx, cy, self.markers.part(cx, cy, x, y))
    }

    /// Albedo of a cell; `None` off the paper. The squares span cells −1 … n − 1 (n inner
    /// corners), the one-square white margin around them is paper too; a marker's bits are
    /// ink or paper as the dictionary has them.
    pub(super) fn albedo(&self, (cx, cy, bit): Cell) -> Option<[f64; 3]> {
        let (cols, rows) = (self.spec.cols as i64, self.spec.rows as i64);
        if !(-2..=cols).contains(&cx) || !(-2..=rows).contains(&cy) {
            return None;
        }
        let on_squares = (-1..cols).contains(&cx) && (-1..rows).contains(&cy);
        let ink = if bit >= 0 {
            bit < 1000
        } else {
            // Around a marker is its white square.
            on_squares && bit == -1 && (cx + cy).rem_euclid(2) == 0
        };
        Some(if ink { INK } else { PAPER })
    }

    /// World positions of the inner corners, row by row (OpenCV's object point order).
    pub fn corners(&self) -> Vec<Point3<f64>> {
        let s = self.spec.square_mm;
        (0..self.spec.rows)
            .flat_map(|j| (0..self.spec.cols).map(move |i| (i, j)))
            .map(|(i, j)| self.at(i as f64 * s, j as f64 * s))
            .collect()
    }

    /// World positions of the paper's four outer corners.
    pub fn paper_corners(&self) -> [Point3<f64>; 4] {
        let s = self.spec.square_mm;
        let (x0, y0) = (-2.0 * s, -2.0 * s);
        let (x1, y1) = (
            (self.spec.cols + 1) as f64 * s,
            (self.spec.rows + 1) as f64 * s,
        );
        [(x0, y0), (x1, y0), (x1, y1), (x0, y1)].map(|(x, y)| self.at(x, y))
    }

    /// World position of board point (x, y) mm.
    fn at(&self, x: f64, y: f64) -> Point3<f64> {
        Point3::from(self.pose.translation) + self.pose.rotation * Vector3::new(x, y, 0.0)
    }
}

/// The finger's geometry in the world: its axis polyline and the bead's centre.
#[derive(Clone, Debug, PartialEq)]
pub struct Finger {
    /// The tube's axis, from the base to where its rounded end starts.
    pub axis: Vec<Point3<f64>>,
    pub tip: Point3<f64>,
}

impl Finger {
    /// From the plant's centre line (base → tip): the bead sits on the tip, and the tube's axis
    /// stops one tube radius plus one bead diameter short of the tip so that its rounded end
    /// touches the bead. Every `stride`-th point is kept.
    pub fn from_centre_line(line: &[[f64; 3]], stride: usize) -> Self {
        let pts: Vec<Point3<f64>> = line.iter().map(|&p| Point3::from(p)).collect();
        let tip = *pts.last().expect("centre line has points");
        let cut = FINGER_RADIUS_MM + BEAD_RADIUS_MM;
        // Walk back from the tip until `cut` of arc length is behind us.
        let mut remaining = cut;
        let mut end = pts.len() - 1;
        let mut last = tip;
        while end > 0 {
            let seg = (pts[end] - pts[end - 1]).norm();
            if seg >= remaining {
                last = pts[end] + (pts[end - 1] - pts[end]) * (remaining / seg);
                break;
            }
            remaining -= seg;
            end -= 1;
        }
        let mut axis: Vec<Point3<f64>> =
            pts[..end].iter().step_by(stride.max(1)).copied().collect();
        axis.push(last);
        Finger { axis, tip }
    }

    /// Nearest surface hit along the ray from `eye` in direction `d` among `pieces` (indices of
    /// axis segments, or `bead` for the bead): outward normal and albedo.
    pub(super) fn hit(
        &self,
        eye: &Point3<f64>,
        d: &Vector3<f64>,
        pieces: &[usize],
        bead: usize,
    ) -> Option<(Vector3<f64>, [f64; 3])> {
        let mut best: Option<(f64, Vector3<f64>, [f64; 3])> = None;
        for &k in pieces {
            let found = if k == bead {
                sphere(eye, d, &self.tip, BEAD_RADIUS_MM)
                    .map(|t| (t, (eye + d * t - self.tip).normalize(), BEAD))
            } else {
                capsule(eye, d, &self.axis[k], &self.axis[k + 1], FINGER_RADIUS_MM)
                    .map(|(t, n)| (t, n, SILICONE))
            };
            if let Some(f) = found {
                if best.as_ref().is_none_or(|b| f.0 < b.0) {
                    best = Some(f);
                }
            }
        }
        best.map(|(_, n, albedo)| (n, albedo))
    }
}

/// Distance between the ray from `o` along unit `d` and the segment a-b, and how far along the
/// ray the closest approach lies.
pub(super) fn ray_segment_gap(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
) -> (f64, f64) {
    let u = b - a;
    let w = a - o;
    let uu = u.norm_squared();
    let ud = u.dot(d);
    let denom = uu - ud * ud;
    // Parameter along the segment of the closest approach to the ray's line, clamped.
    let s = if uu < 1e-18 || denom.abs() < 1e-12 {
        0.0
    } else {
        ((ud * w.dot(d) - w.dot(&u)) / denom).clamp(0.0, 1.0)
    };
    let p = a + u * s;
    let t = (p - o).dot(d);
    ((o + d * t - p).norm(), t)
}

/// Nearest positive hit of a ray (unit `d`) with a sphere.
fn sphere(o: &Point3<f64>, d: &Vector3<f64>, c: &Point3<f64>, r: f64) -> Option<f64> {
    let oc = o - c;
    let b = oc.dot(d);
    let disc = b * b - (oc.norm_squared() - r * r);
    if disc < 0.0 {
        return None;
    }
    let t = -b - disc.sqrt();
    (t > 0.0).then_some(t)
}

/// Nearest positive hit of a ray (unit `d`) with the capsule around segment a-b, and the normal.
pub(super) fn capsule(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    r: f64,
) -> Option<(f64, Vector3<f64>)> {
    let ba = b - a;
    let oa = o - a;
    let baba = ba.norm_squared();
    let bard = ba.dot(d);
    let baoa = ba.dot(&oa);
    let rdoa = d.dot(&oa);
    let oaoa = oa.norm_squared();
    let qa = baba - bard * bard;
    let qb = baba * rdoa - baoa * bard;
    let qc = baba * oaoa - baoa * baoa - r * r * baba;
    let h = qb * qb - qa * qc;
    if h < 0.0 {
        return None;
    }
    let t = (-qb - h.sqrt()) / qa;
    let y = baoa + t * bard;
    // The cylinder's side.
    if qa > 1e-12 && y > 0.0 && y < baba && t > 0.0 {
        let p = o + d * t;
        let along = (p - a).dot(&ba) / baba;
        return Some((t, (p - (a + ba * along)).normalize()));
    }
    // One of the caps.
    let c = if y <= 0.0 { *a } else { *b };
    sphere(o, d, &c, r).map(|t| (t, (o + d * t - c).normalize()))
}
