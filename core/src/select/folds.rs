//! How cross-validation cuts the rows into folds, and why.
//!
//! Shuffled k-fold CV assumes independent rows. A measured time series breaks that: each row is
//! a near copy of its neighbours, so a held-out row is predicted from its neighbours on either
//! side and CV rewards a model that interpolates them (tiny σ, huge C), which then fails on a
//! new ramp (`../shared/notes/realdata.md`: 8.35 mm held out against 3.4 mm for contiguous
//! folds on the soft trunk). `--folds-by auto` (the default) decides from the data:
//!
//! 1. **A designed grid** (every input takes at most [`GRID_LEVELS`] values): the rows are
//!    independent settings of the experiment → shuffled folds (the paper's protocol; the
//!    virtual micro-hand's grid keeps its folds and its search history).
//! 2. **A grouping column** (a column of the file that is neither input nor output, whose every
//!    value occupies one contiguous run of rows, at least two rows long on average, with at least
//!    2 × folds groups: a ramp, trial or iteration id) → whole groups held out.
//! 3. **Near-copies of neighbours** (the median distance between consecutive rows, inputs scaled
//!    to [0, 1], below [`NEAR_COPY_RATIO`] of the median distance between random rows) →
//!    contiguous blocks, one per fold (scikit-learn's unshuffled `KFold`).
//! 4. Otherwise → shuffled folds.
//!
//! `shuffle`, `blocks` or a column name choose directly. The choice and its reason go to the
//! output and the model file.
//!
//! [`assign_folds`] then deals the rows, or whole groups, to the folds: shuffled with the seed
//! for a search, or in blocks of consecutive runs for the intervals ([`Dealing`]).

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::fitness::FitnessError;
use crate::data::{Columns, Dataset};

/// Inputs with at most this many distinct values make a designed grid.
pub const GRID_LEVELS: usize = 30;

/// Consecutive rows closer than this share of random pairs are near copies.
pub const NEAR_COPY_RATIO: f64 = 0.15;

/// How cross-validation's folds are to be cut (`folds_by`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FoldsBy {
    Auto,
    Shuffle,
    Blocks,
    Column(String),
}

impl std::str::FromStr for FoldsBy {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s {
            "auto" => FoldsBy::Auto,
            "shuffle" => FoldsBy::Shuffle,
            "blocks" => FoldsBy::Blocks,
            "" => return Err("give auto, shuffle, blocks or a column name".into()),
            column => FoldsBy::Column(column.to_string()),
        })
    }
}

impl std::fmt::Display for FoldsBy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FoldsBy::Auto => f.write_str("auto"),
            FoldsBy::Shuffle => f.write_str("shuffle"),
            FoldsBy::Blocks => f.write_str("blocks"),
            FoldsBy::Column(c) => f.write_str(c),
        }
    }
}

/// The scheme chosen.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "scheme", rename_all = "snake_case")]
pub enum FoldScheme {
    /// Rows shuffled with the fold seed, dealt to folds.
    Shuffle,
    /// Contiguous blocks of rows in file order, one per fold.
    Blocks,
    /// Whole groups of the column held out together.
    Groups { column: String },
}

/// The scheme and why, as the output and the model file record it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FoldChoice {
    #[serde(flatten)]
    pub scheme: FoldScheme,
    pub reason: String,
}

impl std::fmt::Display for FoldChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.scheme {
            FoldScheme::Shuffle => write!(f, "shuffled folds")?,
            FoldScheme::Blocks => write!(f, "contiguous blocks")?,
            FoldScheme::Groups { column } => write!(f, "whole groups of `{column}`")?,
        }
        write!(f, " ({})", self.reason)
    }
}

/// The choice, the number of folds and the group label of every row (`None`: every row its own
/// group).
#[derive(Clone, Debug, PartialEq)]
pub struct FoldPlan {
    pub choice: FoldChoice,
    /// The folds asked for, or as many as the rows allow ([`within`]).
    pub folds: usize,
    pub labels: Option<Vec<f64>>,
}

/// The folds cut from `rows` rows when `asked` are asked for: as many as allow each fold 2
/// rows or more, at most `asked` (a count below 2, or fewer than 4 rows, is refused when the
/// folds are dealt).
pub fn within(asked: usize, rows: usize) -> usize {
    if asked < 2 {
        asked
    } else {
        asked.min(rows / 2).max(2)
    }
}

/// Errors of choosing the folds.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FoldsError {
    #[error("folds_by={column}: all {rows} rows are in one group; give a column that separates runs, or folds_by=blocks")]
    OneGroup { column: String, rows: usize },
}

/// Chooses the folds of `data` (module docs): `asked` of them, fewer when the rows allow fewer
/// ([`within`], said in the reason). `others` are the file's other numeric columns, one value
/// per row of `data` (for `auto`, and the named column's values for a column).
///
/// # Errors
/// [`FoldsError`] for a grouping column with one group.
pub fn plan(
    by: &FoldsBy,
    data: &Dataset,
    others: &[(String, Vec<f64>)],
    asked: usize,
) -> Result<FoldPlan, FoldsError> {
    let folds = within(asked, data.rows());
    let mut plan = scheme(by, data, others, folds)?;
    if folds < asked {
        plan.choice.reason += &format!(
            "; {folds} folds, not {asked}: {} rows allow no more of 2 rows each",
            data.rows()
        );
    }
    Ok(plan)
}

/// The scheme of [`plan`] for `folds` folds.
fn scheme(
    by: &FoldsBy,
    data: &Dataset,
    others: &[(String, Vec<f64>)],
    folds: usize,
) -> Result<FoldPlan, FoldsError> {
    let blocks = |reason: String| FoldPlan {
        choice: FoldChoice {
            scheme: FoldScheme::Blocks,
            reason,
        },
        folds,
        labels: Some(block_labels(data.rows(), folds)),
    };
    let shuffle = |reason: String| FoldPlan {
        choice: FoldChoice {
            scheme: FoldScheme::Shuffle,
            reason,
        },
        folds,
        labels: None,
    };
    let groups = |column: &str, labels: &[f64], reason: String| FoldPlan {
        choice: FoldChoice {
            scheme: FoldScheme::Groups {
                column: column.to_string(),
            },
            reason,
        },
        folds,
        labels: Some(labels.to_vec()),
    };
    match by {
        FoldsBy::Shuffle => Ok(shuffle("folds_by=shuffle".into())),
        FoldsBy::Blocks => Ok(blocks("folds_by=blocks".into())),
        FoldsBy::Column(column) => {
            let labels = others
                .iter()
                .find(|(name, _)| name == column)
                .map(|(_, v)| v.as_slice())
                .unwrap_or_default();
            let count = distinct(labels);
            if count < 2 {
                return Err(FoldsError::OneGroup {
                    column: column.clone(),
                    rows: labels.len(),
                });
            }
            // Fewer groups than folds: each group its own fold (leave one group out).
            let reason = if count < folds {
                format!("folds_by={column}: {count} groups, so {count} folds (one group held out at a time), not {folds}")
            } else {
                format!("folds_by={column}: {count} groups")
            };
            Ok(FoldPlan {
                folds: folds.min(count),
                ..groups(column, labels, reason)
            })
        }
        FoldsBy::Auto => {
            if let Some(levels) = grid_levels(&data.inputs) {
                return Ok(shuffle(format!(
                    "a designed grid: each input takes at most {levels} values, so rows are independent settings"
                )));
            }
            if let Some((column, labels)) = others.iter().find(|(_, v)| is_run_grouping(v, folds)) {
                let count = distinct(labels);
                return Ok(groups(
                    column,
                    labels,
                    format!("`{column}` holds {count} runs of consecutive rows; each run is held out whole"),
                ));
            }
            let ratio = neighbour_ratio(&data.inputs);
            if ratio < NEAR_COPY_RATIO {
                return Ok(blocks(format!(
                    "consecutive rows are near copies (their median distance is {:.0} % of random rows'): a time series, held out in contiguous blocks",
                    100.0 * ratio
                )));
            }
            Ok(shuffle(format!(
                "rows look independent (consecutive rows {:.0} % as far apart as random ones)",
                100.0 * ratio
            )))
        }
    }
}

/// Row `i` of `n` in block ⌊i·k/n⌋.
fn block_labels(n: usize, folds: usize) -> Vec<f64> {
    (0..n).map(|i| (i * folds / n.max(1)) as f64).collect()
}

fn distinct(values: &[f64]) -> usize {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v.dedup();
    v.len()
}

/// The largest number of distinct values of an input, when every input has at most
/// [`GRID_LEVELS`].
fn grid_levels(inputs: &Columns) -> Option<usize> {
    let levels = (0..inputs.width())
        .map(|j| distinct(&inputs.column(j).collect::<Vec<_>>()))
        .max()?;
    (levels <= GRID_LEVELS).then_some(levels)
}

/// Every value in one contiguous run, at least 2 × `folds` runs, runs 2 rows long on average.
fn is_run_grouping(values: &[f64], folds: usize) -> bool {
    let runs = 1 + values.windows(2).filter(|w| w[0] != w[1]).count();
    !values.is_empty() && runs == distinct(values) && runs >= 2 * folds && values.len() >= 2 * runs
}

/// Median distance between consecutive rows over the median distance between random pairs
/// (1000 pairs, a fixed seed), inputs scaled to [0, 1].
fn neighbour_ratio(inputs: &Columns) -> f64 {
    let n = inputs.rows();
    if n < 3 {
        return 1.0;
    }
    let scaler = crate::model::msvr::MinMaxScaler::fit(inputs);
    let scaled = scaler.transform(inputs);
    let distance = |a: usize, b: usize| -> f64 {
        scaled
            .row(a)
            .iter()
            .zip(scaled.row(b))
            .map(|(p, q)| {
                let d = p - q;
                if d.is_finite() {
                    d * d
                } else {
                    0.0
                }
            })
            .sum::<f64>()
            .sqrt()
    };
    let mut consecutive: Vec<f64> = (1..n).map(|i| distance(i - 1, i)).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(0x666f_6c64);
    let mut random: Vec<f64> = (0..1000)
        .map(|_| distance(rng.random_range(0..n), rng.random_range(0..n)))
        .collect();
    let (Some(c), Some(r)) = (
        crate::stats::median(&mut consecutive),
        crate::stats::median(&mut random),
    ) else {
        return 1.0;
    };
    if r > 0.0 {
        c / r
    } else {
        1.0
    }
}

/// How groups are dealt to folds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dealing {
    /// Shuffled with the seed, each to the fold with the fewest rows so far: every fold holds
    /// runs from all over the data (what a search scores parameters on).
    Shuffled,
    /// In label order, consecutive groups to one fold until it holds its share of the rows:
    /// each fold a block of consecutive runs, as new runs meet a model (what intervals are
    /// calibrated on: runs recorded one after another drift).
    Consecutive,
}

/// The fold of every row. Groups (every row its own group when `groups` is `None`) are dealt
/// to the folds as `dealing` says, so folds are balanced and a group is never split between
/// training and held-out rows.
pub fn assign_folds(
    n: usize,
    folds: usize,
    seed: u64,
    groups: Option<&[f64]>,
    dealing: Dealing,
) -> Result<Vec<usize>, FitnessError> {
    let mut members: Vec<Vec<usize>> = match groups {
        None => (0..n).map(|i| vec![i]).collect(),
        Some(labels) => {
            let mut sorted: Vec<usize> = (0..n).collect();
            sorted.sort_by(|&a, &b| labels[a].total_cmp(&labels[b]));
            sorted
                .chunk_by(|&a, &b| labels[a] == labels[b])
                .map(<[usize]>::to_vec)
                .collect()
        }
    };
    let bad = FitnessError::BadFolds {
        folds,
        rows: n,
        groups: members.len(),
    };
    if folds < 2 || members.len() < folds {
        return Err(bad);
    }
    let mut sizes = vec![0usize; folds];
    let mut fold_of = vec![0; n];
    let mut before = 0;
    if dealing == Dealing::Shuffled {
        members.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    }
    for group in &members {
        let f = match dealing {
            Dealing::Shuffled => (0..folds).min_by_key(|&f| sizes[f]).expect("folds ≥ 2"),
            // The fold whose share of the rows holds the group's middle row.
            Dealing::Consecutive => ((before + group.len() / 2) * folds / n).min(folds - 1),
        };
        before += group.len();
        sizes[f] += group.len();
        for &i in group {
            fold_of[i] = f;
        }
    }
    if sizes.iter().any(|&s| s < 2 || n - s < 2) {
        return Err(bad);
    }
    Ok(fold_of)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folds_shrink_to_what_the_rows_allow_never_below_two() {
        assert_eq!(within(5, 1000), 5);
        assert_eq!(within(5, 10), 5);
        assert_eq!(within(5, 9), 4);
        assert_eq!(within(5, 7), 3);
        assert_eq!(within(5, 3), 2);
        // A count below 2 is the user's, refused where the folds are dealt.
        assert_eq!(within(1, 100), 1);
        let plan = plan(
            &FoldsBy::Shuffle,
            &dataset((0..7).map(f64::from).collect(), 1),
            &[],
            5,
        );
        let plan = plan.unwrap();
        assert_eq!(plan.folds, 3);
        assert!(plan
            .choice
            .reason
            .ends_with("3 folds, not 5: 7 rows allow no more of 2 rows each"));
    }

    fn dataset(x: Vec<f64>, d: usize) -> Dataset {
        let n = x.len() / d;
        Dataset {
            source: "t.csv".into(),
            inputs: Columns::new((0..d).map(|j| format!("x{j}")).collect(), x),
            outputs: Columns::new(vec!["y".into()], vec![0.0; n]),
            weights: None,
        }
    }

    #[test]
    fn a_grid_keeps_shuffled_folds_even_in_nested_order() {
        let mut x = Vec::new();
        for a in 0..6 {
            for b in 0..6 {
                x.extend([a as f64 * 50.0, b as f64 * 50.0]);
            }
        }
        let p = plan(&FoldsBy::Auto, &dataset(x, 2), &[], 5).unwrap();
        assert_eq!(p.choice.scheme, FoldScheme::Shuffle);
        assert!(
            p.choice.reason.contains("designed grid"),
            "{}",
            p.choice.reason
        );
    }

    #[test]
    fn a_slow_ramp_is_held_out_in_blocks_and_a_ramp_id_as_groups() {
        // Two inputs ramping slowly between random targets: near copies.
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (mut x, mut ramp) = (Vec::new(), Vec::new());
        let mut at = [0.0f64, 0.0];
        for r in 0..20 {
            let to = [rng.random_range(0.0..100.0), rng.random_range(0.0..100.0)];
            for k in 1..=25 {
                let t = k as f64 / 25.0;
                x.extend([at[0] + t * (to[0] - at[0]), at[1] + t * (to[1] - at[1])]);
                ramp.push(r as f64);
            }
            at = to;
        }
        let data = dataset(x, 2);
        let p = plan(&FoldsBy::Auto, &data, &[], 5).unwrap();
        assert_eq!(p.choice.scheme, FoldScheme::Blocks, "{}", p.choice.reason);
        let labels = p.labels.unwrap();
        assert_eq!(distinct(&labels), 5);
        assert!(
            labels.windows(2).all(|w| w[0] <= w[1]),
            "blocks follow file order"
        );
        let others = [("ramp".to_string(), ramp)];
        let p = plan(&FoldsBy::Auto, &data, &others, 5).unwrap();
        assert_eq!(
            p.choice.scheme,
            FoldScheme::Groups {
                column: "ramp".into()
            }
        );
        // Random rows: shuffled.
        let x: Vec<f64> = (0..400).map(|_| rng.random_range(0.0..100.0)).collect();
        let p = plan(&FoldsBy::Auto, &dataset(x, 2), &[], 5).unwrap();
        assert_eq!(p.choice.scheme, FoldScheme::Shuffle, "{}", p.choice.reason);
    }

    #[test]
    fn a_grouping_column_with_one_group_is_refused_and_few_groups_are_each_a_fold() {
        let data = dataset((0..40).map(f64::from).collect(), 1);
        let one = [("run".to_string(), vec![1.0; 40])];
        let err = plan(&FoldsBy::Column("run".into()), &data, &one, 5).unwrap_err();
        assert!(err
            .to_string()
            .contains("folds_by=run: all 40 rows are in one group"));
        let three = [(
            "run".to_string(),
            (0..40).map(|i| f64::from(i % 3)).collect(),
        )];
        let p = plan(&FoldsBy::Column("run".into()), &data, &three, 5).unwrap();
        assert_eq!(p.folds, 3, "each group its own fold");
        assert!(p.choice.reason.contains("3 groups, so 3 folds"), "{p:?}");
    }

    #[test]
    fn consecutive_dealing_gives_each_fold_a_block_of_runs_in_label_order() {
        // Twelve runs of 3-8 rows, labelled out of order in the rows.
        let sizes = [3, 8, 5, 4, 6, 7, 3, 5, 8, 4, 6, 5];
        let mut labels = Vec::new();
        for (run, &size) in sizes.iter().enumerate() {
            labels.extend(std::iter::repeat_n((11 - run) as f64, size));
        }
        let n = labels.len();
        let fold_of = assign_folds(n, 4, 1, Some(&labels), Dealing::Consecutive).unwrap();
        // Along the labels (11 - run) the folds never decrease: each fold is a block of runs.
        let mut by_label: Vec<(f64, usize)> = labels.iter().copied().zip(fold_of.clone()).collect();
        by_label.sort_by(|a, b| a.0.total_cmp(&b.0));
        assert!(
            by_label.windows(2).all(|w| w[0].1 <= w[1].1),
            "{by_label:?}"
        );
        // Each fold holds about a quarter of the rows, and a run is never split.
        for f in 0..4 {
            let rows = fold_of.iter().filter(|&&g| g == f).count();
            assert!(rows.abs_diff(n / 4) <= 8, "fold {f}: {rows} of {n}");
        }
        for w in labels.windows(2).zip(fold_of.windows(2)) {
            if w.0[0] == w.0[1] {
                assert_eq!(w.1[0], w.1[1]);
            }
        }
        // Shuffled dealing mixes them (the seed's order).
        let shuffled = assign_folds(n, 4, 1, Some(&labels), Dealing::Shuffled).unwrap();
        assert_ne!(shuffled, fold_of);
    }
}
