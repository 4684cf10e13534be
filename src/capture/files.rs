//! The files that list a session, rewritten whole every second and at the end.

use std::path::Path;

use super::regulator::{pressures_csv, Commanded};
use super::url::redact;
use super::{CaptureError, CaptureOptions, CaptureSummary, Side};
use crate::fsio;
use crate::session::frames::frames_csv;

/// The files that list a session: `frames/frames.csv` (not for a calibration capture),
/// `pressures.csv` (with a protocol) and `capture.json`; rewritten whole (temp file, then
/// rename) every second while filming and at the end, so that they always agree with the
/// images written.
pub(super) struct SessionFiles<'a> {
    pub out: &'a Path,
    pub options: &'a CaptureOptions,
}

impl SessionFiles<'_> {
    pub fn write(
        &self,
        rows: &[(Side, usize, f64)],
        log: &[Commanded],
        summary: &CaptureSummary,
    ) -> Result<(), CaptureError> {
        let write = |path: &Path, text: &str| {
            fsio::write_bytes(path, text.as_bytes()).map_err(|source| CaptureError::Write {
                path: path.to_path_buf(),
                source,
            })
        };
        // capture.json first: it says how to read the others, so a kill between two writes
        // leaves it beside lists as of this pass or the one before, never lists without it.
        let options = self.options;
        let json = serde_json::json!({
            "sources": options.sources.each_ref().map(|s| redact(s)),
            "requested": {"width": options.width, "height": options.height, "fps": options.fps},
            "clock": "time_s = CLOCK_MONOTONIC seconds - start_monotonic_s (Python: time.monotonic() - start_monotonic_s)",
            "summary": summary,
        });
        write(
            &self.out.join("capture.json"),
            &(serde_json::to_string_pretty(&json).expect("serialisable") + "\n"),
        )?;
        if options.calibration.is_none() {
            write(
                &self.out.join("frames/frames.csv"),
                &frames_csv(rows.iter().copied()),
            )?;
        }
        if options.protocol.is_some() {
            write(&self.out.join("pressures.csv"), &pressures_csv(log))?;
        }
        Ok(())
    }
}
