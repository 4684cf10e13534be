//! Continuous ant colony optimisation, ACO_R (Socha & Dorigo, EJOR 185 (2008) 1155), on the
//! logarithms of a [`SearchSpace`]'s axes.
//!
//! An archive keeps the k best solutions found, ranked by fitness; rank l (0-based) has weight
//! ∝ exp(−l² / (2 q² k²)). Each ant picks an archive member s_l by weight and samples every
//! coordinate from N(s_l, ξ · mean over the archive of |s_e − s_l|), reflected into the box.
//! The m ants of an iteration are scored together; the archive keeps the k best of old and new,
//! so an ant that cannot beat the archive's worst is raced out (see [`super::Objective`]).
//! Searching in logarithms gives each decade of a parameter (MSVR's C, ε and σ) the same
//! resolution, where the paper's digits spend it on the largest values.

use std::sync::atomic::AtomicBool;

use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use super::{
    invalid, Objective, Observer, Point, SearchError, SearchResult, SearchSpace, SearchStop,
    Tracker,
};

/// ACO_R settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AcoR {
    /// Archive size k.
    pub archive: usize,
    /// Ants (new candidates) per iteration m.
    pub ants: usize,
    /// Locality q: small values favour the best solutions.
    pub q: f64,
    /// Spread ξ of the sampling (like the evaporation rate).
    pub xi: f64,
    /// Candidates evaluated at most, the archive's first fill included.
    pub budget: usize,
    pub seed: u64,
}

impl Default for AcoR {
    fn default() -> Self {
        AcoR {
            archive: 12,
            ants: 8,
            q: 0.2,
            xi: 0.85,
            budget: 400,
            seed: crate::DEFAULT_SEED,
        }
    }
}

impl AcoR {
    fn check(&self) -> Result<(), SearchError> {
        if self.archive < 2 {
            return invalid("archive", self.archive as f64, "must be at least 2");
        }
        if self.ants == 0 {
            return invalid("ants", 0.0, "must be at least 1");
        }
        if self.budget < self.archive {
            return invalid(
                "budget",
                self.budget as f64,
                format!(
                    "must be at least {} candidates: the first fill of the colony's archive",
                    self.archive
                ),
            );
        }
        if !(self.q > 0.0 && self.q.is_finite()) {
            return invalid("q", self.q, "must be finite and > 0");
        }
        if !(self.xi > 0.0 && self.xi.is_finite()) {
            return invalid("xi", self.xi, "must be finite and > 0");
        }
        Ok(())
    }

    /// Runs the search on `objective` inside `space`.
    ///
    /// # Errors
    /// [`SearchError::InvalidSetting`] for a bad setting; [`SearchError::NothingValid`] if no
    /// candidate found a finite fitness.
    pub fn run(
        &self,
        space: &SearchSpace,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError> {
        self.check()?;
        space.check()?;
        let bounds = space.log_bounds();
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let mut tracker = Tracker::new(observer, interrupt);

        let first: Vec<Vec<f64>> = (0..self.archive)
            .map(|_| {
                bounds
                    .iter()
                    .map(|&(lo, hi)| rng.random_range(lo..=hi))
                    .collect()
            })
            .collect();
        let mut archive = self.score(space, first, f64::INFINITY, objective, &mut tracker);
        archive.sort_by(|a, b| a.1.total_cmp(&b.1));
        let mut spent = self.archive;
        let weights: Vec<f64> = (0..self.archive)
            .map(|l| {
                let qk = self.q * self.archive as f64;
                (-((l * l) as f64) / (2.0 * qk * qk)).exp()
            })
            .collect();
        let total: f64 = weights.iter().sum();
        while spent < self.budget {
            if tracker.interrupted() {
                return tracker.finish(SearchStop::Interrupted);
            }
            let m = self.ants.min(self.budget - spent);
            let ants: Vec<Vec<f64>> = (0..m)
                .map(|_| {
                    let mut x = rng.random::<f64>() * total;
                    let l = weights
                        .iter()
                        .position(|&w| {
                            x -= w;
                            x < 0.0
                        })
                        .unwrap_or(self.archive - 1);
                    let centre = &archive[l].0;
                    (0..bounds.len())
                        .map(|d| {
                            let spread = self.xi
                                * archive
                                    .iter()
                                    .map(|(s, _)| (s[d] - centre[d]).abs())
                                    .sum::<f64>()
                                / (self.archive - 1) as f64;
                            let z: f64 = StandardNormal.sample(&mut rng);
                            reflect(centre[d] + spread * z, bounds[d])
                        })
                        .collect()
                })
                .collect();
            spent += m;
            let bar = archive[self.archive - 1].1;
            archive.extend(self.score(space, ants, bar, objective, &mut tracker));
            archive.sort_by(|a, b| a.1.total_cmp(&b.1));
            archive.truncate(self.archive);
        }
        tracker.finish(SearchStop::Budget)
    }

    /// Scores points (in logarithms) against the bar, records the iteration, returns (point,
    /// fitness) pairs.
    fn score(
        &self,
        space: &SearchSpace,
        points: Vec<Vec<f64>>,
        bar: f64,
        objective: &Objective,
        tracker: &mut Tracker,
    ) -> Vec<(Vec<f64>, f64)> {
        let candidates: Vec<Point> = points.iter().map(|x| space.point_at_log(x)).collect();
        let scores = objective(&candidates, bar);
        tracker.record(&candidates, &scores);
        points.into_iter().zip(scores).collect()
    }
}

/// Folds a coordinate back into [lo, hi] by reflection at the walls.
fn reflect(x: f64, (lo, hi): (f64, f64)) -> f64 {
    let width = hi - lo;
    let mut y = (x - lo).rem_euclid(2.0 * width);
    if y > width {
        y = 2.0 * width - y;
    }
    lo + y
}
