//! The paper's ant colony (§2.3.2, eqs. 13-15, Table 1), digit by digit.
//!
//! A path crosses 12 layers of 10 digit nodes, d0 … d11, read as C = d0d1d2.d3 (0-999.9),
//! ε = 0.d4d5d6d7 (0-0.9999) and σ = d8.d9d10d11 (0-9.999) (eq. 15); its candidates name them
//! `c`, `epsilon` and `sigma`, as MSVR's search box does. The pheromone lives on the
//! edges: from the nest to each node of layer 0, and from each node of layer l to each node of
//! layer l + 1. An ant at node i moves to node j with probability τᵢⱼ / Σₛ τᵢₛ (eq. 13 with
//! η = 1). After all m ants have walked and been scored, every edge evaporates,
//! τ ← (1 − ρ) τ, and each ant k deposits 1/L_k on the edges of its path, L_k its fitness
//! (eq. 14). A path with a zero parameter is invalid: it is not fitted and deposits nothing. The
//! colony stops when every ant took the same path, or after N_max iterations.
//!
//! Defaults are the paper's: m = 20 ants, ρ = 0.04, τ0 = 0.5, N_max = 80.

use std::sync::atomic::AtomicBool;

use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{invalid, Objective, Observer, Point, SearchError, SearchResult, SearchStop, Tracker};

/// The paper's encoding (Table 1, eq. 15): each parameter's name, its digits on the path, and
/// the power of ten of its first digit.
pub const ENCODING: [(&str, usize, i32); 3] = [("c", 4, 2), ("epsilon", 4, -1), ("sigma", 4, 0)];
const LAYERS: usize = ENCODING[0].1 + ENCODING[1].1 + ENCODING[2].1;
const DIGITS: usize = 10;

/// The colony's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AcoPaper {
    pub ants: usize,
    /// Evaporation coefficient ρ.
    pub rho: f64,
    /// Initial pheromone τ0.
    pub tau0: f64,
    /// Iteration cap N_max.
    pub max_iter: usize,
    pub seed: u64,
}

impl Default for AcoPaper {
    fn default() -> Self {
        AcoPaper {
            ants: 20,
            rho: 0.04,
            tau0: 0.5,
            max_iter: 80,
            seed: crate::DEFAULT_SEED,
        }
    }
}

/// The 12 digits of a path.
pub type Path = [u8; LAYERS];

/// Reads a path as (C, ε, σ) by eq. 15 ([`ENCODING`]).
pub fn decode(path: &Path) -> Point {
    let mut point = Point::default();
    let mut at = 0;
    for (name, digits, first_power) in ENCODING {
        let value: f64 = path[at..at + digits]
            .iter()
            .enumerate()
            .map(|(i, &d)| f64::from(d) * 10f64.powi(first_power - i as i32))
            .sum();
        // Rounded to the digits' precision so a path always gives the same bits.
        let decimals = digits as i32 - 1 - first_power;
        let scale = 10f64.powi(decimals);
        point = point.with(name, (value * scale).round() / scale);
        at += digits;
    }
    point
}

impl AcoPaper {
    fn check(&self) -> Result<(), SearchError> {
        if self.ants == 0 {
            return invalid("ants", 0.0, "must be at least 1");
        }
        if !(self.rho > 0.0 && self.rho < 1.0) {
            return invalid("rho", self.rho, "must be in (0, 1)");
        }
        if !(self.tau0 > 0.0 && self.tau0.is_finite()) {
            return invalid("tau0", self.tau0, "must be finite and > 0");
        }
        if self.max_iter == 0 {
            return invalid("max_iter", 0.0, "must be at least 1");
        }
        Ok(())
    }

    /// Runs the colony on `objective` (batch of candidates → fitness, +∞ for invalid).
    ///
    /// # Errors
    /// [`SearchError::InvalidSetting`] for a bad setting; [`SearchError::NothingValid`] if no
    /// ant found a finite fitness before the search ended.
    pub fn run(
        &self,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError> {
        self.check()?;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        // nest[j]: nest → layer 0 node j; edges[l][i][j]: layer l node i → layer l+1 node j.
        let mut nest = [self.tau0; DIGITS];
        let mut edges = [[[self.tau0; DIGITS]; DIGITS]; LAYERS - 1];
        let mut tracker = Tracker::new(observer, interrupt);
        for _ in 0..self.max_iter {
            if tracker.interrupted() {
                return tracker.finish(SearchStop::Interrupted);
            }
            let paths: Vec<Path> = (0..self.ants)
                .map(|_| {
                    let mut path = [0u8; LAYERS];
                    path[0] = pick(&mut rng, &nest);
                    for l in 1..LAYERS {
                        path[l] = pick(&mut rng, &edges[l - 1][usize::from(path[l - 1])]);
                    }
                    path
                })
                .collect();
            let candidates: Vec<Point> = paths.iter().map(decode).collect();
            let scores = score_valid_paths(objective, &candidates);
            tracker.record(&candidates, &scores);

            let keep = 1.0 - self.rho;
            nest.iter_mut().for_each(|t| *t *= keep);
            edges
                .iter_mut()
                .flatten()
                .flatten()
                .for_each(|t| *t *= keep);
            for (path, &score) in paths.iter().zip(&scores) {
                if !(score.is_finite() && score > 0.0) {
                    continue; // invalid path: no deposit (a perfect fit, L = 0, has no finite 1/L)
                }
                nest[usize::from(path[0])] += 1.0 / score;
                for l in 1..LAYERS {
                    edges[l - 1][usize::from(path[l - 1])][usize::from(path[l])] += 1.0 / score;
                }
            }
            if paths.iter().all(|p| p == &paths[0]) {
                return tracker.finish(SearchStop::SamePath);
            }
        }
        tracker.finish(SearchStop::MaxIterations)
    }
}

/// The paper's rule for its digit encoding: a path with a zero-valued parameter is invalid.
pub fn is_valid_path(p: &Point) -> bool {
    p.iter().all(|(_, v)| v > 0.0)
}

/// Scores the valid paths' candidates; an invalid path scores +∞ and is never evaluated.
fn score_valid_paths(objective: &Objective, candidates: &[Point]) -> Vec<f64> {
    let valid: Vec<Point> = candidates
        .iter()
        .filter(|p| is_valid_path(p))
        .cloned()
        .collect();
    let mut scores = objective(&valid, f64::INFINITY).into_iter();
    candidates
        .iter()
        .map(|p| {
            if is_valid_path(p) {
                scores.next().unwrap_or(f64::INFINITY)
            } else {
                f64::INFINITY
            }
        })
        .collect()
}

/// A node drawn with probability proportional to its edge's pheromone (eq. 13, η = 1).
fn pick(rng: &mut ChaCha8Rng, tau: &[f64; DIGITS]) -> u8 {
    let total: f64 = tau.iter().sum();
    let mut x = rng.random::<f64>() * total;
    for (j, &t) in tau.iter().enumerate() {
        if x < t {
            return j as u8;
        }
        x -= t;
    }
    (DIGITS - 1) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_the_papers_example() {
        // Figure 4: 631288322151 → C = 631.2, ε = 0.8832, σ = 2.151.
        let p = decode(&[6, 3, 1, 2, 8, 8, 3, 2, 2, 1, 5, 1]);
        let values: Vec<(&str, f64)> = p.iter().collect();
        assert_eq!(
            values,
            [("c", 631.2), ("epsilon", 0.8832), ("sigma", 2.151)]
        );
        let table2 = decode(&[3, 2, 6, 7, 0, 1, 6, 9, 0, 2, 5, 9]);
        assert_eq!(
            crate::model::msvr::Hyper::from_point(&table2),
            crate::model::msvr::PAPER_TABLE2
        );
        assert!(!is_valid_path(&decode(&[
            0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1
        ])));
        assert!(!is_valid_path(&decode(&[
            1, 1, 1, 1, 0, 0, 0, 0, 1, 1, 1, 1
        ])));
    }
}
