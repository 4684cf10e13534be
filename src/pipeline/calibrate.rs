//! The calibrate stage: chessboard pairs → the calibration file and its figures.

use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::{io_error, PipelineError, Session, Task};
use crate::calib::{self, file, BoardSpec, CalibOptions, PartialBoard, StereoCalibration};
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
/// [`PipelineError::Calib`] when `dir/board.yml` exists but cannot be read;
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
    if !calibration.implausible.is_empty() {
        if !options.force {
            return Err(calib::CalibError::Implausible {
                dir: dir.to_path_buf(),
                problems: calibration.implausible.join("; "),
            }
            .into());
        }
        for problem in &calibration.implausible {
            session.emit(super::Event::Note(format!(
                "warning: written with --force although {problem}"
            )));
        }
    }
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
