//! The triangulate stage: frames, calibration and pressure log → the dataset and the files
//! beside it.

use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::{io_error, PipelineError, Session, Task};
use crate::calib::file::{read_calibration, CalibrationFile};
use crate::capture::flash::FlashLatency;
use crate::capture::CAPTURE_FILE;
use crate::session::frames::FrameList;
use crate::session::pressures::{read_pressure_log, PressureLog};
use crate::triangulate::per_frame::{self, PerFrame};
use crate::triangulate::{self, output, TriangulateOptions, Triangulation};

/// What the stage did and wrote.
pub struct Triangulated {
    pub triangulation: Triangulation,
    /// The dataset first, then the files beside it.
    pub written: Vec<PathBuf>,
}

/// The regulator's log: `given`, else `pressures.csv` beside the frames directory.
///
/// # Errors
/// [`PipelineError::Request`] when none is given and there is no such file.
pub fn pressure_log(frames: &Path, given: Option<PathBuf>) -> Result<PathBuf, PipelineError> {
    given
        .or_else(|| {
            frames
                .parent()
                .map(|d| d.join("pressures.csv"))
                .filter(|p| p.is_file())
        })
        .ok_or_else(|| {
            PipelineError::Request(format!(
                "no pressure log given and no pressures.csv beside {}; give the log (pressures=LOG.csv)",
                frames.display()
            ))
        })
}

/// Both cameras' latencies (ms) measured from the flash `capture` filmed, when the frames'
/// session has them ([`crate::capture::flash`]).
fn flash_latency(frames: &Path) -> Option<[f64; 2]> {
    let text = std::fs::read_to_string(frames.parent()?.join(CAPTURE_FILE)).ok()?;
    let json: serde_json::Value = serde_json::from_str(&text).ok()?;
    let flash: FlashLatency = serde_json::from_value(json["summary"]["flash"].clone()).ok()?;
    flash.both_ms()
}

/// Checks every file `run` writes against every file it reads (the frames and their index, the
/// calibration, the log) and against each other.
fn check_outputs(
    frames: &Path,
    listed: &FrameList,
    calib: &Path,
    pressures: &Path,
    log: &PressureLog,
    out: &Path,
) -> Result<(), PipelineError> {
    let index = frames.join("frames.csv");
    let inputs: Vec<&Path> = [calib, pressures, index.as_path()]
        .into_iter()
        .chain(listed.paths.iter().flatten().map(PathBuf::as_path))
        .chain(listed.videos.iter().flatten().map(PathBuf::as_path))
        .collect();
    let mut planned = vec![Output::new(out, "the dataset")];
    if let Some(col) = log.extra_columns.iter().position(|c| c == "phase") {
        let mut phases: Vec<&str> = log.steps.iter().map(|s| s.extra[col].as_str()).collect();
        phases.sort_unstable();
        phases.dedup();
        planned.extend(phases.into_iter().map(|phase| {
            Output::new(
                output::phase_path(out, phase),
                format!("the dataset of phase `{phase}`"),
            )
        }));
    }
    planned.extend(
        output::BESIDE
            .iter()
            .map(|(suffix, role)| Output::new(output::beside(out, suffix), *role)),
    );
    outputs::check(&inputs, &planned)
}

/// The run's inputs, read and checked: `frames` a directory, the options in their ranges, the
/// calibration, the log, the frame list, and no output naming an input.
fn read_inputs(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
) -> Result<(CalibrationFile, PressureLog, FrameList), PipelineError> {
    if !frames.is_dir() {
        return Err(PipelineError::Place(format!(
            "{} is not a directory of frames",
            frames.display()
        )));
    }
    options.check().map_err(PipelineError::Request)?;
    let calibration = read_calibration(calib)?;
    let log = read_pressure_log(pressures)?;
    let listed = FrameList::read(frames, options.video_start_s)?;
    check_outputs(frames, &listed, calib, pressures, &log, out)?;
    Ok((calibration, log, listed))
}

/// Finds the tip in every frame pair of `frames`, in the hand frame of `calib`, one row per
/// step of the log at `pressures`; writes `out` and the files beside it. Ctrl-C stops at the
/// next frame: the files hold the frames examined, and the summary says `interrupted`.
///
/// # Errors
/// [`PipelineError`]: unreadable inputs, no usable step, `out` naming an input, or a file that
/// cannot be written.
pub fn run(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
    session: &Session,
) -> Result<Triangulated, PipelineError> {
    // Delays not given: the flash `capture` filmed measured them, when it did.
    let flash = options
        .latency_s
        .is_none()
        .then(|| flash_latency(frames))
        .flatten();
    let options = &TriangulateOptions {
        latency_s: options.latency_s.or(flash.map(|ms| ms.map(|ms| ms / 1e3))),
        ..options.clone()
    };
    let (calibration, log, listed) = read_inputs(frames, calib, pressures, options, out)?;
    let result = triangulate::triangulate(
        &listed,
        &calibration,
        &log,
        options,
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::Event::Finished(Task::Frames));
    let mut triangulation = result?;
    if flash.is_some() {
        triangulation.summary.latency.from = Some(format!("from the flash in {CAPTURE_FILE}"));
    }
    let provenance = provenance(session, frames, calib, pressures)?;
    let written = triangulation.write(out, &provenance)?;
    Ok(Triangulated {
        triangulation,
        written,
    })
}

/// The run's provenance: the calibration, the log and the frame list (when there is one) as its
/// inputs.
fn provenance(
    session: &Session,
    frames: &Path,
    calib: &Path,
    pressures: &Path,
) -> Result<crate::provenance::Provenance, PipelineError> {
    let mut provenance = session.provenance(None);
    let index = frames.join("frames.csv");
    let listed_by = Some(index.as_path()).filter(|p| p.exists());
    for input in [calib, pressures].into_iter().chain(listed_by) {
        provenance = provenance.with_input(input).map_err(io_error(input))?;
    }
    Ok(provenance)
}

/// What the per-frame stage did and wrote.
pub struct TriangulatedPerFrame {
    pub per_frame: PerFrame,
    pub written: Vec<PathBuf>,
}

/// The tip at every left frame's instant of `frames` (`triangulate --per-frame`), in the hand
/// frame of `calib`, with the pressures of the log at `pressures` in force then; writes `out`,
/// the per-phase files and the summary beside it. Ctrl-C stops at the next frame: the rows of
/// the frames examined are written, the summary says `interrupted`.
///
/// # Errors
/// As [`run`].
pub fn run_per_frame(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
    session: &Session,
) -> Result<TriangulatedPerFrame, PipelineError> {
    let (calibration, log, listed) = read_inputs(frames, calib, pressures, options, out)?;
    let index = frames.join("frames.csv");
    let result = per_frame::triangulate_per_frame(
        &listed,
        &index,
        &calibration,
        &log,
        options,
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::Event::Finished(Task::Frames));
    let per_frame = result?;
    let provenance = provenance(session, frames, calib, pressures)?;
    let written = per_frame.write(out, &log, &provenance)?;
    Ok(TriangulatedPerFrame { per_frame, written })
}
