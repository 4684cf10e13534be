//! The files that list a session, rewritten whole every second and at the end.

use std::path::Path;

use super::regulator::{pressures_csv, Commanded};
use super::url::redact;
use super::{CaptureError, CaptureOptions, CaptureSummary, Side};
use crate::data::Csv;
use crate::fsio;
use crate::session::frames::{frames_rows, frames_table};

/// The files that list a session: `frames/frames.csv` (not for a calibration capture),
/// `pressures.csv` (with a protocol) and `capture.json`; rewritten whole (temp file, then
/// rename) every second while filming and at the end, so that they always agree with the
/// images written. `frames.csv`'s text grows with the rows (an hour's 216 000 rows took 76 ms to
/// format whole, every second).
pub(super) struct SessionFiles<'a> {
    out: &'a Path,
    options: &'a CaptureOptions,
    /// `frames.csv` of the rows so far, and how many.
    frames: (Csv, usize),
}

/// Writes `text` to `path` atomically.
fn write(path: &Path, text: &str) -> Result<(), CaptureError> {
    write_bytes(path, text.as_bytes())
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), CaptureError> {
    fsio::write_bytes(path, bytes).map_err(|source| CaptureError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes `csv` to `path` atomically.
fn save(path: &Path, csv: &mut Csv) -> Result<(), CaptureError> {
    write_bytes(path, csv.as_bytes())
}

impl<'a> SessionFiles<'a> {
    pub fn new(out: &'a Path, options: &'a CaptureOptions) -> Self {
        SessionFiles {
            out,
            options,
            frames: (frames_table(), 0),
        }
    }

    /// Writes the files while filming: `rows` are those of the last write and the new ones
    /// after them.
    pub fn write(
        &mut self,
        rows: &[(Side, usize, f64)],
        log: &[Commanded],
        summary: &CaptureSummary,
    ) -> Result<(), CaptureError> {
        // capture.json first: it says how to read the others, so a kill between two writes
        // leaves it beside lists as of this pass or the one before, never lists without it.
        let options = self.options;
        write(
            &self.out.join(super::CAPTURE_FILE),
            &self.description(summary),
        )?;
        if options.calibration.is_none() {
            let (csv, listed) = &mut self.frames;
            frames_rows(csv, rows[*listed..].iter().copied());
            *listed = rows.len();
            save(&self.out.join("frames/frames.csv"), csv)?;
        }
        if options.protocol.is_some() {
            write(&self.out.join("pressures.csv"), &pressures_csv(log))?;
        }
        Ok(())
    }

    /// Writes the files at the end: `rows` in their final order. Each file is tried even when
    /// one before it fails (a full disk may still take the small ones); the first failure is
    /// returned.
    pub fn finish(
        self,
        rows: &[(Side, usize, f64)],
        log: &[Commanded],
        summary: &CaptureSummary,
    ) -> Result<(), CaptureError> {
        let options = self.options;
        let mut first = None;
        let mut keep = |result: Result<(), CaptureError>| {
            if let Err(e) = result {
                first.get_or_insert(e);
            }
        };
        if options.protocol.is_some() {
            keep(write(&self.out.join("pressures.csv"), &pressures_csv(log)));
        }
        if options.calibration.is_none() {
            let mut csv = frames_table();
            frames_rows(&mut csv, rows.iter().copied());
            keep(save(&self.out.join("frames/frames.csv"), &mut csv));
        }
        keep(write(
            &self.out.join(super::CAPTURE_FILE),
            &self.description(summary),
        ));
        first.map_or(Ok(()), Err)
    }

    /// `capture.json`'s text.
    fn description(&self, summary: &CaptureSummary) -> String {
        let options = self.options;
        let json = serde_json::json!({
            "sources": options.sources.each_ref().map(|s| redact(s)),
            "requested": {"width": options.width, "height": options.height, "fps": options.fps},
            "clock": "time_s = CLOCK_MONOTONIC seconds - start_monotonic_s (Python: time.monotonic() - start_monotonic_s)",
            "summary": summary,
        });
        serde_json::to_string_pretty(&json).expect("serialisable") + "\n"
    }
}
