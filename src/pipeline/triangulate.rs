//! The triangulate stage: frames, calibration and pressure log → the dataset and the files
//! beside it.

use std::path::{Path, PathBuf};

use super::{io_error, PipelineError, Session, Task};
use crate::calib::file::read_calibration;
use crate::fsio;
use crate::triangulate::{self, pairing, TriangulateOptions, Triangulation};

/// What the stage did and wrote.
pub struct Triangulated {
    pub triangulation: Triangulation,
    /// The dataset first, then the files beside it.
    pub written: Vec<PathBuf>,
}

/// The regulator's log: `given`, else `pressures.csv` beside the frames directory.
///
/// # Errors
/// [`PipelineError::Usage`] when none is given and there is no such file.
pub fn pressure_log(frames: &Path, given: Option<PathBuf>) -> Result<PathBuf, PipelineError> {
    given
        .or_else(|| {
            frames
                .parent()
                .map(|d| d.join("pressures.csv"))
                .filter(|p| p.is_file())
        })
        .ok_or_else(|| {
            PipelineError::Usage(format!(
                "no --pressures given and no pressures.csv beside {}; pass --pressures LOG.csv",
                frames.display()
            ))
        })
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
    if !frames.is_dir() {
        return Err(PipelineError::Usage(format!(
            "{} is not a directory of frames",
            frames.display()
        )));
    }
    if fsio::is_same_file_as_any(out, &[calib, pressures]) {
        return Err(PipelineError::Usage(format!(
            "--out {} is one of the inputs; choose another file",
            out.display()
        )));
    }
    let calibration = read_calibration(calib)?;
    super::create_parent(out).map_err(io_error(out))?;
    let log = pairing::read_pressure_log(pressures)?;
    let result = triangulate::triangulate(
        frames,
        &calibration,
        &log,
        options,
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::Event::Finished(Task::Frames));
    let triangulation = result?;
    let mut provenance = session.provenance(None);
    for input in [calib, pressures, &frames.join("frames.csv")] {
        provenance = provenance.with_input(input).map_err(io_error(input))?;
    }
    let written = triangulation.write(out, &provenance)?;
    Ok(Triangulated {
        triangulation,
        written,
    })
}
