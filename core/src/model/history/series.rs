//! Time series as the history sees them: rows in groups, in time order, with each group's
//! time scale; read from a file with every line named.

use std::collections::HashMap;
use std::path::Path;

use super::{HistoryError, AUTO_COUNT, AUTO_FIRST_STEPS, AUTO_LADDERS, AUTO_RATIO, AUTO_SHIFT};
use crate::data::{self, Columns, DataError};

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
pub(super) fn key(v: f64) -> u64 {
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
pub(super) fn round_significant(v: f64) -> f64 {
    let scale = 10f64.powi(2 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
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
    let (times, lines) = data::read_columns_with_lines(path, &[time.to_string()])
        .map_err(|e| history_column(e, time, group))?;
    let group = group
        .map(|g| data::read_labels(path, g).map_err(|e| history_column(e, time, Some(g))))
        .transpose()?;
    let series = Series {
        time: times.values,
        group: group.map(|(labels, _)| labels),
    };
    Ok((series, lines))
}

/// A missing time or group column said as what the model's input history needs; other errors
/// as they are.
fn history_column(e: DataError, time: &str, group: Option<&str>) -> DataError {
    let DataError::MissingColumn {
        path,
        name,
        available,
    } = e
    else {
        return e;
    };
    let role = if name == time {
        "time"
    } else if Some(name.as_str()) == group {
        "group"
    } else {
        return DataError::MissingColumn {
            path,
            name,
            available,
        };
    };
    DataError::Input {
        path,
        line: 0,
        message: format!(
            "no column `{name}`, which the model's input history needs as its {role} (the header has: {available})"
        ),
    }
}

/// A file's rows as the history's filters run through them: every row's inputs and time (and
/// group), flagged rows too, whose inputs were in force although their outputs were not seen
/// (a frame without the tip), with each row's file line. Built over these, a filter does not
/// bridge a flagged row and a lag counts it.
#[derive(Clone, Debug, PartialEq)]
pub struct Context {
    pub inputs: Columns,
    pub series: Series,
    pub lines: Vec<u64>,
}

impl Context {
    /// Reads `inputs`, `time` and `group` of every row of `path`, flagged rows included.
    ///
    /// # Errors
    /// As [`read_series`].
    pub fn read(
        path: &Path,
        inputs: &[String],
        time: &str,
        group: Option<&str>,
    ) -> Result<Context, DataError> {
        let names: Vec<String> = inputs.iter().cloned().chain([time.to_string()]).collect();
        let every = data::read_through_flags(path, &names, group)
            .map_err(|e| history_column(e, time, group))?;
        let d = inputs.len();
        let mut values = Vec::with_capacity(every.lines.len() * d);
        let mut time = Vec::with_capacity(every.lines.len());
        for row in every.columns.values.chunks_exact(d + 1) {
            values.extend_from_slice(&row[..d]);
            time.push(row[d]);
        }
        Ok(Context {
            inputs: Columns::new(inputs.to_vec(), values),
            series: Series {
                time,
                group: every.labels,
            },
            lines: every.lines,
        })
    }

    /// The rows of the context at file lines `lines` (increasing, each one of the context's).
    ///
    /// # Panics
    /// If a line is not one of the context's rows.
    pub fn rows_at(&self, lines: &[u64]) -> Vec<usize> {
        let mut at = 0;
        lines
            .iter()
            .map(|line| {
                at += self.lines[at..]
                    .iter()
                    .position(|l| l == line)
                    .expect("every line read is in the context");
                at
            })
            .collect()
    }
}

/// A [`HistoryError`] of a file's series, named by the row's file line.
pub fn series_error(path: &Path, lines: &[u64], e: HistoryError) -> DataError {
    DataError::Input {
        path: path.into(),
        line: e.row().map_or(0, |r| lines[r]),
        message: e.to_string(),
    }
}
