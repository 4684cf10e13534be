//! Stereo calibration of two webcams from chessboard pairs, with the quality checks good tools
//! give. OpenCV does the work (detection, per-camera and stereo calibration, rectification);
//! this module chooses, checks and reports.
//!
//! # Steps
//!
//! 1. Pairs: `left*`/`right*` files with the same suffix ([`pairs`]); `*_ref` is the reference
//!    pair (the board at the finger's base).
//! 2. Corners in every image, in parallel ([`detect`]): the sector-based detector; if it finds
//!    fewer usable pairs than needed, the classic one for every image instead (never mixed).
//! 3. Left/right corner order: a board seen by both cameras must run the same way in both
//!    images (first → last corner, and along the first row); a right image whose corners run
//!    the other way (the 180° ambiguity of the detector) has them reversed, and the pair says
//!    so; a pair that still disagrees is rejected.
//! 4. Each camera alone (`calibrate_camera`, 5 distortion coefficients), then both together
//!    (`stereo_calibrate_extended`, starting from those intrinsics, per-pair errors).
//! 5. Outliers: while the worst pair's error exceeds both `reject_factor` × the median and
//!    `reject_floor_px`, it is dropped and the rig recalibrated, keeping at least `min_pairs`.
//! 6. Quality: RMS, mean epipolar distance of the corners (undistorted, both directions),
//!    coverage of the image by corners (share of an 8 × 6 grid of cells), the boards
//!    triangulated back (neighbouring-corner distance in squares, out-of-plane RMS), and
//!    rectification (`stereo_rectify`, zero disparity, α = 0).
//! 7. The hand frame's axes from the reference pair, when there is one: the board's pose in the
//!    left camera (`solve_pnp`), read with the board's x along hand x, its y along hand −z (down
//!    the finger) and its z along hand +y. The corners are taken in the order that makes the
//!    board's x axis point to the image's right. `R_hand` maps left-camera coordinates to the
//!    hand frame's axes; the origin (the tip at zero pressure) is found later, by
//!    `triangulate`.

pub mod detect;
pub mod pairs;

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};
use opencv::calib3d;
use opencv::core::{self, Mat, Point2f, Point3f, Size, TermCriteria, Vector};
use opencv::prelude::*;
use rayon::prelude::*;
use serde::Serialize;

use crate::cv::{self, fixed, mat, points, values};
use crate::opencv_yaml::FileStorage;
use crate::provenance::Provenance;
use crate::stereo::{Intrinsics, Side, StereoRig};
use detect::Detector;
use pairs::ImagePair;

/// Errors of calibrating.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    #[error("cannot list {path}: {source}")]
    List {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "no left*/right* image pairs (PNG or JPEG) in {0}; name them left_00.png, right_00.png, …"
    )]
    NoPairs(PathBuf),
    #[error("{0} is not an image OpenCV can read; remove it or replace it")]
    NotAnImage(PathBuf),
    #[error(
        "{left} is {lw}×{lh} but {right} is {rw}×{rh}; both cameras must capture at the same size"
    )]
    SizeMismatch {
        left: PathBuf,
        right: PathBuf,
        lw: i32,
        lh: i32,
        rw: i32,
        rh: i32,
    },
    #[error("{0} is {1}×{2} but the other images are {3}×{4}; capture every pair at one size")]
    SizeChange(PathBuf, i32, i32, i32, i32),
    #[error("no {cols}x{rows} board (inner corners) found in any image of {dir}{hint}")]
    BoardNotFound {
        dir: PathBuf,
        cols: usize,
        rows: usize,
        hint: String,
    },
    #[error("only {found} usable pairs, {needed} needed: {reasons}")]
    TooFewPairs {
        found: usize,
        needed: usize,
        reasons: String,
    },
    #[error("board: {0}")]
    BadBoard(String),
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    #[error(transparent)]
    Figure(#[from] crate::report::figures::FigureError),
    #[error("writing {path}: {message}")]
    Write { path: PathBuf, message: String },
}

/// The printed board: inner corners along a row and down a column, square size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BoardSpec {
    pub cols: usize,
    pub rows: usize,
    pub square_mm: f64,
}

impl BoardSpec {
    /// # Errors
    /// [`CalibError::BadBoard`] for fewer than 3 corners a side, equal sides (ambiguous
    /// orientation) or a square size that is not a positive number.
    pub fn check(&self) -> Result<(), CalibError> {
        if self.cols < 3 || self.rows < 3 {
            return Err(CalibError::BadBoard(format!(
                "{}x{} inner corners: at least 3 along each side",
                self.cols, self.rows
            )));
        }
        if self.cols == self.rows {
            return Err(CalibError::BadBoard(format!(
                "{}x{}: a square board has no orientation; use one with different counts",
                self.cols, self.rows
            )));
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            return Err(CalibError::BadBoard(format!(
                "square size {} mm: give the printed square's side in mm",
                self.square_mm
            )));
        }
        Ok(())
    }

    /// Object points of the inner corners (mm), row by row.
    fn object_points(&self) -> Vector<Point3f> {
        let s = self.square_mm as f32;
        (0..self.rows)
            .flat_map(|j| {
                (0..self.cols).map(move |i| Point3f::new(i as f32 * s, j as f32 * s, 0.0))
            })
            .collect()
    }
}

/// How pairs are kept or rejected.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CalibOptions {
    /// Fewest pairs the calibration may keep.
    pub min_pairs: usize,
    /// A pair is an outlier when its error exceeds this × the median …
    pub reject_factor: f64,
    /// … and this many pixels.
    pub reject_floor_px: f64,
}

impl Default for CalibOptions {
    fn default() -> Self {
        CalibOptions {
            min_pairs: 6,
            reject_factor: 3.0,
            reject_floor_px: 0.25,
        }
    }
}

/// What happened to one pair.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PairReport {
    pub name: String,
    pub left: PathBuf,
    pub right: PathBuf,
    /// Reprojection RMS in the final calibration (left, right), for used pairs.
    pub rms_px: Option<[f64; 2]>,
    /// Why it is not used, if it is not.
    pub rejected: Option<String>,
    /// Anything done to it (e.g. corners reversed).
    pub note: Option<String>,
}

/// Triangulated boards against the printed square.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BoardCheck {
    /// Mean distance of neighbouring corners, in squares (1 is perfect).
    pub neighbour_mean_squares: f64,
    pub neighbour_sd_squares: f64,
    /// RMS distance of the corners from each board's best plane (mm).
    pub planarity_rms_mm: f64,
}

/// A stereo calibration and its quality.
#[derive(Clone, Debug, Serialize)]
pub struct StereoCalibration {
    pub board: BoardSpec,
    pub detector: Detector,
    /// The image size, both cameras and the left → right pose.
    pub rig: StereoRig,
    pub e: [f64; 9],
    pub f: [f64; 9],
    pub r1: [f64; 9],
    pub r2: [f64; 9],
    pub p1: [f64; 12],
    pub p2: [f64; 12],
    pub q: [f64; 16],
    pub rms_px: f64,
    pub epipolar_px: f64,
    /// Share of an 8 × 6 grid of image cells holding corners (left, right).
    pub coverage: [f64; 2],
    pub board_check: BoardCheck,
    pub pairs: Vec<PairReport>,
    /// Images without a partner, skipped.
    pub unpaired: Vec<PathBuf>,
    /// Left-camera → hand-frame rotation from the reference pair.
    pub hand_axes: Option<[f64; 9]>,
    pub hand_axes_note: String,
}

impl StereoCalibration {
    pub fn used(&self) -> impl Iterator<Item = &PairReport> {
        self.pairs.iter().filter(|p| p.rejected.is_none())
    }

    pub fn rejected(&self) -> impl Iterator<Item = &PairReport> {
        self.pairs.iter().filter(|p| p.rejected.is_some())
    }

    /// The calibration as OpenCV FileStorage YAML (keys in the module docs of `cli::calibrate`).
    pub fn to_yaml(&self, provenance: &Provenance) -> String {
        let mut fs = FileStorage::new();
        self.rig
            .write_yaml(&mut fs)
            .matrix("E", 3, 3, &self.e)
            .matrix("F", 3, 3, &self.f)
            .matrix("R1", 3, 3, &self.r1)
            .matrix("R2", 3, 3, &self.r2)
            .matrix("P1", 3, 4, &self.p1)
            .matrix("P2", 3, 4, &self.p2)
            .matrix("Q", 4, 4, &self.q)
            .real("rms_px", self.rms_px)
            .real("epipolar_px", self.epipolar_px);
        let used: Vec<&PairReport> = self.used().collect();
        let per_view: Vec<f64> = used
            .iter()
            .flat_map(|p| p.rms_px.unwrap_or([f64::NAN; 2]))
            .collect();
        fs.matrix("per_view_rms_px", used.len(), 2, &per_view)
            .strings(
                "views_used",
                &used.iter().map(|p| p.name.clone()).collect::<Vec<_>>(),
            )
            .strings(
                "views_rejected",
                &self.rejected().map(|p| p.name.clone()).collect::<Vec<_>>(),
            )
            .int("board_cols", self.board.cols as i64)
            .int("board_rows", self.board.rows as i64)
            .real("square_mm", self.board.square_mm)
            .string("detector", self.detector.name())
            .reals("coverage", &self.coverage)
            .real(
                "board_neighbour_squares",
                self.board_check.neighbour_mean_squares,
            )
            .real("board_planarity_rms_mm", self.board_check.planarity_rms_mm);
        if let Some(axes) = &self.hand_axes {
            fs.matrix("R_hand", 3, 3, axes);
        }
        fs.string("hand_axes", &self.hand_axes_note)
            .string("handcap_version", &provenance.handcap_version)
            .string("command", &provenance.command.join(" "));
        fs.text().to_string()
    }
}

impl StereoCalibration {
    /// Writes `<stem>_pairs.png/.svg` (each used pair's left and right error, as bars) and
    /// `<stem>_rectified.png` (the first used pair rectified side by side, with horizontal
    /// lines: a point must lie on the same line in both halves). Returns the files written.
    ///
    /// # Errors
    /// [`CalibError`] when an image cannot be read or a figure written.
    pub fn write_figures(&self, stem: &Path) -> Result<Vec<PathBuf>, CalibError> {
        use crate::report::figures::{self, LinePlot, Mark, Series};
        let used: Vec<&PairReport> = self.used().collect();
        let bars = |side: usize, label: &str, offset: f64| Series {
            label: label.into(),
            points: used
                .iter()
                .enumerate()
                .map(|(k, p)| (k as f64, p.rms_px.map_or(f64::NAN, |e| e[side])))
                .collect(),
            mark: Mark::Bars {
                offset,
                width: 0.38,
            },
            colour: side,
        };
        let names: Vec<&str> = used.iter().map(|p| p.name.as_str()).collect();
        let plot = LinePlot {
            title: format!("Reprojection error per pair (RMS {:.3} px)", self.rms_px),
            x_label: format!("pair: {}", names.join(" ")),
            y_label: "RMS error (px)".into(),
            series: vec![bars(0, "left", -0.2), bars(1, "right", 0.2)],
            log_y: false,
        };
        let pairs_stem = stem.with_file_name(format!("{}_pairs", file_stem(stem)));
        figures::write_line_plot(&pairs_stem, &plot)?;
        let mut written = vec![
            pairs_stem.with_extension("png"),
            pairs_stem.with_extension("svg"),
        ];
        if let Some(first) = used.first() {
            let path = stem.with_file_name(format!("{}_rectified.png", file_stem(stem)));
            self.write_rectified(first, &path)?;
            written.push(path);
        }
        Ok(written)
    }

    fn write_rectified(&self, pair: &PairReport, path: &Path) -> Result<(), CalibError> {
        use opencv::{imgcodecs, imgproc};
        let size = Size::new(self.rig.image_size[0], self.rig.image_size[1]);
        let rectified = |image: &Path, k: &[f64; 9], d: &[f64], r: &[f64; 9], p: &[f64; 12]| {
            let src = imgcodecs::imread(
                image
                    .to_str()
                    .ok_or_else(|| CalibError::NotAnImage(image.to_path_buf()))?,
                imgcodecs::IMREAD_COLOR,
            )?;
            let (mut m1, mut m2, mut out) = (Mat::default(), Mat::default(), Mat::default());
            calib3d::init_undistort_rectify_map(
                &mat(3, k)?,
                &mat(1, d)?,
                &mat(3, r)?,
                &mat(3, p)?,
                size,
                core::CV_32FC1,
                &mut m1,
                &mut m2,
            )?;
            imgproc::remap(
                &src,
                &mut out,
                &m1,
                &m2,
                imgproc::INTER_LINEAR,
                core::BORDER_CONSTANT,
                core::Scalar::default(),
            )?;
            Ok::<Mat, CalibError>(out)
        };
        let (left, right) = (&self.rig.left, &self.rig.right);
        let l = rectified(&pair.left, &left.k, &left.dist, &self.r1, &self.p1)?;
        let r = rectified(&pair.right, &right.k, &right.dist, &self.r2, &self.p2)?;
        let mut both = Mat::default();
        let halves: Vector<Mat> = [l, r].into_iter().collect();
        core::hconcat(&halves, &mut both)?;
        for y in (20..size.height).step_by(40) {
            imgproc::line(
                &mut both,
                core::Point::new(0, y),
                core::Point::new(2 * size.width - 1, y),
                core::Scalar::new(0.0, 200.0, 0.0, 0.0),
                1,
                imgproc::LINE_8,
                0,
            )?;
        }
        let write_err = |message: String| CalibError::Write {
            path: path.to_path_buf(),
            message,
        };
        let tmp = crate::fsio::temp_beside(path, ".png").map_err(|e| write_err(e.to_string()))?;
        let tmp_name = tmp
            .path()
            .to_str()
            .ok_or_else(|| write_err("path is not UTF-8".into()))?;
        if !imgcodecs::imwrite(tmp_name, &both, &Vector::new())? {
            return Err(write_err("OpenCV could not encode the PNG".into()));
        }
        tmp.persist(path)
            .map_err(|e| write_err(e.error.to_string()))?;
        Ok(())
    }
}

fn file_stem(path: &Path) -> String {
    path.file_stem()
        .map_or_else(|| "calib".into(), |s| s.to_string_lossy().into_owned())
}

/// Corners of one image: its size and the corners if the board was found.
type Found = ([i32; 2], Option<Vec<[f32; 2]>>);

/// A pair in the calibration: its index among the reports, left and right corners.
struct Usable {
    report: usize,
    left: Vec<[f32; 2]>,
    right: Vec<[f32; 2]>,
}

/// Calibrates the rig from the pairs in `dir`; `progress(done, total)` counts images examined.
///
/// # Errors
/// [`CalibError`] for every problem a user can fix, each naming the file.
pub fn calibrate(
    dir: &Path,
    board: &BoardSpec,
    options: &CalibOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<StereoCalibration, CalibError> {
    board.check()?;
    let listing = pairs::list_pairs(dir).map_err(|source| CalibError::List {
        path: dir.to_path_buf(),
        source,
    })?;
    if listing.pairs.is_empty() {
        return Err(CalibError::NoPairs(dir.to_path_buf()));
    }
    let all: Vec<&ImagePair> = listing
        .pairs
        .iter()
        .chain(listing.reference.iter())
        .collect();
    let images: Vec<&Path> = all
        .iter()
        .flat_map(|p| [p.left.as_path(), p.right.as_path()])
        .collect();
    let grays = read_all(&images)?;

    let done = std::sync::atomic::AtomicUsize::new(0);
    let detect_all = |detector: Detector| -> Result<Vec<Found>, CalibError> {
        grays
            .par_iter()
            .map(|gray| {
                let size = gray.size()?;
                let corners =
                    detect::find_corners(gray, board.cols as i32, board.rows as i32, detector)?;
                let n = done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
                progress(n, grays.len());
                Ok(([size.width, size.height], corners))
            })
            .collect()
    };
    let complete = |found: &[Found]| {
        found[..2 * listing.pairs.len()]
            .chunks(2)
            .filter(|p| p[0].1.is_some() && p[1].1.is_some())
            .count()
    };
    let mut detector = Detector::SectorBased;
    let mut found = detect_all(detector)?;
    if complete(&found) < options.min_pairs {
        let classic = detect_all(Detector::Classic)?;
        if complete(&classic) > complete(&found) {
            detector = Detector::Classic;
            found = classic;
        }
    }
    if found.iter().all(|f| f.1.is_none()) {
        return Err(CalibError::BoardNotFound {
            dir: dir.to_path_buf(),
            cols: board.cols,
            rows: board.rows,
            hint: suggest_board(&grays, board),
        });
    }
    let size = check_sizes(&all, &found)?;

    // Pairs with the board in both images, in a consistent corner order.
    let mut reports = Vec::new();
    let mut usable: Vec<Usable> = Vec::new();
    for (k, pair) in listing.pairs.iter().enumerate() {
        let mut report = PairReport {
            name: pair.name.clone(),
            left: pair.left.clone(),
            right: pair.right.clone(),
            rms_px: None,
            rejected: None,
            note: None,
        };
        match (&found[2 * k].1, &found[2 * k + 1].1) {
            (Some(l), Some(r)) => match order_right_like_left(board, l, r) {
                Some((right, reversed)) => {
                    if reversed {
                        report.note = Some("right corners reversed to match the left".into());
                    }
                    usable.push(Usable {
                        report: reports.len(),
                        left: l.clone(),
                        right,
                    });
                }
                None => {
                    report.rejected = Some(
                        "corners run differently in the left and right images (mirrored?)".into(),
                    )
                }
            },
            (None, None) => report.rejected = Some("board not found in either image".into()),
            (None, _) => report.rejected = Some("board not found in the left image".into()),
            (_, None) => report.rejected = Some("board not found in the right image".into()),
        }
        reports.push(report);
    }
    let needed = options.min_pairs.max(3);
    if usable.len() < needed {
        return Err(too_few(&reports, usable.len(), needed));
    }

    // Pairs that contradict the rig's geometry, then the worst outlier while there is one.
    for (k, why) in inconsistent_pairs(board, size, &usable)?.into_iter().rev() {
        if usable.len() > needed {
            let dropped = usable.remove(k);
            reports[dropped.report].rejected = Some(why);
        }
    }
    let mut rig;
    loop {
        rig = stereo(board, size, &usable)?;
        let errors: Vec<f64> = rig.per_view.iter().map(|e| e[0].max(e[1])).collect();
        let mut sorted = errors.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let (worst, &err) = errors
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .expect("pairs");
        let limit = (options.reject_factor * median).max(options.reject_floor_px);
        if err <= limit || usable.len() <= needed {
            break;
        }
        let dropped = usable.remove(worst);
        reports[dropped.report].rejected = Some(format!(
            "outlier: error {err:.3} px > {:.1} × median {median:.3} px",
            options.reject_factor
        ));
    }
    for (u, e) in usable.iter().zip(&rig.per_view) {
        reports[u.report].rms_px = Some(*e);
    }

    let left: Vec<&[[f32; 2]]> = usable.iter().map(|u| u.left.as_slice()).collect();
    let right: Vec<&[[f32; 2]]> = usable.iter().map(|u| u.right.as_slice()).collect();
    let epipolar_px = epipolar_error(&rig, &left, &right)?;
    let board_check = board_check(board, &rig, &left, &right)?;
    let coverage = [coverage(size, &left), coverage(size, &right)];
    let (r1, r2, p1, p2, q) = rectify(&rig, size)?;

    // The reference pair's images follow the others' in `found`.
    let (hand_axes, hand_axes_note) = match &listing.reference {
        Some(reference) => match &found[2 * listing.pairs.len()].1 {
            Some(corners) => (
                Some(hand_axes(board, &rig, corners)?),
                format!(
                    "from the reference pair {}: board x = hand x, board y = hand -z, board z = hand +y",
                    reference.left.display()
                ),
            ),
            None => (
                None,
                format!("the board was not found in {}", reference.left.display()),
            ),
        },
        None => (None, "no reference pair (left_ref/right_ref)".into()),
    };

    Ok(StereoCalibration {
        board: *board,
        detector,
        rig: rig.cams,
        e: rig.e,
        f: rig.f,
        r1,
        r2,
        p1,
        p2,
        q,
        rms_px: rig.rms,
        epipolar_px,
        coverage,
        board_check,
        pairs: reports,
        unpaired: listing.unpaired.clone(),
        hand_axes,
        hand_axes_note,
    })
}

fn too_few(reports: &[PairReport], found: usize, needed: usize) -> CalibError {
    let reasons: Vec<String> = reports
        .iter()
        .filter_map(|r| r.rejected.as_ref().map(|why| format!("{}: {why}", r.name)))
        .collect();
    CalibError::TooFewPairs {
        found,
        needed,
        reasons: if reasons.is_empty() {
            "capture more pairs".into()
        } else {
            format!("{}; capture more pairs", reasons.join("; "))
        },
    }
}

fn read_all(images: &[&Path]) -> Result<Vec<Mat>, CalibError> {
    images.par_iter().map(|p| detect::read_gray(p)).collect()
}

/// One size for all images, and the same in each pair.
fn check_sizes(all: &[&ImagePair], found: &[Found]) -> Result<[i32; 2], CalibError> {
    let size = found[0].0;
    for (k, pair) in all.iter().enumerate() {
        let (l, r) = (found[2 * k].0, found[2 * k + 1].0);
        if l != r {
            return Err(CalibError::SizeMismatch {
                left: pair.left.clone(),
                right: pair.right.clone(),
                lw: l[0],
                lh: l[1],
                rw: r[0],
                rh: r[1],
            });
        }
        if l != size {
            return Err(CalibError::SizeChange(
                pair.left.clone(),
                l[0],
                l[1],
                size[0],
                size[1],
            ));
        }
    }
    Ok(size)
}

/// Other board sizes that are found in the first few images, as a hint.
fn suggest_board(grays: &[Mat], board: &BoardSpec) -> String {
    let (c, r) = (board.cols as i32, board.rows as i32);
    let candidates = [
        (r, c),
        (c - 1, r - 1),
        (c + 1, r + 1),
        (c - 1, r),
        (c + 1, r),
        (c, r - 1),
        (c, r + 1),
    ];
    for (cols, rows) in candidates {
        if cols < 3 || rows < 3 || cols == rows {
            continue;
        }
        let works = grays.iter().take(4).any(|g| {
            matches!(
                detect::find_corners(g, cols, rows, Detector::SectorBased),
                Ok(Some(_))
            )
        });
        if works {
            let why = if (cols, rows) == (r, c) {
                "columns and rows swapped"
            } else if (cols, rows) == (c - 1, r - 1) {
                "squares counted instead of inner corners"
            } else {
                "a different count"
            };
            return format!("; a {cols}x{rows} board is found ({why}): pass --board {cols}x{rows}");
        }
    }
    "; no nearby size (transposed, ±1) is found either: check the images show the whole board with a white border".into()
}

/// The right image's corners in the left image's order: as detected, or reversed when they
/// run the other way (first → last corner and along the first row). `None` when neither order
/// agrees.
fn order_right_like_left(
    board: &BoardSpec,
    left: &[[f32; 2]],
    right: &[[f32; 2]],
) -> Option<(Vec<[f32; 2]>, bool)> {
    let n = left.len();
    let dir = |c: &[[f32; 2]], a: usize, b: usize| [c[b][0] - c[a][0], c[b][1] - c[a][1]];
    let dot = |u: [f32; 2], v: [f32; 2]| u[0] * v[0] + u[1] * v[1];
    let agrees = |r: &[[f32; 2]]| {
        dot(dir(left, 0, n - 1), dir(r, 0, n - 1)) > 0.0
            && dot(dir(left, 0, board.cols - 1), dir(r, 0, board.cols - 1)) > 0.0
    };
    if agrees(right) {
        return Some((right.to_vec(), false));
    }
    let reversed: Vec<[f32; 2]> = right.iter().rev().copied().collect();
    agrees(&reversed).then_some((reversed, true))
}

/// The OpenCV results of one stereo calibration.
struct Rig {
    cams: StereoRig,
    e: [f64; 9],
    f: [f64; 9],
    rms: f64,
    per_view: Vec<[f64; 2]>,
}

fn criteria() -> Result<TermCriteria, CalibError> {
    Ok(cv::criteria(100, 1e-9)?)
}

/// A board pose: camera from board, rotation and translation (mm).
type Pose = (Matrix3<f64>, Vector3<f64>);

/// One camera calibrated alone: K, distortion, and each view's board pose.
fn single_camera(
    board: &BoardSpec,
    size: [i32; 2],
    image: &Vector<Vector<Point2f>>,
) -> Result<(Mat, Mat, Vec<Pose>), CalibError> {
    let object: Vector<Vector<Point3f>> = image.iter().map(|_| board.object_points()).collect();
    let (mut k, mut d) = (Mat::default(), Mat::default());
    let (mut rv, mut tv) = (Vector::<Mat>::new(), Vector::<Mat>::new());
    calib3d::calibrate_camera(
        &object,
        image,
        Size::new(size[0], size[1]),
        &mut k,
        &mut d,
        &mut rv,
        &mut tv,
        0,
        criteria()?,
    )?;
    let poses = rv
        .iter()
        .zip(tv.iter())
        .map(|(r, t)| {
            let mut m = Mat::default();
            calib3d::rodrigues(&r, &mut m, &mut core::no_array())?;
            Ok((
                Matrix3::from_row_slice(&fixed::<9>(&m)?),
                Vector3::from_row_slice(&fixed::<3>(&t)?),
            ))
        })
        .collect::<Result<Vec<_>, CalibError>>()?;
    Ok((k, d, poses))
}

/// Pairs whose own left → right pose disagrees with the others' (median): more than 2° of
/// rotation or 10 % of the baseline away. Such a pair (a wrong partner image, a camera that
/// moved) would pull the joint calibration everywhere, so it goes first.
fn inconsistent_pairs(
    board: &BoardSpec,
    size: [i32; 2],
    usable: &[Usable],
) -> Result<Vec<(usize, String)>, CalibError> {
    let left: Vector<Vector<Point2f>> = usable.iter().map(|u| points(&u.left)).collect();
    let right: Vector<Vector<Point2f>> = usable.iter().map(|u| points(&u.right)).collect();
    let (_, _, pl) = single_camera(board, size, &left)?;
    let (_, _, pr) = single_camera(board, size, &right)?;
    let relative: Vec<Pose> = pl
        .iter()
        .zip(&pr)
        .map(|((rl, tl), (rr, tr))| {
            let r = rr * rl.transpose();
            (r, tr - r * tl)
        })
        .collect();
    let median = |k: usize| {
        let mut v: Vec<f64> = relative.iter().map(|(_, t)| t[k]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let t_med = Vector3::new(median(0), median(1), median(2));
    // The reference rotation: the pair whose translation is nearest the median.
    let reference = relative
        .iter()
        .min_by(|a, b| (a.1 - t_med).norm().total_cmp(&(b.1 - t_med).norm()))
        .map(|(r, _)| *r)
        .expect("pairs");
    let mut out = Vec::new();
    for (k, (r, t)) in relative.iter().enumerate() {
        let angle = nalgebra::Rotation3::from_matrix_unchecked(r * reference.transpose())
            .angle()
            .to_degrees();
        let off = (t - t_med).norm() / t_med.norm();
        if angle > 2.0 || off > 0.10 {
            out.push((
                k,
                format!(
                    "left and right disagree with the other pairs: relative pose {angle:.1}° and {:.0} % of the baseline off (wrong partner image, or a camera moved?)",
                    100.0 * off
                ),
            ));
        }
    }
    Ok(out)
}

fn stereo(board: &BoardSpec, size: [i32; 2], usable: &[Usable]) -> Result<Rig, CalibError> {
    let image_size = Size::new(size[0], size[1]);
    let object: Vector<Vector<Point3f>> = usable.iter().map(|_| board.object_points()).collect();
    let left: Vector<Vector<Point2f>> = usable.iter().map(|u| points(&u.left)).collect();
    let right: Vector<Vector<Point2f>> = usable.iter().map(|u| points(&u.right)).collect();
    let (mut k1, mut d1, _) = single_camera(board, size, &left)?;
    let (mut k2, mut d2, _) = single_camera(board, size, &right)?;
    let (mut r, mut t, mut e, mut f, mut per_view) = (
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
    );
    let rms = calib3d::stereo_calibrate_extended(
        &object,
        &left,
        &right,
        &mut k1,
        &mut d1,
        &mut k2,
        &mut d2,
        image_size,
        &mut r,
        &mut t,
        &mut e,
        &mut f,
        &mut per_view,
        calib3d::CALIB_USE_INTRINSIC_GUESS,
        criteria()?,
    )?;
    let errors = values(&per_view)?;
    Ok(Rig {
        cams: StereoRig {
            image_size: size,
            left: Intrinsics {
                k: fixed(&k1)?,
                dist: values(&d1)?,
            },
            right: Intrinsics {
                k: fixed(&k2)?,
                dist: values(&d2)?,
            },
            r: fixed(&r)?,
            t: fixed(&t)?,
        },
        e: fixed(&e)?,
        f: fixed(&f)?,
        rms,
        per_view: errors.chunks(2).map(|c| [c[0], c[1]]).collect(),
    })
}

/// Corners as `f64`.
fn wide(c: &[[f32; 2]]) -> Vec<[f64; 2]> {
    c.iter()
        .map(|p| [f64::from(p[0]), f64::from(p[1])])
        .collect()
}

/// Mean distance (px) of each undistorted corner from the epipolar line of its partner, both
/// ways.
fn epipolar_error(
    rig: &Rig,
    left: &[&[[f32; 2]]],
    right: &[&[[f32; 2]]],
) -> Result<f64, CalibError> {
    let f = Matrix3::from_row_slice(&rig.f);
    let (mut sum, mut n) = (0.0, 0usize);
    for (l, r) in left.iter().zip(right) {
        let ul = rig.cams.undistorted(Side::Left, &wide(l))?;
        let ur = rig.cams.undistorted(Side::Right, &wide(r))?;
        for (a, b) in ul.iter().zip(&ur) {
            let (pa, pb) = (Vector3::new(a[0], a[1], 1.0), Vector3::new(b[0], b[1], 1.0));
            let line_r = f * pa;
            let line_l = f.transpose() * pb;
            sum += line_r.dot(&pb).abs() / line_r.x.hypot(line_r.y);
            sum += line_l.dot(&pa).abs() / line_l.x.hypot(line_l.y);
            n += 2;
        }
    }
    Ok(sum / n as f64)
}

/// Share of an 8 × 6 grid of image cells that hold at least one corner.
fn coverage(size: [i32; 2], views: &[&[[f32; 2]]]) -> f64 {
    let mut cells = [[false; 8]; 6];
    for c in views.iter().flat_map(|v| v.iter()) {
        let i = ((c[0] / size[0] as f32) * 8.0).clamp(0.0, 7.0) as usize;
        let j = ((c[1] / size[1] as f32) * 6.0).clamp(0.0, 5.0) as usize;
        cells[j][i] = true;
    }
    cells.iter().flatten().filter(|&&c| c).count() as f64 / 48.0
}

/// Triangulates every used board and compares it with the printed one.
fn board_check(
    board: &BoardSpec,
    rig: &Rig,
    left: &[&[[f32; 2]]],
    right: &[&[[f32; 2]]],
) -> Result<BoardCheck, CalibError> {
    let (mut steps, mut plane_sq, mut plane_n) = (Vec::new(), 0.0, 0usize);
    for (l, r) in left.iter().zip(right) {
        let pts = rig.cams.triangulate(&wide(l), &wide(r))?;
        let n = l.len();
        for j in 0..board.rows {
            for i in 0..board.cols {
                let k = j * board.cols + i;
                if i + 1 < board.cols {
                    steps.push((pts[k + 1] - pts[k]).norm() / board.square_mm);
                }
                if j + 1 < board.rows {
                    steps.push((pts[k + board.cols] - pts[k]).norm() / board.square_mm);
                }
            }
        }
        let centre = pts.iter().sum::<Vector3<f64>>() / n as f64;
        let mut cov = Matrix3::zeros();
        for p in &pts {
            let d = p - centre;
            cov += d * d.transpose();
        }
        let eig = cov.symmetric_eigen();
        plane_sq += eig.eigenvalues.min();
        plane_n += n;
    }
    let mean = steps.iter().sum::<f64>() / steps.len() as f64;
    let sd = (steps.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / steps.len() as f64).sqrt();
    Ok(BoardCheck {
        neighbour_mean_squares: mean,
        neighbour_sd_squares: sd,
        planarity_rms_mm: (plane_sq.max(0.0) / plane_n as f64).sqrt(),
    })
}

type Rectification = ([f64; 9], [f64; 9], [f64; 12], [f64; 12], [f64; 16]);

fn rectify(rig: &Rig, size: [i32; 2]) -> Result<Rectification, CalibError> {
    let (mut r1, mut r2, mut p1, mut p2, mut q) = (
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
    );
    calib3d::stereo_rectify(
        &mat(3, &rig.cams.left.k)?,
        &mat(1, &rig.cams.left.dist)?,
        &mat(3, &rig.cams.right.k)?,
        &mat(1, &rig.cams.right.dist)?,
        Size::new(size[0], size[1]),
        &mat(3, &rig.cams.r)?,
        &mat(3, &rig.cams.t)?,
        &mut r1,
        &mut r2,
        &mut p1,
        &mut p2,
        &mut q,
        calib3d::CALIB_ZERO_DISPARITY,
        0.0,
        Size::new(size[0], size[1]),
        None,
        None,
    )?;
    Ok((
        fixed(&r1)?,
        fixed(&r2)?,
        fixed(&p1)?,
        fixed(&p2)?,
        fixed(&q)?,
    ))
}

/// Left-camera → hand-frame rotation from the reference board's corners in the left image.
fn hand_axes(board: &BoardSpec, rig: &Rig, corners: &[[f32; 2]]) -> Result<[f64; 9], CalibError> {
    // Corners in the order that makes the board's x axis point to the image's right.
    let mut ordered = corners.to_vec();
    if corners[board.cols - 1][0] < corners[0][0] {
        ordered.reverse();
    }
    let (mut rvec, mut tvec) = (Mat::default(), Mat::default());
    calib3d::solve_pnp(
        &board.object_points(),
        &points(&ordered),
        &mat(3, &rig.cams.left.k)?,
        &mat(1, &rig.cams.left.dist)?,
        &mut rvec,
        &mut tvec,
        false,
        calib3d::SOLVEPNP_ITERATIVE,
    )?;
    let mut rot = Mat::default();
    calib3d::rodrigues(&rvec, &mut rot, &mut core::no_array())?;
    let left_from_board = Matrix3::from_row_slice(&fixed::<9>(&rot)?);
    // Board axes in the hand frame: x → x, y → −z, z → +y.
    let hand_from_board = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
    let hand_from_left = hand_from_board * left_from_board.transpose();
    Ok(std::array::from_fn(|k| hand_from_left[(k / 3, k % 3)]))
}
