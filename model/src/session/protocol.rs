//! The pressure protocol a session drives: the paper's design (the training grid and the two
//! sweeps, [`designed`]) or a dynamic one (random excitation between rest holds, [`dynamic`]),
//! which `synth` runs on the virtual hand; `protocol.csv`
//! (`step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s`), which `capture` drives; and the lab's command
//! that sets the pressures.
//!
//! # The dynamic design
//!
//! A rest hold of [`REST_S`] at 0, 0, 0 kPa (phase `rest`: the hand frame's origin, and the
//! finger settled before each trial), then each trial `dyn_1` … `dyn_N` followed by another rest
//! hold. A trial is one command every 1/R s for its duration: for each muscle on its own, an
//! APRBS (amplitude-modulated pseudo-random binary sequence) — levels drawn uniformly from
//! 0-`max_kpa`, each held for a time drawn uniformly from [`APRBS_HOLD_S`] — passed through a
//! rate limit of [`SLEW_KPA_S`]. Why: the random levels cover the pressure box evenly (a
//! multisine crowds the middle), the holds from 0.2 to 1.6 s span the muscles' lags (0.1-1 s),
//! so the data hold settled stretches, step responses and everything between, and the rate
//! limit keeps the commands to what a proportional regulator can follow (a white noise above
//! the muscles' bandwidth would only wear the valves). Each trial draws from its own stream of
//! the seed.

use std::path::Path;

use crate::data::{Csv, DataError, Table};

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
    #[error("{0}")]
    Dynamic(String),
}

/// How long each rest hold of a dynamic protocol lasts (s).
pub const REST_S: f64 = 2.0;
/// The fastest command rate of a dynamic protocol (Hz): proportional regulators update at
/// 100-200 Hz.
pub const MAX_RATE_HZ: f64 = 200.0;
/// The shortest and longest hold of an APRBS level (s).
pub const APRBS_HOLD_S: [f64; 2] = [0.2, 1.6];
/// The fastest change of a dynamic command (kPa/s).
pub const SLEW_KPA_S: f64 = 600.0;

/// A dynamic protocol (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DynamicDesign {
    /// Each trial's length (s).
    pub duration_s: f64,
    /// Commands per second.
    pub rate_hz: f64,
    pub trials: usize,
    pub seed: u64,
    /// The top of the pressure box (kPa); the bottom is 0.
    pub max_kpa: f64,
}

impl Default for DynamicDesign {
    fn default() -> Self {
        DynamicDesign {
            duration_s: 20.0,
            rate_hz: 30.0,
            trials: 4,
            seed: crate::DEFAULT_SEED,
            max_kpa: PROTOCOL_MAX_KPA,
        }
    }
}

/// A dynamic protocol's steps: rest, then each trial and a rest after it (see the module docs).
///
/// # Errors
/// [`ProtocolError::Dynamic`] for a rate above [`MAX_RATE_HZ`] or below one command an hour
/// ([`MAX_HOLD_S`]), a duration that is not positive
/// (or over a day), no trial, or a box outside 0-300 kPa.
pub fn dynamic(d: &DynamicDesign) -> Result<Vec<Step>, ProtocolError> {
    use rand::{Rng, SeedableRng};
    let bad = |why: String| Err(ProtocolError::Dynamic(why));
    // At least one command an hour: each is held one period, and capture holds a command at
    // most MAX_HOLD_S.
    if !(d.rate_hz >= 1.0 / MAX_HOLD_S && d.rate_hz <= MAX_RATE_HZ) {
        return bad(format!("--rate-hz {}: the command rate must be at least one an hour (each command is held one period, at most {MAX_HOLD_S} s) and at most {MAX_RATE_HZ} Hz (what a regulator updates at)", d.rate_hz));
    }
    if !(d.duration_s > 0.0 && d.duration_s <= 86_400.0) {
        return bad(format!(
            "--duration-s {}: each trial must last more than 0 s and at most a day",
            d.duration_s
        ));
    }
    if d.trials == 0 || d.trials > 1000 {
        return bad(format!("--trials {}: give 1-1000 trials", d.trials));
    }
    if !(d.max_kpa > 0.0 && d.max_kpa <= MAX_PRESSURE_KPA) {
        return bad(format!("--max-kpa {}: the pressure box must lie inside 0-{MAX_PRESSURE_KPA} kPa, the muscles' cap", d.max_kpa));
    }
    let period = 1.0 / d.rate_hz;
    let mut steps = Vec::new();
    let mut push = |phase: &str, pressures: [f64; 3], hold_s: f64| {
        let step = steps.len();
        steps.push(Step {
            step,
            phase: phase.to_string(),
            pressures,
            hold_s,
            line: step as u64 + 2,
        });
    };
    push("rest", [0.0; 3], REST_S);
    let commands = (d.duration_s * d.rate_hz).round().max(1.0) as usize;
    let slew = SLEW_KPA_S * period;
    for trial in 1..=d.trials {
        let mut rng =
            rand_chacha::ChaCha8Rng::seed_from_u64(d.seed ^ (trial as u64) << 32 ^ 0x4150_5242);
        let mut level = [0.0; 3];
        let mut until = [0.0; 3];
        let mut command = [0.0f64; 3];
        for k in 0..commands {
            let t = k as f64 * period;
            for i in 0..3 {
                if t >= until[i] {
                    level[i] = rng.random_range(0.0..=d.max_kpa);
                    until[i] = t + rng.random_range(APRBS_HOLD_S[0]..APRBS_HOLD_S[1]);
                }
                let change = (level[i] - command[i]).clamp(-slew, slew);
                command[i] = ((command[i] + change) * 100.0).round() / 100.0;
            }
            push(&format!("dyn_{trial}"), command, period);
        }
        push("rest", [0.0; 3], REST_S);
    }
    Ok(steps)
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
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Step {
    pub step: usize,
    pub phase: String,
    pub pressures: [f64; 3],
    pub hold_s: f64,
    /// Line of the protocol file, for messages.
    pub line: u64,
}

/// The paper's protocol (grid at `grid_step_kpa`, both sweeps at `sweep_step_kpa`), each step
/// held `hold_s`.
///
/// # Errors
/// A grid or sweep step [`designed`] refuses.
pub fn paper_steps(
    grid_step_kpa: f64,
    sweep_step_kpa: f64,
    hold_s: f64,
) -> Result<Vec<Step>, ProtocolError> {
    let mut steps = Vec::new();
    for (phase, pressures) in designed(grid_step_kpa, sweep_step_kpa)? {
        for p in pressures {
            let step = steps.len();
            steps.push(Step {
                step,
                phase: phase.to_string(),
                pressures: p,
                hold_s,
                line: step as u64 + 2,
            });
        }
    }
    Ok(steps)
}

/// `steps` as `protocol.csv` text.
pub fn protocol_csv(steps: &[Step]) -> String {
    let mut csv = Csv::new(["step", "phase", "P1_kpa", "P2_kpa", "P3_kpa", "hold_s"]);
    for s in steps {
        let [p1, p2, p3] = s.pressures.map(|p| p.to_string());
        csv.row([
            s.step.to_string(),
            s.phase.clone(),
            p1,
            p2,
            p3,
            s.hold_s.to_string(),
        ]);
    }
    csv.into_string()
}

/// When each step is commanded (s from the first), and when the last one ends.
pub fn start_times(steps: &[Step]) -> (Vec<f64>, f64) {
    let mut t = 0.0;
    let starts = steps
        .iter()
        .map(|s| {
            let start = t;
            t += s.hold_s;
            start
        })
        .collect();
    (starts, t)
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
        std::fs::write(
            &path,
            protocol_csv(&paper_steps(125.0, 125.0, 0.5).unwrap()),
        )
        .unwrap();
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

    #[test]
    fn a_dynamic_protocol_rests_then_excites_the_box_at_the_rate() {
        let design = DynamicDesign {
            duration_s: 30.0,
            trials: 2,
            ..DynamicDesign::default()
        };
        let steps = dynamic(&design).unwrap();
        let phases: Vec<&str> = steps.iter().map(|s| s.phase.as_str()).collect();
        assert_eq!(phases[0], "rest");
        assert_eq!(*phases.last().unwrap(), "rest");
        for trial in ["dyn_1", "dyn_2"] {
            let rows: Vec<&Step> = steps.iter().filter(|s| s.phase == trial).collect();
            assert_eq!(rows.len(), 900, "{trial}: 30 s at 30 Hz");
            assert!(rows.iter().all(|s| (s.hold_s - 1.0 / 30.0).abs() < 1e-12));
            for i in 0..3 {
                let p: Vec<f64> = rows.iter().map(|s| s.pressures[i]).collect();
                let (lo, hi) = (
                    p.iter().cloned().fold(f64::MAX, f64::min),
                    p.iter().cloned().fold(0.0, f64::max),
                );
                assert!(
                    lo < 40.0 && hi > 210.0 && hi <= 250.0,
                    "{trial} P{}: {lo}-{hi} kPa",
                    i + 1
                );
                let fastest = p
                    .windows(2)
                    .map(|w| (w[1] - w[0]).abs())
                    .fold(0.0, f64::max);
                assert!(
                    fastest <= SLEW_KPA_S / 30.0 + 0.01,
                    "{fastest} kPa a command"
                );
            }
        }
        let rest: Vec<&Step> = steps.iter().filter(|s| s.phase == "rest").collect();
        assert_eq!(rest.len(), 3);
        assert!(rest
            .iter()
            .all(|s| s.pressures == [0.0; 3] && s.hold_s >= 2.0));
        assert_eq!(steps, dynamic(&design).unwrap(), "seeded");
        let other = dynamic(&DynamicDesign {
            seed: 9,
            ..design.clone()
        })
        .unwrap();
        assert_ne!(steps, other);
        // It reads back as it was written.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("protocol.csv");
        std::fs::write(&path, protocol_csv(&steps)).unwrap();
        assert_eq!(read(&path).unwrap(), steps);
    }

    #[test]
    fn a_dynamic_design_outside_the_rules_is_one_line() {
        let ok = DynamicDesign::default();
        for (design, says) in [
            (
                DynamicDesign {
                    rate_hz: 250.0,
                    ..ok.clone()
                },
                "--rate-hz 250",
            ),
            (
                DynamicDesign {
                    duration_s: 0.0,
                    ..ok.clone()
                },
                "--duration-s 0",
            ),
            (
                DynamicDesign {
                    duration_s: -3.0,
                    ..ok.clone()
                },
                "--duration-s -3",
            ),
            (
                DynamicDesign {
                    max_kpa: 320.0,
                    ..ok.clone()
                },
                "--max-kpa 320",
            ),
            (
                DynamicDesign {
                    trials: 0,
                    ..ok.clone()
                },
                "--trials 0",
            ),
        ] {
            let err = dynamic(&design).unwrap_err().to_string();
            assert!(err.starts_with(says) && !err.contains('\n'), "{err}");
        }
    }
}
