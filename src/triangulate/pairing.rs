//! Time: left and right frames into pairs, pairs into the pressure steps of the regulator's log.
//!
//! - The log (`pressures.csv`) has one row per commanded step: `time_s` (when the command was
//!   given, on the capture computer's clock), `P1_kpa,P2_kpa,P3_kpa`, and any other columns
//!   (e.g. `step`, `phase`), which are copied to the dataset. A step lasts until the next row;
//!   the last one lasts the log's median step.
//! - Frames pair by timestamp: a left and a right frame pair when each is the other's nearest
//!   and they are at most `max_dt_s` apart. A frame without such a partner stays unpaired.
//! - A pair belongs to the step active at its earlier frame, if its later frame is before the
//!   next step (by a guard, when the times were corrected for the cameras' delays: see
//!   [`super::latency`]) and its earlier frame at least `settle_s` after the step's command
//!   returned (`command_end_s`, when the log has it; else its time).

use std::path::{Path, PathBuf};

use super::frames::FrameRecord;
use super::TriangulateError;
use crate::data::Table;
use crate::stereo::Side;

/// One commanded step of the log.
#[derive(Clone, Debug, PartialEq)]
pub struct LogStep {
    pub time_s: f64,
    /// When the regulator's command returned ([`COMMAND_END_COLUMN`]; `time_s` when the log
    /// does not say): settling counts from here.
    pub command_end_s: f64,
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
    /// When step `k` ends: the next command, or the median step after the last one.
    pub fn end_s(&self, k: usize) -> f64 {
        self.steps
            .get(k + 1)
            .map_or(self.steps[k].time_s + self.median_step_s, |s| s.time_s)
    }
}

/// The pressure columns of a log.
pub const PRESSURE_COLUMNS: [&str; 3] = ["P1_kpa", "P2_kpa", "P3_kpa"];
/// The optional column of when each step's command returned (s, the log's clock), as
/// `handcap capture` writes it.
pub const COMMAND_END_COLUMN: &str = "command_end_s";

/// Reads the log.
///
/// # Errors
/// [`DataError::Input`](crate::data::DataError::Input) naming the file and line: a missing column, a bad number, times
/// that do not increase, fewer than two steps.
pub fn read_pressure_log(path: &Path) -> Result<PressureLog, TriangulateError> {
    let mut table = Table::open(path, "time_s,P1_kpa,P2_kpa,P3_kpa")?;
    let time_col = table.column("time_s")?;
    let p_cols = [
        table.column(PRESSURE_COLUMNS[0])?,
        table.column(PRESSURE_COLUMNS[1])?,
        table.column(PRESSURE_COLUMNS[2])?,
    ];
    let header = table.header.clone();
    let end_col = header.iter().position(|h| h == COMMAND_END_COLUMN);
    let extra_idx: Vec<usize> = (0..header.len())
        .filter(|i| *i != time_col && !p_cols.contains(i) && Some(*i) != end_col)
        .collect();
    let mut steps: Vec<LogStep> = Vec::new();
    for (line, record) in table.records()? {
        let number = |col: usize| -> Result<f64, TriangulateError> {
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
        steps.push(LogStep {
            time_s,
            command_end_s,
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

/// Left and right frames paired by time: indices into the frame list.
#[derive(Clone, Debug, PartialEq)]
pub struct Pairing {
    pub pairs: Vec<(usize, usize)>,
    /// Frames of each camera with no partner (left, right).
    pub unpaired: [usize; 2],
}

/// Pairs each left frame with the right frame nearest in time when that right frame's nearest
/// left frame is it, and they are at most `max_dt_s` apart; frames stamped late take no part.
/// Pairs come in time order.
pub fn pair_frames(frames: &[FrameRecord], max_dt_s: f64) -> Pairing {
    let by_time = |side: Side| {
        let mut v: Vec<usize> = (0..frames.len())
            .filter(|&i| frames[i].camera == side && frames[i].late_s.is_none())
            .collect();
        v.sort_by(|&a, &b| frames[a].time_s.total_cmp(&frames[b].time_s));
        v
    };
    let (left, right) = (by_time(Side::Left), by_time(Side::Right));
    let nearest = |to: f64, among: &[usize]| -> Option<usize> {
        let k = among.partition_point(|&i| frames[i].time_s < to);
        [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter(|&j| j < among.len())
            .min_by(|&a, &b| {
                (frames[among[a]].time_s - to)
                    .abs()
                    .total_cmp(&(frames[among[b]].time_s - to).abs())
            })
    };
    let mut pairs = Vec::new();
    for &l in &left {
        let Some(r) = nearest(frames[l].time_s, &right) else {
            continue;
        };
        let r = right[r];
        let back = nearest(frames[r].time_s, &left).map(|k| left[k]);
        if back == Some(l) && (frames[l].time_s - frames[r].time_s).abs() <= max_dt_s {
            pairs.push((l, r));
        }
    }
    Pairing {
        unpaired: [left.len() - pairs.len(), right.len() - pairs.len()],
        pairs,
    }
}

/// Where a pair of timestamps falls in the log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    Step(usize),
    /// Before the first command or after the last step.
    OutsideLog,
    /// Earlier than `settle_s` after its step's command returned.
    Settling,
    /// Its frames fall in different steps, or so near the next command that the tip may
    /// already move.
    Straddles,
}

/// The step a pair with times `a`, `b` belongs to; a pair later than `guard_s` before the next
/// command straddles (its frames may show the next step's motion).
pub fn place(log: &PressureLog, a: f64, b: f64, settle_s: f64, guard_s: f64) -> Placement {
    let (first, last) = (a.min(b), a.max(b));
    let k = log.steps.partition_point(|s| s.time_s <= first);
    let Some(k) = k.checked_sub(1) else {
        return Placement::OutsideLog;
    };
    let end = log.end_s(k);
    if first >= end {
        Placement::OutsideLog
    } else if last >= end - guard_s {
        Placement::Straddles
    } else if first - log.steps[k].command_end_s < settle_s {
        Placement::Settling
    } else {
        Placement::Step(k)
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    pub(in crate::triangulate) fn frame(camera: Side, index: usize, time_s: f64) -> FrameRecord {
        FrameRecord {
            camera,
            index,
            time_s,
            line: 0,
            late_s: None,
        }
    }

    #[test]
    fn frames_pair_with_their_mutual_nearest_within_the_tolerance() {
        let f = vec![
            frame(Side::Left, 0, 0.100),
            frame(Side::Left, 1, 0.133),
            frame(Side::Left, 2, 0.166),
            frame(Side::Left, 3, 0.500), // its right partner was dropped
            frame(Side::Right, 0, 0.108),
            frame(Side::Right, 1, 0.141),
            frame(Side::Right, 2, 0.175),
            frame(Side::Right, 3, 0.540), // 40 ms from the nearest left frame
        ];
        let p = pair_frames(&f, 0.02);
        assert_eq!(p.pairs, vec![(0, 4), (1, 5), (2, 6)]);
        assert_eq!(p.unpaired, [1, 1]);
        // Two left frames near one right frame: only the nearer pairs.
        let f = vec![
            frame(Side::Left, 0, 0.100),
            frame(Side::Left, 1, 0.104),
            frame(Side::Right, 0, 0.103),
        ];
        assert_eq!(pair_frames(&f, 0.02).pairs, vec![(1, 2)]);
    }

    #[test]
    fn pairs_fall_in_the_step_active_after_settling() {
        let log = PressureLog {
            path: PathBuf::new(),
            steps: (0..3)
                .map(|k| LogStep {
                    time_s: 0.3 * k as f64,
                    command_end_s: 0.3 * k as f64,
                    pressures_kpa: [0.0; 3],
                    extra: Vec::new(),
                })
                .collect(),
            extra_columns: Vec::new(),
            median_step_s: 0.3,
        };
        assert_eq!(place(&log, 0.12, 0.13, 0.1, 0.0), Placement::Step(0));
        assert_eq!(place(&log, 0.35, 0.36, 0.1, 0.0), Placement::Settling);
        assert_eq!(place(&log, 0.29, 0.31, 0.1, 0.0), Placement::Straddles);
        assert_eq!(place(&log, -0.01, 0.01, 0.1, 0.0), Placement::OutsideLog);
        assert_eq!(place(&log, 0.75, 0.76, 0.1, 0.0), Placement::Step(2));
        assert_eq!(place(&log, 0.95, 0.96, 0.1, 0.0), Placement::OutsideLog);
        // A command that took 0.1 s: settling counts from its end; a guard before the next.
        let mut slow = log.clone();
        slow.steps[2].command_end_s = 0.7;
        assert_eq!(place(&slow, 0.75, 0.76, 0.1, 0.0), Placement::Settling);
        assert_eq!(place(&slow, 0.81, 0.82, 0.1, 0.0), Placement::Step(2));
        assert_eq!(place(&log, 0.25, 0.26, 0.1, 0.05), Placement::Straddles);
    }
}
