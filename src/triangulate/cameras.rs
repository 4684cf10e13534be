//! The tip of each held step seen by any number of cameras (issue 59): the session's frames
//! named by camera (`frames.csv`: `frame,camera,time_s`; `<camera>_<frame:05>.<ext>`), the
//! cameras and the hand frame's axes from the calibration `handcap calibrate` writes for them
//! (Anipose's `calibration.toml` with `[metadata]`'s `hand_rotation`).
//!
//! 1. Each frame placed in the log's steps as a pair's are (settled, not straddling the next
//!    command); in each, the marker's candidates found ([`super::marker`]); a frame with none
//!    gives no view (counted).
//! 2. Each camera's candidates in a step, grouped across its frames by place (within
//!    [`SAME_PLACE_PX`]): a held bead is one group, a red thing beside it another. Each group's
//!    view is the median of its centres, undistorted.
//! 3. The step's tip from one group per camera ([`super::nview`]): linear, refined, the views
//!    gated by a χ² test in units of each view's pixel error ([`BEAD_NOISE_PX`]), every subset
//!    of two or more tried when one view disagrees. Where a camera has several groups, every
//!    choice is tried and the one the most cameras agree on (then the least χ²) kept: the
//!    bead is where the others see it. The cameras used and left out, and the tip's covariance
//!    from the beads' error.
//! 4. The hand frame: its axes from the calibration, its origin the median tip of the steps
//!    at zero pressure.
//! 5. Each row's covariance: the beads' error, scaled up to what the session shows when that is
//!    more (the steps' χ² over their degrees of freedom, the a-posteriori variance of unit
//!    weight, when they have [`MIN_DOF`] or more; never down: a bead's centre also errs the
//!    same way in every camera, by its shading, which no residual shows; the gate keeps
//!    [`BEAD_NOISE_PX`]), in its tip and in the origin's;
//!    and the calibration's, when its JSON has the cameras' covariance: the row (tip less
//!    origin) refitted from the same pixels with each camera unknown moved, by central
//!    differences, carried through that covariance. The hand axes' own uncertainty (the
//!    reference board's pose) is not in it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix3x4, Rotation3, Vector3};
use rayon::prelude::*;

pub(super) mod covariance;

use super::nview::{self, View};
use super::pairing::{self, Placement};
use super::scene;
use super::TriangulateOptions;
use crate::calib::file::ReadCamera;
use crate::calib::graph::CameraCovariance;
use crate::geometry::Intrinsics;
use crate::session::frames::read_frame_rows;
use crate::session::pressures::PressureLog;
use crate::session::SessionError;

/// A bead centre's error per axis (px) in a view: on webcam MJPEG (4:2:0, quality 85) the
/// sub-pixel fit places the bead to about 0.14 px ([`super::subpixel`]), a bias that stays put
/// while the bead does, so a step's several frames do not shrink it.
pub const BEAD_NOISE_PX: f64 = 0.15;
/// The χ² gate's level.
pub const GATE_LEVEL: f64 = 0.999;
/// The degrees of freedom of the steps' residuals (2 per view less 3 per tip) from which
/// the session's own bead error replaces [`BEAD_NOISE_PX`] in the tips' covariances.
pub const MIN_DOF: usize = 30;
/// A camera's candidates in a held step's frames closer than this (px) are one thing seen
/// again.
pub const SAME_PLACE_PX: f64 = 2.0;
/// The most choices of one group per camera a step tries (each camera's best-supported
/// groups first).
const MOST_CHOICES: usize = 256;

/// One frame of `frames.csv`.
#[derive(Clone, Debug)]
pub struct Frame {
    pub camera: usize,
    pub index: usize,
    pub time_s: f64,
    pub path: PathBuf,
}

/// Reads `dir/frames.csv` for `cameras` (their names,
/// [`crate::session::frames::read_frame_rows`]): every frame of a camera it names, and each
/// one's image (`<camera>_<frame:05>.png`, `.jpg` or `.jpeg`); the frames of cameras the
/// calibration does not have are counted by name, not read.
///
/// # Errors
/// [`SessionError`] naming the file and line: a bad number, a frame listed twice, none listed
/// for these cameras, a frame without its image.
pub fn read_frames(
    dir: &Path,
    cameras: &[ReadCamera],
) -> Result<(Vec<Frame>, BTreeMap<String, usize>), SessionError> {
    let other = std::cell::RefCell::new(BTreeMap::new());
    let rows = read_frame_rows(dir, |name| {
        let camera = cameras.iter().position(|c| c.name == name);
        if camera.is_none() {
            *other.borrow_mut().entry(name.to_string()).or_default() += 1;
        }
        Ok(camera)
    })?;
    let frames = rows
        .into_iter()
        .map(|(camera, index, time_s, line)| {
            let name = &cameras[camera].name;
            let path = crate::session::frames::image_path(dir, name, index).ok_or_else(|| {
                crate::data::DataError::Input {
                    path: dir.join("frames.csv"),
                    line,
                    message: format!("no image {name}_{index:05}.png (or .jpg) beside it"),
                }
            })?;
            Ok(Frame {
                camera,
                index,
                time_s,
                path,
            })
        })
        .collect::<Result<_, SessionError>>()?;
    Ok((frames, other.into_inner()))
}

/// What one frame showed.
pub(super) enum Examined {
    /// The marker's candidates, most red first; none when no marker was found.
    Markers(Vec<super::marker::Blob>),
    Unreadable(String),
    /// An image of another size than the camera's calibration (width, height).
    WrongSize([usize; 2]),
    Skipped,
}

/// Frame `f` examined: decoded, its size checked against its camera's, the marker's candidates
/// found; with `thumbnail`, also the frame's [`scene::Thumbnail`] when it was read at its camera's
/// size.
pub(super) fn examine(
    f: &Frame,
    cameras: &[ReadCamera],
    options: &TriangulateOptions,
    thumbnail: bool,
) -> (Examined, Option<scene::Thumbnail>) {
    let size = cameras[f.camera].size;
    match crate::image::decode(&f.path) {
        Err(why) => (
            Examined::Unreadable(format!("{}: {why}", f.path.display())),
            None,
        ),
        Ok(image) if [image.width, image.height] != size.map(|s| s as usize) => {
            (Examined::WrongSize([image.width, image.height]), None)
        }
        Ok(image) => {
            let blobs = super::marker::find_markers(&image, &options.marker).blobs;
            let small = thumbnail
                .then(|| scene::Thumbnail::of(&image).ok())
                .flatten();
            (Examined::Markers(blobs), small)
        }
    }
}

impl CamerasError {
    /// The error of frame `f` of camera `camera`, `got` pixels wide and high.
    pub(super) fn wrong_size(f: &Frame, camera: &ReadCamera, [got_w, got_h]: [usize; 2]) -> Self {
        let [want_w, want_h] = camera.size;
        CamerasError::WrongSize {
            path: f.path.clone(),
            camera: camera.name.clone(),
            got_w,
            got_h,
            want_w,
            want_h,
        }
    }
}

/// A step's tip.
#[derive(Clone, Debug)]
pub struct StepTip {
    pub step: usize,
    /// Hand frame (mm).
    pub tip_mm: Vector3<f64>,
    /// Its covariance in the hand frame (mm²), from the beads' noise.
    pub covariance_mm2: Matrix3<f64>,
    /// The cameras used and left out by the gate (indices into the calibration's).
    pub used: Vec<usize>,
    pub left_out: Vec<usize>,
    pub chi2: f64,
    /// Frames the cameras used saw the step in.
    pub frames: usize,
}

/// What a run found.
#[derive(Clone, Debug, Default)]
pub struct Found {
    pub tips: Vec<StepTip>,
    /// Frames in a settled step, of those without a marker, and with several candidates.
    pub frames_in_steps: usize,
    pub frames_without_marker: usize,
    pub frames_with_several: usize,
    /// Frames in a settled step whose image could not be read, and the first one's reason.
    pub frames_unreadable: usize,
    pub unreadable: Option<String>,
    /// Ctrl-C came before every frame was examined.
    pub interrupted: bool,
    /// Steps seen by fewer than two cameras, and steps whose views no two agreed on.
    pub steps_unseen: usize,
    pub steps_inconsistent: usize,
    /// The hand frame's origin in the world (the first camera's frame, mm) and how many steps
    /// at zero pressure gave it.
    pub origin_mm: Vector3<f64>,
    pub rest_steps: usize,
    /// The beads' pixel error the steps' residuals show (px), when they have [`MIN_DOF`]
    /// degrees of freedom or more: the tips' covariances are scaled to it when it exceeds
    /// [`BEAD_NOISE_PX`].
    pub bead_noise_px: Option<f64>,
    /// The calibration's uncertainty is in the covariances.
    pub calibration_in_covariance: bool,
}

/// What the cameras are: as calibrated, the hand frame's axes (world → hand), and the
/// covariance of their unknowns when the calibration has it.
pub struct Calibration {
    pub cameras: Vec<ReadCamera>,
    pub hand: Rotation3<f64>,
    pub covariance: Option<CameraCovariance>,
}

/// Why there is no dataset.
#[derive(Debug, thiserror::Error)]
pub enum CamerasError {
    #[error("{path} is {got_w}x{got_h} px, but camera {camera} was calibrated at {want_w}x{want_h}: calibrate the cameras at the size they film, or film at the calibrated size")]
    WrongSize {
        path: PathBuf,
        camera: String,
        got_w: usize,
        got_h: usize,
        want_w: i32,
        want_h: i32,
    },
    #[error("no step at 0, 0, 0 kPa has a tip: the hand frame's origin is the tip at rest; start the protocol with a rest step the cameras see")]
    NoOrigin,
    /// Per frame: what a pair's per-frame run would refuse too.
    #[error(transparent)]
    PerFrame(#[from] super::TriangulateError),
}

/// The tips of `frames` in `log`'s steps (module docs), seen by the cameras of `calibration`
/// and given in its hand frame; `progress(done, total)` counts frames examined; once
/// `interrupt` is set, the frames not yet examined are left out (and `interrupted` said).
///
/// # Errors
/// [`CamerasError::WrongSize`] for a frame of another size than its camera's calibration,
/// [`CamerasError::NoOrigin`].
pub fn triangulate(
    frames: &[Frame],
    calibration: &Calibration,
    log: &PressureLog,
    options: &TriangulateOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &std::sync::atomic::AtomicBool,
) -> Result<Found, CamerasError> {
    // 1. Each frame in a step, and its marker.
    use std::sync::atomic::Ordering::{Relaxed, SeqCst};
    let (cameras, hand) = (&calibration.cameras, calibration.hand);
    let done = std::sync::atomic::AtomicUsize::new(0);
    let seen: Vec<Option<(usize, Examined)>> = frames
        .par_iter()
        .map(|f| {
            let Placement::Step(k) = pairing::place(log, f.time_s, f.time_s, options.settle_s, 0.0)
            else {
                return None;
            };
            if interrupt.load(Relaxed) {
                return Some((k, Examined::Skipped));
            }
            let seen = examine(f, cameras, options, false).0;
            progress(done.fetch_add(1, SeqCst) + 1, frames.len());
            Some((k, seen))
        })
        .collect();
    let mut found = Found::default();
    // 2. Each camera's groups of candidates in each step.
    let mut views: BTreeMap<usize, Vec<Vec<Vec<[f64; 2]>>>> = BTreeMap::new();
    for (f, seen) in frames.iter().zip(seen) {
        let Some((k, seen)) = seen else { continue };
        found.frames_in_steps += 1;
        let step = views
            .entry(k)
            .or_insert_with(|| vec![Vec::new(); cameras.len()]);
        match seen {
            Examined::Markers(blobs) => {
                found.frames_without_marker += usize::from(blobs.is_empty());
                found.frames_with_several += usize::from(blobs.len() > 1);
                for b in blobs {
                    group(&mut step[f.camera], b.centre_px);
                }
            }
            Examined::Unreadable(why) => {
                found.unreadable.get_or_insert(why);
                found.frames_unreadable += 1;
            }
            Examined::Skipped => found.interrupted = true,
            Examined::WrongSize(got) => {
                return Err(CamerasError::wrong_size(f, &cameras[f.camera], got));
            }
        }
    }
    // 3. Each step's tip in the world.
    let world = in_world(&views, cameras, &mut found);
    // 4. The hand frame.
    let rest: Vec<usize> = (0..world.len())
        .filter(|&i| log.steps[world[i].step].pressures_kpa == [0.0; 3])
        .collect();
    if rest.is_empty() {
        return Err(CamerasError::NoOrigin);
    }
    let at_rest: Vec<Vector3<f64>> = rest.iter().map(|&i| world[i].tip.point).collect();
    found.origin_mm = crate::stats::median_point(&at_rest);
    found.rest_steps = at_rest.len();
    // 5. Each row's covariance.
    found.calibration_in_covariance = calibration.covariance.is_some();
    let (covariances, bead_noise_px) = covariance::of_rows(&world, &rest, calibration);
    found.bead_noise_px = bead_noise_px;
    found.tips = world
        .into_iter()
        .zip(covariances)
        .map(|(w, covariance_mm2)| {
            let t = w.tip;
            StepTip {
                step: w.step,
                tip_mm: hand * (t.point - found.origin_mm),
                covariance_mm2,
                used: t.used,
                left_out: t.left_out,
                chi2: t.chi2,
                frames: w.frames,
            }
        })
        .collect();
    Ok(found)
}

/// A step's tip in the world (the first camera's frame).
pub(super) struct InWorld {
    pub step: usize,
    /// Its views' indices are the cameras'.
    pub tip: nview::Triangulated,
    /// The frames of the views used.
    pub frames: usize,
    /// The views used: (camera, distorted px).
    pub pixels: Vec<(usize, [f64; 2])>,
}

/// Each step's tip from `views` (each step's cameras' groups of candidates; module docs, step
/// 3); the steps without one are counted in `found`.
fn in_world(
    views: &BTreeMap<usize, Vec<Vec<Vec<[f64; 2]>>>>,
    cameras: &[ReadCamera],
    found: &mut Found,
) -> Vec<InWorld> {
    let projections: Vec<Matrix3x4<f64>> = cameras
        .iter()
        .map(|c| crate::geometry::projection(&c.intrinsics, &c.pose))
        .collect();
    let mut world = Vec::new();
    for (&step, by_camera) in views {
        // Each camera's groups as views, the best supported first.
        let choices: Vec<(usize, Vec<Group>)> = by_camera
            .iter()
            .enumerate()
            .filter(|(_, groups)| !groups.is_empty())
            .map(|(c, groups)| {
                let mut groups: Vec<&Vec<[f64; 2]>> = groups.iter().collect();
                groups.sort_by_key(|g| std::cmp::Reverse(g.len()));
                let camera = &cameras[c].intrinsics;
                let views = groups
                    .into_iter()
                    .map(|centres| {
                        let median = |i: usize| {
                            let mut v: Vec<f64> = centres.iter().map(|p| p[i]).collect();
                            crate::stats::median(&mut v).expect("a centre")
                        };
                        let px = [median(0), median(1)];
                        Group {
                            view: view_of(camera, &projections[c], px),
                            frames: centres.len(),
                            px,
                        }
                    })
                    .collect();
                (c, views)
            })
            .collect();
        match agreed(&choices) {
            Ok((mut tip, chosen)) => {
                let camera = |i: usize| choices[i].0;
                let group = |i: usize| &choices[i].1[chosen[i]];
                let frames = tip.used.iter().map(|&i| group(i).frames).sum();
                let pixels = tip.used.iter().map(|&i| (camera(i), group(i).px)).collect();
                tip.used = tip.used.iter().map(|&i| camera(i)).collect();
                tip.left_out = tip.left_out.iter().map(|&i| camera(i)).collect();
                world.push(InWorld {
                    step,
                    tip,
                    frames,
                    pixels,
                });
            }
            Err(nview::Refused::TooFewViews) => found.steps_unseen += 1,
            Err(nview::Refused::Inconsistent { .. }) => found.steps_inconsistent += 1,
        }
    }
    world
}

/// A camera's candidates in a step's frames at one place (module docs, step 2).
pub(super) struct Group {
    /// The median of their centres, undistorted.
    pub view: View,
    /// How many frames saw it.
    pub frames: usize,
    /// The median of their centres (distorted px).
    pub px: [f64; 2],
}

/// The view of a bead seen at `px` (distorted) by a camera of `intrinsics` and `projection`.
pub(super) fn view_of(intrinsics: &Intrinsics, projection: &Matrix3x4<f64>, px: [f64; 2]) -> View {
    let (x, y) = intrinsics.undistort(px[0], px[1]);
    View {
        projection: *projection,
        px: [
            intrinsics.fx() * x + intrinsics.cx(),
            intrinsics.fy() * y + intrinsics.cy(),
        ],
        sigma_px: BEAD_NOISE_PX,
    }
}

/// Adds candidate `c` to the group of `groups` whose first member lies within
/// [`SAME_PLACE_PX`], or as a group of its own.
fn group(groups: &mut Vec<Vec<[f64; 2]>>, c: [f64; 2]) {
    let near = |g: &&mut Vec<[f64; 2]>| (g[0][0] - c[0]).hypot(g[0][1] - c[1]) < SAME_PLACE_PX;
    match groups.iter_mut().find(near) {
        Some(g) => g.push(c),
        None => groups.push(vec![c]),
    }
}

/// The tip from one view per camera of `choices` (each camera's groups, the best supported
/// first): every choice tried (up to [`MOST_CHOICES`], the best supported first),
/// the one the most views agree on kept, then the least χ². The tip and each camera's choice.
pub(super) fn agreed(
    choices: &[(usize, Vec<Group>)],
) -> Result<(nview::Triangulated, Vec<usize>), nview::Refused> {
    let mut best: Option<(nview::Triangulated, Vec<usize>)> = None;
    let mut refused = nview::Refused::TooFewViews;
    let mut chosen = vec![0; choices.len()];
    for _ in 0..MOST_CHOICES {
        let views: Vec<View> = choices
            .iter()
            .zip(&chosen)
            .map(|((_, groups), &i)| groups[i].view)
            .collect();
        match nview::triangulate(&views, GATE_LEVEL) {
            Ok(t) => {
                let better = best
                    .as_ref()
                    .is_none_or(|(b, _)| (t.used.len(), -t.chi2) > (b.used.len(), -b.chi2));
                if better {
                    best = Some((t, chosen.clone()));
                }
            }
            Err(why) => refused = why,
        }
        // The next choice, counting with each camera a digit.
        let Some(c) = (0..choices.len()).find(|&c| chosen[c] + 1 < choices[c].1.len()) else {
            break;
        };
        chosen[c] += 1;
        chosen[..c].fill(0);
    }
    best.ok_or(refused)
}

/// The dataset's columns before the log's other ones: the pressures, the tip, how sure it is
/// and the cameras it used; the log's other columns (`step`, `phase`, …) follow, as a pair's
/// dataset has them.
pub const HEADER: &str = "P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,sd_x_mm,sd_y_mm,sd_z_mm,cov_xy_mm2,cov_xz_mm2,cov_yz_mm2,n_cameras,cameras,left_out,chi2,n_frames";

impl Found {
    /// Writes `out` (every step's tip), `OUT_<phase>.csv` per phase of the log, and
    /// `OUT_summary.json`, as a pair's datasets are, removing what a previous run into the same
    /// place wrote and this one did not; returns the files written.
    ///
    /// # Errors
    /// [`super::TriangulateError::Write`] naming the file.
    pub fn write(
        &self,
        out: &Path,
        log: &PressureLog,
        cameras: &[ReadCamera],
        options: &TriangulateOptions,
        provenance: &crate::provenance::Provenance,
    ) -> Result<Vec<PathBuf>, super::TriangulateError> {
        let summary = serde_json::json!({
            "per_frame": false,
            "summary": {
                "cameras": cameras.iter().map(|c| &c.name).collect::<Vec<_>>(),
                "tips": self.tips.len(),
                "frames_in_steps": self.frames_in_steps,
                "frames_without_marker": self.frames_without_marker,
                "frames_with_several": self.frames_with_several,
                "frames_unreadable": self.frames_unreadable,
                "first_unreadable": self.unreadable,
                "steps_unseen": self.steps_unseen,
                "steps_inconsistent": self.steps_inconsistent,
                "origin_mm": self.origin_mm.as_slice(),
                "rest_steps": self.rest_steps,
                "bead_noise_px": self.bead_noise_px,
                "calibration_in_covariance": self.calibration_in_covariance,
                "interrupted": self.interrupted,
            },
            "options": options,
            "provenance": provenance,
        });
        let steps: Vec<Option<usize>> = self.tips.iter().map(|t| Some(t.step)).collect();
        super::per_frame::write_rows(out, log, &steps, summary, &|keep| {
            csv(self, |t| keep(Some(t.step)), cameras, log)
        })
    }
}

/// The rows of `found` that `keep` keeps as CSV (camera names joined by `+`), each followed
/// by its log row's other columns.
pub fn csv(
    found: &Found,
    keep: impl Fn(&StepTip) -> bool,
    cameras: &[ReadCamera],
    log: &PressureLog,
) -> String {
    use std::fmt::Write as _;
    let mut out = String::from(HEADER);
    for column in &log.extra_columns {
        let _ = write!(out, ",{column}");
    }
    out.push('\n');
    for t in found.tips.iter().filter(|t| keep(t)) {
        let step = &log.steps[t.step];
        let [p1, p2, p3] = step.pressures_kpa;
        let _ = write!(
            out,
            "{p1},{p2},{p3},{:.4},{:.4},{:.4},{},{},{},{},{:.3},{}",
            t.tip_mm.x,
            t.tip_mm.y,
            t.tip_mm.z,
            covariance_fields(&t.covariance_mm2),
            t.used.len(),
            camera_names(cameras, &t.used),
            camera_names(cameras, &t.left_out),
            t.chi2,
            t.frames
        );
        for value in &step.extra {
            let _ = write!(out, ",{value}");
        }
        out.push('\n');
    }
    out
}

/// A tip's covariance as the dataset's fields: `sd_x_mm,sd_y_mm,sd_z_mm` (4 decimals),
/// `cov_xy_mm2,cov_xz_mm2,cov_yz_mm2`.
pub(super) fn covariance_fields(c: &Matrix3<f64>) -> String {
    let sd = |i: usize| c[(i, i)].max(0.0).sqrt();
    format!(
        "{:.4},{:.4},{:.4},{:.3e},{:.3e},{:.3e}",
        sd(0),
        sd(1),
        sd(2),
        c[(0, 1)],
        c[(0, 2)],
        c[(1, 2)]
    )
}

/// The names of cameras `list`, joined by `+`.
pub(super) fn camera_names(cameras: &[ReadCamera], list: &[usize]) -> String {
    let names: Vec<&str> = list.iter().map(|&c| cameras[c].name.as_str()).collect();
    names.join("+")
}
