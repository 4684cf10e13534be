//! Filming a session as a stage: the settings checked, then [`crate::capture::capture`] with the
//! session's interrupt, its figures handed to `live` about once a second. How the session
//! ended is in the summary ([`crate::capture::Ending`]), for the front end to say.

use std::path::Path;

use super::{PipelineError, Session};
use crate::capture::{self, CaptureOptions, CaptureSummary, Stats};

/// Films a session into `out` (`frames/`, `frames/frames.csv`, `pressures.csv` when a protocol
/// runs, `capture.json`).
///
/// # Errors
/// [`PipelineError::Request`] for settings that cannot work; [`PipelineError::Capture`] for a
/// camera that does not open, `out` holding a capture, a file that cannot be written.
pub fn run(
    out: &Path,
    options: &CaptureOptions,
    session: &Session,
    live: &(dyn Fn(&Stats) + Sync),
) -> Result<CaptureSummary, PipelineError> {
    options.check().map_err(PipelineError::Request)?;
    Ok(capture::capture(out, options, live, session.interrupt)?)
}
