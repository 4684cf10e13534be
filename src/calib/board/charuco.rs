//! A ChArUco board: an ArUco marker in each white square (OpenCV's layout and corner ids), so
//! that any part of it showing two markers is found, and each corner is known by the markers
//! beside it, never read the wrong way round.

use std::str::FromStr;

use opencv::aruco;
use opencv::core::{self, Mat, Point2f, Ptr, Vector};
use opencv::prelude::*;
use serde::Serialize;

use super::{BoardKeys, BoardPattern, BoardSpec, Marker, Pattern};
use crate::calib::detect::{refine, square_px, Detector, Seen};
use crate::calib::{pairs, CalibError, PairCorners};
use crate::opencv_yaml::FileStorage;

/// The fewest corners a ChArUco view is kept with.
pub const MIN_CHARUCO_CORNERS: usize = 4;

/// A ChArUco board's markers: `marker_mm` a side, of `dictionary`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Charuco {
    pub marker_mm: f64,
    pub dictionary: Dictionary,
}

impl Charuco {
    /// The board in `board.yml`'s keys (`pattern: charuco`): its squares (OpenCV's
    /// convention), their size, the markers' size and their dictionary.
    pub(super) fn read(keys: &dyn BoardKeys) -> Result<BoardSpec, String> {
        let squares = |key: &str| -> Result<usize, String> {
            match keys.count(key)? {
                0 => Err(format!("{key} is 0")),
                n => Ok(n - 1),
            }
        };
        let dictionary = match keys.text("dictionary")? {
            Some(name) => name.parse::<Dictionary>()?,
            None => return Err("no dictionary (e.g. DICT_5X5_100)".into()),
        };
        Ok(BoardSpec {
            cols: squares("squares_x")?,
            rows: squares("squares_y")?,
            square_mm: keys.number("square_mm")?,
            pattern: Pattern::Charuco(Charuco {
                marker_mm: keys.number("marker_mm")?,
                dictionary,
            }),
        })
    }

    /// OpenCV's board (its unit mm).
    fn opencv(&self, board: &BoardSpec) -> opencv::Result<Ptr<aruco::CharucoBoard>> {
        aruco::CharucoBoard::create(
            (board.cols + 1) as i32,
            (board.rows + 1) as i32,
            board.square_mm as f32,
            self.marker_mm as f32,
            &self.dictionary.opencv()?,
        )
    }

    /// The board's markers: one in each white square.
    fn marker_count(board: &BoardSpec) -> usize {
        (board.cols + 1) * (board.rows + 1) / 2
    }
}

impl BoardPattern for Charuco {
    fn check(&self, board: &BoardSpec) -> Result<(), CalibError> {
        if !(self.marker_mm.is_finite() && self.marker_mm > 0.0 && self.marker_mm < board.square_mm)
        {
            return Err(CalibError::BadBoard(format!(
                "marker size {} mm with {} mm squares: give the printed marker's side (--marker-mm), smaller than the square",
                self.marker_mm, board.square_mm
            )));
        }
        let have = self.dictionary.opencv()?.bytes_list().rows() as usize;
        let need = Charuco::marker_count(board);
        if need > have {
            return Err(CalibError::BadBoard(format!(
                "{} has {need} markers but {} has only {have}: give a dictionary with more (e.g. --dictionary DICT_5X5_250) or use a smaller board",
                board.layout(),
                self.dictionary.name()
            )));
        }
        Ok(())
    }

    fn seen_in_part(&self) -> bool {
        true
    }

    fn detectors(&self) -> &'static [Detector] {
        &[Detector::Charuco]
    }

    /// Its markers (`detectMarkers`), the corners between them (`interpolateCornersCharuco`),
    /// each refined again by `cornerSubPix` in a window that stays off the markers.
    fn find(
        &self,
        board: &BoardSpec,
        gray: &Mat,
        _detector: Detector,
    ) -> opencv::Result<Option<Seen>> {
        let mut markers = Vector::<Vector<Point2f>>::new();
        let mut marker_ids = Vector::<i32>::new();
        let mut rejected = Vector::<Vector<Point2f>>::new();
        aruco::detect_markers(
            gray,
            &self.dictionary.opencv()?,
            &mut markers,
            &mut marker_ids,
            &aruco::DetectorParameters::create()?,
            &mut rejected,
        )?;
        if marker_ids.len() < 2 {
            return Ok(None);
        }
        let (mut corners, mut ids) = (Vector::<Point2f>::new(), Vector::<i32>::new());
        aruco::interpolate_corners_charuco(
            &markers,
            &marker_ids,
            gray,
            &self.opencv(board)?,
            &mut corners,
            &mut ids,
            &core::no_array(),
            &core::no_array(),
            2,
        )?;
        if ids.len() < MIN_CHARUCO_CORNERS {
            return Ok(None);
        }
        let mut seen: Vec<(usize, [f32; 2])> = ids
            .iter()
            .zip(corners.iter())
            .map(|(id, p)| (id as usize, [p.x, p.y]))
            .collect();
        seen.sort_by_key(|s| s.0);
        let mut seen = Seen {
            ids: seen.iter().map(|s| s.0).collect(),
            px: seen.iter().map(|s| s.1).collect(),
        };
        // OpenCV refines to 0.1 px; again, to 1e-4, in a window that holds no marker edge: the
        // gap between a corner and the markers beside it is (square − marker) / 2.
        let square_px = square_px(board, &seen);
        let gap_px = square_px * (board.square_mm - self.marker_mm) / (2.0 * board.square_mm);
        let half = (gap_px.floor() as i32 - 1).clamp(2, 5);
        let mut refined: Vector<Point2f> =
            seen.px.iter().map(|p| Point2f::new(p[0], p[1])).collect();
        seen.px = refine(gray, &mut refined, half)?;
        Ok(Some(seen))
    }

    fn match_pair(
        &self,
        board: &BoardSpec,
        left: &Seen,
        right: &Seen,
    ) -> Result<(PairCorners, Option<String>), String> {
        pairs::by_ids(board, left, right)
    }

    fn not_found_hint(&self, _board: &BoardSpec, _grays: &[Mat]) -> String {
        format!(
            "; no two {} markers side by side were found: check --dictionary and that the images show the board",
            self.dictionary.name()
        )
    }

    /// The markers where OpenCV places them.
    fn markers(&self, board: &BoardSpec) -> opencv::Result<Vec<Marker>> {
        let opencv_board = self.opencv(board)?;
        let dictionary = self.dictionary.opencv()?;
        let side = dictionary.marker_size() as usize + 2;
        let s = board.square_mm;
        let ids = opencv_board.ids();
        opencv_board
            .obj_points()
            .iter()
            .zip(ids.iter())
            .map(|(points, id)| {
                // OpenCV's board frame has its origin at the board's outer corner, one square
                // before the first inner corner.
                let corners: [[f64; 2]; 4] = std::array::from_fn(|k| {
                    let p = points.get(k).expect("a marker has 4 corners");
                    [f64::from(p.x) - s, f64::from(p.y) - s]
                });
                let centre = corners
                    .iter()
                    .fold([0.0; 2], |a, c| [a[0] + c[0] / 4.0, a[1] + c[1] / 4.0]);
                let mut image = Mat::default();
                aruco::draw_marker(&dictionary, id, side as i32, &mut image, 1)?;
                let white = (0..side * side)
                    .map(|k| {
                        image
                            .at_2d::<u8>((k / side) as i32, (k % side) as i32)
                            .map(|v| *v > 127)
                    })
                    .collect::<opencv::Result<_>>()?;
                Ok(Marker {
                    square: (
                        (centre[0] / s).floor() as i64,
                        (centre[1] / s).floor() as i64,
                    ),
                    corners,
                    side,
                    white,
                })
            })
            .collect()
    }

    fn write_keys(&self, board: &BoardSpec, fs: &mut FileStorage) {
        fs.string("pattern", "charuco")
            .int("squares_x", board.cols as i64 + 1)
            .int("squares_y", board.rows as i64 + 1)
            .real("square_mm", board.square_mm);
        self.calibration_keys(fs);
    }

    fn calibration_keys(&self, fs: &mut FileStorage) {
        fs.real("marker_mm", self.marker_mm)
            .string("dictionary", self.dictionary.name());
    }

    fn measured(&self) -> &'static str {
        "square_mm and marker_mm"
    }

    fn describe(&self, board: &BoardSpec) -> String {
        format!(
            "ChArUco {}x{} squares of {} mm, {} mm markers of {}",
            board.cols + 1,
            board.rows + 1,
            board.square_mm,
            self.marker_mm,
            self.dictionary.name()
        )
    }

    fn options(&self, board: &BoardSpec, mm: &dyn Fn(f64) -> String) -> String {
        format!(
            "--board {} --square-mm {} --marker-mm {} --dictionary {}",
            board.layout(),
            mm(board.square_mm),
            mm(self.marker_mm),
            self.dictionary.name()
        )
    }
}

/// One of OpenCV's predefined ArUco dictionaries, by its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dictionary(i32);

/// OpenCV's predefined dictionaries (`cv::aruco::PREDEFINED_DICTIONARY_NAME`).
const DICTIONARIES: [(&str, i32); 21] = [
    ("DICT_4X4_50", aruco::DICT_4X4_50),
    ("DICT_4X4_100", aruco::DICT_4X4_100),
    ("DICT_4X4_250", aruco::DICT_4X4_250),
    ("DICT_4X4_1000", aruco::DICT_4X4_1000),
    ("DICT_5X5_50", aruco::DICT_5X5_50),
    ("DICT_5X5_100", aruco::DICT_5X5_100),
    ("DICT_5X5_250", aruco::DICT_5X5_250),
    ("DICT_5X5_1000", aruco::DICT_5X5_1000),
    ("DICT_6X6_50", aruco::DICT_6X6_50),
    ("DICT_6X6_100", aruco::DICT_6X6_100),
    ("DICT_6X6_250", aruco::DICT_6X6_250),
    ("DICT_6X6_1000", aruco::DICT_6X6_1000),
    ("DICT_7X7_50", aruco::DICT_7X7_50),
    ("DICT_7X7_100", aruco::DICT_7X7_100),
    ("DICT_7X7_250", aruco::DICT_7X7_250),
    ("DICT_7X7_1000", aruco::DICT_7X7_1000),
    ("DICT_ARUCO_ORIGINAL", aruco::DICT_ARUCO_ORIGINAL),
    ("DICT_APRILTAG_16h5", aruco::DICT_APRILTAG_16h5),
    ("DICT_APRILTAG_25h9", aruco::DICT_APRILTAG_25h9),
    ("DICT_APRILTAG_36h10", aruco::DICT_APRILTAG_36h10),
    ("DICT_APRILTAG_36h11", aruco::DICT_APRILTAG_36h11),
];

impl Dictionary {
    /// Anipose's default, and the one `calib/charuco-10x7.svg` is printed with.
    pub const DEFAULT: Dictionary = Dictionary(aruco::DICT_5X5_100);

    pub fn name(self) -> &'static str {
        DICTIONARIES
            .iter()
            .find(|d| d.1 == self.0)
            .map(|d| d.0)
            .expect("a predefined dictionary")
    }

    /// OpenCV's dictionary.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn opencv(self) -> opencv::Result<Ptr<aruco::Dictionary>> {
        aruco::get_predefined_dictionary_i32(self.0)
    }
}

impl FromStr for Dictionary {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        DICTIONARIES
            .iter()
            .find(|d| d.0.eq_ignore_ascii_case(s.trim()))
            .map(|d| Dictionary(d.1))
            .ok_or_else(|| {
                let names: Vec<&str> = DICTIONARIES.iter().map(|d| d.0).collect();
                format!(
                    "unknown ArUco dictionary {s:?}; one of {}",
                    names.join(", ")
                )
            })
    }
}

impl Serialize for Dictionary {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The markers where [`BoardSpec::markers`] puts them (which the SVG and the renderer
    /// draw) are OpenCV's own board, pixel for pixel: OpenCV's `CharucoBoard::draw` of the
    /// squares' area against the same area filled from the markers' bits.
    #[test]
    fn charuco_markers_are_where_opencv_draws_them() {
        use opencv::core::{Mat, Size};
        use opencv::prelude::*;
        let board = BoardSpec {
            cols: 9,
            rows: 6,
            square_mm: 10.0,
            pattern: Pattern::Charuco(Charuco {
                marker_mm: 7.0,
                dictionary: Dictionary::DEFAULT,
            }),
        };
        let px_per_mm = 10;
        let (w, h) = (100 * px_per_mm, 70 * px_per_mm);
        let mut drawn = Mat::default();
        let Pattern::Charuco(charuco) = board.pattern else {
            unreachable!("a ChArUco board")
        };
        charuco
            .opencv(&board)
            .unwrap()
            .draw(Size::new(w, h), &mut drawn, 0, 1)
            .unwrap();
        let markers = board.markers().unwrap();
        let (mut same, mut total) = (0usize, 0usize);
        for v in 0..h {
            for u in 0..w {
                // The pixel's centre in the board frame (origin one square in).
                let x = (f64::from(u) + 0.5) / f64::from(px_per_mm) - 10.0;
                let y = (f64::from(v) + 0.5) / f64::from(px_per_mm) - 10.0;
                let (cx, cy) = ((x / 10.0).floor() as i64, (y / 10.0).floor() as i64);
                let mut ink = (cx + cy).rem_euclid(2) == 0;
                for m in &markers {
                    let [c0, c1, _, c3] = m.corners;
                    let (a, b) = ((x - c0[0]) / (c1[0] - c0[0]), (y - c0[1]) / (c3[1] - c0[1]));
                    if (0.0..1.0).contains(&a) && (0.0..1.0).contains(&b) {
                        let k =
                            (b * m.side as f64) as usize * m.side + (a * m.side as f64) as usize;
                        ink = !m.white[k];
                    }
                }
                let theirs = *drawn.at_2d::<u8>(v, u).unwrap() < 128;
                same += usize::from(ink == theirs);
                total += 1;
            }
        }
        let share = same as f64 / total as f64;
        assert!(share > 0.99, "{:.4} of the pixels agree", share);
    }
}
