//! The pressure protocol a session drives: the paper's design (the training grid and the two
//! sweeps, [`designed`]), which `synth` runs on the virtual hand; `protocol.csv`
//! (`step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s`), which `capture` drives; and the lab's command
//! that sets the pressures.

use std::fmt::Write as _;
use std::path::Path;

use crate::data::{DataError, Table};

pub use crate::hand::MAX_PRESSURE_KPA;

/// Highest pressure of the paper's protocol (kPa).
pub const PROTOCOL_MAX_KPA: f64 = 250.0;

/// A protocol's design that is not one.
#[derive(Debug, thiserror::Error)]
pub enum ProtocolError {
    #[error("--{flag} {step} kPa: the step must divide 0-{PROTOCOL_MAX_KPA} kPa into whole steps")]
    BadStep { flag: &'static str, step: f64 },
    #[error("--grid-step-kpa {step} kPa makes a grid of {steps:.3e} steps; at most {MAX_GRID_STEPS} (a step of {min_step} kPa or more)")]
    GridTooLarge {
        step: f64,
        steps: f64,
        min_step: f64,
    },
}

/// A named sequence of pressure steps (kPa): `train`, `sweep_a`, `sweep_b`.
pub type Phase = (&'static str, Vec<[f64; 3]>);

/// The paper's protocol: the training grid (every combination of 0, `grid_step_kpa`, …, 250
/// kPa) and the two sweeps (P3, then P2 = P3, every `sweep_step_kpa`), as named pressure
/// sequences in the order they are applied.
pub fn designed(grid_step_kpa: f64, sweep_step_kpa: f64) -> Result<Vec<Phase>, ProtocolError> {
    let grid = levels(grid_step_kpa, "grid-step-kpa")?;
    let steps = (grid.len() as f64).powi(3);
    if steps > MAX_GRID_STEPS as f64 {
        return Err(ProtocolError::GridTooLarge {
            step: grid_step_kpa,
            steps,
            min_step: 5.0,
        });
    }
    let sweep = levels(sweep_step_kpa, "sweep-step-kpa")?;
    let mut train = Vec::with_capacity(grid.len().pow(3));
    for &p1 in &grid {
        for &p2 in &grid {
            for &p3 in &grid {
                train.push([p1, p2, p3]);
            }
        }
    }
    Ok(vec![
        ("train", train),
        ("sweep_a", sweep.iter().map(|&p| [0.0, 0.0, p]).collect()),
        ("sweep_b", sweep.iter().map(|&p| [0.0, p, p]).collect()),
    ])
}

/// The largest training grid: 51³ steps (5 kPa), 11 hours of a real session at
/// 0.3 s a step, and what the MSVR's n × n kernel can hold.
pub const MAX_GRID_STEPS: usize = 51 * 51 * 51;

/// 0, step, 2·step, …, 250 kPa; `flag` names the option in the error.
fn levels(step_kpa: f64, flag: &'static str) -> Result<Vec<f64>, ProtocolError> {
    let count = PROTOCOL_MAX_KPA / step_kpa;
    if !(step_kpa > 0.0
        && count.is_finite()
        && count <= 1e6
        && (count - count.round()).abs() < 1e-9)
    {
        return Err(ProtocolError::BadStep {
            flag,
            step: step_kpa,
        });
    }
    Ok((0..=count.round() as usize)
        .map(|k| k as f64 * step_kpa)
        .collect())
}

/// The longest a protocol may hold a step (s): an hour. A hold beyond is a typo (or 1e300),
/// and a session that waits for it never ends.
pub const MAX_HOLD_S: f64 = 3600.0;

/// Why a hold time is not one, or `None` when it is (positive, finite, at most
/// [`MAX_HOLD_S`]).
pub fn bad_hold(hold_s: f64) -> Option<String> {
    (!(hold_s > 0.0 && hold_s <= MAX_HOLD_S)).then(|| {
        // 1e300 as written, not as 301 digits.
        let shown = if hold_s.abs() < 1e6 {
            hold_s.to_string()
        } else {
            format!("{hold_s:e}")
        };
        format!("hold_s {shown} must be more than 0 and at most {MAX_HOLD_S} s (an hour)")
    })
}

/// One step: the three muscles' pressures, held for `hold_s`.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    pub step: usize,
    pub phase: String,
    pub pressures: [f64; 3],
    pub hold_s: f64,
    /// Line of the protocol file, for messages.
    pub line: u64,
}

/// The paper's protocol (grid at `grid_step_kpa`, both sweeps at `sweep_step_kpa`), each step
/// held `hold_s`, as `protocol.csv` text.
///
/// # Errors
/// A grid or sweep step [`designed`] refuses.
pub fn paper_protocol(
    grid_step_kpa: f64,
    sweep_step_kpa: f64,
    hold_s: f64,
) -> Result<String, ProtocolError> {
    let mut out = String::from("step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s\n");
    let mut step = 0;
    for (phase, pressures) in designed(grid_step_kpa, sweep_step_kpa)? {
        for [p1, p2, p3] in pressures {
            let _ = writeln!(out, "{step},{phase},{p1},{p2},{p3},{hold_s}");
            step += 1;
        }
    }
    Ok(out)
}

/// Reads a protocol, refusing any pressure outside 0-300 kPa and any hold that is not a positive
/// number of seconds, before anything runs.
///
/// # Errors
/// [`DataError::Input`] naming the file and line.
pub fn read(path: &Path) -> Result<Vec<Step>, DataError> {
    let table = Table::open(path, "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s")?;
    let columns =
        ["step", "phase", "P1_kpa", "P2_kpa", "P3_kpa", "hold_s"].map(|name| table.column(name));
    let [step, phase, p1, p2, p3, hold] = columns;
    let (step, phase, hold) = (step?, phase?, hold?);
    let pressure = [p1?, p2?, p3?];
    let mut steps = Vec::new();
    for (line, record) in table.records()? {
        let number = |col: usize, name: &str| -> Result<f64, DataError> {
            record[col]
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    table.bad(line, format!("{name} {:?} is not a number", &record[col]))
                })
        };
        let mut pressures = [0.0; 3];
        for (k, (&col, p)) in pressure.iter().zip(&mut pressures).enumerate() {
            *p = number(col, &format!("P{}_kpa", k + 1))?;
            if !(0.0..=MAX_PRESSURE_KPA).contains(p) {
                return table.fail(
                    line,
                    format!(
                        "P{}_kpa {} is outside 0-{MAX_PRESSURE_KPA} kPa, the muscles' cap; correct the protocol",
                        k + 1,
                        *p
                    ),
                );
            }
        }
        let hold_s = number(hold, "hold_s")?;
        if let Some(why) = bad_hold(hold_s) {
            return table.fail(line, format!("{why}; correct the protocol"));
        }
        let number_of_step = record[step].trim().parse().map_err(|_| {
            table.bad(
                line,
                format!("step {:?} is not a step number", &record[step]),
            )
        })?;
        steps.push(Step {
            step: number_of_step,
            phase: record[phase].to_string(),
            pressures,
            hold_s,
            line,
        });
    }
    if steps.is_empty() {
        return table.fail(1, "no steps".into());
    }
    Ok(steps)
}

/// The lab's command for one step: `template` with `{p1}`, `{p2}`, `{p3}` (kPa) and `{step}`
/// replaced.
///
/// # Panics
/// When a pressure is above [`MAX_PRESSURE_KPA`]: [`read`] refuses such protocols, and this is
/// the last check before a command reaches the regulator.
pub fn command_for(template: &str, step: &Step) -> String {
    assert!(
        step.pressures
            .iter()
            .all(|p| (0.0..=MAX_PRESSURE_KPA).contains(p)),
        "pressure above the cap reached the command"
    );
    // `-0` (a protocol file may hold it) is 0 to a regulator.
    let [p1, p2, p3] = step.pressures.map(crate::data::format_number);
    template
        .replace("{p1}", &p1)
        .replace("{p2}", &p2)
        .replace("{p3}", &p3)
        .replace("{step}", &step.step.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 44, item 12: a protocol's `-0` reaches the regulator as `0`.
    #[test]
    fn negative_zero_reaches_the_command_as_zero() {
        let step = Step {
            step: 3,
            phase: "train".into(),
            pressures: [-0.0, 12.5, 0.0],
            hold_s: 1.0,
            line: 5,
        };
        assert_eq!(command_for("set {p1} {p2} {p3}", &step), "set 0 12.5 0");
    }

    #[test]
    fn the_design_is_the_papers() {
        let p = designed(50.0, 10.0).unwrap();
        assert_eq!(p[0].1.len(), 216);
        assert_eq!(p[1].1.len(), 26);
        assert!(p[1].1.iter().all(|s| s[0] == 0.0 && s[1] == 0.0));
        assert!(p[2].1.iter().all(|s| s[0] == 0.0 && s[1] == s[2]));
        assert_eq!(p[2].1.last().unwrap(), &[0.0, 250.0, 250.0]);
    }

    #[test]
    fn the_paper_protocol_reads_back_and_fills_the_command() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("protocol.csv");
        std::fs::write(&path, paper_protocol(125.0, 125.0, 0.5).unwrap()).unwrap();
        let steps = read(&path).unwrap();
        // 3³ grid steps and 3 of each sweep, the first at rest.
        assert_eq!(steps.len(), 27 + 3 + 3);
        assert_eq!(steps[0].pressures, [0.0; 3]);
        assert_eq!(steps[26].pressures, [250.0; 3]);
        assert_eq!(steps[32].phase, "sweep_b");
        assert_eq!(
            command_for("set {p1} {p2} {p3} #{step}", &steps[5]),
            "set 0 125 250 #5"
        );
    }
}
