//! Grid search on log-spaced values of each axis of a [`SearchSpace`]: the baseline the paper
//! says ACO beats. With a budget B and d axes free to vary, each gets ⌊B^(1/d)⌋ values (at
//! least 2), an axis held at one value (lo = hi) that value alone; the points are visited with
//! the last axis varying slowest, and scored in batches of `batch`, each batch one history
//! iteration.

use std::sync::atomic::AtomicBool;

use serde::{Deserialize, Serialize};

use super::{
    invalid, Objective, Observer, Point, SearchError, SearchResult, SearchSpace, SearchStop,
    Tracker,
};

/// Grid settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    /// Candidates evaluated at most.
    pub budget: usize,
    /// Candidates per history iteration.
    pub batch: usize,
}

impl Default for Grid {
    fn default() -> Self {
        Grid {
            budget: 400,
            batch: 20,
        }
    }
}

impl Grid {
    /// The values per axis for the budget in a box of `axes` axes free to vary.
    pub fn per_axis(&self, axes: usize) -> usize {
        ((self.budget as f64).powf(1.0 / axes.max(1) as f64) + 1e-9)
            .floor()
            .max(2.0) as usize
    }

    /// The grid's points in a box of `axes` axes free to vary.
    pub fn points(&self, axes: usize) -> usize {
        self.per_axis(axes).pow(axes as u32)
    }

    /// Scores every grid point.
    ///
    /// # Errors
    /// [`SearchError::InvalidSetting`] for a budget below 2 values per axis or an empty batch;
    /// a bad box ([`SearchSpace::check`]); [`SearchError::NothingValid`] when no fit succeeded.
    pub fn run(
        &self,
        space: &SearchSpace,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError> {
        space.check()?;
        let bounds = space.log_bounds();
        // An axis held at one value (lo = hi) gets that value alone; the budget goes to the rest.
        let free = bounds.iter().filter(|(lo, hi)| hi > lo).count();
        if self.budget < 1 << free {
            return invalid(
                "budget",
                self.budget as f64,
                "must allow 2 values per free axis (2^axes candidates)",
            );
        }
        if self.batch == 0 {
            return invalid("batch", 0.0, "must be at least 1");
        }
        let k = self.per_axis(free);
        let counts: Vec<usize> = bounds
            .iter()
            .map(|(lo, hi)| if hi > lo { k } else { 1 })
            .collect();
        // Point i's index on each axis is a digit of i in the mixed radix `counts`, the first
        // axis the fastest.
        let points: Vec<Point> = (0..counts.iter().product())
            .map(|i: usize| {
                let mut rest = i;
                let x: Vec<f64> = bounds
                    .iter()
                    .zip(&counts)
                    .map(|(&(lo, hi), &n)| {
                        let step = rest % n;
                        rest /= n;
                        if n == 1 {
                            lo
                        } else {
                            lo + (hi - lo) * step as f64 / (n - 1) as f64
                        }
                    })
                    .collect();
                space.point_at_log(&x)
            })
            .collect();
        let mut tracker = Tracker::new(observer, interrupt);
        for chunk in points.chunks(self.batch) {
            if tracker.interrupted() {
                return tracker.finish(SearchStop::Interrupted);
            }
            let scores = objective(chunk, tracker.best_fitness());
            tracker.record(chunk, &scores);
        }
        tracker.finish(SearchStop::Budget)
    }
}
