//! A chessboard: black and white squares only, found whole or not at all, by OpenCV's
//! sector-based detector or, when that finds too few pairs, the classic one (never both within
//! one calibration).

use opencv::core::Mat;
use serde::Serialize;

use super::{BoardKeys, BoardPattern, BoardSpec, Marker};
use crate::calib::detect::{find_corners, Detector, Seen};
use crate::calib::{pairs, CalibError, PairCorners};
use crate::opencv_yaml::FileStorage;

/// Nothing printed in the squares.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Chessboard {}

impl Chessboard {
    /// The board in `board.yml`'s keys: its inner corners and square size.
    pub(super) fn read(keys: &dyn BoardKeys) -> Result<BoardSpec, String> {
        Ok(BoardSpec::chessboard(
            keys.count("inner_corners_cols")?,
            keys.count("inner_corners_rows")?,
            keys.number("square_mm")?,
        ))
    }
}

impl BoardPattern for Chessboard {
    fn check(&self, board: &BoardSpec) -> Result<(), CalibError> {
        if board.cols == board.rows {
            return Err(CalibError::BadBoard(format!(
                "{}: a square chessboard has no orientation; use one with different counts (or a ChArUco board)",
                board.layout()
            )));
        }
        Ok(())
    }

    fn seen_in_part(&self) -> bool {
        false
    }

    fn detectors(&self) -> &'static [Detector] {
        &[Detector::SectorBased, Detector::Classic]
    }

    fn find(
        &self,
        board: &BoardSpec,
        gray: &Mat,
        detector: Detector,
    ) -> opencv::Result<Option<Seen>> {
        Ok(find_corners(gray, board.cols as i32, board.rows as i32, detector)?.map(Seen::whole))
    }

    /// Every corner is seen or none: the right image's run in the left image's order as
    /// detected, or reversed when they run the other way (the detector's 180° ambiguity).
    fn match_pair(
        &self,
        board: &BoardSpec,
        left: &Seen,
        right: &Seen,
    ) -> Result<(PairCorners, Option<String>), String> {
        match pairs::order_right_like_left(board, &left.px, &right.px) {
            Some((right, reversed)) => Ok((
                PairCorners {
                    report: 0,
                    ids: left.ids.clone(),
                    left: left.px.clone(),
                    right,
                },
                reversed.then(|| "right corners reversed to match the left".into()),
            )),
            None => Err("corners run differently in the left and right images (mirrored?)".into()),
        }
    }

    /// Other board sizes that are found in the first few images.
    fn not_found_hint(&self, board: &BoardSpec, grays: &[Mat]) -> String {
        let (c, r) = (board.cols as i32, board.rows as i32);
        let candidates = [
            (r, c),
            (c - 1, r - 1),
            (c + 1, r + 1),
            (c - 1, r),
            (c + 1, r),
            (c, r - 1),
            (c, r + 1),
        ];
        for (cols, rows) in candidates {
            if cols < 3 || rows < 3 || cols == rows {
                continue;
            }
            let works = grays.iter().take(4).any(|g| {
                matches!(
                    find_corners(g, cols, rows, Detector::SectorBased),
                    Ok(Some(_))
                )
            });
            if works {
                let why = if (cols, rows) == (r, c) {
                    "columns and rows swapped"
                } else if (cols, rows) == (c - 1, r - 1) {
                    "squares counted instead of inner corners"
                } else {
                    "a different count"
                };
                return format!(
                    "; a {cols}x{rows} board is found ({why}): pass --board {cols}x{rows}"
                );
            }
        }
        "; no nearby size (transposed, ±1) is found either: check the images show the whole board with a white border".into()
    }

    fn markers(&self, _board: &BoardSpec) -> opencv::Result<Vec<Marker>> {
        Ok(Vec::new())
    }

    fn write_keys(&self, board: &BoardSpec, fs: &mut FileStorage) {
        fs.int("inner_corners_cols", board.cols as i64)
            .int("inner_corners_rows", board.rows as i64)
            .real("square_mm", board.square_mm);
    }

    fn calibration_keys(&self, _fs: &mut FileStorage) {}

    fn measured(&self) -> &'static str {
        "square_mm"
    }

    fn describe(&self, board: &BoardSpec) -> String {
        format!(
            "{}x{} inner corners, {} mm squares",
            board.cols, board.rows, board.square_mm
        )
    }

    fn options(&self, board: &BoardSpec, mm: &dyn Fn(f64) -> String) -> String {
        format!(
            "--board {} --square-mm {}",
            board.layout(),
            mm(board.square_mm)
        )
    }
}
