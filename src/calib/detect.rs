//! A board's corners in one image, by OpenCV.
//!
//! A ChArUco board is found by its markers (`detectMarkers`, then `interpolateCornersCharuco`
//! for the chessboard corners between them, refined again by `corner_sub_pix` in a window that
//! stays off the markers); any part of it that shows two markers is found. A chessboard has two
//! detectors, never mixed within one calibration: the sector-based one
//! (`find_chessboard_corners_sb` with image normalisation, on a half-size copy of images wider
//! than 1000 px; its corners are refined at full size by `corner_sub_pix` in a 5 × 5 window,
//! which on the synthetic boards brings them under 0.09 px RMS of the truth, where the detector
//! alone gives 0.03-0.13 px at full size), and the classic one
//! (`find_chessboard_corners` with adaptive threshold and normalisation, refined in an 11 × 11
//! window) as the fallback.

use std::path::Path;

use opencv::core::{self, Mat, Point2f, Size, TermCriteria, Vector};
use opencv::prelude::*;
use opencv::{calib3d, imgcodecs, imgproc};

use rayon::prelude::*;

use super::pairs::ImagePair;
use super::{BoardSpec, CalibError, Found};

/// Which OpenCV detector found the corners.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Detector {
    SectorBased,
    Classic,
    Charuco,
}

impl Detector {
    pub fn name(self) -> &'static str {
        match self {
            Detector::SectorBased => "sector-based (findChessboardCornersSB)",
            Detector::Classic => "classic (findChessboardCorners + cornerSubPix)",
            Detector::Charuco => {
                "ChArUco (detectMarkers + interpolateCornersCharuco + cornerSubPix)"
            }
        }
    }
}

/// The corners one image shows, each with its id on the board ([`BoardSpec::grid`]), in
/// ascending id: every corner of a chessboard, or the part of a ChArUco board in view.
#[derive(Clone, Debug, PartialEq)]
pub struct Seen {
    pub ids: Vec<usize>,
    pub px: Vec<[f32; 2]>,
}

impl Seen {
    /// A whole board's corners, in row order.
    pub fn whole(px: Vec<[f32; 2]>) -> Self {
        Seen {
            ids: (0..px.len()).collect(),
            px,
        }
    }

    /// The pixel of corner `id`, if seen.
    pub fn at(&self, id: usize) -> Option<[f32; 2]> {
        self.ids.binary_search(&id).ok().map(|k| self.px[k])
    }

    /// The largest move (px) from `other` of a corner both show; infinite when they share none.
    pub fn moved_from(&self, other: &Seen) -> f64 {
        let mut shared = false;
        let mut most = 0.0f64;
        for (id, p) in self.ids.iter().zip(&self.px) {
            if let Some(q) = other.at(*id) {
                shared = true;
                most = most.max(f64::from(p[0] - q[0]).hypot(f64::from(p[1] - q[1])));
            }
        }
        if shared {
            most
        } else {
            f64::INFINITY
        }
    }
}

/// `board`'s corners in `gray` by `detector` (one of its pattern's); `None` when not found.
///
/// # Errors
/// An OpenCV failure (not "board not found", which is `Ok(None)`).
pub fn find_board(
    gray: &Mat,
    board: &BoardSpec,
    detector: Detector,
) -> opencv::Result<Option<Seen>> {
    board.pattern.kind().find(board, gray, detector)
}

/// `corners` refined by `corner_sub_pix` to 1e-4 px in a window of `half` pixels each side.
pub(super) fn refine(
    gray: &Mat,
    corners: &mut Vector<Point2f>,
    half: i32,
) -> opencv::Result<Vec<[f32; 2]>> {
    let criteria = TermCriteria::new(core::TermCriteria_COUNT + core::TermCriteria_EPS, 50, 1e-4)?;
    imgproc::corner_sub_pix(
        gray,
        corners,
        Size::new(half, half),
        Size::new(-1, -1),
        criteria,
    )?;
    Ok(corners.iter().map(|p| [p.x, p.y]).collect())
}

/// The median distance (px) between seen corners that are neighbours on the board.
pub(super) fn square_px(board: &BoardSpec, seen: &Seen) -> f64 {
    let mut steps: Vec<f64> = Vec::new();
    for (id, p) in seen.ids.iter().zip(&seen.px) {
        for next in board.neighbours(*id) {
            if let Some(q) = seen.at(next) {
                steps.push(f64::from(p[0] - q[0]).hypot(f64::from(p[1] - q[1])));
            }
        }
    }
    crate::stats::median(&mut steps).unwrap_or(0.0)
}

/// Reads an image as 8-bit grey.
///
/// # Errors
/// [`CalibError::NotAnImage`] when OpenCV cannot decode it, or it is too small to show a board.
pub fn read_gray(path: &Path) -> Result<Mat, CalibError> {
    let bytes = std::fs::read(path).map_err(|e| CalibError::NotAnImage {
        path: path.to_path_buf(),
        why: e.to_string(),
    })?;
    let not_image = |why: String| CalibError::NotAnImage {
        path: path.to_path_buf(),
        why,
    };
    let image = crate::cv::decode_image(&Vector::from_slice(&bytes), imgcodecs::IMREAD_GRAYSCALE)
        .map_err(not_image)?;
    if image.cols() < MIN_SIDE_PX || image.rows() < MIN_SIDE_PX {
        return Err(not_image(format!(
            "only {}×{} pixels, too small to show a chessboard (at least {MIN_SIDE_PX} a side)",
            image.cols(),
            image.rows()
        )));
    }
    Ok(image)
}

/// The smallest image side a calibration image may have (OpenCV's detectors need room for
/// their filters, and a board needs a few pixels per square).
const MIN_SIDE_PX: i32 = 64;

/// The inner corners of a `cols × rows` board in `gray`, row by row; `None` when not found.
///
/// # Errors
/// An OpenCV failure (not "board not found", which is `Ok(None)`).
pub fn find_corners(
    gray: &Mat,
    cols: i32,
    rows: i32,
    detector: Detector,
) -> opencv::Result<Option<Vec<[f32; 2]>>> {
    let size = Size::new(cols, rows);
    let mut corners = Vector::<Point2f>::new();
    let (found, window) = match detector {
        // A chessboard has no markers: the sector-based detector is its first.
        Detector::SectorBased | Detector::Charuco => {
            // Images wider than 1000 px are searched at half size (4× faster; squares of a
            // board that fills a useful part of a 720p image stay ≥ 15 px) and the corners
            // mapped back; the refinement below works at full size.
            let scale = if gray.cols() > 1000 { 2 } else { 1 };
            let found = if scale == 1 {
                calib3d::find_chessboard_corners_sb(
                    gray,
                    size,
                    &mut corners,
                    calib3d::CALIB_CB_NORMALIZE_IMAGE,
                )?
            } else {
                let mut half = Mat::default();
                imgproc::resize(
                    gray,
                    &mut half,
                    Size::new(gray.cols() / 2, gray.rows() / 2),
                    0.0,
                    0.0,
                    imgproc::INTER_AREA,
                )?;
                let found = calib3d::find_chessboard_corners_sb(
                    &half,
                    size,
                    &mut corners,
                    calib3d::CALIB_CB_NORMALIZE_IMAGE,
                )?;
                // Pixel centres: full = 2 · half + 0.5.
                corners = corners
                    .iter()
                    .map(|p| Point2f::new(2.0 * p.x + 0.5, 2.0 * p.y + 0.5))
                    .collect();
                found
            };
            (found, 5)
        }
        Detector::Classic => (
            calib3d::find_chessboard_corners(
                gray,
                size,
                &mut corners,
                calib3d::CALIB_CB_ADAPTIVE_THRESH | calib3d::CALIB_CB_NORMALIZE_IMAGE,
            )?,
            11,
        ),
    };
    if !found || corners.len() != (cols * rows) as usize {
        return Ok(None);
    }
    refine(gray, &mut corners, window).map(Some)
}

/// The board in every image of `grays` by `detector`, in parallel: each image's size and the
/// corners found; `done` counts the images examined, reported as `progress(done, total)`.
///
/// # Errors
/// An OpenCV failure.
pub(super) fn find_all(
    grays: &[Mat],
    board: &BoardSpec,
    detector: Detector,
    done: &std::sync::atomic::AtomicUsize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<super::Found>, CalibError> {
    grays
        .par_iter()
        .map(|gray| {
            let size = gray.size()?;
            let corners = find_board(gray, board, detector)?;
            let n = done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
            progress(n, grays.len());
            Ok(([size.width, size.height], corners))
        })
        .collect()
}

pub(super) fn read_all(images: &[&Path]) -> Result<Vec<Mat>, CalibError> {
    images.par_iter().map(|p| read_gray(p)).collect()
}

/// One size for all images, and the same in each pair.
pub(super) fn check_sizes(all: &[&ImagePair], found: &[Found]) -> Result<[i32; 2], CalibError> {
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
