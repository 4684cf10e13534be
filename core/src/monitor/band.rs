//! The online band ([module docs](super)): quantile trackers of several steps, weighed by
//! how well each has tracked the errors' quantile lately (DtACI, Gibbs & Candès 2024).
//!
//! Measured on `scripts/bench_monitor.py`'s sessions (the six by the script; the single tracker
//! it replaced replayed on the same errors in Python, outside the repository): on calm 600 s
//! runs the single tracker of step 0.05 held 0.896 of the rows with a mean radius of 0.71 mm
//! and one 60-row window in twenty at 0.72 or less; the six held 0.904 with 0.61 mm and 0.85.
//! In the 60 rows after an abrupt fault (a camera turned, the finger 10-20 % softer, 1 g hung
//! on it) the single one held 0.71-0.82 on average over five seeds, the six 0.85-0.90.

use std::collections::VecDeque;

/// The online band's radius ([module docs](super)).
#[derive(Clone, Debug)]
pub struct Band {
    /// Each tracker: its radius, its step (a share of the scale) and its weight.
    trackers: Vec<Tracker>,
    miss: f64,
    /// The weights' learning rate and the share spread evenly over the trackers each row.
    learning_rate: f64,
    share: f64,
    /// The starting radius, the least scale of a step.
    start: f64,
    /// The last [`STEP_WINDOW`] errors, for the step's scale.
    recent: VecDeque<f64>,
}

#[derive(Clone, Debug)]
struct Tracker {
    radius: f64,
    step: f64,
    weight: f64,
}

/// How many of the last errors set the band's step ([`Band`]).
pub const STEP_WINDOW: usize = 100;

/// The trackers' steps, as multiples of the band's `gain`.
const STEPS: [f64; 6] = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0];

/// The interval (rows) over which DtACI bounds the band's regret against the best tracker: its
/// learning rate and fixed share follow from it.
pub const INTERVAL_ROWS: f64 = 300.0;

impl Band {
    /// A band starting at `radius` that tracks the `level` quantile with steps of `gain` × ¼ …
    /// 8 times the larger of `radius` and the largest of the last [`STEP_WINDOW`] errors
    /// (conformal PID's scaled step: errors grown tenfold are followed in tens of rows, not
    /// hundreds).
    pub fn new(radius: f64, level: f64, gain: f64) -> Band {
        let miss = 1.0 - level;
        let k = STEPS.len() as f64;
        let i = INTERVAL_ROWS;
        Band {
            trackers: STEPS
                .iter()
                .map(|s| Tracker {
                    radius,
                    step: s * gain,
                    weight: 1.0 / k,
                })
                .collect(),
            miss,
            learning_rate: (3.0 / i).sqrt()
                * (((k * i).ln() + 2.0) / ((1.0 - miss).powi(2) * miss.powi(3))).sqrt(),
            share: 1.0 / (2.0 * i),
            start: radius,
            recent: VecDeque::with_capacity(STEP_WINDOW),
        }
    }

    /// The radius for the next row (at least 0).
    pub fn radius(&self) -> f64 {
        let r: f64 = self.trackers.iter().map(|t| t.weight * t.radius).sum();
        r.max(0.0)
    }

    /// Takes the row's error; whether the band held it. An error that is not a finite number
    /// is a miss that moves nothing.
    pub fn update(&mut self, error: f64) -> bool {
        if !error.is_finite() {
            return false;
        }
        let covered = error <= self.radius();
        if self.recent.len() == STEP_WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(error);
        let scale = self.recent.iter().copied().fold(self.start, f64::max);
        let alpha = self.miss;
        if scale > 0.0 && scale.is_finite() {
            for t in &mut self.trackers {
                // The pinball loss of the `level` quantile, in units of the step's scale.
                let over = error - t.radius;
                let loss = if over > 0.0 {
                    (1.0 - alpha) * over
                } else {
                    -alpha * over
                } / scale;
                t.weight *= (-self.learning_rate * loss).exp();
            }
        }
        let total: f64 = self.trackers.iter().map(|t| t.weight).sum();
        let k = self.trackers.len() as f64;
        for t in &mut self.trackers {
            let weight = if total > 0.0 && total.is_finite() {
                t.weight / total
            } else {
                1.0 / k
            };
            t.weight = (1.0 - self.share) * weight + self.share / k;
            let missed = f64::from(u8::from(error > t.radius));
            t.radius += t.step * scale * (missed - alpha);
        }
        covered
    }
}
