//! The files a triangulation writes, all beside the dataset `OUT.csv`:
//!
//! - `OUT.csv`: one row per pressure step, `P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,n_frames,
//!   spread_mm,reproj_px,dt_ms`, the log's other columns (e.g. `step,phase`), then `flag`
//!   (empty, or the reasons the row is doubtful).
//! - `OUT_<phase>.csv`: the same rows split by the log's `phase` column, when it has one.
//! - `OUT_pairs.csv`: every frame pair, what became of it and its tip (hand frame).
//! - `OUT_hand.yml`: the hand frame (OpenCV YAML): `R_hand`, `t_hand` (p_hand = R_hand · p_left
//!   + t_hand, [`crate::geometry::HandFromLeft`]), `origin_left_mm`.
//! - `OUT_summary.json`: the counts, the options, provenance.
//! - `OUT_detections.png`: a few pairs, cropped around the tip: the detected centroid (green
//!   cross), the reprojected tip (magenta circle), and where the crop is in the left frame.

use std::path::{Path, PathBuf};

use opencv::core::{self, Mat, Point, Rect, Scalar, Size, Vector};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};

use super::{PairRecord, PairStatus, TriangulateError, Triangulation};
use crate::data::{format_fixed, format_number, Csv};
use crate::fsio;
use crate::provenance::Provenance;

/// `OUT` with `suffix` in place of its extension: `dataset.csv` + `_pairs.csv`.
pub fn beside(out: &Path, suffix: &str) -> PathBuf {
    fsio::beside(out, "dataset", suffix)
}

/// `OUT_<phase>.csv`, the phase's characters outside `[A-Za-z0-9-]` replaced by `_`.
pub fn phase_path(out: &Path, phase: &str) -> PathBuf {
    let safe: String = phase
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    beside(out, &format!("_{safe}.csv"))
}

/// The distinct `phases`, in the order they first appear (the per-phase files' order).
pub(crate) fn first_appearances<'a>(phases: impl Iterator<Item = &'a str>) -> Vec<&'a str> {
    let mut seen: Vec<&str> = Vec::new();
    for p in phases {
        if !seen.contains(&p) {
            seen.push(p);
        }
    }
    seen
}

/// Whether `path` is a file a triangulation into `out` writes: one of [`BESIDE`], or a
/// per-phase file ([`phase_path`]) that holds a dataset (its header is a step dataset's or a
/// per-frame one's, of a pair or of more cameras), so that a stale listing never removes
/// another file.
pub(super) fn ours(out: &Path, path: &Path) -> bool {
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    let (Some(name), Some(stem)) = (name(path), name(&beside(out, ""))) else {
        return false;
    };
    if BESIDE
        .iter()
        .any(|(suffix, _)| name == format!("{stem}{suffix}"))
    {
        return true;
    }
    // The header alone is read: a dataset may be large.
    let header = || {
        let mut line = Vec::new();
        let file = std::fs::File::open(path).ok()?;
        std::io::BufRead::read_until(&mut std::io::BufReader::new(file), b'\n', &mut line).ok()?;
        Some(line)
    };
    let dataset = |line: Vec<u8>| {
        let line = line.strip_suffix(b"\n").unwrap_or(&line);
        line.starts_with(DATASET_HEAD.as_bytes())
            || line.starts_with(super::cameras::HEADER.as_bytes())
            || (line.starts_with(b"time_s,") && line.ends_with(PER_FRAME_TAIL.as_bytes()))
    };
    name.starts_with(&format!("{stem}_")) && name.ends_with(".csv") && header().is_some_and(dataset)
}

/// The last columns of a per-frame dataset's header (a pair's and more cameras').
const PER_FRAME_TAIL: &str = ",frame,reproj_px,flag";

/// A pair's step dataset's first columns, which its per-phase files start with too (more
/// cameras' start with [`super::cameras::HEADER`]).
const DATASET_HEAD: &str = "P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,n_frames,spread_mm,reproj_px,dt_ms";

const PAIRS: &str = "_pairs.csv";
const HAND: &str = "_hand.yml";
const SUMMARY: &str = "_summary.json";
const DETECTIONS: &str = "_detections.png";
/// The clock figure's stem: `_clock.png` and `_clock.svg`.
const CLOCK: &str = "_clock";

/// The files beside `OUT` and what each is (the per-phase files are [`phase_path`]).
pub const BESIDE: [(&str, &str); 6] = [
    (PAIRS, "the pairs table"),
    (HAND, "the hand frame"),
    (SUMMARY, "the summary"),
    (DETECTIONS, "the detection figure"),
    ("_clock.png", "the clock figure"),
    ("_clock.svg", "the clock figure"),
];

fn write_err(path: &Path) -> impl Fn(String) -> TriangulateError + '_ {
    move |message| TriangulateError::Write {
        path: path.to_path_buf(),
        message,
    }
}

fn write_text(path: &Path, text: &str) -> Result<(), TriangulateError> {
    fsio::write_bytes(path, text.as_bytes()).map_err(|e| write_err(path)(e.to_string()))
}

impl Triangulation {
    /// The dataset's text, with the rows `keep` selects.
    fn dataset_csv(&self, keep: impl Fn(&super::Row) -> bool) -> String {
        let header = DATASET_HEAD.trim_end().split(',').map(str::to_string);
        let mut csv = Csv::new(
            header
                .chain(self.extra_columns.iter().cloned())
                .chain(["flag".to_string()]),
        );
        for r in self.rows.iter().filter(|r| keep(r)) {
            let [x, y, z] = r.tip_mm;
            csv.row(
                r.pressures_kpa
                    .map(format_number)
                    .into_iter()
                    .chain([
                        format!("{x:.4}"),
                        format!("{y:.4}"),
                        format!("{z:.4}"),
                        r.n_frames.to_string(),
                        format!("{:.4}", r.spread_mm),
                        format!("{:.3}", r.reproj_px),
                        format!("{:.1}", r.dt_ms),
                    ])
                    .chain(r.extra.iter().cloned())
                    .chain([r.flags.join(";")]),
            );
        }
        csv.into_string()
    }

    /// Every frame pair: frames, times, step, status, centroids, tip (hand frame), error.
    fn pairs_csv(&self) -> String {
        let mut csv = Csv::new([
            "left_frame",
            "right_frame",
            "left_time_s",
            "right_time_s",
            "step",
            "status",
            "candidates",
            "left_u_px",
            "left_v_px",
            "right_u_px",
            "right_v_px",
            "x_mm",
            "y_mm",
            "z_mm",
            "reproj_px",
        ]);
        for p in &self.pairs {
            let c = p.centres_px;
            let tip = p
                .point_left_mm
                .map(|q| self.hand_from_left.apply(&q.into()));
            csv.row([
                p.left.index.to_string(),
                p.right.index.to_string(),
                format!("{:.6}", p.left.time_s),
                format!("{:.6}", p.right.time_s),
                p.step.map_or(String::new(), |k| k.to_string()),
                p.status.name().to_string(),
                p.candidates.to_string(),
                format_fixed(c.map(|c| c[0][0]), 3),
                format_fixed(c.map(|c| c[0][1]), 3),
                format_fixed(c.map(|c| c[1][0]), 3),
                format_fixed(c.map(|c| c[1][1]), 3),
                format_fixed(tip.map(|t| t.x), 4),
                format_fixed(tip.map(|t| t.y), 4),
                format_fixed(tip.map(|t| t.z), 4),
                format_fixed(p.reproj_px, 3),
            ]);
        }
        csv.into_string()
    }

    fn hand_yaml(&self, provenance: &Provenance) -> String {
        crate::calib::file::hand_yaml(
            &self.hand_from_left,
            &self.summary.origin.left_mm,
            self.summary.origin.pairs,
            provenance,
        )
    }

    /// Writes the dataset and everything beside it; returns the files written.
    ///
    /// # Errors
    /// [`TriangulateError::Write`] naming the file.
    pub fn write(
        &self,
        out: &Path,
        provenance: &Provenance,
    ) -> Result<Vec<PathBuf>, TriangulateError> {
        let summary = beside(out, SUMMARY);
        let previous = fsio::listed_files(&summary);
        let mut written = Vec::new();
        write_text(out, &self.dataset_csv(|_| true))?;
        written.push(out.to_path_buf());
        if let Some(col) = self.extra_columns.iter().position(|c| c == "phase") {
            for phase in first_appearances(self.rows.iter().map(|r| r.extra[col].as_str())) {
                let path = phase_path(out, phase);
                write_text(&path, &self.dataset_csv(|r| r.extra[col] == phase))?;
                written.push(path);
            }
        }
        let path = beside(out, PAIRS);
        write_text(&path, &self.pairs_csv())?;
        written.push(path);
        let path = beside(out, HAND);
        write_text(&path, &self.hand_yaml(provenance))?;
        written.push(path);
        let path = beside(out, DETECTIONS);
        if self.write_detections(&path)? {
            written.push(path);
        }
        let stem = beside(out, CLOCK);
        if self.write_clock(&stem)? {
            written.extend(crate::plot::line_plot_files(&stem));
        }
        // The summary last, listing every file of this run (itself included), so that the
        // next run into the same place removes what it does not write again.
        written.push(summary.clone());
        let json = serde_json::json!({
            "summary": self.summary,
            "options": self.options,
            "provenance": provenance,
            "files": fsio::file_names(&written),
        });
        write_text(
            &summary,
            &(serde_json::to_string_pretty(&json).expect("serialisable") + "\n"),
        )?;
        let dir = out.parent().unwrap_or(Path::new("."));
        fsio::remove_stale(dir, &previous, &written, |path| ours(out, path));
        Ok(written)
    }

    /// Pairs worth showing: the problem cases first (resolved, ambiguous, reprojection), then
    /// used pairs spread over the session; at most `n`.
    fn examples(&self, n: usize) -> Vec<&PairRecord> {
        let mut out: Vec<&PairRecord> = Vec::new();
        for status in [
            PairStatus::Resolved,
            PairStatus::Ambiguous,
            PairStatus::Reprojection,
        ] {
            if let Some(p) = self
                .pairs
                .iter()
                .find(|p| p.status == status && p.centres_px.is_some())
            {
                out.push(p);
            }
        }
        let used: Vec<&PairRecord> = self
            .pairs
            .iter()
            .filter(|p| p.status == PairStatus::Used)
            .collect();
        let want = n.saturating_sub(out.len()).min(used.len());
        for k in 0..want {
            out.push(used[k * (used.len() - 1) / (want - 1).max(1)]);
        }
        out
    }

    /// Draws [`Self::examples`] into `path`; `false` when there is nothing to draw.
    fn write_detections(&self, path: &Path) -> Result<bool, TriangulateError> {
        let rows: Vec<Mat> = self
            .examples(4)
            .into_iter()
            .map(detection_row)
            .collect::<Result<Vec<Option<Mat>>, opencv::Error>>()?
            .into_iter()
            .flatten()
            .collect();
        if rows.is_empty() {
            return Ok(false);
        }
        let mut sheet = Mat::default();
        core::vconcat(&rows.into_iter().collect::<Vector<Mat>>(), &mut sheet)?;
        let mut png = Vector::<u8>::new();
        imgcodecs::imencode(".png", &sheet, &mut png, &Vector::new())?;
        fsio::write_bytes(path, png.as_slice()).map_err(|e| write_err(path)(e.to_string()))?;
        Ok(true)
    }
}

impl Triangulation {
    /// The clock figure: each pair's right − left time against the session's (unwrapped, as
    /// the drift is measured), and the straight line of the drift. `false` without pairs.
    fn write_clock(&self, stem: &Path) -> Result<bool, TriangulateError> {
        let c = &self.summary.clock;
        let (Some(first), Some(last)) = (c.series.first(), c.series.last()) else {
            return Ok(false);
        };
        let mean = c.series.iter().map(|p| p.1).sum::<f64>() / c.series.len() as f64;
        let middle = (first.0 + last.0) / 2.0;
        let line = |t: f64| mean + c.drift_ms * (t - middle) / (last.0 - first.0).max(1e-9);
        let plot = crate::plot::LinePlot {
            title: format!(
                "Left/right clock: |skew| median {:.1} ms, drift {:+.1} ms over the session",
                c.skew_ms[0], c.drift_ms
            ),
            x_label: "session time (s)".into(),
            y_label: "right − left time of a pair (ms)".into(),
            series: vec![
                crate::plot::Series {
                    label: "pairs".into(),
                    points: c.series.clone(),
                    mark: crate::plot::Mark::Points,
                    colour: crate::plot::BLACK_INDEX,
                },
                crate::plot::Series {
                    label: "drift".into(),
                    points: vec![(first.0, line(first.0)), (last.0, line(last.0))],
                    mark: crate::plot::Mark::Line,
                    colour: 0,
                },
            ],
            log_y: false,
            x_names: Vec::new(),
        };
        crate::plot::write_line_plot(stem, &plot).map_err(|e| TriangulateError::Write {
            path: stem.to_path_buf(),
            message: e.to_string(),
        })?;
        Ok(true)
    }
}

const CROP: i32 = 48;
const ZOOM: i32 = 5;
const HEADER: i32 = 24;
const OVERVIEW: Size = Size {
    width: 320,
    height: CROP * ZOOM,
};

fn bgr(b: f64, g: f64, r: f64) -> Scalar {
    Scalar::new(b, g, r, 0.0)
}

/// One row of the detections sheet: left crop, right crop, left overview, with a caption.
fn detection_row(p: &PairRecord) -> opencv::Result<Option<Mat>> {
    let (Some(centres), Some(lp), Some(rp)) = (p.centres_px, &p.left.path, &p.right.path) else {
        return Ok(None);
    };
    let read = |path: &Path| imgcodecs::imread(path.as_os_str(), imgcodecs::IMREAD_COLOR);
    let (left, right) = (read(lp)?, read(rp)?);
    if left.empty() || right.empty() {
        return Ok(None);
    }
    let reprojected = p.reprojected_px;
    let (lc, rect) = zoomed_crop(&left, centres[0], reprojected.map(|r| r[0]))?;
    let (rc, _) = zoomed_crop(&right, centres[1], reprojected.map(|r| r[1]))?;
    let padded = overview(&left, rect)?;
    let gap =
        Mat::new_rows_cols_with_default(CROP * ZOOM, 8, core::CV_8UC3, bgr(255.0, 255.0, 255.0))?;
    let mut row = Mat::default();
    let parts: Vector<Mat> = [lc, gap.try_clone()?, rc, gap, padded]
        .into_iter()
        .collect();
    core::hconcat(&parts, &mut row)?;
    let mut framed = Mat::default();
    core::copy_make_border(
        &row,
        &mut framed,
        HEADER,
        6,
        0,
        0,
        core::BORDER_CONSTANT,
        bgr(255.0, 255.0, 255.0),
    )?;
    imgproc::put_text(
        &mut framed,
        &caption(p),
        Point::new(6, 17),
        imgproc::FONT_HERSHEY_SIMPLEX,
        0.5,
        bgr(0.0, 0.0, 0.0),
        1,
        imgproc::LINE_AA,
        false,
    )?;
    Ok(Some(framed))
}

/// The [`CROP`]-pixel square around `centre`, enlarged [`ZOOM`] times: the centre found as a
/// green cross, the reprojected point (when there is one) as a magenta circle; and where it
/// lies in the image.
fn zoomed_crop(
    img: &Mat,
    centre: [f64; 2],
    reproj: Option<[f64; 2]>,
) -> opencv::Result<(Mat, Rect)> {
    let x0 = (centre[0].round() as i32 - CROP / 2).clamp(0, img.cols() - CROP);
    let y0 = (centre[1].round() as i32 - CROP / 2).clamp(0, img.rows() - CROP);
    let rect = Rect::new(x0, y0, CROP, CROP);
    let roi = Mat::roi(img, rect)?.try_clone()?;
    let mut big = Mat::default();
    imgproc::resize(
        &roi,
        &mut big,
        Size::new(CROP * ZOOM, CROP * ZOOM),
        0.0,
        0.0,
        imgproc::INTER_NEAREST,
    )?;
    // Sub-pixel drawing: coordinates in 1/16 px.
    let at = |q: [f64; 2]| {
        Point::new(
            (((q[0] - f64::from(x0)) * f64::from(ZOOM) + f64::from(ZOOM - 1) / 2.0) * 16.0).round()
                as i32,
            (((q[1] - f64::from(y0)) * f64::from(ZOOM) + f64::from(ZOOM - 1) / 2.0) * 16.0).round()
                as i32,
        )
    };
    if let Some(q) = reproj {
        imgproc::circle(
            &mut big,
            at(q),
            9 * 16,
            bgr(255.0, 0.0, 255.0),
            1,
            imgproc::LINE_AA,
            4,
        )?;
    }
    let c = at(centre);
    let arm = 7 * 16;
    for (a, b) in [
        (Point::new(c.x - arm, c.y), Point::new(c.x + arm, c.y)),
        (Point::new(c.x, c.y - arm), Point::new(c.x, c.y + arm)),
    ] {
        imgproc::line(&mut big, a, b, bgr(0.0, 220.0, 0.0), 1, imgproc::LINE_AA, 4)?;
    }
    Ok((big, rect))
}

/// The whole left image, [`OVERVIEW`] wide, the crop's place outlined in green, padded to
/// [`OVERVIEW`]'s height.
fn overview(left: &Mat, rect: Rect) -> opencv::Result<Mat> {
    let mut overview = Mat::default();
    imgproc::resize(
        left,
        &mut overview,
        Size::new(OVERVIEW.width, OVERVIEW.width * left.rows() / left.cols()),
        0.0,
        0.0,
        imgproc::INTER_AREA,
    )?;
    let s = f64::from(OVERVIEW.width) / f64::from(left.cols());
    let scaled = |v: i32| (f64::from(v) * s).round() as i32;
    imgproc::rectangle(
        &mut overview,
        Rect::new(
            scaled(rect.x),
            scaled(rect.y),
            scaled(rect.width).max(2),
            scaled(rect.height).max(2),
        ),
        bgr(0.0, 220.0, 0.0),
        1,
        imgproc::LINE_8,
        0,
    )?;
    let mut padded = Mat::default();
    core::copy_make_border(
        &overview,
        &mut padded,
        0,
        OVERVIEW.height - overview.rows(),
        0,
        0,
        core::BORDER_CONSTANT,
        bgr(255.0, 255.0, 255.0),
    )?;
    Ok(padded)
}

/// The pair's frames, step, what became of it (used, or resolved among candidates, else why
/// it was not) and its reprojection error.
fn caption(p: &PairRecord) -> String {
    let verdict = if p.status.used() {
        p.status.name().to_string()
    } else {
        format!("rejected ({})", p.status.name().replace('_', " "))
    };
    format!(
        "left {} / right {}  step {}  {verdict}  reprojection {} px",
        p.left.index,
        p.right.index,
        p.step.map_or("-".into(), |k| k.to_string()),
        p.reproj_px.map_or("-".into(), |e| format!("{e:.2}")),
    )
}
