//! Prediction intervals by conformal prediction: "the tip lies within r of the prediction, 90 %
//! of the time".
//!
//! The score of a row is its Euclidean error ‖y − ŷ‖₂ in output units, so an interval is a
//! sphere around the prediction with joint coverage of every output (the natural shape beside
//! MSVR's spherical ε-tube). The scores are those of held-out rows: each row predicted by the
//! model fitted without its fold, on the folds the search used (whole groups, contiguous blocks
//! or shuffled rows), so a time series' near-copies cannot make the radius too small. The radius
//! at level 1 − α is the ⌈(n + 1)(1 − α)⌉-th smallest of the n scores (split conformal
//! prediction).
//!
//! What the level means: over new rows exchangeable with the held-out ones, at least that share
//! falls within the radius (marginal coverage, averaged over rows), not that every input gets
//! it. Held-out scores of cross-validation (cross-conformal prediction) are about as large as
//! a split's; their worst-case guarantee is 1 − 2α, and in practice they cover 1 − α, since
//! each fold's model saw fewer rows than the final one. Coverage per group (a trial, a ramp)
//! shows where it holds less.
//!
//! The radius widens where an input is farther from the training rows than the held-out rows
//! usually were ([`widening`]): the scores are then the errors divided by each row's widening
//! factor, and the radius at an input is the scores' radius times its factor. Files written
//! before the widening hold a radius that is the same for every input.

use serde::{Deserialize, Serialize};

use crate::data::Columns;
use crate::select::folds::FoldChoice;

pub mod widening;
pub use widening::{Widener, Widening};

/// The levels every model file carries radii for.
pub const LEVELS: [f64; 2] = [0.9, 0.95];

/// Errors of asking for an interval.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum IntervalError {
    #[error("interval level {level} must lie strictly between 0 and 1 (e.g. 0.9 for 90 %)")]
    Level { level: f64 },
    #[error("a {percent} % interval needs at least {needed} held-out rows, and the model has {rows}; ask a lower level or fit on more rows")]
    TooFewRows {
        /// The level in per cent, as [`percent`] writes it.
        percent: String,
        needed: usize,
        rows: usize,
    },
    #[error("the model has no prediction intervals: no held-out predictions were made when it was fitted (its parameters given without intervals=true, or fitness=train); fit it again with intervals=true")]
    Missing,
    #[error("the interval's widening: {0}; fit the model again")]
    Widening(String),
}

/// One level's radius.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Radius {
    pub level: f64,
    /// In output units.
    pub radius: f64,
}

/// The radius at one level around each of a file's rows, as a message sums it up.
#[derive(Clone, Debug, PartialEq)]
pub struct RowRadii {
    pub level: f64,
    /// The radius where the inputs are as near the training rows as the held-out rows were.
    pub radius: f64,
    /// Each row's radius.
    pub radii: Vec<f64>,
}

impl std::fmt::Display for RowRadii {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "{} % interval radius {:.4}",
            percent(self.level),
            self.radius
        )?;
        let wider = self.radii.iter().filter(|&&r| r > self.radius).count();
        if wider == 0 {
            return write!(f, ", the same for every row");
        }
        let widest = self.radii.iter().copied().fold(self.radius, f64::max);
        write!(
            f,
            ", wider on {wider} of {} rows farther from the training rows than the held-out rows were (up to {widest:.4})",
            self.radii.len()
        )
    }
}

/// Coverage of one set of rows at one radius.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Coverage {
    /// The group's label (its value in the group column), `None` for all rows pooled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<f64>,
    pub rows: usize,
    /// The share of rows whose error is within the radius.
    pub covered: f64,
}

/// Coverage of one test file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TestCoverage {
    /// Each radius with the share of the file's rows within it.
    pub pooled: Vec<(Radius, f64)>,
    /// Coverage of each group at the first radius.
    pub groups: Vec<Coverage>,
    /// Whole runs (groups) inside each radius of the per-run band.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub runs: Vec<RunsInside>,
}

/// What the held-out rows said: the radii and where they hold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldOut {
    /// How the held-out rows were cut.
    pub folds: FoldChoice,
    /// Held-out rows (the scores' count).
    pub rows: usize,
    /// The radii at [`LEVELS`] the rows suffice for.
    pub radii: Vec<Radius>,
    /// Coverage of each held-out group (or block) at the first level's radius: where the
    /// radius holds less than the level.
    pub groups: Vec<Coverage>,
    /// The per-run band, when the held-out rows were cut into runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runs: Option<RunBand>,
}

/// A band for whole runs: each held-out run's worst error, and the radii at [`LEVELS`] such
/// that that share of runs like them stays inside the band from its first row to its last
/// (the conformal rank of the runs' worst errors: 9 runs for 90 %, 19 for 95 %). A run spans
/// the inputs, so its band does not widen: it is the same for every row. (Calibrated on the
/// errors over their rows' widening factors, it held 4 of 6 later runs of a drifting plant
/// against 5 of 6, and 97 % of the soft trunk's held-out ramps against 100 %.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunBand {
    /// Each held-out run's largest ‖y − ŷ‖₂, ascending.
    pub worst: Vec<f64>,
    /// The radii at [`LEVELS`] the runs suffice for.
    pub radii: Vec<Radius>,
}

impl RunBand {
    /// The band of the held-out `scores` cut into runs by `labels`.
    pub fn calibrate(scores: &[f64], labels: &[f64]) -> RunBand {
        let mut worst = worst_by_group(scores, labels);
        worst.sort_by(f64::total_cmp);
        RunBand {
            radii: radii(&worst),
            worst,
        }
    }
}

/// Whole test runs inside a per-run band.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunsInside {
    pub radius: Radius,
    pub runs: usize,
    /// Runs every row of which lies within the radius.
    pub inside: usize,
}

/// A model's intervals, as the model file keeps them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intervals {
    #[serde(flatten)]
    pub held_out: HeldOut,
    /// Every held-out row's ‖y − ŷ‖₂ (divided by its widening factor, when the radius
    /// widens), ascending: any level's radius.
    pub scores: Vec<f64>,
    /// What widens the radius off the training rows; absent in files written before it: the
    /// same radius everywhere.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub widening: Option<Widening>,
}

impl Intervals {
    /// Calibrates on held-out predictions: `truth` and `held_out` (rows × outputs) of the same
    /// rows, `labels` each row's group (or block), when there are groups, and the widening
    /// with each row's factor, when the radius widens. `radii` holds the levels of [`LEVELS`]
    /// the rows suffice for (none from fewer than 9 rows).
    ///
    /// # Panics
    /// If the shapes differ.
    pub fn calibrate(
        truth: &Columns,
        held_out: &Columns,
        labels: Option<&[f64]>,
        folds: FoldChoice,
        widening: Option<(Widening, Vec<f64>)>,
    ) -> Intervals {
        let (widening, factors) = widening.unzip();
        let errors = scores(truth, held_out);
        let norms = divided(errors.clone(), factors.as_deref());
        let mut sorted = norms.clone();
        sorted.sort_by(f64::total_cmp);
        let radii = radii(&sorted);
        let groups = match (labels, radii.first()) {
            (Some(labels), Some(first)) => by_group(&norms, labels, first.radius),
            _ => Vec::new(),
        };
        Intervals {
            held_out: HeldOut {
                folds,
                rows: sorted.len(),
                radii,
                groups,
                runs: labels.map(|labels| RunBand::calibrate(&errors, labels)),
            },
            scores: sorted,
            widening,
        }
    }

    /// Each row's widening factor at `inputs` (the model's inputs); `None` when the radius
    /// is the same everywhere.
    ///
    /// # Errors
    /// [`IntervalError::Widening`] when the file's centres give no spread.
    pub fn factors(&self, inputs: &Columns) -> Result<Option<Vec<f64>>, IntervalError> {
        Ok(self.widener()?.map(|w| w.factors(inputs)))
    }

    /// What computes the widening factor at an input; `None` when the radius is the same
    /// everywhere.
    ///
    /// # Errors
    /// [`IntervalError::Widening`] when the file's centres give no spread.
    pub fn widener(&self) -> Result<Option<Widener>, IntervalError> {
        self.widening
            .as_ref()
            .map(Widening::widener)
            .transpose()
            .map_err(IntervalError::Widening)
    }

    /// The radius at `level` around the prediction at each row of `inputs` (the model's
    /// inputs).
    ///
    /// # Errors
    /// As [`Intervals::radius`] and [`Intervals::factors`].
    pub fn radii_at(&self, level: f64, inputs: &Columns) -> Result<RowRadii, IntervalError> {
        let radius = self.radius(level)?;
        let radii = match self.factors(inputs)? {
            Some(factors) => factors.iter().map(|d| radius * d).collect(),
            None => vec![radius; inputs.rows()],
        };
        Ok(RowRadii {
            level,
            radius,
            radii,
        })
    }

    /// Coverage of test rows (`inputs` the model's inputs, for the widening): pooled at each
    /// radius of `radii`, and per group (when `labels` gives each row's group) at the first.
    ///
    /// # Errors
    /// As [`Intervals::factors`].
    pub fn test(
        &self,
        truth: &Columns,
        predicted: &Columns,
        inputs: &Columns,
        labels: Option<&[f64]>,
    ) -> Result<TestCoverage, IntervalError> {
        let errors = scores(truth, predicted);
        let norms = divided(errors.clone(), self.factors(inputs)?.as_deref());
        let radii = &self.held_out.radii;
        Ok(TestCoverage {
            pooled: radii
                .iter()
                .map(|r| (*r, coverage(&norms, r.radius).covered))
                .collect(),
            groups: match (labels, radii.first()) {
                (Some(labels), Some(first)) => by_group(&norms, labels, first.radius),
                _ => Vec::new(),
            },
            runs: match (labels, &self.held_out.runs) {
                (Some(labels), Some(band)) => {
                    let worst = worst_by_group(&errors, labels);
                    band.radii
                        .iter()
                        .map(|&radius| RunsInside {
                            radius,
                            runs: worst.len(),
                            inside: worst.iter().filter(|&&w| w <= radius.radius).count(),
                        })
                        .collect()
                }
                _ => Vec::new(),
            },
        })
    }

    /// The radius at `level` (where the radius widens: at inputs as near the training rows as
    /// the held-out rows usually were).
    ///
    /// # Errors
    /// [`IntervalError`] for a level outside (0, 1) or too few held-out rows for it.
    pub fn radius(&self, level: f64) -> Result<f64, IntervalError> {
        radius(&self.scores, level)
    }

    /// Checks what a model file holds: scores finite, non-negative and ascending, as many as
    /// the held-out rows; each radius the scores' radius at its level; coverages shares; the
    /// widening's numbers and centres of the model's `inputs` inputs, with its σ and `c`.
    ///
    /// # Errors
    /// What is wrong, naming the field.
    pub fn validate(&self, inputs: usize, sigma: f64, c: f64) -> Result<(), String> {
        if let Some(w) = &self.widening {
            w.validate(inputs, sigma, c)?;
        }
        let distance = |s: f64| (0.0..=crate::model::msvr::LARGEST_NUMBER).contains(&s);
        if let Some(s) = self.scores.iter().find(|s| !distance(**s)) {
            return Err(format!(
                "intervals.scores holds {s:e}: scores are distances (between 0 and 1e100)"
            ));
        }
        if self.scores.windows(2).any(|w| w[0] > w[1]) {
            return Err("intervals.scores are not in ascending order".into());
        }
        if self.held_out.rows != self.scores.len() {
            return Err(format!(
                "intervals.rows is {} but there are {} scores",
                self.held_out.rows,
                self.scores.len()
            ));
        }
        for r in &self.held_out.radii {
            if radius(&self.scores, r.level) != Ok(r.radius) {
                return Err(format!(
                    "intervals.radii: the radius at level {} is not the scores' ({})",
                    r.level, r.radius
                ));
            }
        }
        if let Some(band) = &self.held_out.runs {
            if band.worst.iter().any(|w| !(w.is_finite() && *w >= 0.0))
                || band.worst.windows(2).any(|w| w[0] > w[1])
            {
                return Err("intervals.runs.worst are not ascending distances (≥ 0)".into());
            }
            if band.radii != radii(&band.worst) {
                return Err("intervals.runs.radii are not the runs' worst errors' radii".into());
            }
        }
        if let Some(c) = self
            .held_out
            .groups
            .iter()
            .find(|c| !(0.0..=1.0).contains(&c.covered))
        {
            return Err(format!(
                "intervals.groups: a share covered of {} is not between 0 and 1",
                c.covered
            ));
        }
        Ok(())
    }
}

/// `scores` each divided by its row's widening factor, when there are factors.
fn divided(mut scores: Vec<f64>, factors: Option<&[f64]>) -> Vec<f64> {
    if let Some(factors) = factors {
        for (s, d) in scores.iter_mut().zip(factors) {
            *s /= d;
        }
    }
    scores
}

/// The radii at [`LEVELS`] of ascending scores, as many levels as they suffice for.
fn radii(sorted: &[f64]) -> Vec<Radius> {
    LEVELS
        .iter()
        .filter_map(|&level| {
            let radius = radius(sorted, level).ok()?;
            Some(Radius { level, radius })
        })
        .collect()
}

/// Each group's largest score, in ascending label order.
fn worst_by_group(scores: &[f64], labels: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| labels[a].total_cmp(&labels[b]));
    order
        .chunk_by(|&a, &b| labels[a] == labels[b])
        .map(|rows| rows.iter().map(|&i| scores[i]).fold(0.0, f64::max))
        .collect()
}

/// Each row's ‖y − ŷ‖₂.
///
/// # Panics
/// If the shapes differ.
pub fn scores(truth: &Columns, predicted: &Columns) -> Vec<f64> {
    assert_eq!(truth.width(), predicted.width(), "output widths differ");
    assert_eq!(truth.rows(), predicted.rows(), "row counts differ");
    truth
        .iter_rows()
        .zip(predicted.iter_rows())
        .map(|(t, p)| {
            t.iter()
                .zip(p)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect()
}

/// The conformal radius at `level` of ascending scores.
///
/// # Errors
/// [`IntervalError`] for a level outside (0, 1), or fewer scores than the level needs (the
/// ⌈(n + 1)·level⌉-th smallest must exist: 9 rows for 90 %, 19 for 95 %).
pub fn radius(sorted: &[f64], level: f64) -> Result<f64, IntervalError> {
    if !(level > 0.0 && level < 1.0) {
        return Err(IntervalError::Level { level });
    }
    let n = sorted.len();
    let rank = ((n + 1) as f64 * level - 1e-9).ceil() as usize;
    if rank > n || n == 0 {
        return Err(IntervalError::TooFewRows {
            percent: percent(level),
            needed: (level / (1.0 - level) - 1e-9).ceil() as usize,
            rows: n,
        });
    }
    Ok(sorted[rank.max(1) - 1])
}

/// A level in per cent, with the decimals that show it (0.9 → "90", 0.9999 → "99.99",
/// 0.0007 → "0.07"), and in scientific notation below a millionth of a per cent.
pub fn percent(level: f64) -> String {
    let p = level * 100.0;
    (0..=6)
        .map(|decimals| format!("{p:.decimals$}"))
        .find(|s| {
            s.parse::<f64>()
                .is_ok_and(|v| (v - p).abs() <= 1e-9 * p.abs())
        })
        .unwrap_or_else(|| format!("{p:.3e}"))
}

/// Coverage at `radius` of scores, pooled (`group: None`).
pub fn coverage(scores: &[f64], radius: f64) -> Coverage {
    let covered = scores.iter().filter(|&&s| s <= radius).count();
    Coverage {
        group: None,
        rows: scores.len(),
        covered: covered as f64 / scores.len().max(1) as f64,
    }
}

/// Coverage at `radius` of each group of `labels` (one per score), in ascending label order.
pub fn by_group(scores: &[f64], labels: &[f64], radius: f64) -> Vec<Coverage> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| labels[a].total_cmp(&labels[b]));
    order
        .chunk_by(|&a, &b| labels[a] == labels[b])
        .map(|rows| {
            let group: Vec<f64> = rows.iter().map(|&i| scores[i]).collect();
            Coverage {
                group: Some(labels[rows[0]]),
                ..coverage(&group, radius)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_radius_is_the_conformal_rank() {
        let sorted: Vec<f64> = (1..=19).map(f64::from).collect();
        // ⌈20 · 0.9⌉ = 18th smallest; ⌈20 · 0.95⌉ = 19th.
        assert_eq!(radius(&sorted, 0.9), Ok(18.0));
        assert_eq!(radius(&sorted, 0.95), Ok(19.0));
        assert_eq!(radius(&sorted, 0.5), Ok(10.0));
        assert_eq!(radius(&sorted[..9], 0.9), Ok(9.0));
    }

    #[test]
    fn a_level_is_said_in_per_cent_with_the_decimals_that_show_it() {
        let said: Vec<String> = [0.9, 0.95, 0.9999, 0.999999, 0.0007, 1e-9]
            .map(percent)
            .to_vec();
        assert_eq!(said, ["90", "95", "99.99", "99.9999", "0.07", "1.000e-7"]);
    }

    #[test]
    fn too_few_rows_or_a_bad_level_is_an_error_never_a_radius_of_zero() {
        let ten: Vec<f64> = (1..=10).map(f64::from).collect();
        assert_eq!(
            radius(&ten, 0.95),
            Err(IntervalError::TooFewRows {
                percent: "95".into(),
                needed: 19,
                rows: 10
            })
        );
        assert!(radius(&ten[..8], 0.9).is_err());
        for level in [0.0, 1.0, -0.1, 1.5, f64::NAN] {
            assert!(matches!(
                radius(&ten, level),
                Err(IntervalError::Level { .. })
            ));
        }
        assert!(radius(&[], 0.5).is_err());
    }

    /// Exchangeable scores: the radius covers a fresh sample at about the level.
    #[test]
    fn coverage_of_fresh_exchangeable_rows_is_near_the_level() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut draw = |n: usize| -> Vec<f64> {
            (0..n)
                .map(|_| (0..3).map(|_| rng.random::<f64>().powi(2)).sum::<f64>())
                .collect()
        };
        let mut calibration = draw(500);
        calibration.sort_by(f64::total_cmp);
        let fresh = draw(20_000);
        for level in LEVELS {
            let r = radius(&calibration, level).unwrap();
            let c = coverage(&fresh, r).covered;
            assert!((c - level).abs() < 0.025, "level {level}: coverage {c}");
        }
    }

    #[test]
    fn the_run_band_is_the_conformal_rank_of_each_runs_worst_error() {
        // 19 runs of 3 rows; run k's worst error is k + 1.
        let labels: Vec<f64> = (0..57).map(|i| f64::from(i / 3)).collect();
        let scores: Vec<f64> = (0..57)
            .map(|i| f64::from(i / 3 + 1) * [0.2, 1.0, 0.5][i as usize % 3])
            .collect();
        let band = RunBand::calibrate(&scores, &labels);
        assert_eq!(band.worst, (1..=19).map(f64::from).collect::<Vec<_>>());
        let radii: Vec<f64> = band.radii.iter().map(|r| r.radius).collect();
        assert_eq!(radii, [18.0, 19.0]);
        // Eight runs: too few for a 90 % band.
        assert!(RunBand::calibrate(&scores[..24], &labels[..24])
            .radii
            .is_empty());
    }

    #[test]
    fn groups_are_listed_in_label_order_with_their_coverage() {
        let scores = [1.0, 5.0, 2.0, 6.0, 3.0];
        let labels = [2.0, 1.0, 2.0, 1.0, 2.0];
        let g = by_group(&scores, &labels, 4.0);
        assert_eq!(g.len(), 2);
        assert_eq!((g[0].group, g[0].rows, g[0].covered), (Some(1.0), 2, 0.0));
        assert_eq!((g[1].group, g[1].rows, g[1].covered), (Some(2.0), 3, 1.0));
    }
}
