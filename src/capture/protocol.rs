//! The pressure protocol a capture session drives: `protocol.csv`
//! (`step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s`), the paper's by default (the training grid and
//! the two sweeps, [`crate::synth::protocol`]), and the lab's command that sets the pressures.

use std::fmt::Write as _;
use std::path::Path;

use crate::data::{DataError, Table};

pub use crate::hand::MAX_PRESSURE_KPA;

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
/// A grid or sweep step `synth` refuses.
pub fn paper_protocol(
    grid_step_kpa: f64,
    sweep_step_kpa: f64,
    hold_s: f64,
) -> Result<String, crate::synth::SynthError> {
    let config = crate::synth::SynthConfig {
        grid_step_kpa,
        sweep_step_kpa,
        ..crate::synth::SynthConfig::default()
    };
    let mut out = String::from("step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s\n");
    let mut step = 0;
    for (phase, pressures) in crate::synth::protocol(&config)? {
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
    let mut table = Table::open(path, "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s")?;
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
    let [p1, p2, p3] = step.pressures;
    template
        .replace("{p1}", &p1.to_string())
        .replace("{p2}", &p2.to_string())
        .replace("{p3}", &p3.to_string())
        .replace("{step}", &step.step.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

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
