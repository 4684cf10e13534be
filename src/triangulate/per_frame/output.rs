//! What `--per-frame` writes: the rows as CSV (all, and per phase), the summary; and the rows'
//! errors against a truth.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use super::rows::REACH;
use super::{FrameRow, PerFrame, CENTROID};
use crate::data::{Csv, HAND_INPUTS, HAND_OUTPUTS};
use crate::pipeline::monitor::scene_column;
use crate::provenance::Provenance;
use crate::session::pressures::{PressureLog, MEASURED_COLUMNS};
use crate::triangulate::output::{beside, first_appearances, ours, phase_path};
use crate::triangulate::TriangulateError;

/// Camera `camera`'s still-scene field of a row's `scene_px` (empty where not measured).
pub(in crate::triangulate) fn scene_field(scene_px: &[Option<f64>], camera: usize) -> String {
    crate::data::format_fixed(scene_px.get(camera).copied().flatten(), 3)
}

impl PerFrame {
    /// The rows as CSV: `time_s`, the log's other columns, the pressures in force, the tip,
    /// how far each camera's view of the still scene moved (`scene_left_px`,
    /// `scene_right_px`), `frame`, `reproj_px`, `flag`.
    pub fn csv(&self, log: &PressureLog, keep: impl Fn(&FrameRow) -> bool) -> String {
        let in_force = InForce::of(log);
        let scene = ["left", "right"].map(scene_column);
        let after = [&scene[0], &scene[1], "frame", "reproj_px", "flag"];
        let mut csv = Csv::new(in_force.header(&after));
        let number = |v: Option<f64>| v.map_or_else(String::new, crate::data::format_number);
        for r in self.rows.iter().filter(|r| keep(r)) {
            let mut record = in_force.start(r.time_s, r.step);
            let tip = written_tip(r);
            record.extend((0..3).map(|c| number(tip.map(|t| t[c]))));
            record.extend((0..2).map(|c| scene_field(&r.scene_px, c)));
            record.push(r.frame.to_string());
            record.push(crate::data::format_fixed(r.reproj_px, 4));
            record.push(r.flags.join(";"));
            csv.row(record);
        }
        csv.into_string()
    }

    /// Writes `out` (every row), `OUT_<phase>.csv` per phase of the log, and
    /// `OUT_summary.json` ([`write_rows`]); returns the files written.
    ///
    /// # Errors
    /// [`TriangulateError::Write`] naming the file.
    pub fn write(
        &self,
        out: &Path,
        log: &PressureLog,
        provenance: &Provenance,
    ) -> Result<Vec<PathBuf>, TriangulateError> {
        let summary = serde_json::json!({
            "per_frame": true,
            "summary": self.summary,
            "hand_from_left": {
                "R_hand": self.hand_from_left.rotation_rows(),
                "t_hand": self.hand_from_left.translation_array(),
            },
            "options": self.options,
            "provenance": provenance,
        });
        let steps: Vec<Option<usize>> = self.rows.iter().map(|r| r.step).collect();
        write_rows(out, log, &steps, summary, &|keep| {
            self.csv(log, |r| keep(r.step))
        })
    }
}

/// Which rows to write, by their step in the log.
pub(in crate::triangulate) type Keep<'a> = &'a dyn Fn(Option<usize>) -> bool;

/// Writes rows (per frame, or more cameras' held steps; each one's step in the log `steps`):
/// `out`, every row (`csv(keep)`, the rows whose step `keep` keeps), `OUT_<phase>.csv` per
/// phase of the log, and `OUT_summary.json` (`summary` with the files written); removes what a
/// previous run into the same place wrote and this one did not (its summary lists them);
/// returns the files written.
///
/// # Errors
/// [`TriangulateError::Write`] naming the file.
pub(in crate::triangulate) fn write_rows(
    out: &Path,
    log: &PressureLog,
    steps: &[Option<usize>],
    mut summary: serde_json::Value,
    csv: &dyn Fn(Keep<'_>) -> String,
) -> Result<Vec<PathBuf>, TriangulateError> {
    let write = |path: &Path, text: &str| {
        crate::fsio::write_bytes(path, text.as_bytes()).map_err(|e| TriangulateError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    };
    let path = beside(out, "_summary.json");
    let previous = crate::fsio::listed_files(&path);
    let mut written = vec![out.to_path_buf()];
    write(out, &csv(&|_| true))?;
    if let Some(col) = log.extra_columns.iter().position(|c| c == "phase") {
        let phase_of = |step: Option<usize>| step.map(|k| log.steps[k].extra[col].as_str());
        for phase in first_appearances(steps.iter().filter_map(|&s| phase_of(s))) {
            let path = phase_path(out, phase);
            write(&path, &csv(&|s| phase_of(s) == Some(phase)))?;
            written.push(path);
        }
    }
    written.push(path.clone());
    summary["files"] = serde_json::json!(crate::fsio::file_names(&written));
    write(
        &path,
        &(serde_json::to_string_pretty(&summary).expect("serialisable") + "\n"),
    )?;
    let dir = out.parent().unwrap_or(Path::new("."));
    crate::fsio::remove_stale(dir, &previous, &written, |p| ours(out, p));
    Ok(written)
}

/// A row's log columns: those of the step in force, then its pressures — those measured while
/// the command held, where a streaming regulator reported them, else the command's; empty
/// outside the log.
pub(in crate::triangulate) struct InForce<'a> {
    log: &'a PressureLog,
    /// The log's columns of measured pressures, when it has all three.
    measured: Option<Vec<usize>>,
}

impl<'a> InForce<'a> {
    pub(in crate::triangulate) fn of(log: &'a PressureLog) -> Self {
        let measured = MEASURED_COLUMNS
            .iter()
            .map(|name| log.extra_columns.iter().position(|c| c == name))
            .collect();
        InForce { log, measured }
    }

    /// A per-frame dataset's header: `time_s`, the log's other columns, the pressures, the
    /// tip, then the columns `after`.
    pub(in crate::triangulate) fn header(&self, after: &[&str]) -> Vec<String> {
        let mut header = vec!["time_s".to_string()];
        header.extend(self.log.extra_columns.iter().cloned());
        let named = HAND_INPUTS.into_iter().chain(HAND_OUTPUTS);
        header.extend(named.chain(after.iter().copied()).map(String::from));
        header
    }

    /// A row's first fields: its time (at a microsecond), then [`Self::fields`].
    pub(in crate::triangulate) fn start(&self, time_s: f64, step: Option<usize>) -> Vec<String> {
        let mut record = vec![format!("{time_s:.6}")];
        record.extend(self.fields(step));
        record
    }

    /// The log's other columns and the three pressures of `step`.
    pub(in crate::triangulate) fn fields(&self, step: Option<usize>) -> Vec<String> {
        let log = self.log;
        let Some(k) = step else {
            return vec![String::new(); log.extra_columns.len() + 3];
        };
        let step = &log.steps[k];
        let mut fields = step.extra.clone();
        let measured: Option<Vec<String>> = self.measured.as_ref().and_then(|cols| {
            let m: Vec<String> = cols.iter().map(|&c| step.extra[c].clone()).collect();
            m.iter().all(|v| !v.trim().is_empty()).then_some(m)
        });
        match measured {
            Some(m) => fields.extend(m),
            None => fields.extend(step.pressures_kpa.map(crate::data::format_number)),
        }
        fields
    }
}

/// A row's tip as the dataset writes it: a flagged row's is left empty but for the flags
/// `reach` and `centroid`, which keep it for a user who would rather have it.
pub(in crate::triangulate) fn written_tip(row: &FrameRow) -> Option<[f64; 3]> {
    row.tip_mm
        .filter(|_| row.flags.iter().all(|f| [REACH, CENTROID].contains(f)))
}

/// The rows' tips against a truth table with a `frame` column (the synth's
/// `truth/per_frame.csv`): per matched unflagged row, the distance (mm).
pub fn errors_against(rows: &[FrameRow], truth: &BTreeMap<usize, [f64; 3]>) -> Vec<f64> {
    rows.iter()
        .filter(|r| r.flags.is_empty())
        .filter_map(|r| {
            let (tip, want) = (r.tip_mm?, truth.get(&r.frame)?);
            Some((Vector3::from(tip) - Vector3::from(*want)).norm())
        })
        .collect()
}
