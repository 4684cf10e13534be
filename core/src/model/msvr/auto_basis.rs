//! `--basis auto`: exact MSVR up to [`AUTO_EXACT_ROWS`] rows; above, a reduced basis that
//! starts at [`AUTO_FIRST_CENTRES`] and doubles while the cross-validated error falls by more
//! than [`AUTO_GAIN`].

use std::sync::atomic::AtomicBool;

use faer::Mat;
use serde::{Deserialize, Serialize};

use super::fitness::{Fitness, FitnessKind};
use super::folds::FoldPlan;
use super::tune::TuneError;
use super::{Basis, MsvrParams};
use crate::data::Dataset;

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
            let fits = super::check_memory(rows, Basis::Exact).is_ok();
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

/// Whether a larger basis lowered the fitness by more than [`AUTO_GAIN`] (a non-finite one
/// never does).
fn gains(smaller: BasisTrial, larger: BasisTrial) -> bool {
    larger.fitness < smaller.fitness * (1.0 - AUTO_GAIN)
}

/// `auto`'s growth of a reduced basis at the chosen (C, ε, σ): doubles the centres while the
/// cross-validated fitness falls by more than [`AUTO_GAIN`], up to [`AUTO_MAX_CENTRES`], half
/// the rows, what memory allows, or until the pivoted Cholesky keeps fewer centres than asked
/// (more would be redundant at this σ). Returns the decision with every size tried.
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
) -> Result<(BasisDecision, Option<Mat<f64>>), TuneError> {
    let Basis::Reduced { centres, seed } = start.basis else {
        return Ok((start, None));
    };
    let limit = AUTO_MAX_CENTRES.min(data.rows() / 2).max(centres);
    // Each size's held-out predictions, for the intervals of the one chosen.
    let mut predicted = Vec::new();
    let mut score = |m: usize| -> Result<BasisTrial, TuneError> {
        let params = solver.basis(Basis::Reduced { centres: m, seed });
        let scorer = Fitness::new(data, fitness, seed, folds.labels.as_deref(), &params)?;
        let fitness = scorer.evaluate(&[solver.hyper()], f64::INFINITY)[0];
        predicted.push(scorer.held_out_of(&solver.hyper()));
        Ok(BasisTrial {
            centres: m,
            kept: scorer.kept_centres(solver.sigma),
            fitness,
        })
    };
    let mut tried = vec![score(centres)?];
    let why = loop {
        let last = *tried.last().expect("one trial");
        let next = (last.centres * 2).min(limit);
        if last.kept < last.centres {
            break format!(
                "{} of {} centres kept at σ {:.4}: more would be redundant",
                last.kept, last.centres, solver.sigma
            );
        }
        if next == last.centres {
            break format!("the largest basis allowed ({limit} centres)");
        }
        if super::check_memory(
            data.rows(),
            Basis::Reduced {
                centres: next,
                seed,
            },
        )
        .is_err()
        {
            break format!("{next} centres would not fit in memory");
        }
        if interrupt.load(std::sync::atomic::Ordering::Relaxed) {
            break "interrupted".into();
        }
        let trial = score(next)?;
        tried.push(trial);
        if !gains(last, trial) {
            break format!(
                "{} centres improved the cross-validated error by less than {:.0} % ({:.5} → {:.5})",
                trial.centres,
                100.0 * AUTO_GAIN,
                last.fitness,
                trial.fitness
            );
        }
    };
    // The first size the next did not beat by the gain (the last when growth stopped for
    // another reason).
    let chosen = tried
        .windows(2)
        .position(|w| !gains(w[0], w[1]))
        .unwrap_or(tried.len() - 1);
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
