//! What `--per-frame` with more cameras writes: the rows as CSV (all, and per phase), the
//! summary.

use std::path::{Path, PathBuf};

use super::{CamerasRow, PerFrameCameras};
use crate::calib::file::ReadCamera;
use crate::data::Csv;
use crate::pipeline::monitor::scene_column;
use crate::provenance::Provenance;
use crate::session::pressures::PressureLog;
use crate::triangulate::cameras::{camera_names, covariance_fields};
use crate::triangulate::per_frame::output::{scene_field, write_rows, written_tip, InForce};
use crate::triangulate::{TriangulateError, TriangulateOptions};

/// The columns after the pressures: the tip, how sure it is, the cameras it used (then each
/// camera's `scene_<name>_px`), the row's frame (of the rows' camera), its worst reprojection
/// residual and its flags.
const COLUMNS: [&str; 13] = [
    "sd_x_mm",
    "sd_y_mm",
    "sd_z_mm",
    "cov_xy_mm2",
    "cov_xz_mm2",
    "cov_yz_mm2",
    "n_cameras",
    "cameras",
    "left_out",
    "chi2",
    "frame",
    "reproj_px",
    "flag",
];

impl PerFrameCameras {
    /// The rows `keep` keeps as CSV: `time_s`, the log's other columns, the pressures in
    /// force, the tip, its deviations and covariances, `n_cameras`, `cameras`, `left_out`
    /// (names joined by `+`), `chi2`, each camera's `scene_<name>_px` (how far its view of the
    /// still scene lay from its first frame's), `frame`, `reproj_px`, `flag`. A flagged row's
    /// tip is empty but for `reach` and `centroid`, as a pair's.
    pub fn csv(
        &self,
        log: &PressureLog,
        cameras: &[ReadCamera],
        keep: impl Fn(&CamerasRow) -> bool,
    ) -> String {
        let in_force = InForce::of(log);
        let scene: Vec<String> = cameras.iter().map(|c| scene_column(&c.name)).collect();
        let (tip, tail) = COLUMNS.split_at(COLUMNS.len() - 3);
        let names = tip.iter().copied().chain(scene.iter().map(String::as_str));
        let columns: Vec<&str> = names.chain(tail.iter().copied()).collect();
        let mut csv = Csv::new(in_force.header(&columns));
        for r in self.rows.iter().filter(|r| keep(r)) {
            let row = &r.row;
            let mut record = in_force.start(row.time_s, row.step);
            match (written_tip(row), &r.covariance_mm2) {
                (Some(tip), Some(c)) => {
                    record.extend(tip.map(crate::data::format_number));
                    record.extend(covariance_fields(c).split(',').map(String::from));
                    record.push(r.used.len().to_string());
                    record.push(camera_names(cameras, &r.used));
                    record.push(camera_names(cameras, &r.left_out));
                    record.push(format!("{:.3}", r.chi2));
                }
                _ => record.extend(std::iter::repeat_n(String::new(), 13)),
            }
            record.extend((0..cameras.len()).map(|c| scene_field(&row.scene_px, c)));
            record.push(row.frame.to_string());
            record.push(crate::data::format_fixed(row.reproj_px, 4));
            record.push(row.flags.join(";"));
            csv.row(record);
        }
        csv.into_string()
    }

    /// Writes `out` (every row), `OUT_<phase>.csv` per phase of the log, and
    /// `OUT_summary.json`, as a pair's per-frame rows are ([`write_rows`]); returns the files
    /// written.
    ///
    /// # Errors
    /// [`TriangulateError::Write`] naming the file.
    pub fn write(
        &self,
        out: &Path,
        log: &PressureLog,
        cameras: &[ReadCamera],
        options: &TriangulateOptions,
        provenance: &Provenance,
    ) -> Result<Vec<PathBuf>, TriangulateError> {
        let summary = serde_json::json!({
            "per_frame": true,
            "summary": self.summary,
            "options": options,
            "provenance": provenance,
        });
        let steps: Vec<Option<usize>> = self.rows.iter().map(|r| r.row.step).collect();
        write_rows(out, log, &steps, summary, &|keep| {
            self.csv(log, cameras, |r| keep(r.row.step))
        })
    }
}
