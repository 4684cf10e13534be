//! The printed calibration board: its geometry as data, and what is printed in its squares
//! behind one trait.
//!
//! Every board is described by its grid of inner corners (`cols × rows`, row by row) and the
//! square's side ([`BoardSpec`]). A corner's id is its index in that order; the board frame's
//! origin is the first inner corner, x along a row, y down the columns (mm). What is printed
//! in the squares ([`Pattern`]: a chessboard, or a ChArUco board's markers) decides how the
//! board is found, how a pair's corners are matched, its file's keys and how it is drawn: the
//! pattern's own file answers each ([`BoardPattern`]), and nothing else asks which it is. A new
//! pattern is its own file, a variant of [`Pattern`] (with its `--board` prefix and file name
//! in [`Pattern::read`] and [`Layout`]), and its test.

mod charuco;
mod chessboard;

use std::fmt;
use std::str::FromStr;

use opencv::core::{Mat, Point3f, Vector};
use serde::Serialize;

use super::detect::{Detector, Seen};
use super::{CalibError, PairCorners};
use crate::opencv_yaml::FileStorage;
pub use charuco::{Charuco, Dictionary};
pub use chessboard::Chessboard;

/// The printed board: inner corners along a row and down a column, square size, pattern.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BoardSpec {
    pub cols: usize,
    pub rows: usize,
    pub square_mm: f64,
    pub pattern: Pattern,
}

/// What is printed in the squares: the registry of patterns.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum Pattern {
    /// Black and white squares only: found whole or not at all.
    Chessboard(Chessboard),
    /// An ArUco marker in each white square.
    Charuco(Charuco),
}

impl Pattern {
    /// What the pattern does.
    pub fn kind(&self) -> &dyn BoardPattern {
        match self {
            Pattern::Chessboard(p) => p,
            Pattern::Charuco(p) => p,
        }
    }

    /// The board `keys` describe, by their `pattern` key (none: a chessboard).
    ///
    /// # Errors
    /// What is missing or wrong, in words.
    pub fn read(keys: &dyn BoardKeys) -> Result<BoardSpec, String> {
        match keys.text("pattern")?.as_deref() {
            None | Some("chessboard") => Chessboard::read(keys),
            Some("charuco") => Charuco::read(keys),
            Some(other) => Err(format!("pattern {other:?}: chessboard or charuco")),
        }
    }
}

/// A board file's keys, as a pattern reads them (each error says what is missing or wrong).
pub trait BoardKeys {
    fn number(&self, key: &str) -> Result<f64, String>;
    /// A whole number ≥ 0.
    fn count(&self, key: &str) -> Result<usize, String>;
    /// A text, `None` when the key is absent.
    fn text(&self, key: &str) -> Result<Option<String>, String>;
}

/// What a printed pattern does for its board. Every place that depends on what is printed in
/// the squares asks it: calibration (detection, a pair's corners), the files, the printed
/// SVG, the synthetic camera's rendering.
pub trait BoardPattern {
    /// Its own requirements on the board, beyond the grid's.
    ///
    /// # Errors
    /// [`CalibError::BadBoard`] saying what to change.
    fn check(&self, board: &BoardSpec) -> Result<(), CalibError>;
    /// Whether the board is found in part (its corners known by what is printed beside them),
    /// so that views may leave the image in part.
    fn seen_in_part(&self) -> bool;
    /// The detectors tried: the first on every image, a later one only when the first finds
    /// too few pairs.
    fn detectors(&self) -> &'static [Detector];
    /// The board's corners in `gray` by `detector`, in ascending id; `None` when not found.
    ///
    /// # Errors
    /// An OpenCV failure (not "board not found", which is `Ok(None)`).
    fn find(
        &self,
        board: &BoardSpec,
        gray: &Mat,
        detector: Detector,
    ) -> opencv::Result<Option<Seen>>;
    /// The corners both images of a pair show, in one order, and a note; or why the pair
    /// cannot be used.
    ///
    /// # Errors
    /// The reason, in words.
    fn match_pair(
        &self,
        board: &BoardSpec,
        left: &Seen,
        right: &Seen,
    ) -> Result<(PairCorners, Option<String>), String>;
    /// A hint when the board was found in no image (starting with "; ").
    fn not_found_hint(&self, board: &BoardSpec, grays: &[Mat]) -> String;
    /// What is printed besides the squares, in the board frame (for printing and rendering).
    ///
    /// # Errors
    /// An OpenCV failure.
    fn markers(&self, board: &BoardSpec) -> opencv::Result<Vec<Marker>>;
    /// `board.yml`'s keys.
    fn write_keys(&self, board: &BoardSpec, fs: &mut FileStorage);
    /// The pattern's keys in a calibration file, beside the board's layout.
    fn calibration_keys(&self, fs: &mut FileStorage);
    /// The printed sizes a user measures and corrects (`square_mm`, `marker_mm`).
    fn measured(&self) -> &'static str;
    /// The board in words.
    fn describe(&self, board: &BoardSpec) -> String;
    /// The options that describe the board, its lengths written by `mm` (the print's caption).
    fn options(&self, board: &BoardSpec, mm: &dyn Fn(f64) -> String) -> String;
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
            pattern: Pattern::Chessboard(Chessboard {}),
        }
    }

    /// What `--board` names this board by.
    pub fn layout(&self) -> Layout {
        Layout {
            charuco: matches!(self.pattern, Pattern::Charuco(_)),
            cols: self.cols,
            rows: self.rows,
        }
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
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            return Err(CalibError::BadBoard(format!(
                "square size {} mm: give the printed square's side in mm",
                self.square_mm
            )));
        }
        self.pattern.kind().check(self)
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

    /// The detector every image is searched by first.
    pub fn first_detector(&self) -> Detector {
        self.pattern.kind().detectors()[0]
    }

    /// What is printed besides the squares, in the board frame (for printing and rendering).
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn markers(&self) -> opencv::Result<Vec<Marker>> {
        self.pattern.kind().markers(self)
    }
}

/// A board described in part (by a command line, a caller): each `None` is taken from a board
/// file. Messages name the parts as `board=`, `square_mm=`, `marker_mm=`, `dictionary=`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PartialBoard {
    pub layout: Option<Layout>,
    pub square_mm: Option<f64>,
    pub marker_mm: Option<f64>,
    pub dictionary: Option<Dictionary>,
}

impl PartialBoard {
    /// The board these parts describe over `base` (a board file's, or the default one).
    ///
    /// # Errors
    /// What does not fit: marker parts for a chessboard, or a ChArUco board without its
    /// marker size.
    pub fn over(&self, base: &BoardSpec) -> Result<BoardSpec, String> {
        let layout = self.layout.unwrap_or(base.layout());
        let square_mm = self.square_mm.unwrap_or(base.square_mm);
        let pattern = if layout.charuco {
            let (base_marker, base_dictionary) = match base.pattern {
                Pattern::Charuco(c) => (Some(c.marker_mm), Some(c.dictionary)),
                Pattern::Chessboard(_) => (None, None),
            };
            Pattern::Charuco(Charuco {
                marker_mm: self.marker_mm.or(base_marker).ok_or_else(|| {
                    format!("board={layout} needs marker_mm=MM, the printed marker's side (mm)")
                })?,
                dictionary: self
                    .dictionary
                    .or(base_dictionary)
                    .unwrap_or(Dictionary::DEFAULT),
            })
        } else {
            if self.marker_mm.is_some() || self.dictionary.is_some() {
                return Err(format!(
                    "marker_mm=… and dictionary=… describe a ChArUco board, but the board is the chessboard {layout}: give board=charuco:SXxSY"
                ));
            }
            Pattern::Chessboard(Chessboard {})
        };
        Ok(BoardSpec {
            cols: layout.cols,
            rows: layout.rows,
            square_mm,
            pattern,
        })
    }

    /// The first part that says otherwise than `written` (a board file), as `name=value`.
    pub fn contradiction(&self, written: &BoardSpec) -> Option<String> {
        if let Some(l) = self.layout.filter(|&l| l != written.layout()) {
            return Some(format!("board={l}"));
        }
        if let Some(s) = self.square_mm.filter(|&s| s != written.square_mm) {
            return Some(format!("square_mm={s}"));
        }
        if let Pattern::Charuco(c) = written.pattern {
            if let Some(m) = self.marker_mm.filter(|&m| m != c.marker_mm) {
                return Some(format!("marker_mm={m}"));
            }
            if let Some(d) = self.dictionary.filter(|&d| d != c.dictionary) {
                return Some(format!("dictionary={}", d.name()));
            }
        }
        None
    }

    /// Whether the parts describe a board whole, without a file.
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
        f.write_str(&self.pattern.kind().describe(self))
    }
}
