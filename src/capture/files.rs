//! The files that list a session, rewritten whole every second and at the end, and the space
//! kept for them on the session's disk.

use std::io::Write;
use std::path::{Path, PathBuf};

use super::regulator::{pressures_csv, Commanded};
use super::url::redact;
use super::{CaptureError, CaptureOptions, CaptureSummary};
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
    reserve: Reserve,
}

/// Space kept on the session's disk for its lists: a file of [`RESERVE_FILE`] twice their size
/// (at least [`RESERVE_MIN_BYTES`]), grown as they grow, removed before the lists are written at
/// the end. A disk that fills while filming (the images take it) still takes the final lists,
/// so that they name every image on it and every command the regulator was told.
struct Reserve {
    path: PathBuf,
    bytes: usize,
}

/// The reserve's name in the session folder (removed at the session's end; left only by a
/// capture killed outright, and then safe to delete).
pub const RESERVE_FILE: &str = "capture.reserve";
const RESERVE_MIN_BYTES: usize = 1 << 20;

impl Reserve {
    fn new(out: &Path) -> Result<Reserve, CaptureError> {
        std::fs::create_dir_all(out).map_err(|source| CaptureError::Write {
            path: out.to_path_buf(),
            source,
        })?;
        let mut reserve = Reserve {
            path: out.join(RESERVE_FILE),
            bytes: 0,
        };
        reserve.grow_to(RESERVE_MIN_BYTES)?;
        Ok(reserve)
    }

    /// Grows the file to at least `bytes`, in whole MiB, with bytes a compressing file system
    /// cannot shrink.
    fn grow_to(&mut self, bytes: usize) -> Result<(), CaptureError> {
        if bytes <= self.bytes {
            return Ok(());
        }
        let bytes = bytes.div_ceil(RESERVE_MIN_BYTES) * RESERVE_MIN_BYTES;
        let failed = |source| CaptureError::Write {
            path: self.path.clone(),
            source,
        };
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)
            .map_err(failed)?;
        let mut state = 0x9e37_79b9_7f4a_7c15_u64 ^ self.bytes as u64;
        let noise: Vec<u8> = (0..bytes - self.bytes)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state as u8
            })
            .collect();
        file.write_all(&noise)
            .and_then(|()| file.sync_data())
            .map_err(failed)?;
        self.bytes = bytes;
        Ok(())
    }

    /// Gives the space back.
    fn release(&mut self) {
        if self.bytes > 0 {
            let _ = std::fs::remove_file(&self.path);
            self.bytes = 0;
        }
    }
}

impl Drop for Reserve {
    fn drop(&mut self) {
        self.release();
    }
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
    /// The session's files, and the space kept for them.
    ///
    /// # Errors
    /// [`CaptureError::Write`]: the disk cannot hold the reserve.
    pub fn new(out: &'a Path, options: &'a CaptureOptions) -> Result<Self, CaptureError> {
        Ok(SessionFiles {
            out,
            options,
            frames: (frames_table(), 0),
            reserve: Reserve::new(out)?,
        })
    }

    /// Writes the files while filming: `rows` are those of the last write and the new ones
    /// after them.
    pub fn write(
        &mut self,
        rows: &[(usize, usize, f64)],
        log: &[Commanded],
        summary: &CaptureSummary,
    ) -> Result<(), CaptureError> {
        // capture.json first: it says how to read the others, so a kill between two writes
        // leaves it beside lists as of this pass or the one before, never lists without it.
        let options = self.options;
        let description = self.description(summary);
        write(&self.out.join(super::CAPTURE_FILE), &description)?;
        let mut bytes = description.len();
        if options.calibration.is_none() {
            let (csv, listed) = &mut self.frames;
            frames_rows(csv, named(options, &rows[*listed..]));
            *listed = rows.len();
            bytes += csv.as_bytes().len();
            save(&self.out.join("frames/frames.csv"), csv)?;
        }
        if options.protocol.is_some() {
            let log = pressures_csv(log);
            bytes += log.len();
            write(&self.out.join("pressures.csv"), &log)?;
        }
        self.reserve.grow_to(2 * bytes)
    }

    /// Writes the files at the end, in the space kept for them: `rows` in their final order.
    /// Each file is tried even when one before it fails; the first failure is returned.
    pub fn finish(
        mut self,
        rows: &[(usize, usize, f64)],
        log: &[Commanded],
        summary: &CaptureSummary,
    ) -> Result<(), CaptureError> {
        let options = self.options;
        self.reserve.release();
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
            frames_rows(&mut csv, named(options, rows));
            keep(save(&self.out.join("frames/frames.csv"), &mut csv));
        }
        keep(write(
            &self.out.join(super::CAPTURE_FILE),
            &self.description(summary),
        ));
        first.map_or(Ok(()), Err)
    }

    /// `capture.json`'s text: with more cameras than a pair, their names beside their sources.
    fn description(&self, summary: &CaptureSummary) -> String {
        let options = self.options;
        let json = serde_json::json!({
            "sources": options.sources.iter().map(|s| redact(&s.source)).collect::<Vec<_>>(),
            "requested": {"width": options.width, "height": options.height, "fps": options.fps},
            "clock": "time_s = CLOCK_MONOTONIC seconds - start_monotonic_s (Python: time.monotonic() - start_monotonic_s)",
            "summary": summary,
        });
        let mut json = json;
        if !options.is_pair() {
            json["cameras"] = options.sources.iter().map(|s| s.name.clone()).collect();
        }
        serde_json::to_string_pretty(&json).expect("serialisable") + "\n"
    }
}

/// Frame rows `(camera, frame, time_s)` with each camera by its name.
fn named<'a>(
    options: &'a CaptureOptions,
    rows: &'a [(usize, usize, f64)],
) -> impl Iterator<Item = (&'a str, usize, f64)> + 'a {
    rows.iter()
        .map(|&(c, frame, t)| (options.sources[c].name.as_str(), frame, t))
}
