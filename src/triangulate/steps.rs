//! Steps 4-6 of a triangulation, and why one fails: each step's pairs and flags, the hand
//! frame from the zero-pressure steps, one row per step; what to say when no pair is used or
//! no zero-pressure step keeps a tip.

use nalgebra::Vector3;

use super::options::{self, TriangulateOptions};
use super::summary::{Origin, Summary};
use super::{median_95_max, origin_of, spread, PairRecord, Row, TriangulateError};
use crate::geometry::HandFromLeft;
use crate::session::frames::{self, FrameRecord};
use crate::session::pressures::PressureLog;
use crate::stereo::Side;

/// Why no pair could be used: the pairs' counts, and the cause to say first.
pub(super) fn nothing_used(
    pairs: &[PairRecord],
    records: &[FrameRecord],
    summary: &Summary,
    log: &PressureLog,
    options: &TriangulateOptions,
) -> TriangulateError {
    let counts: Vec<String> = summary
        .pairs
        .iter()
        .map(|(k, v)| format!("{v} {k}"))
        .collect();
    // Frames too far apart to pair is the cause to say first: it empties every count.
    let times = |side: Side| -> Vec<f64> {
        let order = frames::in_time_order(records, side);
        order.iter().map(|&i| records[i].time_s).collect()
    };
    let apart_s = crate::frame_times::skew(&times(Side::Left), &times(Side::Right));
    let cause = if apart_s > options.max_dt_s {
        let limit = format!("{:.3}", 1e3 * options.max_dt_s);
        format!(
            "; the left and right frames are {:.1} ms apart (median), more than --max-dt-ms {}: raise it to pair them, or check that both cameras are on one clock and neither lags",
            1e3 * apart_s,
            limit.trim_end_matches('0').trim_end_matches('.')
        )
    } else {
        timing_cause(summary, log)
    };
    let what = if counts.is_empty() {
        "none formed".to_string()
    } else {
        counts.join(", ")
    };
    TriangulateError::NothingUsed(format!(
        "{} pairs of {} left and {} right frames: {what}{cause}",
        pairs.len(),
        summary.frames.listed[0],
        summary.frames.listed[1],
    ))
}

/// The used pairs of each step of the log, their spread (in the left camera: distances do not
/// depend on the frame) and the step's flags, found before the origin, which doubtful rows
/// must not place.
pub(super) struct Steps<'a> {
    pairs: Vec<Vec<&'a PairRecord>>,
    spreads: Vec<f64>,
    flags: Vec<Vec<&'static str>>,
}

impl<'a> Steps<'a> {
    /// Step 4.
    pub(super) fn of(
        used: &[&'a PairRecord],
        log: &PressureLog,
        options: &TriangulateOptions,
    ) -> Self {
        let mut pairs: Vec<Vec<&PairRecord>> = vec![Vec::new(); log.steps.len()];
        for p in used {
            pairs[p.step.expect("used pairs have a step")].push(p);
        }
        let (spreads, flags) = pairs
            .iter()
            .enumerate()
            .map(|(k, step_pairs)| {
                let points: Vec<Vector3<f64>> =
                    step_pairs.iter().filter_map(|p| p.point_left_mm).collect();
                let spread = spread(&points);
                let mut flags = Vec::new();
                if points.len() < options.min_frames {
                    flags.push("few_frames");
                }
                if spread > options.max_spread_mm {
                    flags.push("spread");
                }
                if log.end_s(k) - log.steps[k].time_s > 1.5 * log.planned_s(k) {
                    flags.push("long_step");
                }
                (spread, flags)
            })
            .unzip();
        Steps {
            pairs,
            spreads,
            flags,
        }
    }

    /// Step 6: one row per step with a used pair, the median of its pairs in the hand frame
    /// (flagged `reach` beyond the finger's length from its base).
    pub(super) fn rows(
        &self,
        hand_from_left: &HandFromLeft,
        log: &PressureLog,
        options: &TriangulateOptions,
        summary: &mut Summary,
    ) -> Vec<Row> {
        let mut rows = Vec::new();
        for (k, step_pairs) in self.pairs.iter().enumerate() {
            if step_pairs.is_empty() {
                summary.steps_without_tip.push(k);
                continue;
            }
            let tips: Vec<Vector3<f64>> = step_pairs
                .iter()
                .map(|p| {
                    hand_from_left
                        .apply(&p.point_left_mm.expect("used").into())
                        .coords
                })
                .collect();
            let tip = crate::stats::median_point(&tips);
            let mut flags = self.flags[k].clone();
            if (tip - Vector3::new(0.0, 0.0, options.finger_mm)).norm()
                > options.finger_mm + options::REACH_MARGIN_MM
            {
                flags.push("reach");
            }
            rows.push(Row {
                step: k,
                pressures_kpa: log.steps[k].pressures_kpa,
                tip_mm: tip.into(),
                n_frames: tips.len(),
                spread_mm: self.spreads[k],
                reproj_px: step_pairs
                    .iter()
                    .filter_map(|p| p.reproj_px)
                    .fold(0.0, f64::max),
                dt_ms: step_pairs
                    .iter()
                    .map(|p| 1e3 * (p.left.time_s - p.right.time_s).abs())
                    .fold(0.0, f64::max),
                extra: log.steps[k].extra.clone(),
                flags,
            });
        }
        summary.rows = rows.len();
        summary.rows_flagged = rows.iter().filter(|r| !r.flags.is_empty()).count();
        rows
    }
}

/// Step 5: the hand frame, its origin the median tip of the zero-pressure steps whose rows are
/// not doubtful.
pub(super) fn hand_frame(
    r_hand: nalgebra::Rotation3<f64>,
    steps: &Steps,
    pairs: &[PairRecord],
    records: &[FrameRecord],
    log: &PressureLog,
    options: &TriangulateOptions,
    summary: &mut Summary,
) -> Result<HandFromLeft, TriangulateError> {
    let zero: Vec<usize> = (0..log.steps.len())
        .filter(|&k| {
            log.steps[k]
                .pressures_kpa
                .iter()
                .all(|p| p.abs() <= options.zero_kpa)
        })
        .collect();
    let at_zero: Vec<Vector3<f64>> = zero
        .iter()
        .filter(|&&k| steps.flags[k].is_empty())
        .flat_map(|&k| steps.pairs[k].iter().filter_map(|p| p.point_left_mm))
        .collect();
    if at_zero.is_empty() {
        return Err(TriangulateError::NoOrigin {
            zero: zero.len(),
            zero_kpa: options.zero_kpa,
            why: no_origin_cause(&zero, &steps.flags, pairs, records, log, options, summary),
        });
    }
    let (origin, spread_mm) = origin_of(&at_zero);
    summary.origin = Origin {
        left_mm: origin.into(),
        zero_steps: zero.len(),
        pairs: at_zero.len(),
        spread_mm,
    };
    summary.step_spread_mm = median_95_max(
        steps
            .pairs
            .iter()
            .zip(&steps.spreads)
            .filter(|(pairs, _)| !pairs.is_empty())
            .map(|(_, &s)| s)
            .collect(),
    );
    Ok(HandFromLeft::new(r_hand, -(r_hand * origin)))
}

/// Why the zero-pressure steps `zero` gave no origin, and what to do: their rows were flagged
/// (and why), or their pairs came to nothing (counted by what became of them), or their frames
/// were too far apart to pair, and [`timing_cause`]; else log and film such a step.
fn no_origin_cause(
    zero: &[usize],
    flags: &[Vec<&'static str>],
    pairs: &[PairRecord],
    records: &[FrameRecord],
    log: &PressureLog,
    options: &TriangulateOptions,
    summary: &Summary,
) -> String {
    let in_zero = |t: f64| {
        zero.iter()
            .any(|&k| (log.steps[k].time_s..log.end_s(k)).contains(&t))
    };
    let flagged: Vec<&str> = zero
        .iter()
        .flat_map(|&k| flags[k].iter().copied())
        .collect();
    let mut said = Vec::new();
    if flagged.contains(&"few_frames") {
        said.push(format!(
            "their rows have fewer than --min-frames {} frame pairs (a capture that keeps one or two frames a step needs --min-frames 1)",
            options.min_frames
        ));
    }
    if flagged.contains(&"spread") {
        said.push(format!(
            "their pairs disagree by more than --max-spread-mm {}",
            options.max_spread_mm
        ));
    }
    let mut became: std::collections::BTreeMap<&str, usize> = Default::default();
    for p in pairs
        .iter()
        .filter(|p| !p.status.used() && in_zero(p.left.time_s.min(p.right.time_s)))
    {
        *became.entry(p.status.name()).or_default() += 1;
    }
    if !became.is_empty() {
        let counts: Vec<String> = became.iter().map(|(k, v)| format!("{v} {k}")).collect();
        said.push(format!("their frame pairs: {}", counts.join(", ")));
    }
    let times = |side: Side| -> Vec<f64> {
        frames::in_time_order(records, side)
            .into_iter()
            .map(|i| records[i].time_s)
            .filter(|&t| in_zero(t))
            .collect()
    };
    let (left, right) = (times(Side::Left), times(Side::Right));
    if left.is_empty() || right.is_empty() {
        said.push(format!(
            "{} left and {} right frames fall in them",
            left.len(),
            right.len()
        ));
    } else if pairs.iter().all(|p| !in_zero(p.left.time_s)) {
        let apart = crate::frame_times::skew(&left, &right);
        if apart > options.max_dt_s {
            said.push(format!(
                "their left and right frames are {:.1} ms apart (median), more than --max-dt-ms {}: none paired (the finger holds still: a larger --max-dt-ms pairs them)",
                1e3 * apart,
                1e3 * options.max_dt_s
            ));
        }
    }
    let timing = timing_cause(summary, log);
    if said.is_empty() && timing.is_empty() {
        return "log and film at least one step at 0, 0, 0 kPa".into();
    }
    format!("{}{timing}", said.join("; "))
        .trim_start_matches("; ")
        .to_string()
}

/// What in the session's timing leaves no settled frame, as "; …" (empty when nothing): when
/// most pairs were settling or straddling a command, the regulator's commands taking a large
/// share of each step, and camera delays measured that large — each said, as both can be.
fn timing_cause(summary: &Summary, log: &PressureLog) -> String {
    let count = |k: &str| summary.pairs.get(k).copied().unwrap_or(0);
    let formed: usize = summary.pairs.values().sum();
    if 2 * (count("settling") + count("straddles")) <= formed {
        return String::new();
    }
    let step_ms = 1e3 * log.median_step_s;
    let large = |ms: f64| ms >= 0.25 * step_ms;
    let mut said = String::new();
    if let Some([median, _]) = summary
        .clock
        .command_ms
        .filter(|[median, _]| large(*median))
    {
        said += &format!(
            "; the regulator's commands took {median:.0} ms (median) of {step_ms:.0} ms steps, and the finger settles after a command returns: hold each step longer or speed up the regulator"
        );
    }
    let delays = summary.latency.cameras.each_ref();
    if let [Some(l), Some(r)] = delays.map(|d| d.as_ref().map(|d| d.delay_ms)) {
        if !summary.latency.given && large(l.max(r)) {
            said += &format!(
                "; the cameras' delays were measured at {l:.0}/{r:.0} ms (left/right) of {step_ms:.0} ms steps: if they are not that late, give --latency-ms"
            );
        }
    }
    said
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::triangulate::latency::Delay;

    /// Hostile probe 11 (issue 61): a camera 300 ms late and a regulator taking 180 ms of 600 ms
    /// steps: the refusal named only the regulator.
    #[test]
    fn hostile_a_late_camera_and_a_slow_regulator_are_both_said() {
        let mut summary = Summary::default();
        summary.pairs.insert("settling", 9);
        summary.pairs.insert("used", 1);
        summary.clock.command_ms = Some([180.0, 190.0]);
        let delay = |delay_ms| Delay {
            delay_ms,
            within_ms: 2.0,
            moves: 10,
            lead_ms: 0.0,
        };
        summary.latency.cameras = [Some(delay(20.0)), Some(delay(300.0))];
        let log = PressureLog {
            path: "p.csv".into(),
            steps: Vec::new(),
            extra_columns: Vec::new(),
            median_step_s: 0.6,
        };
        let said = timing_cause(&summary, &log);
        assert!(said.contains("commands took 180 ms"), "{said}");
        assert!(said.contains("measured at 20/300 ms"), "{said}");
        summary.clock.command_ms = Some([10.0, 12.0]);
        let said = timing_cause(&summary, &log);
        assert!(
            !said.contains("regulator") && said.contains("20/300"),
            "{said}"
        );
        summary.latency.given = true;
        assert_eq!(timing_cause(&summary, &log), "");
    }
}
