//! Grid search on log-spaced values of each axis of a [`SearchSpace`]: the baseline the paper
//! says ACO beats. With a budget B and d axes, each axis gets ⌊B^(1/d)⌋ values (at least 2);
//! the points are visited with the last axis varying slowest, and scored in batches of
//! `batch`, each batch one history iteration.

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
    /// The values per axis for the budget in a box of `axes` axes.
    pub fn per_axis(&self, axes: usize) -> usize {
        ((self.budget as f64).powf(1.0 / axes.max(1) as f64) + 1e-9)
            .floor()
            .max(2.0) as usize
    }

    /// The grid's points in a box of `axes` axes.
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
        let axes = space.len();
        if self.budget < 1 << axes {
            return invalid(
                "budget",
                self.budget as f64,
                "must allow 2 values per axis (2^axes candidates)",
            );
        }
        if self.batch == 0 {
            return invalid("batch", 0.0, "must be at least 1");
        }
        let k = self.per_axis(axes);
        let bounds = space.log_bounds();
        // Point i's index on axis a is its a-th base-k digit, the first axis the fastest.
        let points: Vec<Point> = (0..self.points(axes))
            .map(|i| {
                let x: Vec<f64> = bounds
                    .iter()
                    .enumerate()
                    .map(|(a, &(lo, hi))| {
                        let step = (i / k.pow(a as u32)) % k;
                        lo + (hi - lo) * step as f64 / (k - 1) as f64
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
