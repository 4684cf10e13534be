//! The synth stage: the datasets and, with a capture configuration, the rendered capture.

use std::path::{Path, PathBuf};

use super::{io_error, PipelineError, Session, Task};
use crate::synth::capture::{self, CaptureConfig, CaptureSummary};
use crate::synth::{self as plant_data, SynthConfig};

/// What the stage wrote.
pub struct Synthesized {
    pub datasets: Vec<PathBuf>,
    /// The capture, when one was rendered; `interrupted` says it is incomplete.
    pub capture: Option<CaptureSummary>,
    pub seconds: f64,
}

/// Writes the datasets into `out` and, with `capture_config`, the rendered capture and the
/// manifest. Ctrl-C stops rendering between images: the images written are complete, and the
/// summary says `interrupted`.
///
/// # Errors
/// [`PipelineError::Synth`] for bad settings or a file that cannot be written.
pub fn run(
    out: &Path,
    config: &SynthConfig,
    capture_config: Option<&CaptureConfig>,
    session: &Session,
) -> Result<Synthesized, PipelineError> {
    let started = std::time::Instant::now();
    let provenance = session.provenance(Some(config.seed));
    // A dynamic session's dataset is its per-frame truth; the settled grid is the steps'.
    let datasets = if capture_config.is_some_and(|c| c.dynamic.is_some()) {
        std::fs::create_dir_all(out).map_err(io_error(out))?;
        Vec::new()
    } else {
        plant_data::write_datasets(out, config, &provenance)?
    };
    let Some(capture_config) = capture_config else {
        return Ok(Synthesized {
            datasets,
            capture: None,
            seconds: started.elapsed().as_secs_f64(),
        });
    };
    let result = capture::write_capture(
        out,
        config,
        capture_config,
        &provenance,
        &session.counter(Task::Render),
        session.interrupt,
    );
    session.emit(super::Event::Finished(Task::Render));
    let mut summary = result?;
    summary.interrupted |= session.interrupted();
    plant_data::write_manifest(
        out,
        config,
        &datasets,
        Some((capture_config, &summary)),
        &provenance,
    )?;
    Ok(Synthesized {
        datasets,
        capture: Some(summary),
        seconds: started.elapsed().as_secs_f64(),
    })
}
