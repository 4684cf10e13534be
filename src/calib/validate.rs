//! `calibrate --validate`: the calibration's stated uncertainty checked against itself.
//!
//! The pairs are split in two halves (every other pair, and [`SPLITS`] − 1 seeded random
//! splits besides), each half calibrated alone, with its own covariance ([`uncertainty`]). At
//! points of the finger's working volume (a cube of ±[`VOLUME_MM`] around the finger's base,
//! 3 × 3 × 3 points), the pixels the full calibration sees there are triangulated by each
//! half: the halves' positions differ by their calibrations' errors, whose variance the
//! covariances predict (the halves share no pair, so the variances add). The ratio of the
//! disagreement's RMS to the predicted one is ≈ 1 when the stated deviations are honest and
//! above when they are too small (corner errors that are not independent, as JPEG and blur
//! make them, or a lens the five-coefficient model does not fit: mrcal's warning).
//!
//! The full calibration's deviation of a tip's position is also mapped over the volume against
//! the distance from the nearest board corner the calibration saw: away from the boards the
//! model is extrapolated. A finger base farther than [`FAR_SQUARES`] squares from every board
//! corner gets a warning.

use nalgebra::{Point3, Vector3};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rayon::prelude::*;
use serde::Serialize;

use super::{stereo, uncertainty, BoardSpec, CalibError, KnownIntrinsics, PairCorners};
use crate::geometry::CamFromBoard;
use crate::stereo::StereoRig;

/// Splits of the pairs into halves: alternate pairs, then seeded random ones.
pub const SPLITS: usize = 5;
/// Half the working volume's side (mm) around the finger's base.
pub const VOLUME_MM: f64 = 25.0;
/// A finger base farther than this many squares from every board corner is warned about.
pub const FAR_SQUARES: f64 = 5.0;
/// Fewest pairs in each half.
pub const MIN_HALF: usize = 3;

/// What the halves said.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Validation {
    pub splits: usize,
    /// Pairs in each half.
    pub half_pairs: [usize; 2],
    /// RMS of the halves' disagreement over the volume's points and the splits, along the left
    /// camera's x, y, z (mm) …
    pub disagreement_mm: [f64; 3],
    /// … and what the halves' covariances predict for it.
    pub predicted_mm: [f64; 3],
    /// Disagreement over prediction (all axes): ≈ 1 when the stated deviations are honest.
    pub ratio: f64,
    /// The full calibration's tip position sd (norm, mm) at each point of the volume, with its
    /// distance from the nearest board corner seen (mm), nearest first.
    pub map: Vec<(f64, f64)>,
    /// The finger's base's distance from the nearest board corner seen (mm).
    pub base_distance_mm: f64,
    /// What to do, when something is off.
    pub warnings: Vec<String>,
}

/// The calibration from every pair, as [`validate`] checks it.
pub(super) struct Full<'a> {
    pub rig: &'a StereoRig,
    pub uncertainty: &'a uncertainty::Uncertainty,
    /// The boards' poses in the left camera.
    pub poses: &'a [CamFromBoard],
    /// The finger's base (left camera, mm).
    pub base: Vector3<f64>,
}

/// Validates the calibration `full` from its `usable` pairs (and the `known` intrinsics it was
/// given), the random splits drawn with `seed`. `None` with fewer than 2 × [`MIN_HALF`] pairs,
/// or when a half's covariance cannot be had.
///
/// # Errors
/// An OpenCV failure.
pub(super) fn validate(
    board: &BoardSpec,
    size: [i32; 2],
    usable: &[PairCorners],
    known: &[Option<KnownIntrinsics>; 2],
    full: &Full,
    seed: u64,
) -> Result<Option<Validation>, CalibError> {
    let Full {
        rig: full_rig,
        base,
        ..
    } = *full;
    let n = usable.len();
    if n < 2 * MIN_HALF {
        return Ok(None);
    }
    let free = [known[0].is_none() && known[1].is_none(); 2];
    let steps = [-VOLUME_MM, 0.0, VOLUME_MM];
    let volume: Vec<Vector3<f64>> = (0..27)
        .map(|k| base + Vector3::new(steps[k / 9], steps[k / 3 % 3], steps[k % 3]))
        .collect();
    let pixels: Vec<[[f64; 2]; 2]> = volume
        .iter()
        .filter_map(|p| {
            let p = Point3::from(*p);
            Some([
                full_rig.left.pixel(&p)?,
                full_rig.right.pixel(&full_rig.right_from_left.apply(&p))?,
            ])
        })
        .collect();

    // The halves of every split (drawn in order, so the seed gives the same ones), each
    // calibrated on its own: in parallel, the splits' sums taken in order after.
    let mut order: Vec<usize> = (0..n).collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let halves: Vec<Vec<PairCorners>> = (0..SPLITS)
        .flat_map(|split| {
            if split == 0 {
                [0, 1].map(|h| usable.iter().skip(h).step_by(2).cloned().collect())
            } else {
                order.shuffle(&mut rng);
                let (a, b) = order.split_at(n / 2);
                [a, b].map(|rows| rows.iter().map(|&k| usable[k].clone()).collect())
            }
        })
        .collect();
    let fits = halves
        .par_iter()
        .map(|half| {
            let rig = stereo(board, size, half, known)?.cams;
            let poses = uncertainty::board_poses(board, &rig, half)?;
            let at = (base, String::new());
            let u = uncertainty::estimate(board, &rig, free, half, &poses, at)?;
            Ok(u.map(|u| (rig, u)))
        })
        .collect::<Result<Vec<_>, CalibError>>()?;
    let Some(fits) = fits.into_iter().collect::<Option<Vec<_>>>() else {
        return Ok(None);
    };
    let (mut seen, mut predicted) = ([0.0f64; 3], [0.0f64; 3]);
    let mut count = 0usize;
    for split in fits.chunks(2) {
        for px in &pixels {
            let [a, b] = [&split[0], &split[1]].map(|(rig, _)| rig.triangulate(&[px[0]], &[px[1]]));
            let (a, b) = (a?[0], b?[0]);
            let [sa, sb] = [&split[0], &split[1]].map(|(rig, u)| u.point_sd(rig, &a));
            let (sa, sb) = (sa?.position, sb?.position);
            for axis in 0..3 {
                seen[axis] += (a[axis] - b[axis]).powi(2);
                predicted[axis] += sa[axis].powi(2) + sb[axis].powi(2);
            }
            count += 1;
        }
    }
    let rms = |v: [f64; 3]| v.map(|s| (s / count.max(1) as f64).sqrt());
    let ratio = (seen.iter().sum::<f64>() / predicted.iter().sum::<f64>()).sqrt();

    let (map, base_distance_mm) = deviation_map(board, usable, full, &volume)?;

    let mut warnings = Vec::new();
    if ratio > 2.0 {
        warnings.push(format!(
            "the halves disagree {ratio:.1} × more than the stated deviations allow: they are too small (corner errors that are not independent, from JPEG or blur, or a lens the 5-coefficient model does not fit); take the bootstrap's (`--bootstrap 200`) or scale them by {ratio:.1}"
        ));
    }
    let far = FAR_SQUARES * board.square_mm;
    if base_distance_mm > far {
        warnings.push(format!(
            "the finger's base is {base_distance_mm:.0} mm from the nearest board corner the calibration saw (more than {FAR_SQUARES} squares): the lens model is extrapolated there; take pairs with the board where the finger works"
        ));
    }
    Ok(Some(Validation {
        splits: SPLITS,
        half_pairs: [n - n / 2, n / 2],
        disagreement_mm: rms(seen),
        predicted_mm: rms(predicted),
        ratio,
        map,
        base_distance_mm,
        warnings,
    }))
}

/// The full calibration's deviation of a tip (mm, its norm) at each point of `volume` against
/// the point's distance from the nearest board corner the calibration saw (sorted by distance),
/// and that distance for the finger's base.
fn deviation_map(
    board: &BoardSpec,
    usable: &[PairCorners],
    full: &Full,
    volume: &[Vector3<f64>],
) -> Result<(Vec<(f64, f64)>, f64), CalibError> {
    let Full {
        rig: full_rig,
        uncertainty: full_uncertainty,
        poses,
        base,
    } = *full;
    let corners: Vec<Vector3<f64>> = poses
        .iter()
        .zip(usable)
        .flat_map(|(pose, pair)| {
            let on_board = board.corners_mm(&pair.ids);
            on_board
                .into_iter()
                .map(|p| pose.apply(&p).coords)
                .collect::<Vec<_>>()
        })
        .collect();
    let nearest = |p: &Vector3<f64>| {
        corners
            .iter()
            .map(|c| (c - p).norm())
            .fold(f64::INFINITY, f64::min)
    };
    let mut map = volume
        .iter()
        .map(|p| {
            let sd = full_uncertainty.point_sd(full_rig, p)?.position;
            Ok((nearest(p), Vector3::from(sd).norm()))
        })
        .collect::<Result<Vec<_>, CalibError>>()?;
    map.sort_by(|a, b| a.0.total_cmp(&b.0));
    let base_distance_mm = nearest(&base);
    Ok((map, base_distance_mm))
}
