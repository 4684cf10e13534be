//! The regulator's log, `pressures.csv`: one row per commanded step, `time_s` (when the
//! command was given, on the capture computer's clock), `P1_kpa,P2_kpa,P3_kpa`, optionally
//! `command_end_s` (when the command returned), optionally `hold_s` (how long the protocol
//! held it), and any other columns (e.g. `step`, `phase`), which are copied to the dataset. A
//! step lasts until the next row; the last one its `hold_s`, or the log's median step where the
//! log does not say. `capture` and `synth` write it ([`pressures_csv`]), `triangulate` reads
//! it ([`read_pressure_log`]).

use std::path::{Path, PathBuf};

use super::SessionError;
use crate::data::{Csv, Table};

/// One commanded step of the log.
#[derive(Clone, Debug, PartialEq)]
pub struct LogStep {
    pub time_s: f64,
    /// When the regulator's command returned ([`COMMAND_END_COLUMN`]; `time_s` when the log
    /// does not say): settling counts from here.
    pub command_end_s: f64,
    /// How long the protocol held it ([`HOLD_COLUMN`]), when the log says.
    pub hold_s: Option<f64>,
    pub pressures_kpa: [f64; 3],
    /// The row's other columns, as written.
    pub extra: Vec<String>,
}

/// The regulator's log.
#[derive(Clone, Debug, PartialEq)]
pub struct PressureLog {
    pub path: PathBuf,
    pub steps: Vec<LogStep>,
    /// Names of the other columns, in order.
    pub extra_columns: Vec<String>,
    /// The median time between consecutive steps (s).
    pub median_step_s: f64,
}

impl PressureLog {
    /// The step in force at `t` (`None` before the first command or after the last step).
    pub fn step_at(&self, t: f64) -> Option<usize> {
        let k = self
            .steps
            .partition_point(|s| s.time_s <= t)
            .checked_sub(1)?;
        (t < self.end_s(k)).then_some(k)
    }

    /// When step `k` ends: the next command, or its hold after the last one.
    pub fn end_s(&self, k: usize) -> f64 {
        self.steps
            .get(k + 1)
            .map_or(self.steps[k].time_s + self.last_hold_s(), |s| s.time_s)
    }

    /// How long step `k` was meant to hold: its `hold_s`, or the log's median step where the
    /// log does not say.
    pub fn planned_s(&self, k: usize) -> f64 {
        self.steps[k].hold_s.unwrap_or(self.median_step_s)
    }

    /// How long the last step was held ([`Self::planned_s`]).
    fn last_hold_s(&self) -> f64 {
        self.planned_s(self.steps.len() - 1)
    }

    /// When the regulator holds step `k`'s pressures: from its command's return (its start,
    /// when the log does not say) to the next command's return (or the last step's hold after
    /// its return). A regulator that takes 175 ms to answer starts moving the finger then, not when
    /// it was told.
    pub fn held_s(&self, k: usize) -> (f64, f64) {
        let start = self.steps[k].command_end_s;
        let end = self
            .steps
            .get(k + 1)
            .map_or(start + self.last_hold_s(), |s| s.command_end_s);
        (start, end)
    }
}

/// The pressure columns of a log.
pub const PRESSURE_COLUMNS: [&str; 3] = ["P1_kpa", "P2_kpa", "P3_kpa"];
/// The optional column of when each step's command returned (s, the log's clock), as
/// `handcap capture` writes it.
pub const COMMAND_END_COLUMN: &str = "command_end_s";
/// The optional column of how long the protocol held each step (s): the log's last row says
/// when the session's commands ended.
pub const HOLD_COLUMN: &str = "hold_s";

/// Reads the log.
///
/// # Errors
/// [`DataError::Input`](crate::data::DataError::Input) naming the file and line: a missing column, a bad number, times
/// that do not increase, fewer than two steps.
pub fn read_pressure_log(path: &Path) -> Result<PressureLog, SessionError> {
    let table = Table::open(path, "time_s,P1_kpa,P2_kpa,P3_kpa")?;
    let time_col = table.column("time_s")?;
    let p_cols = [
        table.column(PRESSURE_COLUMNS[0])?,
        table.column(PRESSURE_COLUMNS[1])?,
        table.column(PRESSURE_COLUMNS[2])?,
    ];
    let header = table.header.clone();
    let end_col = header.iter().position(|h| h == COMMAND_END_COLUMN);
    let hold_col = header.iter().position(|h| h == HOLD_COLUMN);
    let extra_idx: Vec<usize> = (0..header.len())
        .filter(|&i| {
            i != time_col && !p_cols.contains(&i) && ![end_col, hold_col].contains(&Some(i))
        })
        .collect();
    let mut steps: Vec<LogStep> = Vec::new();
    for (line, record) in table.records()? {
        let number = |col: usize| -> Result<f64, SessionError> {
            record[col]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    table
                        .bad(
                            line,
                            format!("{} {:?} is not a number", &header[col], &record[col]),
                        )
                        .into()
                })
        };
        let time_s = number(time_col)?;
        if let Some(prev) = steps.last() {
            if time_s <= prev.time_s {
                return table.fail(
                    line,
                    format!(
                        "time_s {time_s} is not after the previous row's {}; sort the log by time",
                        prev.time_s
                    ),
                );
            }
        }
        let command_end_s = match end_col {
            Some(col) => {
                let end = number(col)?;
                if end < time_s {
                    return table.fail(
                        line,
                        format!(
                            "{COMMAND_END_COLUMN} {end} is before the command's time_s {time_s}"
                        ),
                    );
                }
                end
            }
            None => time_s,
        };
        let hold_s = match hold_col {
            Some(col) => match number(col)? {
                hold if hold > 0.0 => Some(hold),
                hold => {
                    return table.fail(line, format!("{HOLD_COLUMN} {hold} must be more than 0"))
                }
            },
            None => None,
        };
        steps.push(LogStep {
            time_s,
            command_end_s,
            hold_s,
            pressures_kpa: [number(p_cols[0])?, number(p_cols[1])?, number(p_cols[2])?],
            extra: extra_idx.iter().map(|&i| record[i].to_string()).collect(),
        });
    }
    if steps.len() < 2 {
        return table.fail(0, "fewer than two steps logged".into());
    }
    let mut gaps: Vec<f64> = steps
        .windows(2)
        .map(|w| w[1].time_s - w[0].time_s)
        .collect();
    let median_step_s = crate::stats::upper_median(&mut gaps).expect("two steps or more");
    Ok(PressureLog {
        path: path.to_path_buf(),
        steps,
        extra_columns: extra_idx.iter().map(|&i| header[i].to_string()).collect(),
        median_step_s,
    })
}

/// One row of the log as written: `phase`, `step` and the protocol's `hold_s` go in their
/// columns, `command_end_s` when the command's return was recorded.
pub struct Logged<'a> {
    pub time_s: f64,
    pub command_end_s: Option<f64>,
    pub hold_s: f64,
    pub pressures_kpa: [f64; 3],
    pub step: usize,
    pub phase: &'a str,
    /// What a streaming regulator measured while this command held (`Some(None)`: nothing;
    /// `None`: no such columns in the log).
    pub measured_kpa: Option<Option<[f64; 3]>>,
}

/// `pressures.csv` of `rows`; the `command_end_s` column when the first row has it, the
/// measured pressures' columns ([`MEASURED_COLUMNS`]) when it has those.
pub fn pressures_csv<'a>(rows: impl IntoIterator<Item = Logged<'a>>) -> String {
    let mut rows = rows.into_iter().peekable();
    let with_end = rows.peek().is_some_and(|r| r.command_end_s.is_some());
    let with_measured = rows.peek().is_some_and(|r| r.measured_kpa.is_some());
    let mut header = vec!["time_s"];
    header.extend(PRESSURE_COLUMNS);
    header.extend(["step", "phase", HOLD_COLUMN]);
    header.extend(with_end.then_some(COMMAND_END_COLUMN));
    header.extend(MEASURED_COLUMNS.iter().filter(|_| with_measured));
    let mut csv = Csv::new(header);
    for r in rows {
        let mut row = vec![format!("{:.6}", r.time_s)];
        row.extend(r.pressures_kpa.map(|p| p.to_string()));
        row.extend([
            r.step.to_string(),
            r.phase.to_string(),
            r.hold_s.to_string(),
        ]);
        if with_end {
            row.push(
                r.command_end_s
                    .map_or_else(String::new, |end| format!("{end:.6}")),
            );
        }
        if with_measured {
            match r.measured_kpa.flatten() {
                Some(m) => row.extend(m.map(|p| p.to_string())),
                None => row.extend([String::new(), String::new(), String::new()]),
            }
        }
        csv.row(row);
    }
    csv.into_string()
}

/// The columns of what a streaming regulator measured while each command held (kPa).
pub const MEASURED_COLUMNS: [&str; 3] = ["P1_measured_kpa", "P2_measured_kpa", "P3_measured_kpa"];
