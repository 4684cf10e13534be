//! Input history for time series: features of the inputs' past in front of any model.
//!
//! Pneumatic muscles, tendons and soft trunks lag and hysterese: the tip at a pressure depends
//! on how the pressure got there. A model of the present inputs alone cannot say that; one that
//! also sees each input's recent past can. [`History`] turns the inputs of a time series (rows
//! in time order within each group: a run, a ramp, a trial) into the present inputs followed by
//! one block of the same width per memory feature:
//! - `ema`: exponentially filtered copies, `f ← f + (1 − e^(−Δt/τ)) (u − f)` for each time
//!   constant τ (seconds, or whatever unit the time column has), started at the group's first
//!   input (as if it had been held long before). Irregular sampling is handled by Δt, so a
//!   decimated training log and a dense test log give the same filters.
//! - `lags`: the inputs K rows back (the group's first row before its start): plain, but tied to
//!   the sampling rate, so train and use at one rate.
//!
//! Features are named `<input>@ema<τ>` and `<input>@lag<k>`. Inputs outside a time series
//! (the inverse, a controller's set point) use the steady state, where every filter and lag
//! equals the input ([`SteadyState`]).

mod series;

use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::msvr::MsvrParams;
use super::{Differentiable, Predict};
use crate::data::{self, Columns, DataError, Dataset};
pub use series::{
    read_series, series_error, useless_time_constant, Context, Series, TimeScale, TAU_REACH,
};

/// The first automatic time constant, in median sampling intervals: half of one, so the first
/// filter mostly holds the previous input (the direction of approach, which hysteresis
/// depends on).
pub const AUTO_FIRST_STEPS: f64 = 0.5;
/// The ratio between successive automatic time constants.
pub const AUTO_RATIO: f64 = 4.0;
/// Automatic time constants in a ladder at most (fewer when a group is short).
pub const AUTO_COUNT: usize = 3;
/// Ladders `auto` screens: slow actuators (a trunk's seconds of lag at 12 Hz) need the longer
/// ones, settled steps the shortest.
pub const AUTO_LADDERS: usize = 5;
/// The ratio between successive ladders' first constants: half of [`AUTO_RATIO`]'s steps, so a
/// lag between two of one ladder's constants meets one of the next's.
pub const AUTO_SHIFT: f64 = 2.0;

/// Errors of a time series that history cannot be built on (rows are 0-based).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum HistoryError {
    #[error("time {time} {what} the previous row's {previous}{}: rows must be in time order within each group", in_group(*group))]
    NotIncreasing {
        row: usize,
        time: f64,
        previous: f64,
        what: &'static str,
        group: Option<f64>,
    },
    #[error("{}{rows} rows, but {memory} needs at least {needed} per group", group.map_or_else(String::new, |g| format!("group {g}: ")))]
    TooShort {
        group: Option<f64>,
        rows: usize,
        memory: String,
        needed: usize,
    },
    #[error("{what}: {given} rows, but the inputs have {rows}")]
    Length {
        what: &'static str,
        given: usize,
        rows: usize,
    },
    #[error("inputs are ({found}) but the history was built on ({expected})")]
    Inputs { expected: String, found: String },
}

impl HistoryError {
    /// The row the error is about, when it is one row's.
    pub fn row(&self) -> Option<usize> {
        match self {
            HistoryError::NotIncreasing { row, .. } => Some(*row),
            _ => None,
        }
    }
}

fn in_group(group: Option<f64>) -> String {
    group.map_or_else(
        || " (several runs one after another: give each row its run, groups=…)".into(),
        |g| format!(" in group {g}"),
    )
}

/// What the features remember of the past.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Memory {
    /// Exponentially filtered copies with these time constants (time-column units).
    Ema { tau: Vec<f64> },
    /// The inputs 1..=rows rows back.
    Lags { rows: usize },
}

impl Memory {
    /// Feature blocks beyond the present inputs.
    pub fn blocks(&self) -> usize {
        match self {
            Memory::Ema { tau } => tau.len(),
            Memory::Lags { rows } => *rows,
        }
    }

    fn suffixes(&self) -> Vec<String> {
        match self {
            Memory::Ema { tau } => tau.iter().map(|t| format!("@ema{t}")).collect(),
            Memory::Lags { rows } => (1..=*rows).map(|k| format!("@lag{k}")).collect(),
        }
    }

    /// Rows each group needs: one past the longest lag; two for filters (one row has no past).
    fn rows_needed(&self) -> usize {
        match self {
            Memory::Ema { .. } => 2,
            Memory::Lags { rows } => rows + 1,
        }
    }
}

impl fmt::Display for Memory {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            Memory::Ema { tau } => {
                let t: Vec<String> = tau.iter().map(f64::to_string).collect();
                write!(f, "ema:{}", t.join(","))
            }
            Memory::Lags { rows } => write!(f, "lags:{rows}"),
        }
    }
}

/// What `--history` asks for.
#[derive(Clone, Debug, PartialEq)]
pub enum HistoryChoice {
    /// Filtered copies with time constants from the data, kept only if cross-validation says
    /// they help.
    Auto,
    None,
    /// Filtered copies with these time constants, or from the data when empty.
    Ema(Vec<f64>),
    Lags(usize),
}

impl HistoryChoice {
    /// The choice of exactly `memory` (`None`: no history): a model's own, fitted again.
    pub fn of(memory: Option<&Memory>) -> HistoryChoice {
        match memory {
            None => HistoryChoice::None,
            Some(Memory::Ema { tau }) => HistoryChoice::Ema(tau.clone()),
            Some(Memory::Lags { rows }) => HistoryChoice::Lags(*rows),
        }
    }
}

impl std::str::FromStr for HistoryChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || {
            format!("`{s}`: give auto, none, ema (time constants from the data), ema:τ1,τ2,… (positive, in the time column's unit) or lags:K (K ≥ 1)")
        };
        match s {
            "auto" => Ok(HistoryChoice::Auto),
            "none" => Ok(HistoryChoice::None),
            "ema" => Ok(HistoryChoice::Ema(Vec::new())),
            _ => {
                if let Some(list) = s.strip_prefix("ema:") {
                    let tau: Vec<f64> = list
                        .split(',')
                        .map(|t| t.trim().parse::<f64>())
                        .collect::<Result<_, _>>()
                        .map_err(|_| bad())?;
                    if tau.is_empty() || tau.iter().any(|t| !(t.is_finite() && *t > 0.0)) {
                        return Err(bad());
                    }
                    if let Some(t) = tau
                        .iter()
                        .enumerate()
                        .find_map(|(k, t)| tau[..k].contains(t).then_some(t))
                    {
                        return Err(format!(
                            "`{s}`: time constant {t} is given twice; each gives one filtered copy"
                        ));
                    }
                    Ok(HistoryChoice::Ema(tau))
                } else if let Some(k) = s.strip_prefix("lags:") {
                    match k.trim().parse::<usize>() {
                        Ok(k) if k >= 1 => Ok(HistoryChoice::Lags(k)),
                        _ => Err(bad()),
                    }
                } else {
                    Err(bad())
                }
            }
        }
    }
}

/// Whether a model sees its inputs' history, and why: the log, the report and the model file
/// say it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HistoryDecision {
    /// The features the model was fitted on; `None`: the present inputs alone.
    pub used: Option<History>,
    pub reason: String,
    /// Each feature set searched on the same folds (the present inputs first).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tried: Vec<HistoryTrial>,
    /// `auto`'s screen of time-constant ladders: each scored on a small grid around the
    /// present-input model's (C, ε, σ), σ widened by √(copies of the inputs), at its best
    /// point; the best ladder was searched.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub screened: Vec<HistoryTrial>,
}

/// One feature set `auto` scored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HistoryTrial {
    /// `None`: the present inputs alone.
    pub memory: Option<Memory>,
    /// The best cross-validated fitness of its search (or of the given parameters).
    pub fitness: f64,
    /// The (C, ε, σ) its search chose (or it was screened at); absent in files written
    /// before they were kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub params: Option<MsvrParams>,
}

/// `auto` keeps history when its cross-validated error is lower than the present inputs' by
/// more than this share (more features cost time and an extra column for every user).
pub const AUTO_GAIN: f64 = 0.02;

/// The choice between the present inputs and a history, from their cross-validated fitness:
/// the history when it is lower by more than [`AUTO_GAIN`] and by more than one standard error
/// of the paired fold differences, `paired` (the present inputs' error less the history's, and
/// its standard error; `None` when the folds' errors are not known): a near-tie goes to the
/// present inputs, the simpler model. A history asked for alone is used.
pub fn decide(
    tried: Vec<(Option<History>, f64, MsvrParams)>,
    screened: Vec<HistoryTrial>,
    asked: &str,
    paired: Option<(f64, f64)>,
) -> HistoryDecision {
    let trials: Vec<HistoryTrial> = tried
        .iter()
        .map(|(h, fitness, params)| HistoryTrial {
            memory: h.as_ref().map(|h| h.memory.clone()),
            fitness: *fitness,
            params: Some(*params),
        })
        .collect();
    match tried.as_slice() {
        [(None, s, _), (Some(h), f, _)] => {
            let gains = *f < s * (1.0 - AUTO_GAIN);
            let (margin, se) = paired.unwrap_or((s - f, 0.0));
            let kept = gains && margin > se;
            let verdict = if kept {
                format!(
                    "{} lowers the cross-validated error from {s:.5} to {f:.5} (by {margin:.5}, more than one standard error, {se:.5})",
                    h.memory
                )
            } else if !gains {
                format!(
                    "{} does not lower the cross-validated error by {:.0} % ({s:.5} → {f:.5}): the present inputs alone",
                    h.memory,
                    100.0 * AUTO_GAIN
                )
            } else {
                format!(
                    "{} lowers the cross-validated error from {s:.5} to {f:.5}, by {margin:.5}, within one standard error of the paired fold differences ({se:.5}): the present inputs alone, the simpler",
                    h.memory
                )
            };
            HistoryDecision {
                used: kept.then(|| h.clone()),
                reason: format!("{asked}: {verdict}"),
                tried: trials,
                screened,
            }
        }
        _ => HistoryDecision {
            used: tried.into_iter().next().and_then(|(h, ..)| h),
            reason: asked.to_string(),
            tried: Vec::new(),
            screened,
        },
    }
}

impl fmt::Display for HistoryChoice {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            HistoryChoice::Auto => write!(f, "auto"),
            HistoryChoice::None => write!(f, "none"),
            HistoryChoice::Ema(tau) if tau.is_empty() => write!(f, "ema"),
            HistoryChoice::Ema(tau) => write!(f, "{}", Memory::Ema { tau: tau.clone() }),
            HistoryChoice::Lags(rows) => write!(f, "{}", Memory::Lags { rows: *rows }),
        }
    }
}

/// The history features of a model: which columns give time and group, and what is remembered.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct History {
    /// The time column (rows in increasing time within each group).
    pub time: String,
    /// The column whose values name the groups (runs, ramps, trials); `None`: one series.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
    /// The inputs the features are built from, in order.
    pub inputs: Vec<String>,
    pub memory: Memory,
}

impl History {
    /// The model's input names: the inputs, then each memory block's.
    pub fn feature_names(&self) -> Vec<String> {
        let mut names = self.inputs.clone();
        for suffix in self.memory.suffixes() {
            names.extend(self.inputs.iter().map(|n| format!("{n}{suffix}")));
        }
        names
    }

    /// The features of `inputs` (rows of a time series in `series`): each row's inputs followed
    /// by each memory block.
    ///
    /// # Errors
    /// [`HistoryError`]: time not increasing within a group, a group too short for the memory,
    /// columns other than [`History::inputs`], or lengths that differ.
    pub fn features(&self, inputs: &Columns, series: &Series) -> Result<Columns, HistoryError> {
        if inputs.names != self.inputs {
            return Err(HistoryError::Inputs {
                expected: self.inputs.join(","),
                found: inputs.names_list(),
            });
        }
        let n = inputs.rows();
        for (what, given) in [
            ("time", Some(series.time.len())),
            ("group", series.group.as_ref().map(Vec::len)),
        ] {
            if let Some(given) = given.filter(|&g| g != n) {
                return Err(HistoryError::Length {
                    what,
                    given,
                    rows: n,
                });
            }
        }
        let groups = series.check()?;
        let needed = self.memory.rows_needed();
        if let Some((group, rows)) = groups.iter().find(|(_, rows)| rows.len() < needed) {
            return Err(HistoryError::TooShort {
                group: *group,
                rows: rows.len(),
                memory: self.memory.to_string(),
                needed,
            });
        }
        let d = inputs.width();
        let width = d * (1 + self.memory.blocks());
        let mut values = vec![0.0; n * width];
        for (_, rows) in &groups {
            let mut running = self.running(inputs.row(rows[0]), series.time[rows[0]]);
            for &row in rows {
                let out = &mut values[row * width..(row + 1) * width];
                running.step(inputs.row(row), series.time[row], out);
            }
        }
        Ok(Columns::new(self.feature_names(), values))
    }

    /// The features of a series as its rows come (a live session), the memory starting at
    /// the inputs `first` at `time` as [`History::features`] starts each group.
    pub fn running(&self, first: &[f64], time: f64) -> Running {
        Running {
            filters: Filters::new(&self.memory, first),
            last_time: time,
        }
    }

    /// A dataset's inputs replaced by their features.
    ///
    /// # Errors
    /// As [`History::features`].
    pub fn dataset(&self, raw: &Dataset, series: &Series) -> Result<Dataset, HistoryError> {
        Ok(Dataset {
            source: raw.source.clone(),
            inputs: self.features(&raw.inputs, series)?,
            outputs: raw.outputs.clone(),
            weights: raw.weights.clone(),
        })
    }

    /// The features of a file's rows at `lines` (those a model sees), built over every row of
    /// its `context`, flagged rows included.
    ///
    /// # Errors
    /// As [`History::features`], about the context's rows.
    pub fn features_at(&self, context: &Context, lines: &[u64]) -> Result<Columns, HistoryError> {
        let all = self.features(&context.inputs, &context.series)?;
        let rows = context.rows_at(lines);
        let width = all.width();
        let values = rows
            .iter()
            .flat_map(|&r| all.values[r * width..(r + 1) * width].iter().copied())
            .collect();
        Ok(Columns::new(all.names, values))
    }

    /// Reads the inputs, time and group of a CSV file and builds the features of its
    /// unflagged rows, through the flagged ones.
    ///
    /// # Errors
    /// [`DataError`]: the file's own, a missing time or group column (saying the model needs
    /// it), or a [`HistoryError`] named by the file line.
    pub fn read_features(&self, path: &Path) -> Result<(Columns, Columns), DataError> {
        let (inputs, lines) = data::read_columns_with_lines(path, &self.inputs)?;
        let context = Context::read(path, &self.inputs, &self.time, self.group.as_deref())?;
        let features = self
            .features_at(&context, &lines)
            .map_err(|e| series_error(path, &context.lines, e))?;
        Ok((inputs, features))
    }
}

/// A series' features as its rows come ([`History::running`]).
pub struct Running {
    filters: Filters,
    last_time: f64,
}

impl Running {
    /// The next row's inputs `u` at `time` (not before the last): writes its features (the
    /// inputs, then each memory block) into `out`.
    pub fn step(&mut self, u: &[f64], time: f64, out: &mut [f64]) {
        let d = u.len();
        out[..d].copy_from_slice(u);
        self.filters.step(u, time - self.last_time, &mut out[d..]);
        self.last_time = time;
    }
}

/// One group's running memory.
enum Filters {
    Ema {
        tau: Vec<f64>,
        /// `tau.len() × d`, block by block.
        state: Vec<f64>,
    },
    Lags {
        /// The last `rows` inputs, newest first.
        past: std::collections::VecDeque<Vec<f64>>,
    },
}

impl Filters {
    fn new(memory: &Memory, first: &[f64]) -> Self {
        match memory {
            Memory::Ema { tau } => Filters::Ema {
                tau: tau.clone(),
                state: first.repeat(tau.len()),
            },
            Memory::Lags { rows } => Filters::Lags {
                past: std::iter::repeat_n(first.to_vec(), *rows).collect(),
            },
        }
    }

    /// Takes the input `u`, `dt` after the previous one, and writes the memory blocks.
    fn step(&mut self, u: &[f64], dt: f64, out: &mut [f64]) {
        let d = u.len();
        match self {
            Filters::Ema { tau, state } => {
                for (block, &t) in state.chunks_exact_mut(d).zip(tau.iter()) {
                    let gain = 1.0 - (-dt / t).exp();
                    for (f, &x) in block.iter_mut().zip(u) {
                        *f += gain * (x - *f);
                    }
                }
                out.copy_from_slice(state);
            }
            Filters::Lags { past } => {
                for (block, lagged) in out.chunks_exact_mut(d).zip(past.iter()) {
                    block.copy_from_slice(lagged);
                }
                past.pop_back();
                past.push_front(u.to_vec());
            }
        }
    }
}

/// A model seen at rest: every filter and lag of its history (if it has one) equal to the
/// input, so the map from the present inputs alone (for the inverse, and any input without a
/// past).
pub struct SteadyState<'a> {
    model: &'a dyn Differentiable,
    inputs: &'a [String],
    /// Copies of the inputs the model sees (1 + memory blocks).
    copies: usize,
}

impl<'a> SteadyState<'a> {
    /// `history`: the one the model was fitted on; `None`, the model as it is.
    ///
    /// # Panics
    /// If the model's inputs are not `history`'s features.
    pub fn new(model: &'a dyn Differentiable, history: Option<&'a History>) -> Self {
        let Some(history) = history else {
            return SteadyState {
                model,
                inputs: model.inputs(),
                copies: 1,
            };
        };
        assert_eq!(
            model.inputs(),
            history.feature_names(),
            "the model was not fitted on this history's features"
        );
        SteadyState {
            model,
            inputs: &history.inputs,
            copies: 1 + history.memory.blocks(),
        }
    }

    /// The model's own inputs at rows of present inputs `x`: each row with its filters and
    /// lags equal to it.
    pub fn features(&self, x: &Columns) -> Columns {
        Columns::new(
            self.model.inputs().to_vec(),
            x.iter_rows()
                .flat_map(|row| row.repeat(self.copies))
                .collect(),
        )
    }
}

impl Predict for SteadyState<'_> {
    fn inputs(&self) -> &[String] {
        self.inputs
    }

    fn outputs(&self) -> &[String] {
        self.model.outputs()
    }

    fn predict_row(&self, x: &[f64], out: &mut [f64]) {
        if self.copies == 1 {
            return self.model.predict_row(x, out);
        }
        self.model.predict_row(&x.repeat(self.copies), out);
    }

    /// The present inputs' range (the filtered copies lie inside it).
    fn training_range(&self) -> Option<(&[f64], &[f64])> {
        let d = self.inputs.len();
        self.model
            .training_range()
            .map(|(min, max)| (&min[..d], &max[..d]))
    }
}

impl Differentiable for SteadyState<'_> {
    fn predict_with_jacobian(&self, x: &[f64], out: &mut [f64], jacobian: &mut [f64]) {
        if self.copies == 1 {
            return self.model.predict_with_jacobian(x, out, jacobian);
        }
        let (d, q) = (x.len(), out.len());
        let mut full = vec![0.0; q * d * self.copies];
        self.model
            .predict_with_jacobian(&x.repeat(self.copies), out, &mut full);
        // ∂f/∂u = Σ over copies of ∂f/∂(copy), every copy being u.
        for (i, row) in full.chunks_exact(d * self.copies).enumerate() {
            let target = &mut jacobian[i * d..(i + 1) * d];
            target.fill(0.0);
            for block in row.chunks_exact(d) {
                for (t, v) in target.iter_mut().zip(block) {
                    *t += v;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
