//! `board.yml`: the printed board's description, and the built-in default.

use std::path::Path;

use opencv::core;
use opencv::prelude::*;

use super::reason;
use crate::calib::{BoardKeys, BoardSpec, CalibError, Pattern};
use crate::opencv_yaml::FileStorage;

/// The board description's file name inside a calibration directory.
pub const BOARD_FILE: &str = "board.yml";

/// The repository's `calib/board.yml`: the printed board handcap assumes when a calibration
/// directory has no `board.yml` and no flags say otherwise.
pub const DEFAULT_BOARD_YAML: &str = include_str!("../../../calib/board.yml");

/// [`DEFAULT_BOARD_YAML`] read.
pub fn default_board() -> BoardSpec {
    read_board_text(DEFAULT_BOARD_YAML).expect("calib/board.yml is a board description")
}

/// Reads a board description from its text.
///
/// # Errors
/// As [`read_board`].
pub fn read_board_text(text: &str) -> Result<BoardSpec, CalibError> {
    let mode = core::FileStorage_Mode::READ as i32 | core::FileStorage_Mode::MEMORY as i32;
    board_from(text, mode, Path::new("(built-in board.yml)"))
}

/// `board.yml`: the printed board. A chessboard by its inner corners and square size; a ChArUco
/// board (`pattern: charuco`) by its squares (OpenCV's convention), their size, the markers'
/// size and their dictionary.
pub fn board_yaml(board: &BoardSpec) -> String {
    let mut fs = FileStorage::new();
    board.pattern.kind().write_keys(board, &mut fs);
    fs.text().to_string()
}

/// Reads `board.yml`.
///
/// # Errors
/// [`CalibError::BadBoard`] naming the file and what is missing.
pub fn read_board(path: &Path) -> Result<BoardSpec, CalibError> {
    let bad = |what: String| board_error(path, &what);
    if !path.is_file() {
        return Err(bad("no such file".into()));
    }
    let name = path
        .to_str()
        .ok_or_else(|| bad("the path is not UTF-8".into()))?;
    board_from(name, core::FileStorage_Mode::READ as i32, path)
}

/// A board description that cannot be used, and what to do instead.
fn board_error(path: &Path, what: &str) -> CalibError {
    CalibError::BadBoard(format!(
        "{}: {what}; pass --board COLSxROWS --square-mm MM (or --board charuco:SXxSY with --marker-mm and --dictionary), or write the file (see calib/board.yml and calib/charuco-board.yml)",
        path.display()
    ))
}

/// Reads a board description from a file name or, with the MEMORY flag, the text itself.
fn board_from(source: &str, mode: i32, path: &Path) -> Result<BoardSpec, CalibError> {
    let bad = |what: String| board_error(path, &what);
    let fs = core::FileStorage::new(source, mode, "").map_err(|e| bad(reason(&e)))?;
    Pattern::read(&Keys(fs)).map_err(bad)
}

/// A board file's keys, read through OpenCV's FileStorage.
struct Keys(core::FileStorage);

impl BoardKeys for Keys {
    fn number(&self, key: &str) -> Result<f64, String> {
        let node = self.0.get(key).map_err(|e| reason(&e))?;
        if node.empty().unwrap_or(true)
            || !node.is_real().unwrap_or(false) && !node.is_int().unwrap_or(false)
        {
            return Err(format!("no number for {key}"));
        }
        node.to_f64().map_err(|e| reason(&e))
    }

    fn count(&self, key: &str) -> Result<usize, String> {
        let v = self.number(key)?;
        if v.fract() != 0.0 || v < 0.0 {
            return Err(format!("{key} is {v}, not a whole number"));
        }
        Ok(v as usize)
    }

    fn text(&self, key: &str) -> Result<Option<String>, String> {
        let node = self.0.get(key).map_err(|e| reason(&e))?;
        if node.empty().unwrap_or(true) {
            return Ok(None);
        }
        if !node.is_string().unwrap_or(false) {
            return Err(format!("{key} is not a text"));
        }
        node.to_string().map(Some).map_err(|e| reason(&e))
    }
}
