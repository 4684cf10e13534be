//! Finding the calibration image pairs in a directory: `left<suffix>` with `right<suffix>`,
//! PNG or JPEG. The pair whose suffix (without the extension and a leading `_`) is `ref` is the
//! reference pair that fixes the hand frame.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{BoardSpec, CalibError, PairReport};

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

/// The right image's corners in the left image's order: as detected, or reversed when they
/// run the other way (first → last corner and along the first row). `None` when neither order
/// agrees.
pub(super) fn order_right_like_left(
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
