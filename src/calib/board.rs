//! The printed calibration board: a chessboard or a ChArUco board, its corners, their ids and
//! where they lie on it.
//!
//! Both kinds are described by their grid of inner corners (`cols × rows`, row by row) and the
//! square's side. A corner's id is its index in that order: for a chessboard every corner is
//! seen or none is; a ChArUco board (ArUco markers in its white squares, OpenCV's layout and
//! corner ids) may be seen in part, and each corner is known by the markers beside it. The board
//! frame's origin is the first inner corner, x along a row, y down the columns (mm).

use std::fmt;
use std::str::FromStr;

use opencv::aruco;
use opencv::core::{Mat, Point3f, Ptr, Vector};
use opencv::prelude::*;
use serde::Serialize;

use super::CalibError;

/// The printed board: inner corners along a row and down a column, square size, pattern.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BoardSpec {
    pub cols: usize,
    pub rows: usize,
    pub square_mm: f64,
    pub pattern: Pattern,
}

/// What is printed in the squares.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Pattern {
    /// Black and white squares only: found whole or not at all.
    Chessboard,
    /// An ArUco marker of `dictionary` in each white square, `marker_mm` a side.
    Charuco {
        marker_mm: f64,
        dictionary: Dictionary,
    },
}

/// `--board`: `9x6` (a chessboard's inner corners) or `charuco:10x7` (a ChArUco board's
/// squares, OpenCV's convention), as inner corners.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    pub charuco: bool,
    pub cols: usize,
    pub rows: usize,
}

impl FromStr for Layout {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let wrong = || {
            format!(
                "expected COLSxROWS inner corners such as 9x6, or charuco:SXxSY squares such as charuco:10x7, got {s:?}"
            )
        };
        let (charuco, counts) = match s.strip_prefix("charuco:") {
            Some(rest) => (true, rest),
            None => (false, s),
        };
        let (c, r) = counts.split_once(['x', 'X']).ok_or_else(wrong)?;
        let n = |v: &str| v.trim().parse::<usize>().map_err(|_| wrong());
        let (c, r) = (n(c)?, n(r)?);
        if charuco {
            if c < 2 || r < 2 {
                return Err(format!(
                    "{s}: a ChArUco board has at least 2 squares a side"
                ));
            }
            Ok(Layout {
                charuco,
                cols: c - 1,
                rows: r - 1,
            })
        } else {
            Ok(Layout {
                charuco,
                cols: c,
                rows: r,
            })
        }
    }
}

impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.charuco {
            write!(f, "charuco:{}x{}", self.cols + 1, self.rows + 1)
        } else {
            write!(f, "{}x{}", self.cols, self.rows)
        }
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

/// One ArUco marker of a ChArUco board: its square ((i, j) along a row and down a column; the
/// square whose top-left corner is the first inner corner is (0, 0), so the board's squares run
/// from (−1, −1)), its corners in the board frame (mm; top-left, top-right, bottom-right, bottom-left of the
/// marker's image) and its bits, `side × side` row by row with the black border, `true` white.
#[derive(Clone, Debug, PartialEq)]
pub struct Marker {
    pub square: (i64, i64),
    pub corners: [[f64; 2]; 4],
    pub side: usize,
    pub white: Vec<bool>,
}

impl BoardSpec {
    /// A chessboard of `cols × rows` inner corners.
    pub fn chessboard(cols: usize, rows: usize, square_mm: f64) -> Self {
        BoardSpec {
            cols,
            rows,
            square_mm,
            pattern: Pattern::Chessboard,
        }
    }

    /// What `--board` names this board by.
    pub fn layout(&self) -> Layout {
        Layout {
            charuco: self.is_charuco(),
            cols: self.cols,
            rows: self.rows,
        }
    }

    pub fn is_charuco(&self) -> bool {
        matches!(self.pattern, Pattern::Charuco { .. })
    }

    /// The number of inner corners.
    pub fn corner_count(&self) -> usize {
        self.cols * self.rows
    }

    /// # Errors
    /// [`CalibError::BadBoard`] for fewer than 3 corners a side, a chessboard with equal sides
    /// (ambiguous orientation), a square size that is not a positive number, or a ChArUco
    /// board whose markers are not smaller than its squares or outnumber its dictionary.
    pub fn check(&self) -> Result<(), CalibError> {
        let layout = self.layout();
        if self.cols < 3 || self.rows < 3 {
            return Err(CalibError::BadBoard(format!(
                "{layout} has {}x{} inner corners: at least 3 along each side",
                self.cols, self.rows
            )));
        }
        if self.cols == self.rows && !self.is_charuco() {
            return Err(CalibError::BadBoard(format!(
                "{layout}: a square chessboard has no orientation; use one with different counts (or a ChArUco board)"
            )));
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            return Err(CalibError::BadBoard(format!(
                "square size {} mm: give the printed square's side in mm",
                self.square_mm
            )));
        }
        if let Pattern::Charuco {
            marker_mm,
            dictionary,
        } = self.pattern
        {
            if !(marker_mm.is_finite() && marker_mm > 0.0 && marker_mm < self.square_mm) {
                return Err(CalibError::BadBoard(format!(
                    "marker size {marker_mm} mm with {} mm squares: give the printed marker's side (--marker-mm), smaller than the square",
                    self.square_mm
                )));
            }
            let have = dictionary.opencv()?.bytes_list().rows() as usize;
            let need = self.marker_count();
            if need > have {
                return Err(CalibError::BadBoard(format!(
                    "{layout} has {need} markers but {} has only {have}: give a dictionary with more (e.g. --dictionary DICT_5X5_250) or use a smaller board",
                    dictionary.name()
                )));
            }
        }
        Ok(())
    }

    /// A ChArUco board's markers: one in each white square.
    fn marker_count(&self) -> usize {
        (self.cols + 1) * (self.rows + 1) / 2
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

    /// Corner `id`'s column and row in the grid.
    pub fn grid(&self, id: usize) -> (usize, usize) {
        (id % self.cols, id / self.cols)
    }

    /// Object points of corners `ids` (mm), in their order.
    pub(super) fn object_points(&self, ids: &[usize]) -> Vector<Point3f> {
        let s = self.square_mm as f32;
        ids.iter()
            .map(|&id| {
                let (i, j) = self.grid(id);
                Point3f::new(i as f32 * s, j as f32 * s, 0.0)
            })
            .collect()
    }

    /// The corners `ids` (mm) exactly as OpenCV calibrated with them
    /// ([`BoardSpec::object_points`]'s `f32` values, widened), for handcap's own geometry.
    pub(super) fn corners_mm(&self, ids: &[usize]) -> Vec<nalgebra::Point3<f64>> {
        self.object_points(ids)
            .iter()
            .map(|p| nalgebra::Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)))
            .collect()
    }

    /// The corners next to corner `id` along its row and down its column (the one after it
    /// in each, where the board has one): each pair of neighbours once.
    pub fn neighbours(&self, id: usize) -> impl Iterator<Item = usize> {
        let (i, j) = self.grid(id);
        let right = (i + 1 < self.cols).then_some(id + 1);
        let below = (j + 1 < self.rows).then_some(id + self.cols);
        right.into_iter().chain(below)
    }

    /// OpenCV's ChArUco board (its unit mm); `None` for a chessboard.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn charuco(&self) -> opencv::Result<Option<Ptr<aruco::CharucoBoard>>> {
        let Pattern::Charuco {
            marker_mm,
            dictionary,
        } = self.pattern
        else {
            return Ok(None);
        };
        aruco::CharucoBoard::create(
            (self.cols + 1) as i32,
            (self.rows + 1) as i32,
            self.square_mm as f32,
            marker_mm as f32,
            &dictionary.opencv()?,
        )
        .map(Some)
    }

    /// A ChArUco board's markers where OpenCV places them (none for a chessboard), for
    /// rendering and printing.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn markers(&self) -> opencv::Result<Vec<Marker>> {
        let (Some(board), Pattern::Charuco { dictionary, .. }) = (self.charuco()?, self.pattern)
        else {
            return Ok(Vec::new());
        };
        let dictionary = dictionary.opencv()?;
        let side = dictionary.marker_size() as usize + 2;
        let s = self.square_mm;
        let ids = board.ids();
        board
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
}

/// What a command line says of the board (`--board`, `--square-mm`, `--marker-mm`,
/// `--dictionary`); each `None` is taken from a board file.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BoardFlags {
    pub layout: Option<Layout>,
    pub square_mm: Option<f64>,
    pub marker_mm: Option<f64>,
    pub dictionary: Option<Dictionary>,
}

impl BoardFlags {
    /// The board the flags describe over `base` (a board file's, or the default one).
    ///
    /// # Errors
    /// A usage message: marker flags for a chessboard, or a ChArUco board without its marker
    /// size.
    pub fn over(&self, base: &BoardSpec) -> Result<BoardSpec, String> {
        let layout = self.layout.unwrap_or(base.layout());
        let square_mm = self.square_mm.unwrap_or(base.square_mm);
        let pattern = if layout.charuco {
            let (base_marker, base_dictionary) = match base.pattern {
                Pattern::Charuco {
                    marker_mm,
                    dictionary,
                } => (Some(marker_mm), Some(dictionary)),
                Pattern::Chessboard => (None, None),
            };
            Pattern::Charuco {
                marker_mm: self.marker_mm.or(base_marker).ok_or_else(|| {
                    format!("--board {layout} needs --marker-mm, the printed marker's side (mm)")
                })?,
                dictionary: self
                    .dictionary
                    .or(base_dictionary)
                    .unwrap_or(Dictionary::DEFAULT),
            }
        } else {
            if self.marker_mm.is_some() || self.dictionary.is_some() {
                return Err(format!(
                    "--marker-mm and --dictionary describe a ChArUco board, but the board is the chessboard {layout}: give --board charuco:SXxSY"
                ));
            }
            Pattern::Chessboard
        };
        Ok(BoardSpec {
            cols: layout.cols,
            rows: layout.rows,
            square_mm,
            pattern,
        })
    }

    /// The first flag that says otherwise than `written` (a board file), as the user typed it.
    pub fn contradiction(&self, written: &BoardSpec) -> Option<String> {
        if let Some(l) = self.layout.filter(|&l| l != written.layout()) {
            return Some(format!("--board {l}"));
        }
        if let Some(s) = self.square_mm.filter(|&s| s != written.square_mm) {
            return Some(format!("--square-mm {s}"));
        }
        if let Pattern::Charuco {
            marker_mm,
            dictionary,
        } = written.pattern
        {
            if let Some(m) = self.marker_mm.filter(|&m| m != marker_mm) {
                return Some(format!("--marker-mm {m}"));
            }
            if let Some(d) = self.dictionary.filter(|&d| d != dictionary) {
                return Some(format!("--dictionary {}", d.name()));
            }
        }
        None
    }

    /// Whether the flags describe a board whole, without a file.
    pub fn complete(&self) -> bool {
        match self.layout {
            Some(l) if l.charuco => self.square_mm.is_some() && self.marker_mm.is_some(),
            Some(_) => self.square_mm.is_some(),
            None => false,
        }
    }
}

impl fmt::Display for BoardSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.pattern {
            Pattern::Chessboard => write!(
                f,
                "{}x{} inner corners, {} mm squares",
                self.cols, self.rows, self.square_mm
            ),
            Pattern::Charuco {
                marker_mm,
                dictionary,
            } => write!(
                f,
                "ChArUco {}x{} squares of {} mm, {} mm markers of {}",
                self.cols + 1,
                self.rows + 1,
                self.square_mm,
                marker_mm,
                dictionary.name()
            ),
        }
    }
}
