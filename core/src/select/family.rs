//! The model families a selection chooses among, and the rule `auto` chooses by.
//!
//! Both families are kernel expansions f(x) = Σᵢ K(x, xᵢ) βᵢ + b with the RBF kernel on inputs
//! scaled to [0, 1], fitted exact or on a reduced basis, so the model file, `predict`, the
//! inverse, the C export and the intervals serve them alike:
//! - `msvr`, the paper's: C, ε and σ shared by the outputs, the tube's loss (robust by
//!   default);
//! - `krr`, kernel ridge regression (scikit-learn's `KernelRidge`, with an intercept): the
//!   squared loss and no tube. It is MSVR with ε = 0 and the quadratic loss, whose
//!   iteratively reweighted solve is then one linear solve (the weights never change: the
//!   solver stops at its second iteration), so it is fitted by the same code; its search
//!   moves C (the ridge is 1/(2C)) and σ only.
//!
//! `auto` searches each on the same rows and folds and keeps the one with the lower
//! cross-validated error, unless they are within one standard error of their paired
//! difference over the folds: then the simpler, kernel ridge (two parameters, one solve).

use serde::{Deserialize, Serialize};

use super::run::{Kept, Run, Scoring};
use super::SelectError;
use crate::model::msvr::fitness::{self, Dealing, FitnessKind};
use crate::model::msvr::tune::{self, Chosen, TuneError};
use crate::model::msvr::{Hyper, Loss, MsvrParams};

/// A family of models.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Family {
    /// The paper's multi-output SVR.
    #[default]
    Msvr,
    /// Kernel ridge regression.
    Krr,
}

impl Family {
    /// Every family, the paper's first.
    pub const ALL: [Family; 2] = [Family::Msvr, Family::Krr];

    /// The axes of a search box it moves (of [`Hyper::AXES`]).
    pub fn axes(self) -> &'static [&'static str] {
        match self {
            Family::Msvr => &Hyper::AXES,
            Family::Krr => &["c", "sigma"],
        }
    }

    /// The solver's settings with what the family fixes: kernel ridge has no tube (ε = 0) and
    /// the squared loss.
    pub fn solver(self, params: MsvrParams) -> MsvrParams {
        match self {
            Family::Msvr => params,
            Family::Krr => MsvrParams {
                epsilon: 0.0,
                ..params.loss(Loss::Quadratic)
            },
        }
    }

    /// Its name, as `--model` takes it and the report's tables label its rows.
    pub fn name(self) -> &'static str {
        match self {
            Family::Msvr => "msvr",
            Family::Krr => "krr",
        }
    }

    /// What a report calls it.
    pub fn title(self) -> &'static str {
        match self {
            Family::Msvr => "MSVR",
            Family::Krr => "kernel ridge",
        }
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Which family a selection fits: one, or `auto`'s choice between them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FamilyChoice {
    Auto,
    #[default]
    Msvr,
    Krr,
}

impl FamilyChoice {
    /// The families it searches, the paper's first.
    pub fn families(self) -> Vec<Family> {
        match self {
            FamilyChoice::Auto => Family::ALL.to_vec(),
            FamilyChoice::Msvr => vec![Family::Msvr],
            FamilyChoice::Krr => vec![Family::Krr],
        }
    }
}

impl std::str::FromStr for FamilyChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(FamilyChoice::Auto),
            "msvr" => Ok(FamilyChoice::Msvr),
            "krr" => Ok(FamilyChoice::Krr),
            _ => Err(format!("`{s}`: give auto, msvr or krr")),
        }
    }
}

impl std::fmt::Display for FamilyChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FamilyChoice::Auto => f.write_str("auto"),
            FamilyChoice::Msvr => Family::Msvr.fmt(f),
            FamilyChoice::Krr => Family::Krr.fmt(f),
        }
    }
}

/// One family `auto` searched: its cross-validated error and each fold's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FamilyTrial {
    pub family: Family,
    /// The search's best cross-validated MAE.
    pub fitness: f64,
    /// The held-out MAE of each fold, at the parameters chosen, and its held-out values (rows
    /// × outputs).
    pub folds: Vec<f64>,
    pub values: Vec<usize>,
    pub params: MsvrParams,
}

/// Which family the model is, and why: the log, the report and the model file say it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FamilyDecision {
    pub used: Family,
    pub reason: String,
    /// Each family `auto` searched on the same folds.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tried: Vec<FamilyTrial>,
}

impl FamilyDecision {
    /// The decision when one family was asked for.
    pub fn asked(family: Family) -> FamilyDecision {
        FamilyDecision {
            used: family,
            reason: format!("model={family}"),
            tried: Vec::new(),
        }
    }

    /// The reason without its `model=…: ` label.
    pub fn verdict(&self) -> &str {
        self.reason
            .split_once(": ")
            .map_or(&self.reason, |(_, v)| v)
    }
}

/// `auto`'s choice among `tried` (each scored on the same folds): the lowest cross-validated
/// error, unless kernel ridge's is within one standard error of the paired fold differences
/// above it.
pub fn decide(tried: Vec<FamilyTrial>) -> FamilyDecision {
    let best = tried
        .iter()
        .min_by(|a, b| a.fitness.total_cmp(&b.fitness))
        .expect("a family was tried");
    let simple = tried.iter().find(|t| t.family == Family::Krr);
    let (used, verdict) = match simple {
        Some(simple) if simple.family != best.family => {
            let (margin, se) = paired(simple, best);
            let (title, k) = (best.family.title(), best.folds.len());
            let (ridge, lower) = (simple.fitness, best.fitness);
            if margin <= se {
                (
                    Family::Krr,
                    format!("{title}'s {lower:.5} is within one standard error of kernel ridge's {ridge:.5} (difference {margin:.5} ≤ {se:.5} over {k} folds): the simpler, kernel ridge"),
                )
            } else {
                (
                    best.family,
                    format!("{title} lowers the cross-validated error from kernel ridge's {ridge:.5} to {lower:.5} (by {margin:.5}, more than one standard error, {se:.5}, over {k} folds)"),
                )
            }
        }
        _ => (
            best.family,
            format!(
                "{} has the lowest cross-validated error ({:.5})",
                best.family.title(),
                best.fitness
            ),
        ),
    };
    FamilyDecision {
        used,
        reason: format!("model=auto: {verdict}"),
        tried,
    }
}

/// The cross-validated error of `a` less `b`'s and its standard error over the folds.
fn paired(a: &FamilyTrial, b: &FamilyTrial) -> (f64, f64) {
    crate::stats::paired_difference(&a.folds, &b.folds, &a.values)
}

/// How a selection compares its families.
impl Run<'_> {
    /// The families to search: [`Plan::family`]'s, or MSVR alone for `auto` where nothing is
    /// cross-validated (given parameters, the training fitness) or the paper's colony
    /// searches.
    pub(super) fn families(&self, present: &Scoring) -> Vec<Family> {
        let selection = &self.plan.selection;
        let compares = selection.searched()
            && !selection.paper()
            && matches!(present.fitness, FitnessKind::Cv { .. });
        match self.plan.family {
            FamilyChoice::Auto if !compares => vec![Family::Msvr],
            choice => choice.families(),
        }
    }

    /// The decision when one family was searched of the `planned`: asked for, `auto` with
    /// nothing to compare families by, or `auto` stopped before the second.
    pub(super) fn asked(&self, family: Family, planned: usize) -> FamilyDecision {
        let reason = match (self.plan.family, planned) {
            (FamilyChoice::Auto, 1) => "model=auto: MSVR, the paper's (families are compared by a cross-validated search of their own box; the parameters given, fitness=train and the paper's colony leave none)".to_string(),
            (FamilyChoice::Auto, _) => format!(
                "model=auto: {} (a stop came before the other family was searched)",
                family.title()
            ),
            _ => return FamilyDecision::asked(family),
        };
        FamilyDecision {
            used: family,
            reason,
            tried: Vec::new(),
        }
    }

    /// `auto`'s choice among the families' selections ([`decide`] on each one's
    /// held-out error per fold, the same folds for all).
    pub(super) fn compare(
        &self,
        each: Vec<(Family, Kept)>,
    ) -> Result<(FamilyDecision, Kept), SelectError> {
        let mut trials = Vec::new();
        for (family, (_, chosen, scored)) in &each {
            let (folds, values) = self.fold_errors(chosen, scored)?;
            trials.push(FamilyTrial {
                family: *family,
                fitness: chosen.fitness.unwrap_or(f64::NAN),
                folds,
                values,
                params: chosen.params,
            });
        }
        let decision = decide(trials);
        let kept = each
            .into_iter()
            .find(|(f, _)| *f == decision.used)
            .expect("the family kept was searched")
            .1;
        Ok((decision, kept))
    }

    /// The held-out MAE of each fold of `scored` at `chosen`'s parameters (the search's
    /// held-out predictions, or one fit per fold when it kept none), and its held-out values.
    pub(super) fn fold_errors(
        &self,
        chosen: &Chosen,
        scored: &Scoring,
    ) -> Result<(Vec<f64>, Vec<usize>), SelectError> {
        let FitnessKind::Cv { folds } = scored.fitness else {
            return Ok((Vec::new(), Vec::new()));
        };
        let seed = self.plan.seed().unwrap_or(crate::DEFAULT_SEED);
        let rows = &scored.scored;
        let computed;
        let predicted = match &chosen.held_out {
            Some(p) => p,
            None => {
                computed = tune::held_out_predictions(
                    rows,
                    seed,
                    &scored.plan,
                    Dealing::Shuffled,
                    &chosen.params,
                )?;
                &computed
            }
        };
        let labels = scored.plan.labels.as_deref();
        let fold_of = fitness::assign_folds(rows.rows(), folds, seed, labels, Dealing::Shuffled)
            .map_err(TuneError::from)?;
        Ok(fitness::fold_maes(rows, predicted, &fold_of, folds))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(family: Family, folds: &[f64]) -> FamilyTrial {
        FamilyTrial {
            family,
            fitness: folds.iter().sum::<f64>() / folds.len() as f64,
            folds: folds.to_vec(),
            values: vec![30; folds.len()],
            params: MsvrParams::default(),
        }
    }

    #[test]
    fn auto_keeps_kernel_ridge_within_one_standard_error_and_msvr_beyond_it() {
        // MSVR lower by 0.02 on average, the folds disagreeing by far more: a tie.
        let tie = decide(vec![
            trial(Family::Msvr, &[1.0, 2.0, 1.5, 1.2, 0.9]),
            trial(Family::Krr, &[1.2, 1.8, 1.6, 1.1, 1.0]),
        ]);
        assert_eq!(tie.used, Family::Krr, "{}", tie.reason);
        assert!(tie.reason.contains("within one standard error"));
        // MSVR lower on every fold by 0.1 ± 0.01: kept.
        let won = decide(vec![
            trial(Family::Msvr, &[1.0, 2.0, 1.5, 1.2, 0.9]),
            trial(Family::Krr, &[1.1, 2.11, 1.59, 1.3, 1.01]),
        ]);
        assert_eq!(won.used, Family::Msvr, "{}", won.reason);
        // Kernel ridge lower: kept, whatever the margin.
        let ridge = decide(vec![
            trial(Family::Msvr, &[1.1, 2.11, 1.59, 1.3, 1.01]),
            trial(Family::Krr, &[1.0, 2.0, 1.5, 1.2, 0.9]),
        ]);
        assert_eq!(ridge.used, Family::Krr);
        assert_eq!(ridge.tried.len(), 2);
    }

    /// Kernel ridge is MSVR with ε = 0 and the quadratic loss: its fit is the closed form
    /// [K + I/(2C), 1; 1ᵀ, 0] [β; b] = [y; 0] on the scaled inputs, solved here apart.
    #[test]
    fn kernel_ridge_is_the_closed_form_with_an_intercept() {
        use crate::data::{Columns, Dataset};
        use crate::model::ModelSpec;
        use nalgebra::{DMatrix, DVector};
        let n = 30;
        let x: Vec<f64> = (0..n).map(|i| 2.0 + 0.37 * i as f64).collect();
        let y: Vec<f64> = x
            .iter()
            .flat_map(|v| [(v / 2.0).sin() + 0.1 * (7.0 * v).cos(), 3.0 + 0.2 * v])
            .collect();
        let data = Dataset {
            source: "inline".into(),
            inputs: Columns::new(vec!["p".into()], x.clone()),
            outputs: Columns::new(vec!["a".into(), "b".into()], y.clone()),
        };
        let (c, sigma) = (40.0, 0.15);
        let params = Family::Krr.solver(MsvrParams::new(c, 0.3, sigma).loss(Loss::Robust));
        assert_eq!((params.epsilon, params.loss), (0.0, Loss::Quadratic));
        let model = ModelSpec::Msvr(params).fit(&data).unwrap();
        assert!(
            model.diagnostics().iterations <= 2,
            "{:?}",
            model.diagnostics()
        );
        let (lo, hi) = (x[0], x[n - 1]);
        let s: Vec<f64> = x.iter().map(|v| (v - lo) / (hi - lo)).collect();
        let k = |a: f64, b: f64| (-(a - b).powi(2) / (2.0 * sigma * sigma)).exp();
        let mut system = DMatrix::zeros(n + 1, n + 1);
        for i in 0..n {
            for j in 0..n {
                system[(i, j)] = k(s[i], s[j]);
            }
            system[(i, i)] += 1.0 / (2.0 * c);
            system[(i, n)] = 1.0;
            system[(n, i)] = 1.0;
        }
        let lu = system.lu();
        for out in 0..2 {
            let mut rhs = DVector::zeros(n + 1);
            for i in 0..n {
                rhs[i] = y[2 * i + out];
            }
            let solution = lu.solve(&rhs).unwrap();
            for probe in [2.5, 6.1, 12.0] {
                let sp = (probe - lo) / (hi - lo);
                let expected = solution[n] + (0..n).map(|i| solution[i] * k(sp, s[i])).sum::<f64>();
                let mut got = [0.0; 2];
                model.predictor().predict_row(&[probe], &mut got);
                assert!(
                    (got[out] - expected).abs() < 1e-6,
                    "output {out} at {probe}: {} against the closed form's {expected}",
                    got[out]
                );
            }
        }
    }

    #[test]
    fn family_names_parse_and_print_alike() {
        for name in ["auto", "msvr", "krr"] {
            assert_eq!(name.parse::<FamilyChoice>().unwrap().to_string(), name);
        }
        assert!("svr"
            .parse::<FamilyChoice>()
            .unwrap_err()
            .contains("auto, msvr or krr"));
    }
}
