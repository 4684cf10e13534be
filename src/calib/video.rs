//! Calibration pairs picked from two videos of the board (`left.<video>`, `right.<video>` and
//! their `frames.csv`, or `--video-start-s`, as `triangulate` reads them): a lab films the board
//! being moved about instead of taking 20 still pairs.
//!
//! Every sixth frame pair (five a second at 30 fps) is searched for the board in both images;
//! where both show it, the next pair is searched too, and the pair is kept only when no corner
//! moved more than [`STILL_PX`] between the two (a moving board is smeared by the exposure and
//! skewed by the rolling shutter, so it is never used). Of the still pairs, a pair is picked
//! when the board in the left image stands somewhere new: against every pair picked, its
//! centre 5 % of the image away, or its size 10 % or its foreshortening (the ratio of opposite
//! sides) 8 % different, or turned 8° in the image; at most `max_pairs`. The picked frames are written as `left_NN.png` /
//! `right_NN.png` (lossless) into a folder beside the calibration, with the board file and a
//! reference pair (`left_ref`, `right_ref`) of the videos' folder, and calibrated from there,
//! so the pairs can be looked at and the calibration run again.

use std::path::{Path, PathBuf};

use opencv::core::Mat;
use opencv::imgproc;
use opencv::prelude::*;
use rayon::prelude::*;

use super::detect::{find_board, Seen};
use super::{BoardSpec, CalibError};
use crate::session::frames::FrameList;
use crate::video::{Frame, VideoReader};

/// Most a corner may move between two consecutive frames of a still board (px).
pub const STILL_PX: f64 = 0.5;

/// A board's corners in the left and the right image.
type BothImages = [Seen; 2];

/// Frame pairs between two searched ones.
const STRIDE: usize = 6;

/// What picking found.
#[derive(Clone, Debug, PartialEq)]
pub struct Picked {
    /// Frame pairs searched, pairs with the board in both images, still ones, picked ones.
    pub searched: usize,
    pub seen: usize,
    pub still: usize,
    /// The picked pairs' frame numbers (left, right).
    pub frames: Vec<[usize; 2]>,
    /// The folder the pairs were written to.
    pub dir: PathBuf,
}

fn failed(path: &Path) -> impl Fn(String) -> CalibError + '_ {
    move |why| CalibError::NotAnImage {
        path: path.to_path_buf(),
        why,
    }
}

/// A video frame in grey, decoded as `triangulate` decodes it.
fn gray(frame: Frame) -> Result<Mat, String> {
    use crate::image::{Buffers, RgbImage};
    use crate::session::frames::{decode_frame, FrameData};
    let mut rgb = RgbImage::default();
    decode_frame(&FrameData::Video(frame), &mut rgb, &mut Buffers::default())?;
    let flat = Mat::from_slice(&rgb.data).map_err(|e| e.message)?;
    let image = flat.reshape(3, rgb.height as i32).map_err(|e| e.message)?;
    let mut g = Mat::default();
    imgproc::cvt_color_def(&image, &mut g, imgproc::COLOR_RGB2GRAY).map_err(|e| e.message)?;
    Ok(g)
}

/// Frame `index` of a video read front to back (`None` past its end).
fn frame_at(video: &mut VideoReader, index: usize, path: &Path) -> Result<Option<Mat>, CalibError> {
    let err = failed(path);
    match video.frame(index).map_err(|e| err(e.message))? {
        Some(f) => gray(f).map(Some).map_err(err),
        None => Ok(None),
    }
}

/// Where the board stands in an image: centre (share of the width and height), size (share of
/// the diagonal), foreshortening across and down (ratios of opposite sides), turn in the image
/// (radians, of its first row). Of a part of a board, the part's: its corners nearest the
/// board's four (the board's own when it is whole).
pub(crate) fn footprint(board: &BoardSpec, seen: &Seen, size: [i32; 2]) -> [f64; 6] {
    let extreme = |score: &dyn Fn(f64, f64) -> f64| {
        let k = (0..seen.ids.len())
            .max_by(|&a, &b| {
                let at = |k: usize| {
                    let (i, j) = board.grid(seen.ids[k]);
                    score(i as f64, j as f64)
                };
                at(a).total_cmp(&at(b)).then(b.cmp(&a))
            })
            .expect("a board seen has corners");
        [f64::from(seen.px[k][0]), f64::from(seen.px[k][1])]
    };
    let [a, b, d, e] = [
        extreme(&|i, j| -(i + j)),
        extreme(&|i, j| i - j),
        extreme(&|i, j| j - i),
        extreme(&|i, j| i + j),
    ];
    let len = |u: [f64; 2], v: [f64; 2]| (u[0] - v[0]).hypot(u[1] - v[1]);
    let (w, h) = (f64::from(size[0]), f64::from(size[1]));
    let cx = (a[0] + b[0] + d[0] + e[0]) / 4.0 / w;
    let cy = (a[1] + b[1] + d[1] + e[1]) / 4.0 / h;
    let extent = (len(a, e) + len(b, d)) / 2.0 / w.hypot(h);
    let turn = (b[1] - a[1]).atan2(b[0] - a[0]);
    [
        cx,
        cy,
        extent,
        len(a, b) / len(d, e),
        len(a, d) / len(b, e),
        turn,
    ]
}

/// Whether a board at `f` stands somewhere none of the `picked` ones does.
pub(crate) fn new_place(f: &[f64; 6], picked: &[[f64; 6]]) -> bool {
    picked.iter().all(|q| {
        (f[0] - q[0]).abs().max((f[1] - q[1]).abs()) >= 0.05
            || (f[2] / q[2] - 1.0).abs() >= 0.1
            || (f[3] / q[3] - 1.0).abs() >= 0.08
            || (f[4] / q[4] - 1.0).abs() >= 0.08
            || (f[5] - q[5]).abs() >= 8f64.to_radians()
    })
}

/// Diverse pairs among the still ones (the board somewhere new in each), in time order: at most
/// `max_pairs` of their numbers.
fn diverse(
    board: &BoardSpec,
    still: &[(usize, BothImages, [i32; 2])],
    max_pairs: usize,
) -> Vec<usize> {
    let mut places: Vec<[f64; 6]> = Vec::new();
    let mut picked = Vec::new();
    for (k, corners, size) in still {
        let place = footprint(board, &corners[0], *size);
        if picked.len() < max_pairs && new_place(&place, &places) {
            places.push(place);
            picked.push(*k);
        }
    }
    picked
}

/// Picks still, diverse board pairs from the videos of `dir` and writes them into `out_dir`
/// (module docs); `progress(done, total)` counts pairs searched.
///
/// # Errors
/// [`CalibError`] naming the video or the file that failed.
pub fn pick_pairs(
    frames: &FrameList,
    board: &BoardSpec,
    max_pairs: usize,
    out_dir: &Path,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Picked, CalibError> {
    let [left_path, right_path] = frames.videos.clone().expect("videos");
    let open = |p: &Path| VideoReader::open(p).map_err(failed(p));
    let mut videos = [open(&left_path)?, open(&right_path)?];
    let pairs = crate::session::frames::pair_frames(&frames.records, 0.02).pairs;
    let numbers: Vec<[usize; 2]> = pairs
        .iter()
        .map(|&(l, r)| [frames.records[l].index, frames.records[r].index])
        .collect();
    // Searched pairs and their successors, in order of frame number.
    let searched: Vec<usize> = (0..numbers.len().saturating_sub(1))
        .step_by(STRIDE)
        .filter(|&k| {
            numbers[k + 1][0] == numbers[k][0] + 1 && numbers[k + 1][1] == numbers[k][1] + 1
        })
        .collect();
    let detector = board.first_detector();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let mut still: Vec<(usize, BothImages, [i32; 2])> = Vec::new();
    let mut seen = 0;
    for chunk in searched.chunks(16) {
        // Read in order: each searched pair and the next.
        let mut images = Vec::new();
        for &k in chunk {
            let mut four = Vec::new();
            for [l, r] in [numbers[k], numbers[k + 1]] {
                let left = frame_at(&mut videos[0], l, &left_path)?;
                let right = frame_at(&mut videos[1], r, &right_path)?;
                four.push(left.zip(right));
            }
            images.push((k, four));
        }
        let found: Vec<(usize, Option<[BothImages; 2]>, [i32; 2])> = images
            .into_par_iter()
            .map(|(k, four)| {
                let size = four
                    .first()
                    .and_then(|p| p.as_ref())
                    .map_or([0, 0], |(l, _)| [l.cols(), l.rows()]);
                let corners = |m: &Mat| find_board(m, board, detector).ok().flatten();
                let mut both = Vec::new();
                for pair in four.iter().flatten() {
                    match (corners(&pair.0), corners(&pair.1)) {
                        (Some(l), Some(r)) => both.push([l, r]),
                        _ => break,
                    }
                }
                done.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                progress(
                    done.load(std::sync::atomic::Ordering::SeqCst),
                    searched.len(),
                );
                let found = <[BothImages; 2]>::try_from(both).ok();
                (k, found, size)
            })
            .collect();
        for (k, f, size) in found {
            let Some([now, next]) = f else { continue };
            seen += 1;
            let moved = now
                .iter()
                .zip(&next)
                .map(|(a, b)| a.moved_from(b))
                .fold(0.0, f64::max);
            if moved <= STILL_PX {
                still.push((k, now, size));
            }
        }
    }
    drop(videos);

    let picked = diverse(board, &still, max_pairs);
    if picked.is_empty() {
        return Err(CalibError::NoVideoPairs {
            left: left_path,
            searched: searched.len(),
            seen,
            still: still.len(),
        });
    }
    std::fs::create_dir_all(out_dir).map_err(|e| CalibError::Write {
        path: out_dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut videos = [open(&left_path)?, open(&right_path)?];
    for (n, &k) in picked.iter().enumerate() {
        for (side, (video, path)) in videos.iter_mut().zip([&left_path, &right_path]).enumerate() {
            let image = frame_at(video, numbers[k][side], path)?
                .ok_or_else(|| failed(path)("ended early".into()))?;
            let name = out_dir.join(format!("{}_{n:02}.png", ["left", "right"][side]));
            let mut png = opencv::core::Vector::<u8>::new();
            opencv::imgcodecs::imencode_def(".png", &image, &mut png)?;
            crate::fsio::write_bytes(&name, png.as_slice()).map_err(|e| CalibError::Write {
                path: name.clone(),
                message: e.to_string(),
            })?;
        }
    }
    Ok(Picked {
        searched: searched.len(),
        seen,
        still: still.len(),
        frames: picked.iter().map(|&k| numbers[k]).collect(),
        dir: out_dir.to_path_buf(),
    })
}
