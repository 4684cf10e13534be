//! The calibration's figures: each pair's error, and a pair rectified side by side.

use std::path::{Path, PathBuf};

use crate::plot::{self as figures, LinePlot, Mark, Series};

use opencv::calib3d;
use opencv::core::{self, Mat, Size, Vector};
use opencv::prelude::*;

use super::{CalibError, PairReport, StereoCalibration};
use crate::cv::mat;

impl StereoCalibration {
    /// Writes `<stem>_pairs.png/.svg` (each used pair's left and right error, as bars) and
    /// `<stem>_rectified.png` (the first used pair rectified side by side, a white gap between
    /// them and each named, with horizontal lines: a point must lie on the same line in both
    /// halves). Returns the files written.
    ///
    /// # Errors
    /// [`CalibError`] when an image cannot be read or a figure written.
    pub fn write_figures(&self, stem: &Path) -> Result<Vec<PathBuf>, CalibError> {
        let used: Vec<&PairReport> = self.used().collect();
        let bars = |side: usize, label: &str, offset: f64| Series {
            label: label.into(),
            points: used
                .iter()
                .enumerate()
                .map(|(k, p)| (k as f64, p.rms_px.map_or(f64::NAN, |e| e[side])))
                .collect(),
            mark: Mark::Bars {
                offset,
                width: 0.38,
            },
            colour: side,
        };
        let plot = LinePlot {
            title: format!("Reprojection error per pair (RMS {:.3} px)", self.rms_px),
            x_label: "pair".into(),
            y_label: "RMS error (px)".into(),
            series: vec![bars(0, "left", -0.2), bars(1, "right", 0.2)],
            log_y: false,
            x_names: used.iter().map(|p| p.name.clone()).collect(),
        };
        let [pairs, rectified] = stems(stem);
        figures::write_line_plot(&pairs, &plot)?;
        let mut written = figures::line_plot_files(&pairs).to_vec();
        if let Some(first) = used.first() {
            self.write_rectified(first, &rectified)?;
            written.push(rectified);
        }
        Ok(written)
    }

    fn write_rectified(&self, pair: &PairReport, path: &Path) -> Result<(), CalibError> {
        use opencv::{imgcodecs, imgproc};
        let size = Size::new(self.rig.image_size[0], self.rig.image_size[1]);
        let rectified = |image: &Path, k: &[f64; 9], d: &[f64], r: &[f64; 9], p: &[f64; 12]| {
            let not_image = |why: String| CalibError::NotAnImage {
                path: image.to_path_buf(),
                why,
            };
            let bytes = std::fs::read(image).map_err(|e| not_image(e.to_string()))?;
            let src = crate::cv::decode_image(&Vector::from_slice(&bytes), imgcodecs::IMREAD_COLOR)
                .map_err(not_image)?;
            let (mut m1, mut m2, mut out) = (Mat::default(), Mat::default(), Mat::default());
            calib3d::init_undistort_rectify_map(
                &mat(3, k)?,
                &mat(1, d)?,
                &mat(3, r)?,
                &mat(3, p)?,
                size,
                core::CV_32FC1,
                &mut m1,
                &mut m2,
            )?;
            imgproc::remap(
                &src,
                &mut out,
                &m1,
                &m2,
                imgproc::INTER_LINEAR,
                core::BORDER_CONSTANT,
                core::Scalar::default(),
            )?;
            Ok::<Mat, CalibError>(out)
        };
        let (left, right) = (&self.rig.left, &self.rig.right);
        let l = rectified(&pair.left, &left.k, &left.dist, &self.r1, &self.p1)?;
        let r = rectified(&pair.right, &right.k, &right.dist, &self.r2, &self.p2)?;
        // The two images apart by a white gap, each named, so two boards never read as one.
        const GAP_PX: i32 = 16;
        let gap = Mat::new_rows_cols_with_default(
            size.height,
            GAP_PX,
            l.typ(),
            core::Scalar::all(255.0),
        )?;
        let mut both = Mat::default();
        let halves: Vector<Mat> = [l, gap, r].into_iter().collect();
        core::hconcat(&halves, &mut both)?;
        let width = both.cols();
        for y in (20..size.height).step_by(40) {
            imgproc::line(
                &mut both,
                core::Point::new(0, y),
                core::Point::new(width - 1, y),
                core::Scalar::new(0.0, 200.0, 0.0, 0.0),
                1,
                imgproc::LINE_8,
                0,
            )?;
        }
        for (name, x) in [("left", 12), ("right", size.width + GAP_PX + 12)] {
            for (colour, thickness) in [(0.0, 6), (255.0, 2)] {
                imgproc::put_text(
                    &mut both,
                    name,
                    core::Point::new(x, 44),
                    imgproc::FONT_HERSHEY_SIMPLEX,
                    1.2,
                    core::Scalar::all(colour),
                    thickness,
                    imgproc::LINE_AA,
                    false,
                )?;
            }
        }
        let write_err = |message: String| CalibError::Write {
            path: path.to_path_buf(),
            message,
        };
        let mut png = Vector::<u8>::new();
        if !imgcodecs::imencode(".png", &both, &mut png, &Vector::new())? {
            return Err(write_err("OpenCV could not encode the PNG".into()));
        }
        crate::fsio::write_bytes(path, png.as_slice()).map_err(|e| write_err(e.to_string()))
    }
}

/// The figures written beside the calibration file `stem`: `STEM_pairs.png`, `STEM_pairs.svg`
/// and `STEM_rectified.png`.
pub fn figure_paths(stem: &Path) -> [PathBuf; 3] {
    let [pairs, rectified] = stems(stem);
    let [png, svg] = figures::line_plot_files(&pairs);
    [png, svg, rectified]
}

/// `STEM_pairs` (the per-pair error plot's stem) and `STEM_rectified.png`.
fn stems(stem: &Path) -> [PathBuf; 2] {
    ["_pairs", "_rectified.png"].map(|suffix| crate::fsio::beside(stem, "calib", suffix))
}
