//! Pairs into the pressure steps of the regulator's log ([`crate::session::pressures`]): a
//! pair belongs to the step active at its earlier frame, if its later frame is before the next
//! step (by a guard, when the times were corrected for the cameras' delays: see
//! [`super::latency`]) and its earlier frame at least `settle_s` after the step's command
//! returned (`command_end_s`, when the log has it; else its time).

use crate::session::pressures::PressureLog;

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
mod tests {
    use super::*;
    use crate::session::pressures::LogStep;
    use std::path::PathBuf;

    #[test]
    fn pairs_fall_in_the_step_active_after_settling() {
        let log = PressureLog {
            path: PathBuf::new(),
            steps: (0..3)
                .map(|k| LogStep {
                    time_s: 0.3 * k as f64,
                    command_end_s: 0.3 * k as f64,
                    hold_s: None,
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
