//! `--basis auto`: exact MSVR up to [`AUTO_EXACT_ROWS`] rows; above, a reduced basis that
//! starts at [`AUTO_FIRST_CENTRES`] and doubles while the cross-validated error falls by more
//! than [`AUTO_GAIN`].

use std::sync::atomic::AtomicBool;

use serde::{Deserialize, Serialize};

use super::fitness::{Fitness, FitnessKind, HeldOutRows};
use super::folds::FoldPlan;
use super::tune::TuneError;
use crate::data::Dataset;
use crate::model::msvr::{Basis, MsvrParams};

/// Up to this many rows, `--basis auto` fits exact MSVR (a kernel at every row): a search of
/// 120 candidates × 5 folds stays within minutes on 2 cores, and the n × n kernel within 0.2 GB.
pub const AUTO_EXACT_ROWS: usize = 2000;
/// The reduced basis `auto` searches with and starts growing from.
pub const AUTO_FIRST_CENTRES: usize = 200;
/// The largest basis `auto` grows to.
pub const AUTO_MAX_CENTRES: usize = 3200;
/// `auto` doubles the basis while the cross-validated error falls by more than this share.
pub const AUTO_GAIN: f64 = 0.02;

/// What `--basis` asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BasisChoice {
    /// Exact where affordable, else a reduced basis grown while it helps.
    Auto,
    Exact,
    /// A reduced basis of this many centres.
    Centres(usize),
}

impl std::str::FromStr for BasisChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(BasisChoice::Auto),
            "exact" => Ok(BasisChoice::Exact),
            m => match m.parse::<usize>() {
                Ok(m) if m >= 1 => Ok(BasisChoice::Centres(m)),
                _ => Err("give auto, exact or a number of centres ≥ 1".into()),
            },
        }
    }
}

/// The basis used and why, as the log, the report and the model file say it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BasisDecision {
    pub basis: Basis,
    pub reason: String,
    /// `auto`'s growth: each basis size tried with its cross-validated fitness, in order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tried: Vec<BasisTrial>,
}

/// One basis size `auto` tried.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BasisTrial {
    pub centres: usize,
    /// Centres kept at the chosen σ (fewer: the rest were redundant).
    pub kept: usize,
    pub fitness: f64,
}

/// Errors of choosing a basis.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BasisError {
    #[error("a basis of {centres} centres for {rows} rows: at most one centre per row; give basis={rows} or fewer, or basis=auto")]
    MoreCentresThanRows { centres: usize, rows: usize },
}

/// The basis to search and fit with before any growth: `exact`, the given centres, or for
/// `auto` exact up to [`AUTO_EXACT_ROWS`] rows (and when its kernel fits in memory), else
/// [`AUTO_FIRST_CENTRES`] centres. `seed` picks the centres.
///
/// # Errors
/// [`BasisError::MoreCentresThanRows`].
pub fn initial_basis(
    choice: BasisChoice,
    rows: usize,
    seed: u64,
) -> Result<BasisDecision, BasisError> {
    let reduced = |centres| Basis::Reduced { centres, seed };
    Ok(match choice {
        BasisChoice::Exact => BasisDecision {
            basis: Basis::Exact,
            reason: "asked for (basis=exact)".into(),
            tried: Vec::new(),
        },
        BasisChoice::Centres(centres) if centres > rows => {
            return Err(BasisError::MoreCentresThanRows { centres, rows })
        }
        BasisChoice::Centres(centres) => BasisDecision {
            basis: reduced(centres),
            reason: format!("asked for (basis={centres})"),
            tried: Vec::new(),
        },
        BasisChoice::Auto => {
            let fits = crate::model::msvr::check_memory(rows, Basis::Exact).is_ok();
            if rows <= AUTO_EXACT_ROWS && fits {
                BasisDecision {
                    basis: Basis::Exact,
                    reason: format!(
                        "{rows} rows: exact MSVR, a kernel at every row, is affordable up to {AUTO_EXACT_ROWS}"
                    ),
                    tried: Vec::new(),
                }
            } else {
                BasisDecision {
                    basis: reduced(AUTO_FIRST_CENTRES.min(rows / 2).max(1)),
                    reason: format!(
                        "{rows} rows: more than exact MSVR's {AUTO_EXACT_ROWS}, so a reduced basis"
                    ),
                    tried: Vec::new(),
                }
            }
        }
    })
}

/// Whether a larger basis lowered the fitness by more than [`AUTO_GAIN`] and by more than `se`,
/// the standard error of the paired fold differences (a non-finite fitness never does).
fn gains(smaller: BasisTrial, larger: BasisTrial, se: f64) -> bool {
    larger.fitness < smaller.fitness * (1.0 - AUTO_GAIN) && smaller.fitness - larger.fitness > se
}

/// `auto`'s growth of a reduced basis at the chosen (C, ε, σ): doubles the centres while the
/// cross-validated fitness falls by more than [`AUTO_GAIN`] and by more than one standard error
/// of its paired fold differences (as `--history auto` and `--model auto` decide), up to
/// [`AUTO_MAX_CENTRES`], half the rows, what memory allows, or until the pivoted Cholesky keeps
/// fewer centres than asked (more would be redundant at this σ). Returns the decision with
/// every size tried.
///
/// # Errors
/// [`TuneError`] when the folds cannot be cut.
pub fn grow_basis(
    start: BasisDecision,
    data: &Dataset,
    fitness: FitnessKind,
    folds: &FoldPlan,
    solver: &MsvrParams,
    interrupt: &AtomicBool,
) -> Result<(BasisDecision, Option<HeldOutRows>), TuneError> {
    let Basis::Reduced { centres, seed } = start.basis else {
        return Ok((start, None));
    };
    let limit = AUTO_MAX_CENTRES.min(data.rows() / 2).max(centres);
    let labels = folds.labels.as_deref();
    // A size's score and held-out predictions (for the intervals of the one chosen, and the
    // paired fold differences between sizes).
    let score = |m: usize| -> Result<(BasisTrial, Option<HeldOutRows>), TuneError> {
        let params = solver.basis(Basis::Reduced { centres: m, seed });
        let scorer = Fitness::new(data, fitness, seed, labels, &params)?;
        let fitness = scorer.evaluate(&[solver.hyper()], f64::INFINITY)[0];
        let trial = BasisTrial {
            centres: m,
            kept: scorer.kept_centres(solver.sigma),
            fitness,
        };
        Ok((trial, scorer.held_out_of(&solver.hyper())))
    };
    // The standard error of the paired fold differences of two sizes' held-out predictions
    // (0 without folds).
    let se = |a: &Option<HeldOutRows>, b: &Option<HeldOutRows>| match (a, b) {
        (Some(a), Some(b)) => {
            let ((a, values), (b, _)) = (a.fold_maes(data), b.fold_maes(data));
            crate::stats::paired_difference(&a, &b, &values).1
        }
        _ => 0.0,
    };
    let (first, held_out) = score(centres)?;
    let (mut tried, mut predicted) = (vec![first], vec![held_out]);
    // Why growth stopped, and the size chosen: the last one, or the one before when the last
    // did not beat it.
    let (why, chosen) = loop {
        let last = *tried.last().expect("one trial");
        let next = (last.centres * 2).min(limit);
        let at_last = tried.len() - 1;
        if last.kept < last.centres {
            break (
                format!(
                    "{} of {} centres kept at σ {:.4}: more would be redundant",
                    last.kept, last.centres, solver.sigma
                ),
                at_last,
            );
        }
        if next == last.centres {
            break (
                format!("the largest basis allowed ({limit} centres)"),
                at_last,
            );
        }
        if crate::model::msvr::check_memory(
            data.rows(),
            Basis::Reduced {
                centres: next,
                seed,
            },
        )
        .is_err()
        {
            break (format!("{next} centres would not fit in memory"), at_last);
        }
        if interrupt.load(std::sync::atomic::Ordering::Relaxed) {
            break ("interrupted".into(), at_last);
        }
        let (trial, held_out) = score(next)?;
        let se = se(&predicted[at_last], &held_out);
        tried.push(trial);
        predicted.push(held_out);
        if !gains(last, trial, se) {
            break (
                format!(
                    "{} centres did not improve the cross-validated error by more than {:.0} % and one standard error ({:.5} → {:.5}; standard error {se:.5})",
                    trial.centres,
                    100.0 * AUTO_GAIN,
                    last.fitness,
                    trial.fitness
                ),
                at_last,
            );
        }
    };
    let decision = BasisDecision {
        basis: Basis::Reduced {
            centres: tried[chosen].centres,
            seed,
        },
        reason: format!("{}; grown: {why}", start.reason),
        tried,
    };
    Ok((decision, predicted.swap_remove(chosen)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Columns;
    use crate::select::folds::{FoldChoice, FoldScheme};

    fn trial(centres: usize, fitness: f64) -> BasisTrial {
        BasisTrial {
            centres,
            kept: centres,
            fitness,
        }
    }

    #[test]
    fn growth_needs_two_percent_and_one_standard_error() {
        let (small, larger) = (trial(200, 1.0), trial(400, 0.95));
        assert!(gains(small, larger, 0.01));
        // 5 % lower, but the folds disagree by more than that.
        assert!(!gains(small, larger, 0.06));
        // Beyond its standard error, but under 2 %.
        assert!(!gains(small, trial(400, 0.99), 0.001));
        assert!(!gains(small, trial(400, f64::NAN), 0.0));
    }

    /// A wavy map that 8 centres cannot follow: the basis grows (its fold-by-fold standard
    /// errors are finite and far below the gain), and stops once doubling gains too little.
    #[test]
    fn a_basis_too_small_for_the_map_grows_while_the_folds_agree_it_helps() {
        let n = 600;
        let x: Vec<f64> = (0..n)
            .flat_map(|i| {
                let (a, b) = (i as f64 * 0.618_034 % 1.0, i as f64 * 0.754_878 % 1.0);
                [a, b]
            })
            .collect();
        let y: Vec<f64> = x
            .chunks(2)
            .map(|p| (6.0 * p[0]).sin() * (5.0 * p[1]).cos())
            .collect();
        let data = Dataset {
            source: "inline".into(),
            inputs: Columns::new(vec!["a".into(), "b".into()], x),
            outputs: Columns::new(vec!["y".into()], y),
            weights: None,
        };
        let folds = FoldPlan {
            choice: FoldChoice {
                scheme: FoldScheme::Shuffle,
                reason: String::new(),
            },
            folds: 5,
            labels: None,
        };
        let start = BasisDecision {
            basis: Basis::Reduced {
                centres: 8,
                seed: 3,
            },
            reason: "test".into(),
            tried: Vec::new(),
        };
        let solver = MsvrParams::new(1000.0, 0.001, 0.15);
        let (decision, held_out) = grow_basis(
            start,
            &data,
            FitnessKind::Cv { folds: 5 },
            &folds,
            &solver,
            &AtomicBool::new(false),
        )
        .unwrap();
        let Basis::Reduced { centres, .. } = decision.basis else {
            panic!("{decision:?}")
        };
        assert!(centres >= 32, "{}: {:?}", decision.reason, decision.tried);
        assert!(held_out.is_some());
        let tried = &decision.tried;
        assert!(tried[1].fitness < 0.5 * tried[0].fitness, "{tried:?}");
    }
}
