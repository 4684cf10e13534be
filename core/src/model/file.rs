//! The model file: versioned JSON with the model, its fit diagnostics and its provenance.
//!
//! ```json
//! { "format": "handcap-model", "version": 1, "kind": "msvr",
//!   "model": { "inputs": [...], "outputs": [...], "params": {...}, "scaler": {...},
//!              "support_vectors": [[...]], "coefficients": [[...]], "bias": [...], "fit": {...} },
//!   "family": { "used": "krr", "reason": "model=auto: ...", "tried": [...] },
//!   "history": { "used": { "time": "t_s", "group": "trial", "inputs": [...],
//!                          "memory": { "kind": "ema", "tau": [0.6, 2.4] } }, "reason": "...", "tried": [...] },
//!   "intervals": { "folds": { "scheme": "groups", ... }, "rows": 780,
//!                  "radii": [{ "level": 0.9, "radius": 1.2 }, { "level": 0.95, "radius": 1.6 }],
//!                  "groups": [{ "group": 3, "rows": 40, "covered": 0.85 }, ...], "scores": [...] },
//!   "provenance": { "handcap_version": "...", "command": [...], "seed": null, "inputs": [...] } }
//! ```
//! A model with input history (`history.used`) was fitted on the features
//! [`History::feature_names`] lists: its `model.inputs`; a file to predict needs the time (and
//! group) column besides the inputs ([`ModelFile::read_inputs`]).
//! Numbers are written so they read back to the same `f64`: a saved and reloaded model
//! predicts bit for bit what the fitted one did.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::data::{self, Columns, DataError};
use crate::fsio;
use crate::model::history::{History, HistoryDecision, Memory, SteadyState};
use crate::model::interval::{IntervalError, Intervals, RowRadii, Widener};
pub use crate::model::StoredModel;
use crate::model::{ModelSpec, Predict};
use crate::provenance::Provenance;
use crate::select::family::{Family, FamilyDecision};
use crate::select::tune::{BasisDecision, SearchSummary};

/// The `format` field of every model file.
pub const FORMAT: &str = "handcap-model";
/// The version this build writes and reads.
pub const VERSION: u32 = 1;

/// Errors of reading or writing a model file.
#[derive(Debug, thiserror::Error)]
pub enum ModelFileError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path}: not a handcap model file ({reason}); give a model file that `handcap model` or the Python estimator wrote"
    )]
    Invalid { path: PathBuf, reason: String },
    #[error("{path}: model file version {found}, this handcap reads version {VERSION}; refit with this version")]
    Version { path: PathBuf, found: u32 },
    #[error("{path}: a model of the family `{name}`, which this handcap does not know (it knows {known}); use the handcap that wrote it, or fit the model again")]
    Family {
        path: PathBuf,
        name: String,
        known: String,
    },
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// A model with what made it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelFile {
    pub format: String,
    pub version: u32,
    #[serde(flatten)]
    pub model: StoredModel,
    /// The search that chose the hyper-parameters; absent when they were given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search: Option<SearchSummary>,
    /// The basis and why it was chosen; absent in files written before the reduced basis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub basis: Option<BasisDecision>,
    /// The family and why (`model=auto` compared them); absent in files written before
    /// families: MSVR.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub family: Option<FamilyDecision>,
    /// The input history and why; absent when no time column was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub history: Option<HistoryDecision>,
    /// Conformal prediction intervals from held-out residuals; absent in files written before
    /// them, or when the search scored on the training data.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intervals: Option<Intervals>,
    pub provenance: Provenance,
}

impl ModelFile {
    pub fn new(
        model: StoredModel,
        search: Option<SearchSummary>,
        basis: Option<BasisDecision>,
        history: Option<HistoryDecision>,
        intervals: Option<Intervals>,
        provenance: Provenance,
    ) -> Self {
        ModelFile {
            format: FORMAT.to_string(),
            version: VERSION,
            model,
            search,
            basis,
            family: None,
            history,
            intervals,
            provenance,
        }
    }

    /// The family of its model, as the file says (MSVR when it does not).
    pub fn family(&self) -> Family {
        self.family.as_ref().map_or(Family::MSVR, |d| d.used)
    }

    /// The prediction interval's radius at `level` (output units).
    ///
    /// # Errors
    /// [`IntervalError`]: a bad level, too few held-out rows for it, or a file without intervals.
    pub fn interval_radius(&self, level: f64) -> Result<f64, IntervalError> {
        match &self.intervals {
            Some(i) => i.radius(level),
            None => Err(IntervalError::Missing),
        }
    }

    /// The prediction interval's radius at `level` around the prediction at each row of
    /// `inputs` (the model's inputs: its features, with history).
    ///
    /// # Errors
    /// As [`ModelFile::interval_radius`], and a widening its centres do not give.
    pub fn interval_radii(&self, level: f64, inputs: &Columns) -> Result<RowRadii, IntervalError> {
        match &self.intervals {
            Some(i) => i.radii_at(level, inputs),
            None => Err(IntervalError::Missing),
        }
    }

    /// What computes the interval's widening factor at the model's inputs; `None` when its
    /// radius is the same everywhere (or it has no intervals).
    ///
    /// # Errors
    /// A widening its centres do not give.
    pub fn interval_widener(&self) -> Result<Option<Widener>, IntervalError> {
        Ok(match &self.intervals {
            Some(i) => i.widener()?,
            None => None,
        })
    }

    /// The input history the model was fitted on, if any.
    pub fn history(&self) -> Option<&History> {
        self.history.as_ref().and_then(|d| d.used.as_ref())
    }

    /// The inputs of a CSV file as written there, and as the model takes them (the same, or
    /// with the history's features built per group in time order).
    ///
    /// # Errors
    /// [`DataError`]: the file's own, or a time (or group) column that a history model needs
    /// and the file lacks or has out of order.
    pub fn read_inputs(&self, path: &Path) -> Result<(Columns, Columns), DataError> {
        match self.history() {
            None => {
                let x = data::read_columns(path, self.model.predictor().inputs())?;
                Ok((x.clone(), x))
            }
            Some(h) => h.read_features(path),
        }
    }

    /// The map from the present inputs alone, for the inverse: the model itself, or with input
    /// history its steady state (every filter and lag equal to the input).
    pub fn steady_state(&self) -> SteadyState<'_> {
        SteadyState::new(self.model.differentiable(), self.history())
    }

    /// The outputs at rest: every input 0 and held there (the steady state of a history
    /// model), where the monitor measures the finger's response from.
    pub fn at_rest(&self) -> Vec<f64> {
        let rest = self.steady_state();
        let mut out = vec![0.0; rest.outputs().len()];
        rest.predict_row(&vec![0.0; rest.inputs().len()], &mut out);
        out
    }

    /// Writes the file atomically.
    ///
    /// # Errors
    /// [`ModelFileError::Write`].
    pub fn save(&self, path: &Path) -> Result<(), ModelFileError> {
        let json = serde_json::to_vec_pretty(self).expect("model serialises");
        fsio::write_bytes(path, &json).map_err(|source| ModelFileError::Write {
            path: path.into(),
            source,
        })
    }

    /// Reads and checks a model file.
    ///
    /// # Errors
    /// [`ModelFileError::Read`], [`ModelFileError::Version`], [`ModelFileError::Family`] (a
    /// family this build does not know), or [`ModelFileError::Invalid`] with what is wrong.
    pub fn load(path: &Path) -> Result<Self, ModelFileError> {
        let bytes = std::fs::read(path).map_err(|source| ModelFileError::Read {
            path: path.into(),
            source,
        })?;
        let invalid = |reason: String| ModelFileError::Invalid {
            path: path.into(),
            reason,
        };
        #[derive(Deserialize)]
        struct Header {
            format: Option<String>,
            version: Option<u32>,
            family: Option<serde_json::Value>,
        }
        let header: Header =
            serde_json::from_slice(&bytes).map_err(|e| invalid(format!("not JSON: {e}")))?;
        if header.format.as_deref() != Some(FORMAT) {
            return Err(invalid(format!("`format` is not \"{FORMAT}\"")));
        }
        match header.version {
            Some(VERSION) => {}
            Some(found) => {
                return Err(ModelFileError::Version {
                    path: path.into(),
                    found,
                })
            }
            None => return Err(invalid("no `version`".into())),
        }
        // The family kept; one `auto` only tried may be unknown to this build.
        let used = header.family.as_ref().and_then(|f| f.get("used")?.as_str());
        if let Some(name) = used.filter(|name| Family::named(name).is_none()) {
            return Err(ModelFileError::Family {
                path: path.into(),
                name: name.to_string(),
                known: Family::names(),
            });
        }
        let file: ModelFile = serde_json::from_slice(&bytes).map_err(|e| invalid(e.to_string()))?;
        file.validate().map_err(invalid)?;
        Ok(file)
    }

    /// Checks every invariant prediction, the inverse and the intervals rely on, beyond what
    /// the model's own form checks (shapes, finite numbers): names unique and no output named
    /// as an input; numbers of a size a fit can give; the history's features are the model's
    /// inputs, with time constants that are positive and finite; interval radii and scores
    /// finite, non-negative and in order. A file that passes cannot make a command panic.
    ///
    /// # Errors
    /// What is wrong, in a few words naming the field.
    pub fn validate(&self) -> Result<(), String> {
        let model = self.model.predictor();
        unique("model.inputs", model.inputs())?;
        unique("model.outputs", model.outputs())?;
        if let Some(name) = model.outputs().iter().find(|o| model.inputs().contains(o)) {
            return Err(format!("{name:?} is both an input and an output"));
        }
        match self.history() {
            Some(history) => {
                validate_history(history, model.inputs())?;
                let named = [&history.time].into_iter().chain(&history.group);
                let columns = || history.inputs.iter().chain(model.outputs());
                if let Some(name) = named.into_iter().find(|n| columns().any(|c| c == *n)) {
                    return Err(format!(
                        "the history's time or group column {name:?} is also an input or an output"
                    ));
                }
            }
            // Filtered inputs without the history that builds them would be planned and
            // exported as free inputs.
            None => {
                if let Some(name) = model.inputs().iter().find(|n| is_history_feature(n)) {
                    return Err(format!(
                        "input {name:?} is a history's feature, but the file has no history"
                    ));
                }
            }
        }
        if let Some(intervals) = &self.intervals {
            let ModelSpec::Msvr(params) = self.model.spec();
            intervals.validate(model.inputs().len(), params.sigma, params.c)?;
        }
        Ok(())
    }
}

/// Whether `name` is one of a history's feature names (`<input>@ema<τ>`, `<input>@lag<k>`).
fn is_history_feature(name: &str) -> bool {
    name.rsplit_once('@').is_some_and(|(_, suffix)| {
        let number = |s: Option<&str>| s.is_some_and(|v| v.parse::<f64>().is_ok());
        number(suffix.strip_prefix("ema")) || number(suffix.strip_prefix("lag"))
    })
}

/// `names` has no name twice.
fn unique(field: &str, names: &[String]) -> Result<(), String> {
    let mut seen = std::collections::HashSet::new();
    match names.iter().find(|n| !seen.insert(n.as_str())) {
        Some(name) => Err(format!("{field} names {name:?} twice")),
        None => Ok(()),
    }
}

/// The history `h` builds exactly the features `inputs` (counted before they are named: a
/// tampered lag count must not allocate), from unique inputs, with usable time constants.
fn validate_history(h: &History, inputs: &[String]) -> Result<(), String> {
    unique("history.inputs", &h.inputs)?;
    if h.inputs.is_empty() {
        return Err("history.inputs is empty".into());
    }
    if let Memory::Ema { tau } = &h.memory {
        if let Some(t) = tau.iter().find(|t| !(t.is_finite() && **t > 0.0)) {
            return Err(format!(
                "history time constant {t} is not a positive number"
            ));
        }
        let mut sorted = tau.clone();
        sorted.sort_by(f64::total_cmp);
        if sorted.windows(2).any(|w| w[0] == w[1]) {
            return Err("history names a time constant twice".into());
        }
    }
    let features = h
        .memory
        .blocks()
        .checked_add(1)
        .and_then(|copies| copies.checked_mul(h.inputs.len()));
    if features != Some(inputs.len()) || h.feature_names() != inputs {
        return Err(format!(
            "history ({} of {}) does not build the model's inputs ({})",
            h.memory,
            h.inputs.join(","),
            inputs.join(",")
        ));
    }
    Ok(())
}
