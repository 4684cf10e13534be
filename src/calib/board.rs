//! The printed calibration board: its corners and where they lie on it.

use opencv::core::{Point3f, Vector};
use serde::Serialize;

use super::CalibError;

/// The printed board: inner corners along a row and down a column, square size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BoardSpec {
    pub cols: usize,
    pub rows: usize,
    pub square_mm: f64,
}

impl BoardSpec {
    /// # Errors
    /// [`CalibError::BadBoard`] for fewer than 3 corners a side, equal sides (ambiguous
    /// orientation) or a square size that is not a positive number.
    pub fn check(&self) -> Result<(), CalibError> {
        if self.cols < 3 || self.rows < 3 {
            return Err(CalibError::BadBoard(format!(
                "{}x{} inner corners: at least 3 along each side",
                self.cols, self.rows
            )));
        }
        if self.cols == self.rows {
            return Err(CalibError::BadBoard(format!(
                "{}x{}: a square board has no orientation; use one with different counts",
                self.cols, self.rows
            )));
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            return Err(CalibError::BadBoard(format!(
                "square size {} mm: give the printed square's side in mm",
                self.square_mm
            )));
        }
        Ok(())
    }

    /// The centre of the inner corners, in the board's frame (mm).
    pub fn centre(&self) -> nalgebra::Point3<f64> {
        let s = self.square_mm;
        nalgebra::Point3::new(
            (self.cols - 1) as f64 * s / 2.0,
            (self.rows - 1) as f64 * s / 2.0,
            0.0,
        )
    }

    /// Object points of the inner corners (mm), row by row.
    pub(super) fn object_points(&self) -> Vector<Point3f> {
        let s = self.square_mm as f32;
        (0..self.rows)
            .flat_map(|j| {
                (0..self.cols).map(move |i| Point3f::new(i as f32 * s, j as f32 * s, 0.0))
            })
            .collect()
    }

    /// The corners (mm) exactly as OpenCV calibrated with them ([`BoardSpec::object_points`]'s
    /// `f32` values, widened), for handcap's own geometry.
    pub(super) fn corners_mm(&self) -> Vec<nalgebra::Point3<f64>> {
        self.object_points()
            .iter()
            .map(|p| nalgebra::Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)))
            .collect()
    }
}
