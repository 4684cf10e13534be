//! Finding the calibration image pairs in a directory: `left<suffix>` with `right<suffix>`,
//! PNG or JPEG. The pair whose suffix (without the extension and a leading `_`) is `ref` is the
//! reference pair that fixes the hand frame.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::detect::Seen;
use super::{BoardSpec, CalibError, PairCorners, PairReport};

/// One left/right pair of images.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImagePair {
    /// The shared suffix without extension and leading separator, e.g. `03` or `ref`.
    pub name: String,
    pub left: PathBuf,
    pub right: PathBuf,
}

/// The pairs of a directory, in name order, and the files that have no partner.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PairListing {
    pub pairs: Vec<ImagePair>,
    pub reference: Option<ImagePair>,
    pub unpaired: Vec<PathBuf>,
}

const EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// Lists `dir`'s image pairs.
///
/// # Errors
/// The directory cannot be read.
pub fn list_pairs(dir: &Path) -> std::io::Result<PairListing> {
    let mut sides: BTreeMap<String, [Option<PathBuf>; 2]> = BTreeMap::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        let lower = name.to_ascii_lowercase();
        let Some((stem, ext)) = lower.rsplit_once('.') else {
            continue;
        };
        if !EXTENSIONS.contains(&ext) {
            continue;
        }
        let (side, rest) = if let Some(rest) = stem.strip_prefix("left") {
            (0, rest)
        } else if let Some(rest) = stem.strip_prefix("right") {
            (1, rest)
        } else {
            continue;
        };
        let key = rest.trim_start_matches(['_', '-', '.']).to_string();
        sides.entry(key).or_default()[side] = Some(path);
    }
    let mut listing = PairListing::default();
    for (name, [left, right]) in sides {
        match (left, right) {
            (Some(left), Some(right)) => {
                let pair = ImagePair { name, left, right };
                if pair.name == "ref" {
                    listing.reference = Some(pair);
                } else {
                    listing.pairs.push(pair);
                }
            }
            (Some(one), None) | (None, Some(one)) => listing.unpaired.push(one),
            (None, None) => {}
        }
    }
    Ok(listing)
}

/// The fewest corners both images of a pair must show, not all in one line of the board.
pub const MIN_COMMON_CORNERS: usize = 8;

/// The corners both images show, matched by id, and a note on anything done to them; `Err`
/// with the reason when the pair cannot be used.
///
/// A chessboard's corners are all seen or none; the right image's run in the left image's order
/// as detected, or reversed when they run the other way (the detector's 180° ambiguity; first →
/// last corner and along the first row must agree). A ChArUco board's ids are its own.
pub fn match_corners(
    board: &BoardSpec,
    left: &Seen,
    right: &Seen,
) -> Result<(PairCorners, Option<String>), String> {
    board.pattern.kind().match_pair(board, left, right)
}

/// The corners both images show by their ids (a board whose corners are known by what is
/// printed beside them), with a note when not all are; refused when too few or in one line.
pub(crate) fn by_ids(
    board: &BoardSpec,
    left: &Seen,
    right: &Seen,
) -> Result<(PairCorners, Option<String>), String> {
    let mut pair = PairCorners {
        report: 0,
        ids: Vec::new(),
        left: Vec::new(),
        right: Vec::new(),
    };
    for (id, l) in left.ids.iter().zip(&left.px) {
        if let Some(r) = right.at(*id) {
            pair.ids.push(*id);
            pair.left.push(*l);
            pair.right.push(r);
        }
    }
    let n = pair.ids.len();
    if n < MIN_COMMON_CORNERS {
        return Err(format!(
            "only {n} corners seen in both images (left {}, right {}; at least {MIN_COMMON_CORNERS} needed)",
            left.ids.len(),
            right.ids.len()
        ));
    }
    if collinear(board, &pair.ids) {
        return Err(format!(
            "the {n} corners seen in both images lie in one line of the board"
        ));
    }
    let note = (n < board.corner_count())
        .then(|| format!("{n} of {} corners in both images", board.corner_count()));
    Ok((pair, note))
}

/// Whether the corners `ids` lie on one straight line of the board.
fn collinear(board: &BoardSpec, ids: &[usize]) -> bool {
    let at = |id: usize| {
        let (i, j) = board.grid(id);
        (i as i64, j as i64)
    };
    let (a, b) = (at(ids[0]), at(ids[ids.len() - 1]));
    ids.iter().all(|&id| {
        let c = at(id);
        (b.0 - a.0) * (c.1 - a.1) == (b.1 - a.1) * (c.0 - a.0)
    })
}

/// The right image's corners in the left image's order: as detected, or reversed when they
/// run the other way (first → last corner and along the first row). `None` when neither order
/// agrees.
pub(crate) fn order_right_like_left(
    board: &BoardSpec,
    left: &[[f32; 2]],
    right: &[[f32; 2]],
) -> Option<(Vec<[f32; 2]>, bool)> {
    let n = left.len();
    let dir = |c: &[[f32; 2]], a: usize, b: usize| [c[b][0] - c[a][0], c[b][1] - c[a][1]];
    let dot = |u: [f32; 2], v: [f32; 2]| u[0] * v[0] + u[1] * v[1];
    let agrees = |r: &[[f32; 2]]| {
        dot(dir(left, 0, n - 1), dir(r, 0, n - 1)) > 0.0
            && dot(dir(left, 0, board.cols - 1), dir(r, 0, board.cols - 1)) > 0.0
    };
    if agrees(right) {
        return Some((right.to_vec(), false));
    }
    let reversed: Vec<[f32; 2]> = right.iter().rev().copied().collect();
    agrees(&reversed).then_some((reversed, true))
}

/// The error of too few usable pairs, with each rejected pair's reason.
pub(super) fn too_few(reports: &[PairReport], found: usize, needed: usize) -> CalibError {
    let reasons: Vec<String> = reports
        .iter()
        .filter_map(|r| r.rejected.as_ref().map(|why| format!("{}: {why}", r.name)))
        .collect();
    CalibError::TooFewPairs {
        found,
        needed,
        reasons: if reasons.is_empty() {
            "capture more pairs".into()
        } else {
            format!("{}; capture more pairs", reasons.join("; "))
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{Charuco, Dictionary, Pattern};

    fn seen(ids: impl Iterator<Item = usize>) -> Seen {
        let ids: Vec<usize> = ids.collect();
        let px = ids.iter().map(|&id| [id as f32, 2.0 * id as f32]).collect();
        Seen { ids, px }
    }

    #[test]
    fn charuco_corners_are_matched_by_id_and_too_few_are_refused() {
        let board = BoardSpec {
            cols: 9,
            rows: 6,
            square_mm: 10.0,
            pattern: Pattern::Charuco(Charuco {
                marker_mm: 7.5,
                dictionary: Dictionary::DEFAULT,
            }),
        };
        // Ids 10-29 on the left, 20-39 on the right: 20-29 in both, matched pixel to pixel.
        let (pair, note) = match_corners(&board, &seen(10..30), &seen(20..40)).unwrap();
        assert_eq!(pair.ids, (20..30).collect::<Vec<_>>());
        assert_eq!(pair.left, pair.right);
        assert_eq!(note.unwrap(), "10 of 54 corners in both images");
        let why = match_corners(&board, &seen(0..12), &seen(7..20)).unwrap_err();
        assert_eq!(
            why,
            "only 5 corners seen in both images (left 12, right 13; at least 8 needed)"
        );
        // One row of the board (9 corners) fixes no plane.
        let why = match_corners(&board, &seen(9..18), &seen(9..18)).unwrap_err();
        assert!(why.contains("lie in one line"), "{why}");
    }

    #[test]
    fn pairs_by_suffix_and_lists_the_rest() {
        let dir = tempfile::tempdir().unwrap();
        for f in [
            "left_00.png",
            "right_00.png",
            "left01.jpg",
            "right01.jpg",
            "left_02.png",
            "left_ref.png",
            "right_ref.png",
            "notes.txt",
            "board.yml",
        ] {
            std::fs::write(dir.path().join(f), b"x").unwrap();
        }
        let l = list_pairs(dir.path()).unwrap();
        let names: Vec<&str> = l.pairs.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["00", "01"]);
        assert_eq!(l.reference.unwrap().name, "ref");
        assert_eq!(l.unpaired, [dir.path().join("left_02.png")]);
    }
}
