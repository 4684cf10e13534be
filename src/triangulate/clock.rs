//! The session's clock, checked from the timestamps alone: how far apart the two frames of a
//! pair were taken, whether that drifts over the session, frames a camera dropped, and steps
//! filmed only while the finger was still moving.
//!
//! - Skew: right − left time of each pair (the pairing takes each camera's nearest frame), its
//!   size's median and 95th percentile. Free-running webcams run at slightly different rates,
//!   so the difference walks; USB latency that grows on one camera moves it too.
//! - Drift: a straight line through the differences against the session's time, times the
//!   session's length. A difference that walks past half a frame period makes the pairing take
//!   the next frame and the difference jump by a period; the differences are unwrapped across
//!   such jumps first (each against the median of the last [`UNWRAP_WINDOW`], so one frame
//!   stamped half a period off does not shift all later ones), so a drift of several periods is
//!   measured whole.
//! - Dropped: within a step each camera should deliver every frame; the frames missing from
//!   each step's span ([`crate::frame_times::dropped`]: a frame stamped late is no drop; gaps
//!   between steps are not counted: a capture may film only around its steps).
//! - Settling only: steps with pairs, but all within `settle_s` of the command's end: no row
//!   comes from them; hold each step longer.
//! - Commands: how long the regulator's commands took, when the log says when they returned
//!   (settling counts from there).

use serde::Serialize;

use super::pairing::{place, Placement};
use crate::session::frames::{in_time_order, FrameRecord};
use crate::session::pressures::PressureLog;
use crate::stats::Line;
use crate::stereo::Side;

/// What the timestamps say (module docs).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ClockCheck {
    /// |right − left| of the pairs (ms): median, 95th percentile.
    pub skew_ms: [f64; 2],
    /// Change of right − left over the session (ms), unwrapped.
    pub drift_ms: f64,
    /// Each camera's frame period: the median interval between frames of one step (ms; 0 when
    /// no step has two of its frames).
    pub period_ms: [f64; 2],
    /// Frames missing within steps, per camera.
    pub dropped: [usize; 2],
    /// Log rows (0-based) filmed only while settling.
    pub settling_only: Vec<usize>,
    /// How long the regulator's commands took (ms): median, largest; `None` when the log does
    /// not say when they returned, or says every one returned at once.
    pub command_ms: Option<[f64; 2]>,
    /// Per pair: session time (s) and right − left unwrapped (ms), for the figure.
    #[serde(skip)]
    pub series: Vec<(f64, f64)>,
}

impl ClockCheck {
    /// The frame periods as text: `33.3/33.4 ms`, `—` for a camera with one frame per step.
    pub fn periods(&self) -> String {
        let one = |p: f64| {
            if p > 0.0 {
                format!("{p:.1}")
            } else {
                "—".into()
            }
        };
        format!("{}/{} ms", one(self.period_ms[0]), one(self.period_ms[1]))
    }
}

/// Pairs whose median the next difference is unwrapped against.
pub const UNWRAP_WINDOW: usize = 15;

/// Checks the clock of `frames` paired as `pairs` against `log`.
pub fn check(
    frames: &[FrameRecord],
    pairs: &[(usize, usize)],
    log: &PressureLog,
    settle_s: f64,
    guard_s: f64,
) -> ClockCheck {
    let mut c = ClockCheck::default();
    // Periods and drops, per camera, from frames of one step.
    for (side, cam) in [Side::Left, Side::Right].into_iter().zip(0..) {
        let times: Vec<(f64, Option<usize>)> = in_time_order(frames, side)
            .into_iter()
            .map(|i| (frames[i].time_s, log.step_at(frames[i].time_s)))
            .collect();
        // Each step's frames, in time order.
        let runs: Vec<Vec<f64>> = times
            .chunk_by(|a, b| a.1 == b.1)
            .filter(|run| run[0].1.is_some())
            .map(|run| run.iter().map(|t| t.0).collect())
            .collect();
        let mut gaps: Vec<f64> = runs
            .iter()
            .flat_map(|run| run.windows(2).map(|w| w[1] - w[0]))
            .collect();
        let period = crate::stats::median(&mut gaps).unwrap_or(0.0);
        c.period_ms[cam] = 1e3 * period;
        c.dropped[cam] = runs
            .iter()
            .map(|run| crate::frame_times::dropped(run, period))
            .sum();
    }
    // Skew and drift from the pairs, in time order.
    let mut diffs: Vec<(f64, f64)> = pairs
        .iter()
        .map(|&(l, r)| {
            let (tl, tr) = (frames[l].time_s, frames[r].time_s);
            ((tl + tr) / 2.0, tr - tl)
        })
        .collect();
    diffs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut sizes: Vec<f64> = diffs.iter().map(|d| 1e3 * d.1.abs()).collect();
    if let Some([median, p95]) = crate::stats::quantiles(&mut sizes, [0.5, 0.95]) {
        c.skew_ms = [median, p95];
    }
    // The frame period the differences wrap by: the cameras' measured ones (none when no step
    // has two frames of a camera: then nothing is unwrapped).
    let known: Vec<f64> = c.period_ms.iter().copied().filter(|p| *p > 0.0).collect();
    let period = 1e-3 * known.iter().sum::<f64>() / known.len().max(1) as f64;
    // Each difference is unwrapped against the median of the last few unwrapped ones, not the
    // last one alone: a single frame stamped half a period off would otherwise move every
    // later difference by a whole period (a drift where there is none).
    let mut recent: std::collections::VecDeque<f64> = std::collections::VecDeque::new();
    for (t, d) in &diffs {
        let reference = crate::stats::median(&mut recent.iter().copied().collect::<Vec<_>>());
        let unwrapped = match reference {
            Some(p) if period > 0.0 => d - ((d - p) / period).round() * period,
            _ => *d,
        };
        if recent.len() == UNWRAP_WINDOW {
            recent.pop_front();
        }
        recent.push_back(unwrapped);
        c.series.push((*t, 1e3 * unwrapped));
    }
    if let Some(line) = Line::fit(&c.series) {
        let span = c.series[c.series.len() - 1].0 - c.series[0].0;
        c.drift_ms = line.slope * span;
    }
    // Steps whose every pair was settling.
    let mut settling = vec![false; log.steps.len()];
    let mut placed = vec![false; log.steps.len()];
    for &(l, r) in pairs {
        let (a, b) = (frames[l].time_s, frames[r].time_s);
        match place(log, a, b, settle_s, guard_s) {
            Placement::Step(k) => placed[k] = true,
            Placement::Settling => {
                if let Some(k) = log.step_at(a.min(b)) {
                    settling[k] = true;
                }
            }
            _ => {}
        }
    }
    let mut took: Vec<f64> = log
        .steps
        .iter()
        .map(|s| 1e3 * (s.command_end_s - s.time_s))
        .collect();
    if took.iter().any(|&t| t > 0.0) {
        let largest = took.iter().copied().fold(0.0, f64::max);
        c.command_ms = crate::stats::median(&mut took).map(|m| [m, largest]);
    }
    c.settling_only = (0..log.steps.len())
        .filter(|&k| settling[k] && !placed[k])
        .collect();
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::frames::pair_frames;
    use crate::session::frames::tests::frame;
    use crate::session::pressures::LogStep;

    fn log(times: &[f64]) -> PressureLog {
        PressureLog {
            path: "log.csv".into(),
            steps: times
                .iter()
                .map(|&time_s| LogStep {
                    time_s,
                    command_end_s: time_s,
                    hold_s: None,
                    pressures_kpa: [0.0; 3],
                    extra: Vec::new(),
                })
                .collect(),
            extra_columns: Vec::new(),
            median_step_s: 1.0,
        }
    }

    #[test]
    fn a_drift_of_several_periods_and_the_dropped_frames_are_found() {
        // 30 fps for 10 s, one step a second; the right clock runs 80 ms (2.4 periods) ahead by
        // the end; the left camera drops frames 100-102, the right camera frame 200.
        let mut frames = Vec::new();
        for k in 0..300 {
            let t = 0.01 + k as f64 / 30.0;
            if !(100..=102).contains(&k) {
                frames.push(frame(Side::Left, k, t));
            }
            if k != 200 {
                frames.push(frame(Side::Right, k, t + 0.005 + 0.080 * t / 10.0));
            }
        }
        let log = log(&(0..10).map(f64::from).collect::<Vec<_>>());
        let pairing = pair_frames(&frames, 0.02);
        let c = check(&frames, &pairing.pairs, &log, 0.05, 0.0);
        assert!((c.drift_ms - 80.0).abs() < 1.0, "{c:?}");
        assert_eq!(c.dropped, [3, 1]);
        assert!((c.period_ms[0] - 33.333).abs() < 0.01, "{:?}", c.period_ms);
        assert!(c.skew_ms[1] <= 16.7, "{:?}", c.skew_ms);
        assert!(c.settling_only.is_empty());
        // Held for less than the settling time, a step gives no row: said.
        let c = check(&frames, &pairing.pairs, &log, 1.5, 0.0);
        assert_eq!(c.settling_only.len(), 10);
    }

    #[test]
    fn jittery_stamps_make_no_drift_and_no_drops() {
        // 30 fps for 20 s, the right camera 12 ms after the left, both stamped with up to
        // ±9 ms of jitter (a busy USB bus): pairs 12 ± 18 ms apart, some of them by more than
        // half a period from the one before.
        let mut frames = Vec::new();
        let mut state = 7u64;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for k in 0..600 {
            let t = 0.01 + k as f64 / 30.0;
            let mut stamp = |base: f64| base + 0.018 * (uniform() - 0.5);
            frames.push(frame(Side::Left, k, stamp(t)));
            frames.push(frame(Side::Right, k, stamp(t + 0.012)));
        }
        let log = log(&(0..20).map(f64::from).collect::<Vec<_>>());
        let pairing = pair_frames(&frames, 0.04);
        let c = check(&frames, &pairing.pairs, &log, 0.05, 0.0);
        assert!(c.drift_ms.abs() < 3.0, "drift {} ms", c.drift_ms);
        assert_eq!(c.dropped, [0, 0]);
    }
}
