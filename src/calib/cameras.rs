//! Calibration of more than two cameras (issue 59), from a folder of board views named by
//! camera: `<camera>_NN.<ext>` (one NN is one instant; a camera that does not see the board
//! then has no file) and `<camera>_ref.<ext>`, the reference board at the finger's base, for
//! every camera that sees it. Camera names are words (`[a-z][a-z0-9]*`); a folder of `left`
//! and `right` alone is a pair, calibrated by [`super::calibrate`].
//!
//! 1. The board in every image (the board's first detector, in parallel).
//! 2. Each camera's intrinsics from its own views (OpenCV's `calibrateCamera`).
//! 3. The cameras' poses from the views they share, the intrinsics refined with them
//!    ([`super::graph`]); the world is the first camera's frame (the names in order).
//! 4. The hand frame's axes from the reference board's pose in the world, as the pair's from
//!    its left camera.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Rotation3;

use super::checks::hand_from;
use super::detect::{self, read_all, Seen};
use super::fit::single_camera;
use super::graph::{self, CameraPose, GraphError, Sighting};
use super::{BoardSpec, CalibError, Found, View};
use crate::cv::{fixed, values};
use crate::geometry::Intrinsics;

/// The instant name of the reference board's views.
pub const REFERENCE: &str = "ref";
/// Fewest views of the board a camera's intrinsics are solved from.
pub const MIN_VIEWS: usize = 3;

/// The board views of a folder, by camera name and instant name (`00`, `01`, …, `ref`).
pub type Listing = BTreeMap<String, BTreeMap<String, PathBuf>>;

/// The files of `dir` named `<camera>_<NN or ref>.<png|jpg|jpeg>`, by camera.
///
/// # Errors
/// The folder cannot be listed.
pub fn list(dir: &Path) -> std::io::Result<Listing> {
    let mut listing = Listing::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        let (Some(stem), Some(ext)) = (
            path.file_stem().and_then(|s| s.to_str()),
            path.extension().and_then(|s| s.to_str()),
        ) else {
            continue;
        };
        if !["png", "jpg", "jpeg"].contains(&ext.to_ascii_lowercase().as_str()) {
            continue;
        }
        let Some((camera, instant)) = stem.rsplit_once('_') else {
            continue;
        };
        let word = crate::session::frames::is_camera_name(camera);
        let instant_ok = instant == REFERENCE
            || (!instant.is_empty() && instant.bytes().all(|b| b.is_ascii_digit()));
        if word && instant_ok {
            listing
                .entry(camera.to_string())
                .or_default()
                .insert(instant.to_string(), path);
        }
    }
    Ok(listing)
}

/// Whether a listing is more than a pair: cameras other than `left` and `right`.
pub fn is_graph(listing: &Listing) -> bool {
    listing.keys().any(|name| name != "left" && name != "right")
}

/// One camera of the graph.
#[derive(Clone, Debug)]
pub struct CameraFit {
    pub name: String,
    pub size: [i32; 2],
    /// `calibrateCamera`'s reprojection RMS over its own views (px); the intrinsics, refined
    /// with the poses, are the pose's.
    pub intrinsics_rms_px: f64,
    /// Its images with the board found, of all its images.
    pub views: usize,
    pub images: usize,
    pub pose: CameraPose,
}

/// The calibration of a graph of cameras.
#[derive(Clone, Debug)]
pub struct GraphCalibration {
    pub board: BoardSpec,
    pub cameras: Vec<CameraFit>,
    /// The joint refinement's figures ([`graph::Graph`]).
    pub rms_px: f64,
    pub outliers: usize,
    pub reject_px: f64,
    pub poorly_tied: Vec<String>,
    /// World (the first camera) → hand frame, from the reference board; why not, else.
    pub hand_axes: Option<Rotation3<f64>>,
    pub hand_axes_note: String,
    /// The covariance of the cameras' unknowns ([`graph::CameraCovariance`]).
    pub covariance: Option<graph::CameraCovariance>,
    /// The gates it fails ([`super::gates`]): a reprojection RMS above
    /// [`super::gates::MAX_RMS_PX`], a camera's own or all cameras' together.
    pub implausible: Vec<String>,
}

/// Step 1: the board in every image of `paths`; an error naming the board and the folder when
/// it is in none.
fn find_boards(
    dir: &Path,
    paths: &[&Path],
    board: &BoardSpec,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<Found>, CalibError> {
    let grays = read_all(paths)?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let found = detect::find_all(&grays, board, board.first_detector(), &done, progress)?;
    if found.iter().all(|f| f.1.is_none()) {
        return Err(CalibError::BoardNotFound {
            dir: dir.to_path_buf(),
            cols: board.cols,
            rows: board.rows,
            hint: board.pattern.kind().not_found_hint(board, &grays),
        });
    }
    Ok(found)
}

/// A camera's own calibration: its images' size, its intrinsics from its own views and their
/// reprojection RMS (px), its images with the board found, of all its images.
struct Own {
    size: [i32; 2],
    intrinsics: Intrinsics,
    rms_px: f64,
    views: usize,
    images: usize,
    /// The boards' reprojection RMS with the intrinsics given for it, when given (px).
    given_rms_px: Option<f64>,
}

/// Intrinsics given for every camera of `listing` or none (the joint refinement keeps all of
/// them, or refines all).
///
/// # Errors
/// [`CalibError::GivenNames`] naming the cameras without a file and the names not among them.
fn given_for_all(
    dir: &Path,
    listing: &Listing,
    given: &BTreeMap<String, super::KnownIntrinsics>,
) -> Result<(), CalibError> {
    let missing: Vec<&str> = listing
        .keys()
        .filter(|n| !given.contains_key(n.as_str()))
        .map(String::as_str)
        .collect();
    let unknown: Vec<&str> = given
        .keys()
        .filter(|n| !listing.contains_key(n.as_str()))
        .map(String::as_str)
        .collect();
    if given.is_empty() || (missing.is_empty() && unknown.is_empty()) {
        return Ok(());
    }
    Err(CalibError::GivenNames {
        missing: missing.join(", "),
        unknown: unknown.join(", "),
        dir: dir.to_path_buf(),
    })
}

/// What is implausible about each camera's own fit (its RMS above the gate's) and the
/// intrinsics `given` for it (its boards reprojected far worse with them than with its own).
fn own_implausible(
    names: &[&String],
    cameras: &[Own],
    given: &BTreeMap<String, super::KnownIntrinsics>,
) -> Vec<String> {
    let limit = super::gates::MAX_RMS_PX;
    let mut implausible = Vec::new();
    for (name, own) in names.iter().zip(cameras) {
        if super::gates::exceeds(own.rms_px, limit) {
            implausible.push(format!("camera {name}'s own views reproject at {:.2} px (above {limit} px): a blurred or moving board, or another camera's images among its own", own.rms_px));
        }
        let Some(rms) = own.given_rms_px else {
            continue;
        };
        if super::gates::given_implausible(rms, own.rms_px) {
            implausible.push(format!(
                "{}: camera {name}'s boards reproject at {rms:.3} px with these intrinsics and at {:.3} px with the camera's own fit from the same images; they are not this camera's at this zoom and focus: calibrate it again, or give none",
                given[name.as_str()].path.display(),
                own.rms_px
            ));
        }
    }
    implausible
}

/// Step 2 for camera `name`, whose images and what was found in them are `images`; `given`,
/// its intrinsics known beforehand, checked against them.
fn own_intrinsics(
    dir: &Path,
    name: &str,
    board: &BoardSpec,
    images: &[(&PathBuf, &Found)],
    given: Option<&super::KnownIntrinsics>,
) -> Result<Own, CalibError> {
    let size = images[0].1 .0;
    if let Some((path, ([w, h], _))) = images.iter().find(|(_, f)| f.0 != size) {
        return Err(CalibError::SizeChange(
            (*path).clone(),
            *w,
            *h,
            size[0],
            size[1],
        ));
    }
    let seen: Vec<&Seen> = images.iter().filter_map(|(_, f)| f.1.as_ref()).collect();
    if seen.len() < MIN_VIEWS {
        return Err(CalibError::TooFewViews {
            camera: name.to_string(),
            dir: dir.to_path_buf(),
            found: seen.len(),
            needed: MIN_VIEWS,
        });
    }
    let views: Vec<View> = seen.iter().map(|s| View::from(*s)).collect();
    if let Some(k) = given.filter(|k| k.image_size != size) {
        return Err(CalibError::GivenSize {
            path: k.path.clone(),
            camera: name.to_string(),
            given: k.image_size,
            size,
        });
    }
    let given_rms_px = given
        .map(|k| super::gates::reprojection_rms(board, &k.intrinsics, &views))
        .transpose()?;
    let (k, d, _, rms) = single_camera(board, size, &views)?;
    let intrinsics = Intrinsics {
        k: fixed(&k)?,
        dist: values(&d)?,
    };
    Ok(Own {
        size,
        intrinsics,
        rms_px: rms,
        views: seen.len(),
        images: images.len(),
        given_rms_px,
    })
}

/// Calibrates the cameras of `listing` (module docs); `progress(done, total)` counts images
/// examined.
///
/// # Errors
/// [`CalibError`] naming the image, the camera or the folder, and what to do.
pub fn calibrate(
    dir: &Path,
    listing: &Listing,
    board: &BoardSpec,
    given: &BTreeMap<String, super::KnownIntrinsics>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<GraphCalibration, CalibError> {
    board.check()?;
    let names: Vec<&String> = listing.keys().collect();
    if let [one] = names[..] {
        return Err(CalibError::OneCamera {
            camera: one.clone(),
            dir: dir.to_path_buf(),
        });
    }
    given_for_all(dir, listing, given)?;
    let files: Vec<(usize, &String, &PathBuf)> = listing
        .values()
        .enumerate()
        .flat_map(|(c, views)| views.iter().map(move |(instant, path)| (c, instant, path)))
        .collect();
    let paths: Vec<&Path> = files.iter().map(|f| f.2.as_path()).collect();
    // 1. The board in every image.
    let found = find_boards(dir, &paths, board, progress)?;
    // Instants in order, the reference last.
    let mut instants: Vec<&String> = files.iter().map(|f| f.1).collect();
    instants.sort_by_key(|i| (i.as_str() == REFERENCE, i.to_string()));
    instants.dedup();
    // 2. Each camera's intrinsics from its own views.
    let cameras = names
        .iter()
        .enumerate()
        .map(|(c, name)| {
            let own: Vec<usize> = (0..files.len()).filter(|&i| files[i].0 == c).collect();
            let images: Vec<(&PathBuf, &Found)> =
                own.iter().map(|&i| (files[i].2, &found[i])).collect();
            own_intrinsics(dir, name, board, &images, given.get(name.as_str()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    // 3. The poses.
    let sightings: Vec<Sighting> = files
        .iter()
        .zip(&found)
        .filter_map(|(&(camera, instant, _), (_, seen))| {
            Some(Sighting {
                camera,
                instant: instants.iter().position(|i| *i == instant).expect("listed"),
                seen: seen.clone()?,
            })
        })
        .collect();
    let (intrinsics, kept): (Vec<Intrinsics>, _) = if given.is_empty() {
        let own = cameras.iter().map(|c| c.intrinsics.clone()).collect();
        (own, graph::Intrinsic::Refined)
    } else {
        let known = names.iter().map(|n| given[n.as_str()].intrinsics.clone());
        (known.collect(), graph::Intrinsic::Given)
    };
    let graph = graph::calibrate(board, &intrinsics, kept, &sightings).map_err(|e| match e {
        GraphError::Untied { camera } => CalibError::Untied {
            camera: names[camera].to_string(),
            dir: dir.to_path_buf(),
        },
        GraphError::Calib(e) => e,
    })?;
    // 4. The hand frame's axes.
    let reference = instants.iter().position(|i| i.as_str() == REFERENCE);
    let in_world = reference.and_then(|r| graph.boards.iter().find(|b| b.0 == r));
    let (hand_axes, hand_axes_note) = match (reference, in_world) {
        (Some(_), Some((_, pose))) => (
            Some(hand_from(pose.rotation)),
            "from the reference board (*_ref): board x = hand x, board y = hand -z, board z = hand +y".into(),
        ),
        (Some(_), None) => (None, "the reference board was found in no camera's image".into()),
        (None, _) => (None, format!("no reference board (<camera>_{REFERENCE} images)")),
    };
    let limit = super::gates::MAX_RMS_PX;
    let mut implausible = own_implausible(&names, &cameras, given);
    if super::gates::exceeds(graph.rms_px, limit) {
        implausible.push(format!("the cameras together reproject at {:.2} px (above {limit} px): views named with the same NN that were not taken at the same instant, or a camera moved between them", graph.rms_px));
    }
    Ok(GraphCalibration {
        implausible,
        board: *board,
        cameras: names
            .iter()
            .zip(cameras)
            .zip(&graph.cameras)
            .map(|((name, own), pose)| CameraFit {
                name: name.to_string(),
                size: own.size,
                intrinsics_rms_px: own.rms_px,
                views: own.views,
                images: own.images,
                pose: pose.clone(),
            })
            .collect(),
        rms_px: graph.rms_px,
        covariance: graph.covariance.clone(),
        outliers: graph.outliers,
        reject_px: graph.reject_px,
        poorly_tied: graph
            .poorly_tied
            .iter()
            .map(|&c| names[c].to_string())
            .collect(),
        hand_axes,
        hand_axes_note,
    })
}
