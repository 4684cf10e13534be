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

use std::collections::HashMap;
use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{Differentiable, Predict};
use crate::data::{self, Columns, DataError, Dataset};

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
    /// `auto`'s screen of time-constant ladders: each scored at the present-input model's
    /// (C, ε) and its σ widened by √(copies of the inputs); the best was searched.
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
}

/// `auto` keeps history when its cross-validated error is lower than the present inputs' by
/// more than this share (more features cost time and an extra column for every user).
pub const AUTO_GAIN: f64 = 0.02;

/// The choice between the present inputs and a history, from their cross-validated fitness:
/// the history when it is lower by more than [`AUTO_GAIN`] (or asked for alone).
pub fn decide(
    tried: Vec<(Option<History>, f64)>,
    screened: Vec<HistoryTrial>,
    asked: &str,
) -> HistoryDecision {
    let trials: Vec<HistoryTrial> = tried
        .iter()
        .map(|(h, fitness)| HistoryTrial {
            memory: h.as_ref().map(|h| h.memory.clone()),
            fitness: *fitness,
        })
        .collect();
    match tried.as_slice() {
        [(None, s), (Some(h), f)] => {
            let kept = *f < s * (1.0 - AUTO_GAIN);
            let verdict = if kept {
                format!(
                    "{} lowers the cross-validated error from {s:.5} to {f:.5}",
                    h.memory
                )
            } else {
                format!(
                    "{} does not lower the cross-validated error by {:.0} % ({s:.5} → {f:.5}): the present inputs alone",
                    h.memory,
                    100.0 * AUTO_GAIN
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
            used: tried.into_iter().next().and_then(|(h, _)| h),
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

/// The time (and group) of each row of a time series.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub time: Vec<f64>,
    /// Each row's group; `None`: one group.
    pub group: Option<Vec<f64>>,
}

/// A group's value (`None`: the only group) and its rows, in time order.
pub type Group = (Option<f64>, Vec<usize>);

/// A group's key (values compared bit for bit; −0 and 0 are one group).
fn key(v: f64) -> u64 {
    (v + 0.0).to_bits()
}

impl Series {
    /// Rows in each group, in order of first appearance, after checking that time increases
    /// within every group.
    ///
    /// # Errors
    /// [`HistoryError::NotIncreasing`] at the first row whose time repeats or goes back.
    pub fn check(&self) -> Result<Vec<Group>, HistoryError> {
        let mut order: Vec<Group> = Vec::new();
        let mut index: HashMap<u64, usize> = HashMap::new();
        for (row, &time) in self.time.iter().enumerate() {
            let g = self.group.as_ref().map(|g| g[row]);
            let slot = *index.entry(g.map_or(0, key)).or_insert_with(|| {
                order.push((g, Vec::new()));
                order.len() - 1
            });
            let rows = &mut order[slot].1;
            if let Some(&last) = rows.last() {
                let previous = self.time[last];
                if time <= previous {
                    return Err(HistoryError::NotIncreasing {
                        row,
                        time,
                        previous,
                        what: if time == previous {
                            "repeats"
                        } else {
                            "goes back from"
                        },
                        group: g,
                    });
                }
            }
            rows.push(row);
        }
        Ok(order)
    }

    /// Ladders of time constants from the data, shortest first: each has [`AUTO_COUNT`]
    /// constants at most, from [`AUTO_FIRST_STEPS`] median sampling intervals up by
    /// [`AUTO_RATIO`], each ladder starting [`AUTO_SHIFT`] times later than the one before; none
    /// longer than half the median group's span (a ladder keeps at least its first; ladders
    /// left alike are given once). [`AUTO_LADDERS`] ladders at most.
    ///
    /// # Errors
    /// As [`Series::check`].
    pub fn time_constant_ladders(&self) -> Result<Vec<Vec<f64>>, HistoryError> {
        let TimeScale { step, span, .. } = self.time_scale()?;
        let mut ladders: Vec<Vec<f64>> = Vec::new();
        for shift in 0..AUTO_LADDERS {
            let first = AUTO_FIRST_STEPS * step * AUTO_SHIFT.powi(shift as i32);
            let ladder: Vec<f64> = (0..AUTO_COUNT)
                .map(|k| round_significant(first * AUTO_RATIO.powi(k as i32)))
                .enumerate()
                .filter(|&(k, tau)| k == 0 || tau <= 0.5 * span)
                .map(|(_, tau)| tau)
                .collect();
            if !ladders.contains(&ladder) && (shift == 0 || ladder[0] <= 0.5 * span) {
                ladders.push(ladder);
            }
        }
        Ok(ladders)
    }
}

/// The series' times at a glance: the median interval between rows, the median and the
/// longest run's span (within groups, time-column units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeScale {
    pub step: f64,
    pub span: f64,
    pub longest: f64,
}

impl Series {
    /// The series' [`TimeScale`].
    ///
    /// # Errors
    /// As [`Series::check`].
    pub fn time_scale(&self) -> Result<TimeScale, HistoryError> {
        let groups = self.check()?;
        let mut steps: Vec<f64> = Vec::new();
        let mut spans: Vec<f64> = Vec::new();
        for (_, rows) in &groups {
            steps.extend(rows.windows(2).map(|w| self.time[w[1]] - self.time[w[0]]));
            spans.push(self.time[*rows.last().expect("a group has rows")] - self.time[rows[0]]);
        }
        let longest = spans.iter().copied().fold(0.0, f64::max);
        Ok(TimeScale {
            step: crate::stats::upper_median(&mut steps).unwrap_or(1.0),
            span: crate::stats::upper_median(&mut spans).unwrap_or(0.0),
            longest,
        })
    }
}

/// Why time constants `tau` cannot see this series' history, when they cannot: far below its
/// sampling (the filter is the input itself) or far beyond its longest run (the filter never
/// leaves its first value). `None` when each lies within [`TAU_REACH`] of them.
pub fn useless_time_constant(tau: &[f64], scale: TimeScale) -> Option<String> {
    let (low, high) = (scale.step / TAU_REACH, scale.longest * TAU_REACH);
    let t = *tau.iter().find(|&&t| t < low || t > high)?;
    let short = |v: f64| {
        if (1e-3..1e6).contains(&v.abs()) {
            round_significant(v).to_string()
        } else {
            format!("{v:.2e}")
        }
    };
    let why = if t < low {
        format!("far below the rows' interval ({})", short(scale.step))
    } else {
        format!("far beyond the longest run ({})", short(scale.longest))
    };
    Some(format!(
        "time constant {} is {why}: its filter {}; give time constants from {} to {} (or ema, from the data)",
        short(t),
        if t < low { "is the input itself" } else { "never moves" },
        short(low),
        short(high)
    ))
}

/// How far (as a factor) a time constant may lie below a series' interval or beyond its
/// longest run ([`useless_time_constant`]).
pub const TAU_REACH: f64 = 100.0;

/// `v` to 3 significant digits (names stay readable: `@ema0.6`, not `@ema0.6000000000000001`).
fn round_significant(v: f64) -> f64 {
    let scale = 10f64.powi(2 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
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
            let mut state = Filters::new(&self.memory, inputs.row(rows[0]));
            let mut last_time = series.time[rows[0]];
            for &row in rows {
                let out = &mut values[row * width..(row + 1) * width];
                let u = inputs.row(row);
                out[..d].copy_from_slice(u);
                state.step(u, series.time[row] - last_time, &mut out[d..]);
                last_time = series.time[row];
            }
        }
        Ok(Columns::new(self.feature_names(), values))
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
        })
    }

    /// Reads the inputs, time and group of a CSV file and builds the features.
    ///
    /// # Errors
    /// [`DataError`]: the file's own, a missing time or group column (saying the model needs
    /// it), or a [`HistoryError`] named by the file line.
    pub fn read_features(&self, path: &Path) -> Result<(Columns, Columns), DataError> {
        let inputs = data::read_columns(path, &self.inputs)?;
        let series = read_series(path, &self.time, self.group.as_deref())?;
        let features = self
            .features(&inputs, &series.0)
            .map_err(|e| series_error(path, &series.1, e))?;
        Ok((inputs, features))
    }
}

/// Reads a file's time column (and group column): the series and each row's file line.
///
/// # Errors
/// [`DataError`]: the file's own; a missing column says that input history needs it.
pub fn read_series(
    path: &Path,
    time: &str,
    group: Option<&str>,
) -> Result<(Series, Vec<u64>), DataError> {
    let needs = |name: &'static str| {
        move |e: DataError| {
            match e {
            DataError::MissingColumn {
                path,
                name: missing,
                available,
            } => DataError::Input {
                path,
                line: 0,
                message: format!(
                    "no column `{missing}`, which the model's input history needs as its {name} (the header has: {available})"
                ),
            },
            e => e,
        }
        }
    };
    let (times, lines) =
        data::read_columns_with_lines(path, &[time.to_string()]).map_err(needs("time"))?;
    let group = group
        .map(|g| data::read_labels(path, g).map_err(needs("group")))
        .transpose()?;
    let series = Series {
        time: times.values,
        group: group.map(|(labels, _)| labels),
    };
    Ok((series, lines))
}

/// A [`HistoryError`] of a file's series, named by the row's file line.
pub fn series_error(path: &Path, lines: &[u64], e: HistoryError) -> DataError {
    DataError::Input {
        path: path.into(),
        line: e.row().map_or(0, |r| lines[r]),
        message: e.to_string(),
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
mod tests {
    use super::*;

    fn history(memory: Memory) -> History {
        History {
            time: "t".into(),
            group: Some("g".into()),
            inputs: vec!["u".into()],
            memory,
        }
    }

    fn one_input(values: &[f64]) -> Columns {
        Columns::new(vec!["u".into()], values.to_vec())
    }

    #[test]
    fn ema_by_hand_per_group_with_irregular_steps() {
        let h = history(Memory::Ema { tau: vec![1.0] });
        // Group 0: a step from 0 to 1 seen at t = 0, 1, 3; group 1 interleaved, held at 5.
        let series = Series {
            time: vec![0.0, 0.0, 1.0, 1.0, 3.0],
            group: Some(vec![0.0, 1.0, 0.0, 1.0, 0.0]),
        };
        let f = h
            .features(&one_input(&[0.0, 5.0, 1.0, 5.0, 1.0]), &series)
            .unwrap();
        assert_eq!(f.names, ["u", "u@ema1"]);
        let e1 = 1.0 - (-1.0f64).exp();
        let e3 = e1 + (1.0 - e1) * (1.0 - (-2.0f64).exp());
        let expected = [0.0, 0.0, 5.0, 5.0, 1.0, e1, 5.0, 5.0, 1.0, e3];
        for (v, e) in f.values.iter().zip(expected) {
            assert!((v - e).abs() < 1e-15, "{:?}", f.values);
        }
    }

    #[test]
    fn lags_start_at_the_first_row() {
        let h = history(Memory::Lags { rows: 2 });
        let series = Series {
            time: vec![0.0, 1.0, 2.0, 3.0],
            group: None,
        };
        let h = History { group: None, ..h };
        let f = h
            .features(&one_input(&[1.0, 2.0, 3.0, 4.0]), &series)
            .unwrap();
        assert_eq!(f.names, ["u", "u@lag1", "u@lag2"]);
        assert_eq!(
            f.values,
            [1.0, 1.0, 1.0, 2.0, 1.0, 1.0, 3.0, 2.0, 1.0, 4.0, 3.0, 2.0]
        );
    }

    #[test]
    fn time_must_increase_within_a_group() {
        let series = Series {
            time: vec![0.0, 1.0, 1.0],
            group: Some(vec![3.0, 3.0, 3.0]),
        };
        let e = series.check().unwrap_err();
        assert_eq!(e.row(), Some(2));
        assert_eq!(
            e.to_string(),
            "time 1 repeats the previous row's 1 in group 3: rows must be in time order within each group"
        );
        // Another group may restart the clock.
        let ok = Series {
            time: vec![0.0, 1.0, 0.0],
            group: Some(vec![3.0, 3.0, 4.0]),
        };
        assert_eq!(ok.check().unwrap().len(), 2);
    }

    #[test]
    fn short_groups_are_refused() {
        let h = history(Memory::Lags { rows: 3 });
        let series = Series {
            time: vec![0.0, 1.0, 2.0, 0.0, 1.0, 2.0, 3.0],
            group: Some(vec![1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0]),
        };
        let e = h
            .features(&one_input(&[0.0, 1.0, 2.0, 0.0, 1.0, 2.0, 3.0]), &series)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "group 1: 3 rows, but lags:3 needs at least 4 per group"
        );
    }

    #[test]
    fn time_constants_follow_the_sampling() {
        let series = Series {
            time: (0..200).map(|i| 0.05 * i as f64).collect(),
            group: None,
        };
        // 0.5 × 0.05 = 0.025, then × 4; each ladder starting × 2 later; nothing longer than
        // half the 9.95 s span.
        assert_eq!(
            series.time_constant_ladders().unwrap(),
            [
                vec![0.025, 0.1, 0.4],
                vec![0.05, 0.2, 0.8],
                vec![0.1, 0.4, 1.6],
                vec![0.2, 0.8, 3.2],
                vec![0.4, 1.6]
            ]
        );
        let short = Series {
            time: vec![0.0, 1.0, 2.0],
            group: None,
        };
        // A 2 s span: constants up to 1 s.
        assert_eq!(
            short.time_constant_ladders().unwrap(),
            [vec![0.5], vec![1.0]]
        );
    }

    #[test]
    fn choices_parse() {
        assert_eq!(
            "ema:0.25,1,4".parse::<HistoryChoice>(),
            Ok(HistoryChoice::Ema(vec![0.25, 1.0, 4.0]))
        );
        assert_eq!("lags:3".parse(), Ok(HistoryChoice::Lags(3)));
        for bad in ["ema:", "ema:-1", "lags:0", "lag:2", "ema:1,x"] {
            assert!(bad.parse::<HistoryChoice>().is_err(), "{bad}");
        }
    }
}
