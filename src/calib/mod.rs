//! Stereo calibration of two webcams from board pairs (a chessboard, or a ChArUco board seen
//! whole or in part), with the quality checks good tools give. OpenCV does the work
//! (detection, per-camera and stereo calibration, rectification); this module chooses, checks
//! and reports.
//!
//! # Steps
//!
//! 1. Pairs: `left*`/`right*` files with the same suffix ([`pairs`]); `*_ref` is the reference
//!    pair (the board at the finger's base).
//! 2. Corners in every image, in parallel ([`detect`]), each with its id on the board
//!    ([`BoardSpec::grid`]). A chessboard: the sector-based detector; if it finds fewer usable
//!    pairs than needed, the classic one for every image instead (never mixed). A ChArUco board:
//!    its markers, and the corners between them.
//! 3. Left/right corners matched ([`pairs::match_corners`]). A chessboard seen by both cameras
//!    must run the same way in both images (first → last corner, and along the first row); a
//!    right image whose corners run the other way (the 180° ambiguity of the detector) has them
//!    reversed, and the pair says so; a pair that still disagrees is rejected. A ChArUco
//!    board's corners are matched by id; a pair with fewer than
//!    [`pairs::MIN_COMMON_CORNERS`] corners in both images, or all in one line, is rejected
//!    with the count.
//! 4. Each camera alone (`calibrate_camera`, 5 distortion coefficients), then both together
//!    (`stereo_calibrate_extended`, starting from those intrinsics, per-pair errors); each view
//!    with the object points of the corners it shows.
//! 5. Outliers: while the worst pair's error exceeds both `reject_factor` × the median and
//!    `reject_floor_px`, it is dropped and the rig recalibrated, keeping at least `min_pairs`.
//! 6. Quality: RMS, mean epipolar distance of the corners (undistorted, both directions),
//!    coverage of the image by corners (share of an 8 × 6 grid of cells), the boards
//!    triangulated back (neighbouring-corner distance in squares, out-of-plane RMS), and
//!    rectification (`stereo_rectify`, zero disparity, α = 0).
//! 7. The hand frame's axes from the reference pair, when there is one: the board's pose in the
//!    left camera (`solve_pnp`), read with the board's x along hand x, its y along hand −z (down
//!    the finger) and its z along hand +y; the board is read so that its x axis points to the
//!    image's right (turned half round about its normal if need be). `R_hand` maps left-camera
//!    coordinates to the hand frame's axes; the origin (the tip at zero pressure) is found
//!    later, by `triangulate`.

mod board;
pub mod cameras;
mod checks;
pub mod detect;
pub mod figures;
pub mod file;
mod fit;
pub mod gates;
pub mod graph;
pub mod guidance;
pub mod pairs;
pub mod print;
mod steps;
pub mod uncertainty;
pub mod validate;
pub mod video;

pub use board::{
    BoardKeys, BoardPattern, BoardSpec, Charuco, Chessboard, Dictionary, Layout, Marker,
    PartialBoard, Pattern,
};
use checks::{board_check, epipolar_error, rectify};
use detect::read_all;
use fit::{stereo, StereoFit};
use pairs::too_few;
use steps::{detect_boards, given_intrinsics, how_sure, image_size, reference_axes, usable_pairs};

use std::path::{Path, PathBuf};

use nalgebra::Rotation3;
use serde::Serialize;

use crate::geometry::Intrinsics;
use crate::stereo::StereoRig;
use detect::{Detector, Seen};
use pairs::ImagePair;

/// Images the classic corner detector is first tried on when the sector-based one finds no
/// board in any image.
const CLASSIC_SAMPLE: usize = 4;

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
    #[error("{path}: {why}; remove it or replace it")]
    NotAnImage { path: PathBuf, why: String },
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
    #[error("camera {camera} shows the board in {found} images of {dir}, {needed} needed for its intrinsics; add views of the board filling its image at several tilts")]
    TooFewViews {
        camera: String,
        dir: PathBuf,
        found: usize,
        needed: usize,
    },
    #[error("camera {camera} shares no board view with the others in {dir}: show the board to it and to another camera at the same instant (the same NN in both files' names)")]
    Untied { camera: String, dir: PathBuf },
    #[error("{dir} has board views of one camera, {camera}: a calibration of cameras takes two or more seeing the board at the same instants (<camera>_NN images with the same NN)")]
    OneCamera { camera: String, dir: PathBuf },
    #[error("--intrinsics names every camera of {dir} or none: {}{}", if missing.is_empty() { String::new() } else { format!("no file for {missing}") }, if unknown.is_empty() { String::new() } else { format!("{}{unknown} not among its cameras", if missing.is_empty() { "" } else { "; " }) })]
    GivenNames {
        missing: String,
        unknown: String,
        dir: PathBuf,
    },
    #[error("{path} is for {}x{} images, but camera {camera}'s are {}x{}: give the intrinsics of this camera at the size it films", given[0], given[1], size[0], size[1])]
    GivenSize {
        path: PathBuf,
        camera: String,
        given: [i32; 2],
        size: [i32; 2],
    },
    #[error("{left} and its right video: no still board pair in {searched} frame pairs searched (the board in both images in {seen}, still in {still}); film the whole board in both cameras, holding it still for half a second at each pose")]
    NoVideoPairs {
        left: PathBuf,
        searched: usize,
        seen: usize,
        still: usize,
    },
    #[error("{path}: intrinsics of {fw}×{fh} images, but the calibration images are {w}×{h}; give the file of this camera at this resolution")]
    IntrinsicsSize {
        path: PathBuf,
        fw: i32,
        fh: i32,
        w: i32,
        h: i32,
    },
    #[error("{dir}: the calibration cannot be right: {problems}. Nothing was written; `--force` writes it anyway, marked as forced")]
    Implausible { dir: PathBuf, problems: String },
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    #[error(transparent)]
    Figure(#[from] crate::plot::FigureError),
    #[error("writing {path}: {message}")]
    Write { path: PathBuf, message: String },
}

/// A camera's intrinsics known from an earlier calibration (`--intrinsics`), and its file.
#[derive(Clone, Debug, PartialEq)]
pub struct KnownIntrinsics {
    pub path: PathBuf,
    pub image_size: [i32; 2],
    pub intrinsics: Intrinsics,
}

/// How pairs are kept or rejected, and what is known beforehand.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CalibOptions {
    /// Fewest pairs the calibration may keep.
    pub min_pairs: usize,
    /// A pair is an outlier when its error exceeds this × the median …
    pub reject_factor: f64,
    /// … and this many pixels.
    pub reject_floor_px: f64,
    /// Intrinsics of the left and right camera fixed instead of solved (see `fit::stereo`).
    #[serde(skip)]
    pub intrinsics: [Option<KnownIntrinsics>; 2],
    /// With more cameras, the intrinsics of every camera by name, fixed instead of solved
    /// ([`cameras`]; none, or all of them).
    #[serde(skip)]
    pub named_intrinsics: std::collections::BTreeMap<String, KnownIntrinsics>,
    /// Recalibrations on pairs drawn with replacement, for [`Bootstrap`] (0: none) …
    pub bootstrap: usize,
    /// … and the seed of the draws.
    pub seed: u64,
    /// For videos without `frames.csv`: each video's first frame on one clock (s).
    pub video_start_s: Option<[f64; 2]>,
    /// Most pairs picked from videos ([`video`]).
    pub max_video_pairs: usize,
    /// Write a calibration that fails a gate ([`gates`]), marked as forced.
    pub force: bool,
    /// Check the stated uncertainty against two halves of the pairs ([`validate`]).
    pub validate: bool,
}

impl Default for CalibOptions {
    fn default() -> Self {
        CalibOptions {
            min_pairs: 6,
            reject_factor: 3.0,
            reject_floor_px: 0.25,
            intrinsics: [None, None],
            named_intrinsics: std::collections::BTreeMap::new(),
            bootstrap: 0,
            seed: 1,
            video_start_s: None,
            max_video_pairs: 25,
            force: false,
            validate: false,
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
#[derive(Clone, Debug)]
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
    pub board_check: BoardCheck,
    /// The parameters' standard deviations and the tip's (`None` when they cannot be had:
    /// [`uncertainty::estimate`]).
    pub uncertainty: Option<uncertainty::Uncertainty>,
    /// The same deviations by a bootstrap over the pairs, when asked for.
    pub bootstrap: Option<Bootstrap>,
    /// Coverage, tilt, and what to capture next.
    pub guidance: guidance::Guidance,
    pub pairs: Vec<PairReport>,
    /// Images without a partner, skipped.
    pub unpaired: Vec<PathBuf>,
    /// Left-camera → hand-frame axes (p_hand = R_hand · p_left, up to the origin).
    pub hand_axes: Option<Rotation3<f64>>,
    pub hand_axes_note: String,
    /// Why the calibration cannot be right ([`gates`]); empty when it passes every gate.
    pub implausible: Vec<String>,
    /// The stated uncertainty checked against two halves of the pairs, when asked for.
    pub validation: Option<validate::Validation>,
}

impl StereoCalibration {
    pub fn used(&self) -> impl Iterator<Item = &PairReport> {
        self.pairs.iter().filter(|p| p.rejected.is_none())
    }

    pub fn rejected(&self) -> impl Iterator<Item = &PairReport> {
        self.pairs.iter().filter(|p| p.rejected.is_some())
    }
}

/// Corners of one image: its size and the corners if the board was found.
type Found = ([i32; 2], Option<Seen>);

/// The cameras' standard deviations by a bootstrap over the pairs: the rig calibrated again
/// `rounds` times, each on as many pairs as were used, drawn from them with replacement; the
/// deviations are the spread of those calibrations (rotations about the left camera's axes,
/// from the calibration's own).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Bootstrap {
    pub rounds: usize,
    pub seed: u64,
    pub parameters: uncertainty::ParameterSd,
}

/// A pair in the calibration: its index among the reports, and the corners both images show,
/// matched by id (ascending): their ids, left and right pixels.
#[derive(Clone, Debug)]
pub struct PairCorners {
    report: usize,
    pub ids: Vec<usize>,
    pub left: Vec<[f32; 2]>,
    pub right: Vec<[f32; 2]>,
}

impl PairCorners {
    /// The left (`side` 0) or right (1) image's corners.
    pub fn view(&self, side: usize) -> View<'_> {
        View {
            ids: &self.ids,
            px: if side == 0 { &self.left } else { &self.right },
        }
    }
}

/// One image's corners: their ids on the board and pixels.
#[derive(Clone, Copy, Debug)]
pub struct View<'a> {
    pub ids: &'a [usize],
    pub px: &'a [[f32; 2]],
}

impl<'a> From<&'a Seen> for View<'a> {
    fn from(seen: &'a Seen) -> Self {
        View {
            ids: &seen.ids,
            px: &seen.px,
        }
    }
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
    // 1. The pairs, then the reference pair, and their images.
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
    // 2. The board in every image.
    let (detector, found) = detect_boards(dir, &grays, board, &listing, options, progress)?;
    let size = image_size(&all, &found, options)?;
    // 3. Pairs with the board in both images, in a consistent corner order.
    let (mut reports, mut usable) = usable_pairs(board, &listing, &found);
    let needed = options.min_pairs.max(3);
    if usable.len() < needed {
        return Err(too_few(&reports, usable.len(), needed));
    }
    // 4. Given intrinsics against these images, before they fix the fit.
    let given = given_intrinsics(board, size, &usable, options)?;
    // 5. The fit, its outliers dropped, and its checks.
    let rig = fit::without_outliers(board, size, &mut usable, &mut reports, options, needed)?;
    for (u, e) in usable.iter().zip(&rig.per_view) {
        reports[u.report].rms_px = Some(*e);
    }
    let epipolar_px = epipolar_error(&rig, &usable)?;
    let board_check = board_check(board, &rig, &usable)?;
    let (r1, r2, p1, p2, q) = rectify(&rig, size)?;
    // 6. The hand frame's axes from the reference pair (its images follow the others').
    let reference = listing
        .reference
        .as_ref()
        .map(|pair| (pair, &found[2 * listing.pairs.len()].1));
    let (hand_axes, hand_axes_note) = reference_axes(board, &rig, reference)?;
    // 7. How sure all this is, and what to capture next.
    let sure = how_sure(board, size, &rig, &usable, reference, options)?;
    // 8. The gates: given intrinsics that fail their own fail the others through them, so
    //    only the cause is said.
    let fitted = gates::fitted(
        board,
        rig.rms,
        &board_check,
        rig.cams.right_from_left.translation.norm(),
        sure.median_distance_mm,
    );
    let implausible = if given.is_empty() { fitted } else { given };
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
        board_check,
        uncertainty: sure.uncertainty,
        bootstrap: sure.bootstrap,
        guidance: sure.guidance,
        pairs: reports,
        unpaired: listing.unpaired.clone(),
        hand_axes,
        hand_axes_note,
        implausible,
        validation: sure.validation,
    })
}
