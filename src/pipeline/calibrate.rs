//! The calibrate stage: chessboard pairs → the calibration file and its figures.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::{io_error, PipelineError, Session, Task};
use crate::calib::uncertainty::{self, ParameterSd};
use crate::calib::{
    self, file, validate, BoardSpec, CalibOptions, KnownIntrinsics, PartialBoard, StereoCalibration,
};
use crate::fsio;

/// What the stage did and wrote.
pub struct Calibrated {
    pub calibration: StereoCalibration,
    /// The pairs picked from videos, when the folder held videos.
    pub picked: Option<calib::video::Picked>,
    /// The calibration file first, then the figures.
    pub written: Vec<PathBuf>,
}

/// The board: what `flags` give, the rest from `dir/board.yml`, or, when the directory has
/// none, from the printed board of the repository's `calib/board.yml` (said in an
/// [`super::Event::Note`]). A flag that contradicts `dir/board.yml` is refused: a board read as
/// 6x9 instead of 9x6 turns the hand frame by 90°.
///
/// # Errors
/// [`PipelineError::Camera`] (a calibration error) when `dir/board.yml` exists but cannot be read;
/// [`PipelineError::Request`] when a flag contradicts it, or the flags do not fit together.
pub fn board(
    dir: &Path,
    given: &PartialBoard,
    session: &Session,
) -> Result<BoardSpec, PipelineError> {
    let path = dir.join(file::BOARD_FILE);
    let base = if path.exists() {
        let written = file::read_board(&path)?;
        if let Some(part) = given.contradiction(&written) {
            return Err(PipelineError::Request(format!(
                "{part} contradicts {} ({written}); correct the file or drop the option",
                path.display()
            )));
        }
        written
    } else {
        let b = file::default_board();
        if !given.complete() {
            session.emit(super::Event::Note(format!(
                "no {} and no board described: assuming the printed board of calib/board.yml ({b})",
                path.display()
            )));
        }
        b
    };
    given.over(&base).map_err(PipelineError::Request)
}

/// Calibrates from the pairs in `dir` and writes `out` (OpenCV YAML) and the figures beside it.
///
/// # Errors
/// [`PipelineError`]: too few usable pairs, unreadable images, a file that cannot be written,
/// or `out` naming an input.
pub fn run(
    dir: &Path,
    board: &BoardSpec,
    options: &CalibOptions,
    out: &Path,
    session: &Session,
) -> Result<Calibrated, PipelineError> {
    let picked = pick_from_videos(dir, board, options, out, session)?;
    let dir = picked.as_ref().map_or(dir, |p| p.dir.as_path());
    let listing = calib::pairs::list_pairs(dir).map_err(io_error(dir))?;
    let board_file = dir.join(file::BOARD_FILE);
    let images = listing
        .pairs
        .iter()
        .chain(&listing.reference)
        .flat_map(|p| [p.left.as_path(), p.right.as_path()])
        .chain(listing.unpaired.iter().map(PathBuf::as_path));
    let known = options
        .intrinsics
        .iter()
        .flatten()
        .map(|k| k.path.as_path());
    let inputs: Vec<&Path> = images.chain([board_file.as_path()]).chain(known).collect();
    let [pairs_png, pairs_svg, rectified] = calib::figures::figure_paths(out);
    outputs::check(
        &inputs,
        &[
            Output::new(out, "the calibration"),
            Output::new(file::toml_path(out), "the Anipose calibration.toml"),
            Output::new(file::json_path(out), "the calibration as JSON"),
            Output::new(pairs_png, "the per-pair error figure"),
            Output::new(pairs_svg, "the per-pair error figure"),
            Output::new(rectified, "the rectified pair figure"),
        ],
    )?;
    let result = calib::calibrate(dir, board, options, &session.counter(Task::Detect));
    session.emit(super::Event::Finished(Task::Detect));
    let calibration = result?;
    refuse_implausible(dir, &calibration.implausible, options.force, session)?;
    let seed = (options.bootstrap > 0).then_some(options.seed);
    let yaml = file::calibration_yaml(&calibration, &session.provenance(seed));
    fsio::write_bytes(out, yaml.as_bytes()).map_err(io_error(out))?;
    let toml = file::toml_path(out);
    fsio::write_bytes(&toml, file::anipose_toml(&calibration).as_bytes())
        .map_err(io_error(&toml))?;
    let json = file::json_path(out);
    fsio::write_bytes(&json, file::calibration_json(&calibration).as_bytes())
        .map_err(io_error(&json))?;
    let mut written = vec![out.to_path_buf(), toml, json];
    written.extend(calibration.write_figures(out)?);
    Ok(Calibrated {
        calibration,
        picked,
        written,
    })
}

/// A calibration failing a gate (`implausible`) refused, or with `force` written with a
/// warning for each failure.
///
/// # Errors
/// [`calib::CalibError::Implausible`] naming every failure.
fn refuse_implausible(
    dir: &Path,
    implausible: &[String],
    force: bool,
    session: &Session,
) -> Result<(), PipelineError> {
    if !implausible.is_empty() && !force {
        return Err(calib::CalibError::Implausible {
            dir: dir.to_path_buf(),
            problems: implausible.join("; "),
        }
        .into());
    }
    for problem in implausible {
        session.emit(super::Event::Note(format!(
            "warning: written with --force although {problem}"
        )));
    }
    Ok(())
}

/// The folder the pairs picked from videos go to: `OUT_frames/` beside the calibration file.
pub fn video_pairs_dir(out: &Path) -> PathBuf {
    fsio::beside(out, "calib", "_frames")
}

/// When `dir` holds `left.<video>` and `right.<video>`: still, diverse board pairs picked from
/// them ([`calib::video`]) into [`video_pairs_dir`], with `dir`'s board file and reference pair.
fn pick_from_videos(
    dir: &Path,
    board: &BoardSpec,
    options: &CalibOptions,
    out: &Path,
    session: &Session,
) -> Result<Option<calib::video::Picked>, PipelineError> {
    use crate::session::frames::{self, FrameList};
    if !matches!(frames::videos(dir)?, (Some(_), Some(_))) {
        return Ok(None);
    }
    let frames = FrameList::read(dir, options.video_start_s)?;
    let to = video_pairs_dir(out);
    if to.exists() {
        return Err(PipelineError::Request(format!(
            "{} exists (pairs picked by an earlier run): remove it, or calibrate from it directly",
            to.display()
        )));
    }
    let picked = calib::video::pick_pairs(
        &frames,
        board,
        options.max_video_pairs,
        &to,
        &session.counter(Task::Detect),
    );
    session.emit(super::Event::Finished(Task::Detect));
    let picked = picked?;
    let listing = calib::pairs::list_pairs(dir).map_err(io_error(dir))?;
    let copies = listing
        .reference
        .iter()
        .flat_map(|p| [p.left.clone(), p.right.clone()])
        .chain(Some(dir.join(file::BOARD_FILE)).filter(|p| p.exists()));
    for from in copies {
        let name = from.file_name().expect("a file");
        std::fs::copy(&from, to.join(name)).map_err(io_error(&to.join(name)))?;
    }
    session.emit(super::Event::Note(format!(
        "videos: {} frame pairs searched, the board in both images in {}, still in {}; {} picked into {}",
        picked.searched,
        picked.seen,
        picked.still,
        picked.frames.len(),
        picked.dir.display()
    )));
    Ok(Some(picked))
}

impl fmt::Display for Calibrated {
    /// What the calibration found, as `handcap calibrate` prints it.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let c = &self.calibration;
        for image in &c.unpaired {
            writeln!(f, "skipped {}: no partner image", image.display())?;
        }
        writeln!(
            f,
            "{} pairs used, {} rejected; detector: {}",
            c.used().count(),
            c.rejected().count(),
            c.detector.name()
        )?;
        for p in &c.pairs {
            match (&p.rms_px, &p.rejected) {
                (Some([l, r]), _) => writeln!(
                    f,
                    "  {:>6}  left {l:.3} px  right {r:.3} px{}",
                    p.name,
                    p.note
                        .as_ref()
                        .map(|n| format!("  ({n})"))
                        .unwrap_or_default()
                )?,
                (_, Some(why)) => writeln!(f, "  {:>6}  rejected: {why}", p.name)?,
                _ => {}
            }
        }
        let baseline = c.rig.right_from_left.translation.norm();
        writeln!(
            f,
            "RMS {:.3} px, epipolar {:.3} px, baseline {baseline:.2} mm, f {:.1}/{:.1} px",
            c.rms_px,
            c.epipolar_px,
            c.rig.left.fx(),
            c.rig.right.fx()
        )?;
        let parameters = |sd: &ParameterSd| {
            let camera = |sd: Option<[f64; 9]>| match sd {
                Some(sd) => format!(
                    "fx ±{:.2} fy ±{:.2} cx ±{:.2} cy ±{:.2} px",
                    sd[0], sd[1], sd[2], sd[3]
                ),
                None => "fixed".into(),
            };
            let [rx, ry, rz] = sd.rotation_deg;
            format!(
            "left {}; right {}; baseline ±{:.3} mm ({:.3} %), rotation ±{rx:.3}/{ry:.3}/{rz:.3}° about x/y/z",
            camera(sd.intrinsics[0]),
            camera(sd.intrinsics[1]),
            sd.baseline_mm,
            100.0 * sd.baseline_mm / baseline
        )
        };
        match &c.uncertainty {
            Some(u) => {
                writeln!(
                    f,
                    "1 sd (covariance of the fit, corners ±{:.3} px): {}",
                    u.corner_sd_px,
                    parameters(&u.parameters)
                )?;
                let t = &u.tip;
                let axes = |v: [f64; 3]| format!("±{:.3}/{:.3}/{:.3} mm", v[0], v[1], v[2]);
                writeln!(f,
                "tip at {} ({:.0} mm away), x/y/depth: position {} and a {} mm move {} from the calibration; {} per {} px of marker noise",
                u.at,
                nalgebra::Vector3::from(u.at_mm).norm(),
                axes(t.position),
                uncertainty::DISPLACEMENT_MM,
                axes(t.displacement),
                axes(t.marker),
                uncertainty::MARKER_NOISE_PX
            )?;
            }
            None => writeln!(f, "{}", file::uncertainty_note(c))?,
        }
        if let Some(b) = &c.bootstrap {
            writeln!(
                f,
                "1 sd (bootstrap, {} rounds, seed {}): {}",
                b.rounds,
                b.seed,
                parameters(&b.parameters)
            )?;
        }
        let g = &c.guidance;
        let coverage = g.coverage();
        writeln!(f,
        "coverage {:.0} % / {:.0} % of the image (left / right, # = corners seen); board tilt sd {:.0}° about x, {:.0}° about y",
        100.0 * coverage[0],
        100.0 * coverage[1],
        g.tilt_sd_deg[0],
        g.tilt_sd_deg[1]
    )?;
        for (l, r) in g.map(0).iter().zip(g.map(1)) {
            writeln!(f, "  {l}  {r}")?;
        }
        writeln!(
            f,
            "boards triangulate to {:.4} ± {:.4} squares, {:.3} mm off-plane RMS",
            c.board_check.neighbour_mean_squares,
            c.board_check.neighbour_sd_squares,
            c.board_check.planarity_rms_mm
        )?;
        if let Some(v) = &c.validation {
            validation(f, v)?;
        }
        writeln!(f, "hand axes: {}", c.hand_axes_note)?;
        for a in &g.advice {
            writeln!(f, "advice: {a}")?;
        }
        Ok(())
    }
}

/// The validation: the stated deviations checked against two halves of the pairs.
fn validation(f: &mut fmt::Formatter, v: &validate::Validation) -> fmt::Result {
    let axes = |v: [f64; 3]| format!("{:.4}/{:.4}/{:.4}", v[0], v[1], v[2]);
    writeln!(f,
        "validation ({} splits into halves of {}/{} pairs): the halves' tips disagree by {} mm RMS (x/y/depth) over ±{} mm around the finger, their covariances predict {} mm: ratio {:.2} (about 1 when the stated deviations are honest)",
        v.splits,
        v.half_pairs[0],
        v.half_pairs[1],
        axes(v.disagreement_mm),
        validate::VOLUME_MM,
        axes(v.predicted_mm),
        v.ratio
    )?;
    if let (Some(near), Some(far)) = (v.map.first(), v.map.last()) {
        writeln!(f,
            "  tip position sd {:.4} mm {:.0} mm from the nearest board corner seen, {:.4} mm at {:.0} mm; the finger's base is {:.0} mm from one",
            near.1, near.0, far.1, far.0, v.base_distance_mm
        )?;
    }
    for w in &v.warnings {
        writeln!(f, "  warning: {w}")?;
    }
    Ok(())
}

/// What `handcap calibrate` did: a pair's calibration or more cameras'.
pub enum Done {
    Pair(Box<Calibrated>),
    Cameras(Box<CalibratedCameras>),
}

impl Done {
    /// The files written, the calibration first.
    pub fn written(&self) -> &[PathBuf] {
        match self {
            Done::Pair(done) => &done.written,
            Done::Cameras(done) => &done.written,
        }
    }
}

impl fmt::Display for Done {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            Done::Pair(done) => done.fmt(f),
            Done::Cameras(done) => done.fmt(f),
        }
    }
}

/// Calibrates the cameras whose views `dir` holds: a pair ([`run`]) or more cameras
/// ([`run_cameras`], which refuses the options only a pair has).
///
/// # Errors
/// As [`run`] and [`run_cameras`]; [`PipelineError::Request`] for a pair's option with more
/// cameras.
pub fn run_any(
    dir: &Path,
    board: &BoardSpec,
    options: &CalibOptions,
    out: &Path,
    session: &Session,
) -> Result<Done, PipelineError> {
    let listing = calib::cameras::list(dir).map_err(io_error(dir))?;
    if !calib::cameras::is_graph(&listing) {
        if !options.named_intrinsics.is_empty() {
            return Err(PipelineError::Request(format!(
                "--intrinsics NAME=FILE is for more cameras; {} holds a pair's views: give --intrinsics LEFT,RIGHT",
                dir.display()
            )));
        }
        return run(dir, board, options, out, session).map(|done| Done::Pair(Box::new(done)));
    }
    let pair_only = [
        (
            "--intrinsics LEFT,RIGHT (with more cameras, --intrinsics NAME=FILE,…)",
            options.intrinsics.iter().any(Option::is_some),
        ),
        ("--bootstrap", options.bootstrap > 0),
        ("--validate", options.validate),
        ("--video-start-s", options.video_start_s.is_some()),
    ];
    if let Some((flag, _)) = pair_only.iter().find(|(_, given)| *given) {
        return Err(PipelineError::Request(format!(
            "{flag} is for a pair of cameras (left_NN, right_NN); {} holds the views of {} cameras ({})",
            dir.display(),
            listing.len(),
            listing.keys().cloned().collect::<Vec<_>>().join(", ")
        )));
    }
    let given = &options.named_intrinsics;
    run_cameras(dir, &listing, board, given, options.force, out, session)
        .map(|done| Done::Cameras(Box::new(done)))
}

/// `--intrinsics`' files read: `LEFT,RIGHT` for a pair (`-` for a camera to solve), or
/// `NAME=FILE` for each of more cameras; the pair's, and the named ones'.
///
/// # Errors
/// [`PipelineError::Request`] for a list of neither form; an unreadable file.
#[allow(clippy::type_complexity)]
pub fn given_intrinsics(
    list: &[PathBuf],
) -> Result<
    (
        [Option<KnownIntrinsics>; 2],
        BTreeMap<String, KnownIntrinsics>,
    ),
    PipelineError,
> {
    let texts: Vec<String> = list.iter().map(|p| p.to_string_lossy().into()).collect();
    // A pair's path may hold `=`: the named form's name is a camera's.
    let named: Vec<(&str, &str)> = texts
        .iter()
        .filter_map(|t| t.split_once('='))
        .filter(|(name, _)| crate::session::frames::is_camera_name(name))
        .collect();
    let mut pair = [None, None];
    if named.is_empty() {
        if !list.is_empty() && list.len() != 2 {
            return Err(PipelineError::Request(
                "--intrinsics takes LEFT,RIGHT (`-` for a camera to solve), or NAME=FILE for each of more cameras".into(),
            ));
        }
        for (slot, path) in pair.iter_mut().zip(list) {
            if path.as_os_str() != "-" {
                *slot = Some(file::read_intrinsics(path)?);
            }
        }
        return Ok((pair, BTreeMap::new()));
    }
    if named.len() != list.len() {
        return Err(PipelineError::Request(
            "--intrinsics with more cameras takes NAME=FILE for each of them (cam1=cam1.yml,cam2=cam2.yml,…)".into(),
        ));
    }
    let mut given = BTreeMap::new();
    for (name, path) in named {
        let known = file::read_intrinsics(Path::new(path))?;
        if given.insert(name.to_string(), known).is_some() {
            return Err(PipelineError::Request(format!(
                "--intrinsics names camera {name} twice: give each camera's file once"
            )));
        }
    }
    Ok((pair, given))
}

/// What the calibration of more than two cameras did and wrote.
pub struct CalibratedCameras {
    pub calibration: calib::cameras::GraphCalibration,
    /// The cameras whose intrinsics were given, and their files.
    pub given: Vec<(String, PathBuf)>,
    pub written: Vec<PathBuf>,
}

/// Calibrates the cameras of `listing` (more than a pair, [`calib::cameras`]) from the views in
/// `dir` and writes their Anipose `calibration.toml` beside `out` (`OUT.toml`) and the
/// calibration with its deviations as JSON (`OUT.json`).
///
/// # Errors
/// [`PipelineError`]: too few views, a camera tied to none of the others, a gate failed
/// without `force`, unreadable images, a file that cannot be written, or the output naming an
/// input.
#[allow(clippy::too_many_arguments)]
pub fn run_cameras(
    dir: &Path,
    listing: &calib::cameras::Listing,
    board: &BoardSpec,
    given: &BTreeMap<String, KnownIntrinsics>,
    force: bool,
    out: &Path,
    session: &Session,
) -> Result<CalibratedCameras, PipelineError> {
    let board_file = dir.join(file::BOARD_FILE);
    let inputs: Vec<&Path> = listing
        .values()
        .flat_map(|views| views.values().map(PathBuf::as_path))
        .chain([board_file.as_path()])
        .chain(given.values().map(|k| k.path.as_path()))
        .collect();
    let (toml, json) = (file::toml_path(out), file::json_path(out));
    outputs::check(
        &inputs,
        &[
            Output::new(&toml, "the Anipose calibration.toml"),
            Output::new(&json, "the calibration as JSON"),
        ],
    )?;
    let progress = session.counter(Task::Detect);
    let result = calib::cameras::calibrate(dir, listing, board, given, &progress);
    session.emit(super::Event::Finished(Task::Detect));
    let calibration = result?;
    refuse_implausible(dir, &calibration.implausible, force, session)?;
    let cameras: Vec<file::AniposeCamera> = calibration
        .cameras
        .iter()
        .map(|c| file::AniposeCamera {
            name: &c.name,
            size: c.size,
            intrinsics: &c.pose.intrinsics,
            pose: c.pose.cam_from_world,
        })
        .collect();
    let text = file::cameras_toml(&cameras, calibration.rms_px, calibration.hand_axes);
    fsio::write_bytes(&toml, text.as_bytes()).map_err(io_error(&toml))?;
    let text = file::cameras_json(&calibration);
    fsio::write_bytes(&json, text.as_bytes()).map_err(io_error(&json))?;
    Ok(CalibratedCameras {
        calibration,
        given: given
            .iter()
            .map(|(n, k)| (n.clone(), k.path.clone()))
            .collect(),
        written: vec![toml, json],
    })
}

impl fmt::Display for CalibratedCameras {
    /// What the calibration found, as `handcap calibrate` prints it.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let c = &self.calibration;
        for (i, camera) in c.cameras.iter().enumerate() {
            let pose = &camera.pose;
            let [w, h] = camera.size;
            write!(
                f,
                "{}: {w}x{h}, the board in {} of {} images, intrinsics RMS {:.3} px, f {:.1} px; {} instants shared; ",
                camera.name, camera.views, camera.images, camera.intrinsics_rms_px,
                pose.intrinsics.fx(), pose.shared
            )?;
            match i {
                0 => writeln!(f, "the world")?,
                _ => writeln!(
                    f,
                    "at {:.1} mm from {}, 1 sd {:.3}° and {:.3} mm",
                    pose.cam_from_world.centre().coords.norm(),
                    c.cameras[0].name,
                    pose.rotation_sd_deg,
                    pose.position_sd_mm
                )?,
            }
        }
        writeln!(
            f,
            "all cameras together: RMS {:.3} px, {} corners left out as wrong (beyond {:.2} px)",
            c.rms_px, c.outliers, c.reject_px
        )?;
        if !c.poorly_tied.is_empty() {
            writeln!(
                f,
                "poorly tied: {} (fewer than {} instants shared with another camera); add views where it and another camera see the board at once",
                c.poorly_tied.join(", "),
                calib::graph::MIN_SHARED
            )?;
        }
        for (name, path) in &self.given {
            writeln!(
                f,
                "{name} intrinsics fixed as {} gives them",
                path.display()
            )?;
        }
        writeln!(f, "hand frame axes: {}", c.hand_axes_note)
    }
}
