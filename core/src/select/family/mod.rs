//! The model families a selection chooses among, the one seam each implements ([`Kind`]), and
//! the rule `auto` chooses by.
//!
//! Every family is a kernel expansion f(x) = Σᵢ K(x, xᵢ) βᵢ + b with the RBF kernel on inputs
//! scaled to [0, 1], fitted exact or on a reduced basis by the shared solver, so the model
//! file, `predict`, the inverse, the C export and the intervals serve them alike. A family
//! says which axes of (C, ε, σ) a search moves, what it holds fixed, and how it is named; the
//! folds, the fitness, the search, the basis, the history and the intervals ask it through
//! [`Kind`] and know no family by name.
//!
//! A new family is its own module here implementing [`Kind`], one entry in [`Family::ALL`],
//! its tests (in its module) and its line in `docs/models.md`.
//!
//! `auto` searches each on the same rows and folds and keeps the one with the lowest
//! cross-validated error. Keeping the family with fewer axes (kernel ridge) whenever it was
//! within one standard error of the paired fold differences was measured on every held-out
//! block of the two real datasets (`docs/benchmarks.md`, ten static splits): it cost the
//! tendon arm 16 % (17.41 against 14.97 mm held out, one near tie kept the squared loss on a
//! block of transients: 22.89 against 10.69) and the soft trunk 0.5 %, and was dropped. The
//! history's and the basis' near-tie rules stay: there the simpler choice is nested in the
//! other.

use serde::{Deserialize, Serialize};

use super::run::{Kept, Run, Scoring};
use super::SelectError;
use crate::model::msvr::{Hyper, Loss, MsvrParams};
use crate::select::fitness::FitnessKind;
use crate::select::folds::Dealing;
use crate::select::tune::{self, Chosen, Pinned};

mod krr;
mod msvr;

/// What a family of models is to the selection, the model file and the reports.
pub trait Kind: Sync {
    /// Its name, as `--model` takes it, the model file stores it and the report's tables
    /// label its rows.
    fn name(&self) -> &'static str;

    /// What a report calls it.
    fn title(&self) -> &'static str;

    /// What an exported C header calls it.
    fn description(&self) -> &'static str;

    /// The axes of a search box it moves (of [`Hyper::AXES`]); it holds the others at
    /// [`Kind::solver`]'s values.
    fn axes(&self) -> &'static [&'static str];

    /// The loss it always fits with, when it fixes one.
    fn fixed_loss(&self) -> Option<Loss> {
        None
    }

    /// The solver's settings with what the family fixes.
    fn solver(&self, params: MsvrParams) -> MsvrParams;
}

/// A family of models: a handle on its [`Kind`], compared, printed and stored by its name.
#[derive(Clone, Copy)]
pub struct Family(&'static dyn Kind);

impl Family {
    /// The paper's multi-output SVR.
    pub const MSVR: Family = Family(&msvr::Msvr);
    /// Kernel ridge regression.
    pub const KRR: Family = Family(&krr::Krr);

    /// Every family this build knows, the paper's first.
    pub const ALL: [Family; 2] = [Family::MSVR, Family::KRR];

    /// The family named `name`.
    pub fn named(name: &str) -> Option<Family> {
        Family::ALL.into_iter().find(|f| f.name() == name)
    }

    /// The families' names, as a message lists them: `msvr or krr`.
    pub fn names() -> String {
        Family::names_where(|_| true)
    }

    /// The names of the families `keep` keeps, as a message lists them: `a, b or c`.
    pub fn names_where(keep: impl Fn(&Family) -> bool) -> String {
        let names: Vec<&str> = Family::ALL
            .iter()
            .filter(|f| keep(f))
            .map(|f| f.name())
            .collect();
        match names.split_last() {
            Some((last, [])) => (*last).to_string(),
            Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
            None => String::new(),
        }
    }

    /// The axes it moves as a message names them: `C and σ`.
    pub fn moves(self) -> String {
        let labels: Vec<&str> = self.axes().iter().map(|a| label(a)).collect();
        labels.join(" and ")
    }

    /// The value it holds `axis` at when fitting with `params`, when it does not move it.
    pub fn holds(self, axis: &str, params: MsvrParams) -> Option<f64> {
        if self.axes().contains(&axis) {
            return None;
        }
        let h = self.solver(params).hyper();
        Some(match axis {
            "c" => h.c,
            "epsilon" => h.epsilon,
            _ => h.sigma,
        })
    }

    /// Whether it fits with what `pinned` holds: each pinned axis one it moves or holds at the
    /// value pinned (with `params`), the loss given its own.
    pub fn honours(self, pinned: &Pinned, params: MsvrParams) -> bool {
        let axes = pinned
            .values()
            .all(|(axis, value)| self.holds(axis, params).is_none_or(|held| held == value));
        let loss = match (self.fixed_loss(), pinned.loss) {
            (Some(fixed), Some(given)) => fixed == given,
            _ => true,
        };
        axes && loss
    }

    /// The settings a report shows for it: `settings` without those it fixes (the axes it
    /// does not move, a fixed loss).
    pub fn shown(self, mut settings: Vec<(&'static str, String)>) -> Vec<(&'static str, String)> {
        let fixed: Vec<&str> = Hyper::AXES
            .iter()
            .filter(|axis| !self.axes().contains(axis))
            .map(|axis| label(axis))
            .chain(self.fixed_loss().map(|_| "loss"))
            .collect();
        settings.retain(|(name, _)| !fixed.contains(name));
        settings
    }
}

/// How reports and messages write an axis of [`Hyper::AXES`]: `C`, `ε`, `σ`.
fn label(axis: &str) -> &'static str {
    match axis {
        "c" => "C",
        "epsilon" => "ε",
        _ => "σ",
    }
}

impl std::ops::Deref for Family {
    type Target = dyn Kind;
    fn deref(&self) -> &(dyn Kind + 'static) {
        self.0
    }
}

impl Default for Family {
    fn default() -> Family {
        Family::MSVR
    }
}

impl PartialEq for Family {
    fn eq(&self, other: &Family) -> bool {
        self.name() == other.name()
    }
}

impl Eq for Family {}

impl std::fmt::Debug for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for Family {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for Family {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Family, D::Error> {
        let name = String::deserialize(d)?;
        Family::named(&name).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "model family `{name}` unknown to this handcap (it knows {})",
                Family::names()
            ))
        })
    }
}

/// Which family a selection fits: one, or `auto`'s choice among them all.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FamilyChoice {
    Auto,
    One(Family),
}

impl Default for FamilyChoice {
    /// The paper's family alone.
    fn default() -> FamilyChoice {
        FamilyChoice::MSVR
    }
}

impl FamilyChoice {
    /// The paper's family alone.
    pub const MSVR: FamilyChoice = FamilyChoice::One(Family::MSVR);

    /// The axes of (C, ε, σ) a search moves for it: its family's, or for `auto` all three.
    pub fn axes(self) -> &'static [&'static str] {
        match self {
            FamilyChoice::Auto => &Hyper::AXES,
            FamilyChoice::One(family) => family.axes(),
        }
    }

    /// Refuses a parameter given (`pinned`, with `params`) that the family asked for holds at
    /// another value, a loss given that it does not fit with, or a parameter of 0 that a search
    /// (`searched`) would hold in its box: the box is on a log scale, above 0.
    ///
    /// # Errors
    /// What to give instead, naming the parameters as `field=value`.
    pub fn check_pinned(
        self,
        pinned: &Pinned,
        params: MsvrParams,
        searched: bool,
    ) -> Result<(), String> {
        if let (FamilyChoice::One(family), Some(given)) = (self, pinned.loss) {
            if let Some(fixed) = family.fixed_loss().filter(|&fixed| fixed != given) {
                return Err(format!("loss={given} with model={family}: {} fits with the {fixed} loss; leave it out, or use model={}", family.title(), Family::names_where(|f| f.fixed_loss().is_none())));
            }
        }
        for (axis, value) in pinned.values() {
            if let FamilyChoice::One(family) = self {
                if let Some(held) = family.holds(axis, params).filter(|&held| held != value) {
                    return Err(format!("{axis}={value} with model={family}: {} holds {axis} at {held} (it does not move it); leave it out, or use model={}", family.title(), Family::names_where(|f| f.axes().contains(&axis))));
                }
            }
            let moves = self.families().iter().any(|f| f.axes().contains(&axis));
            if value <= 0.0 && moves && searched {
                let holding = Family::names_where(|f| f.holds(axis, params) == Some(value));
                return Err(format!("{axis}={value} with a search: the search holds it in its box, on a log scale above 0; give {axis} above 0, search=none to fit with it as given, or model={holding}"));
            }
        }
        Ok(())
    }

    /// Whether the parameters `pinned` holds leave an axis it moves to search.
    pub fn searches(self, pinned: &Pinned) -> bool {
        self.axes()
            .iter()
            .any(|axis| !pinned.values().any(|(name, _)| name == *axis))
    }

    /// The families it searches, the paper's first.
    pub fn families(self) -> Vec<Family> {
        match self {
            FamilyChoice::Auto => Family::ALL.to_vec(),
            FamilyChoice::One(family) => vec![family],
        }
    }
}

impl std::str::FromStr for FamilyChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(FamilyChoice::Auto),
            _ => Family::named(s)
                .map(FamilyChoice::One)
                .ok_or_else(|| format!("`{s}`: give auto, {}", Family::names())),
        }
    }
}

impl std::fmt::Display for FamilyChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FamilyChoice::Auto => f.write_str("auto"),
            FamilyChoice::One(family) => family.fmt(f),
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
    /// Each family `auto` searched on the same folds (read: those this build knows).
    #[serde(
        default,
        skip_serializing_if = "Vec::is_empty",
        deserialize_with = "known_trials"
    )]
    pub tried: Vec<FamilyTrial>,
}

/// The trials of a stored decision, less those of families this build does not know (a file
/// of a newer build whose `auto` also tried another family still serves its model).
fn known_trials<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<FamilyTrial>, D::Error> {
    let stored = Vec::<serde_json::Value>::deserialize(d)?;
    let known = |t: &serde_json::Value| {
        let name = t.get("family").and_then(serde_json::Value::as_str);
        name.is_none_or(|name| Family::named(name).is_some())
    };
    stored
        .into_iter()
        .filter(known)
        .map(|t| serde_json::from_value(t).map_err(serde::de::Error::custom))
        .collect()
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
/// error, as a user's grid search refits its best. The reason gives each other family's
/// paired difference above it and that difference's standard error, and calls a difference
/// within one standard error a near tie. A rule keeping the family with fewer axes in a near
/// tie was measured and dropped (module docs).
pub fn decide(tried: Vec<FamilyTrial>) -> FamilyDecision {
    let best = tried
        .iter()
        .min_by(|a, b| a.fitness.total_cmp(&b.fitness))
        .expect("a family was tried");
    let (title, k, lower) = (best.family.title(), best.folds.len(), best.fitness);
    let others: Vec<String> = tried
        .iter()
        .filter(|t| t.family != best.family)
        .map(|t| {
            let (margin, se) = paired(t, best);
            let tie = if margin <= se { ": a near tie" } else { "" };
            format!(
                "{}'s {:.5} (difference {margin:.5}, one standard error {se:.5} over {k} folds{tie})",
                t.family.title(),
                t.fitness
            )
        })
        .collect();
    let verdict = if others.is_empty() {
        format!("{title} has the lowest cross-validated error ({lower:.5})")
    } else {
        format!(
            "{title} has the lowest cross-validated error, {lower:.5}, against {}",
            others.join(", ")
        )
    };
    FamilyDecision {
        used: best.family,
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
            FamilyChoice::Auto if !compares => vec![Family::MSVR],
            FamilyChoice::Auto => Family::ALL
                .iter()
                .copied()
                .filter(|f| f.honours(&self.plan.pinned, self.plan.params))
                .collect(),
            choice => choice.families(),
        }
    }

    /// The decision when one family was searched of the `planned`: asked for, `auto` with
    /// nothing to compare families by, or `auto` stopped before the second.
    pub(super) fn asked(&self, family: Family, planned: usize) -> FamilyDecision {
        let reason = match (self.plan.family, planned) {
            (FamilyChoice::Auto, 1) => format!("model=auto: {}, the only family searched (families are compared by a cross-validated search of their own box; fitness=train and the paper's colony leave none, and a family that holds a parameter given at another value, or fits with another loss than the one given, is left out)", family.title()),
            (FamilyChoice::Auto, _) => format!(
                "model=auto: {} (a stop came before the other families were searched)",
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
        let FitnessKind::Cv { .. } = scored.fitness else {
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
        Ok(predicted.fold_maes(rows))
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
    fn auto_keeps_the_lowest_cross_validated_error_and_names_a_near_tie() {
        // MSVR lower by 0.02 on average, the folds disagreeing by far more: a near tie, kept
        // all the same (kernel ridge, with fewer axes, was kept here before).
        let tie = decide(vec![
            trial(Family::MSVR, &[1.0, 2.0, 1.5, 1.2, 0.9]),
            trial(Family::KRR, &[1.2, 1.8, 1.6, 1.1, 1.0]),
        ]);
        assert_eq!(tie.used, Family::MSVR, "{}", tie.reason);
        assert!(tie.reason.contains("a near tie"), "{}", tie.reason);
        assert!(
            tie.reason.contains("kernel ridge's 1.34000"),
            "{}",
            tie.reason
        );
        // MSVR lower on every fold by 0.1 ± 0.01: kept, no tie.
        let won = decide(vec![
            trial(Family::MSVR, &[1.0, 2.0, 1.5, 1.2, 0.9]),
            trial(Family::KRR, &[1.1, 2.11, 1.59, 1.3, 1.01]),
        ]);
        assert_eq!(won.used, Family::MSVR, "{}", won.reason);
        assert!(!won.reason.contains("tie"), "{}", won.reason);
        // Kernel ridge lower, in whichever order they were tried: kept.
        for tried in [
            vec![
                trial(Family::MSVR, &[1.1, 2.11, 1.59, 1.3, 1.01]),
                trial(Family::KRR, &[1.0, 2.0, 1.5, 1.2, 0.9]),
            ],
            vec![
                trial(Family::KRR, &[1.0, 2.0, 1.5, 1.2, 0.9]),
                trial(Family::MSVR, &[1.1, 2.11, 1.59, 1.3, 1.01]),
            ],
        ] {
            let ridge = decide(tried);
            assert_eq!(ridge.used, Family::KRR, "{}", ridge.reason);
            assert_eq!(ridge.tried.len(), 2);
        }
        // One family: kept.
        let alone = decide(vec![trial(Family::MSVR, &[1.0, 2.0])]);
        assert_eq!(alone.used, Family::MSVR);
        assert!(alone.reason.contains("lowest"));
    }

    #[test]
    fn family_names_parse_print_and_store_alike() {
        for name in ["auto", "msvr", "krr"] {
            assert_eq!(name.parse::<FamilyChoice>().unwrap().to_string(), name);
        }
        assert!("svr"
            .parse::<FamilyChoice>()
            .unwrap_err()
            .contains("auto, msvr or krr"));
        for family in Family::ALL {
            let stored = serde_json::to_string(&family).unwrap();
            assert_eq!(stored, format!("\"{}\"", family.name()));
            assert_eq!(serde_json::from_str::<Family>(&stored).unwrap(), family);
        }
        let err = serde_json::from_str::<Family>("\"gp\"").unwrap_err();
        assert!(
            err.to_string()
                .contains("`gp` unknown to this handcap (it knows msvr or krr)"),
            "{err}"
        );
        // A newer build's decision that also tried a family this one does not know.
        let mut decided = decide(vec![
            trial(Family::MSVR, &[1.0, 2.0]),
            trial(Family::KRR, &[1.5, 2.5]),
        ]);
        let mut stored = serde_json::to_value(&decided).unwrap();
        let mut other = stored["tried"][1].clone();
        other["family"] = "gp".into();
        stored["tried"].as_array_mut().unwrap().push(other);
        let read: FamilyDecision = serde_json::from_value(stored).unwrap();
        assert_eq!(read, decided);
        decided.tried.clear();
        assert_eq!(serde_json::to_value(&decided).unwrap().get("tried"), None);
    }

    /// What a family fixes is what the refusals and the report read: kernel ridge holds ε at
    /// 0 and the squared loss, MSVR holds nothing.
    #[test]
    fn a_family_holds_the_axes_it_does_not_move() {
        let params = MsvrParams::new(10.0, 0.3, 0.2);
        assert_eq!(Family::KRR.holds("epsilon", params), Some(0.0));
        assert_eq!(Family::KRR.holds("c", params), None);
        assert!(Hyper::AXES
            .iter()
            .all(|a| Family::MSVR.holds(a, params).is_none()));
        let settings = vec![
            ("model", "x".into()),
            ("C", "1".into()),
            ("ε", "0".into()),
            ("σ", "1".into()),
            ("loss", "q".into()),
            ("basis", "exact".into()),
        ];
        let names =
            |s: Vec<(&'static str, String)>| s.into_iter().map(|(n, _)| n).collect::<Vec<_>>();
        assert_eq!(
            names(Family::KRR.shown(settings.clone())),
            ["model", "C", "σ", "basis"]
        );
        assert_eq!(names(Family::MSVR.shown(settings.clone())), names(settings));
    }
}
