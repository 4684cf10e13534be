//! Grid search on log-spaced values of C, ε and σ inside the data-derived [`SearchSpace`]: the
//! baseline the paper says ACO beats. With a budget B, each axis gets ⌊B^(1/3)⌋ values
//! (at least 2); candidates are scored in batches of `batch`, each batch one history iteration.

use std::sync::atomic::AtomicBool;

use serde::{Deserialize, Serialize};

use super::{
    invalid, Hyper, Objective, Observer, SearchError, SearchResult, SearchSpace, SearchStop,
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
    /// The values per axis for the budget.
    pub fn per_axis(&self) -> usize {
        ((self.budget as f64).cbrt() + 1e-9).floor().max(2.0) as usize
    }

    /// Scores every grid point.
    ///
    /// # Errors
    /// [`SearchError::InvalidSetting`] for a budget below 8 or an empty batch;
    /// [`SearchError::NothingValid`] when no fit succeeded.
    pub fn run(
        &self,
        space: &SearchSpace,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError> {
        if self.budget < 8 {
            return invalid(
                "budget",
                self.budget as f64,
                "must be at least 8 (2 values per axis)",
            );
        }
        if self.batch == 0 {
            return invalid("batch", 0.0, "must be at least 1");
        }
        space.check()?;
        let k = self.per_axis();
        let axis = |(lo, hi): (f64, f64)| -> Vec<f64> {
            (0..k)
                .map(|i| (lo + (hi - lo) * i as f64 / (k - 1) as f64).exp())
                .collect()
        };
        let [c, eps, sigma] = space.log_bounds().map(axis);
        let mut points = Vec::with_capacity(k * k * k);
        for &s in &sigma {
            for &cv in &c {
                for &e in &eps {
                    points.push(Hyper {
                        c: cv,
                        epsilon: e,
                        sigma: s,
                    });
                }
            }
        }
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
