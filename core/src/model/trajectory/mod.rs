//! The dynamic inverse: commands along a whole trajectory so that a history model's predicted
//! outputs follow a target path (the muscles' lag anticipated), and learning from repetitions
//! (iterative learning control).
//!
//! The finger is at rest (every input 0 for all time before) at the first row; command `u_k`
//! is in force from row k's time until row k+1's, as in a dynamic session's log. The model's
//! features at row k are linear in the commands: the present `u_k`, and each memory block
//! `Σ_{j≤k} w_kj u_j` (an exponential filter: `w_kj = g_j Π_{j<i≤k} (1 − g_i)`,
//! `g_i = 1 − exp(−Δt_i / τ)`; a lag: `u_{k−l}`), so the outputs' Jacobian over every command
//! is the kernel's exact derivative through those weights.
//!
//! [`plan`]: min Σ_k ‖y_k − y*_k‖² + λ (Δ₀/Δt)² Σ_k ‖(u_k − u_{k−1}) / range‖² over the box,
//! each input changing by at most its rate limit per second. Δt is the path's median step and
//! Δ₀ = 1/30 s ([`SMOOTHNESS_STEP_S`]): the cost is the sum over rows of ∫ ‖e‖² dt + λ Δ₀² ∫ ‖u̇ /
//! range‖² dt divided by Δt, so a path sampled faster or slower is planned alike and λ means
//! what it means on a 30 Hz path. Solved by projected Levenberg-Marquardt on
//! receding windows (a few times the model's memory long; the first half of each window is
//! kept, the rest planned again with the next), from the pointwise inverse of the steady state
//! (the static feed-forward). A model without history has nothing to anticipate: the pointwise
//! inverse is the plan.
//!
//! [`learn`]: one repetition of iterative learning control. The error of the run played with the
//! previous commands, e = y* − y_measured, smoothed along time (the Q-filter) and shifted by how
//! late the outputs measured run against the model's prediction of them (a finger slower than
//! the model: the error at k + late is what the commands at k left), moves the reference the
//! model's prediction of those commands aims at: r = ŷ(u_prev) + γ e; the next
//! commands are planned for r from u_prev (a Gauss-Newton step on the model's Jacobian along the
//! path). Where the plant's map is the model's times (1 + δ), the error shrinks by |1 − γ(1 + δ)|
//! a repetition: with γ = 0.5 it converges for δ from −100 % to +300 %, by 0.3-0.7 a
//! repetition for δ within ±40 %. The smoothness term matters here: commands that chatter
//! where the model is least right make the corrections grow instead of shrink (on the virtual
//! plant, λ = 0.001 stalled at 0.3 mm RMS where λ = 0.05-0.2 went on to 0.01).

use rayon::prelude::*;
use serde::Serialize;

use super::history::{History, Memory};
use super::inverse::{self, InverseError, InverseOptions};
use super::msvr::kernel::squared_distance;
use super::Differentiable;
use crate::stats;

mod window;

use window::{project, refine};

/// A model on its features, and the history that builds them from the commands (`None`: the
/// features are the commands).
#[derive(Clone, Copy)]
pub struct Dynamic<'a> {
    pub model: &'a dyn Differentiable,
    pub history: Option<&'a History>,
}

/// Settings of [`plan`] and [`learn`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlanOptions {
    /// The pointwise inverse's settings (the box, the reach).
    pub inverse: InverseOptions,
    /// Largest change of each input per unit of time (`None`: unlimited).
    pub rate: Option<Vec<f64>>,
    /// λ: the weight of the commands' smoothness against the squared output error, on a path
    /// sampled at [`SMOOTHNESS_STEP_S`] (other steps are scaled to weigh the same over time).
    pub smoothness: f64,
    /// Levenberg-Marquardt iterations per window at most.
    pub max_iter: usize,
}

/// Commands along a trajectory and what the model predicts they do.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PathPlan {
    /// `n × d`, row-major.
    pub inputs: Vec<f64>,
    /// The model's outputs along the commands (`n × q`).
    pub predicted: Vec<f64>,
    /// The model's inputs (the commands and their history) each output was predicted at
    /// (`n × features`): where an interval's radius is taken.
    pub features: Vec<f64>,
    /// Each row's distance from its target, and whether it is within reach.
    pub error: Vec<f64>,
    pub reached: Vec<bool>,
}

impl PathPlan {
    /// Root mean square of the rows' errors.
    pub fn rms(&self) -> f64 {
        rms(&self.error)
    }
}

/// Root mean square.
pub fn rms(values: &[f64]) -> f64 {
    (values.iter().map(|e| e * e).sum::<f64>() / values.len().max(1) as f64).sqrt()
}

impl<'a> Dynamic<'a> {
    fn d(&self) -> usize {
        self.history
            .map_or(self.model.inputs().len(), |h| h.inputs.len())
    }

    fn blocks(&self) -> usize {
        self.history.map_or(0, |h| h.memory.blocks())
    }

    /// The model's own inputs per row: the commands, then each memory block's.
    fn width(&self) -> usize {
        self.d() * (1 + self.blocks())
    }

    /// The rows memory reaches back (for the windows' length).
    fn memory_rows(&self, time: &[f64]) -> usize {
        let dt = median_step(time);
        match self.history.map(|h| &h.memory) {
            None => 0,
            Some(Memory::Ema { tau }) => {
                let longest = tau.iter().copied().fold(0.0, f64::max);
                (longest / dt).ceil() as usize
            }
            Some(Memory::Lags { rows }) => *rows,
        }
    }

    /// Block `b`'s weights at row `k`: (j, w) with the block = Σ w u_j.
    fn weights(&self, time: &[f64], b: usize, k: usize) -> Vec<(usize, f64)> {
        match self.history.map(|h| &h.memory) {
            Some(Memory::Ema { tau }) => {
                let mut out = Vec::new();
                let mut kept = 1.0;
                for j in (1..=k).rev() {
                    let g = 1.0 - (-(time[j] - time[j - 1]) / tau[b]).exp();
                    out.push((j, g * kept));
                    kept *= 1.0 - g;
                    if kept < 1e-12 {
                        break;
                    }
                }
                // Row 0 is reached from rest with no time elapsed: its weight is 0.
                out
            }
            Some(Memory::Lags { .. }) => k
                .checked_sub(b + 1)
                .map(|j| vec![(j, 1.0)])
                .unwrap_or_default(),
            None => Vec::new(),
        }
    }

    /// The model along the rows of `time`: every block's weights at every row.
    fn along<'t>(self, time: &'t [f64]) -> Along<'a, 't> {
        let weights = (0..self.blocks())
            .map(|b| (0..time.len()).map(|k| self.weights(time, b, k)).collect())
            .collect();
        Along {
            dynamic: self,
            time,
            weights,
        }
    }
}

/// A model along the rows of a time grid: the features of any commands on it.
struct Along<'a, 't> {
    dynamic: Dynamic<'a>,
    time: &'t [f64],
    /// Block b's weights at row k: `weights[b][k]`, (j, w) with the block = Σ w u_j.
    weights: Vec<Vec<Vec<(usize, f64)>>>,
}

impl Along<'_, '_> {
    /// The features at row `k` of the commands `u` (`n × d`).
    fn features(&self, u: &[f64], k: usize) -> Vec<f64> {
        let d = self.dynamic.d();
        let mut x = vec![0.0; self.dynamic.width()];
        x[..d].copy_from_slice(&u[k * d..(k + 1) * d]);
        for (b, w) in self.weights.iter().enumerate() {
            let block = &mut x[d * (1 + b)..d * (2 + b)];
            for &(j, w) in &w[k] {
                for i in 0..d {
                    block[i] += w * u[j * d + i];
                }
            }
        }
        x
    }

    /// The features of every row of the commands `u` (`n × features`), rows in parallel.
    fn all_features(&self, u: &[f64]) -> Vec<f64> {
        let width = self.dynamic.width();
        let mut x = vec![0.0; self.time.len() * width];
        x.par_chunks_mut(width)
            .enumerate()
            .for_each(|(k, row)| row.copy_from_slice(&self.features(u, k)));
        x
    }

    /// The model's outputs at the rows of `features` (`n × q`).
    fn predict_at(&self, features: &[f64]) -> Vec<f64> {
        let q = self.dynamic.model.outputs().len();
        let width = self.dynamic.width();
        let mut y = vec![0.0; features.len() / width * q];
        y.par_chunks_mut(q)
            .zip(features.par_chunks(width))
            .for_each(|(out, x)| self.dynamic.model.predict_row(x, out));
        y
    }

    /// The model's outputs along the commands `u` from rest (`n × q`).
    fn predict(&self, u: &[f64]) -> Vec<f64> {
        self.predict_at(&self.all_features(u))
    }

    /// The predicted outputs of commands `u`, the features they were predicted at, and their
    /// distances from `targets`.
    fn finish(&self, targets: &[f64], u: Vec<f64>, reach: f64) -> PathPlan {
        let q = self.dynamic.model.outputs().len();
        let features = self.all_features(&u);
        let predicted = self.predict_at(&features);
        let error = distances(&predicted, targets, q);
        PathPlan {
            inputs: u,
            predicted,
            features,
            reached: error.iter().map(|&e| e <= reach).collect(),
            error,
        }
    }
}

/// The distance between each row of `a` and of `b` (rows of `q`).
pub fn distances(a: &[f64], b: &[f64], q: usize) -> Vec<f64> {
    a.chunks(q)
        .zip(b.chunks(q))
        .map(|(a, b)| squared_distance(a, b).sqrt())
        .collect()
}

/// The half-width of the Q-filter on the error measured (s): ±2 rows of a 30 Hz path, so that
/// a path sampled faster or slower is filtered over the same time.
pub const ERROR_SMOOTHING_S: f64 = 2.0 / 30.0;

/// The step λ is stated at (s): a 30 Hz path weighs its commands' successive differences by
/// λ itself, a path of step Δt by λ (Δ₀/Δt)², the same weight over time.
pub const SMOOTHNESS_STEP_S: f64 = 1.0 / 30.0;

/// The shortest window [`plan`] and [`learn`] solve at once (s; 60 rows at 30 Hz), however short
/// the model's memory.
pub const MIN_WINDOW_S: f64 = 2.0;

/// `seconds` of `time` in rows at its median step (at least 1).
fn rows_in(seconds: f64, time: &[f64]) -> usize {
    ((seconds / median_step(time)).round() as usize).max(1)
}

/// The median time step of `time` (positive).
fn median_step(time: &[f64]) -> f64 {
    let mut steps: Vec<f64> = time.windows(2).map(|w| w[1] - w[0]).collect();
    stats::upper_median(&mut steps).unwrap_or(1.0)
}

/// The static feed-forward along `targets` (`n × q`, one row per `time`): each row's pointwise
/// inverse of the steady state `steady`, and what the model predicts those commands do when
/// played in time.
///
/// # Errors
/// [`InverseError`]: targets of the wrong width or an empty box.
pub fn pointwise(
    dynamic: Dynamic<'_>,
    steady: &dyn Differentiable,
    time: &[f64],
    targets: &[f64],
    options: &PlanOptions,
) -> Result<PathPlan, InverseError> {
    let q = steady.outputs().len();
    let solutions: Vec<inverse::InverseSolution> = targets
        .par_chunks(q)
        .map(|t| inverse::solve(steady, t, &options.inverse))
        .collect::<Result<_, _>>()?;
    let u = solutions.iter().flat_map(|s| s.inputs.clone()).collect();
    Ok(dynamic
        .along(time)
        .finish(targets, u, options.inverse.reach))
}

/// Plans commands along `targets` from rest, starting from `start` (the [`pointwise`] plan):
/// the module docs' least squares. A model without history keeps `start`, within the box and
/// the rate limit.
pub fn plan(
    dynamic: Dynamic<'_>,
    time: &[f64],
    targets: &[f64],
    start: &PathPlan,
    options: &PlanOptions,
) -> PathPlan {
    let along = dynamic.along(time);
    if dynamic.history.is_none() {
        let mut u = start.inputs.clone();
        project(&mut u, time, 0, options);
        return along.finish(targets, u, options.inverse.reach);
    }
    refine(&along, targets, start.inputs.clone(), options)
}

/// How far a model may miss the run it learns from, in units of the run's extent (the RMS
/// distance of the targets and of the outputs measured from the targets' mean, plus the
/// reach): learning shrinks the error only where the model's map is within a few times the
/// plant's (module docs), and a model whose prediction of the run lies ten extents away is not
/// a model of this finger.
pub const MODEL_MISS: f64 = 10.0;

/// One repetition of learning (module docs): the commands `previous` were played and the
/// outputs `measured` (`n × q`, at the rows' times) seen; `gain` is γ. The plan's `reached`
/// says whether each row's prediction reached the reference the model aims at (the target
/// moved by the error measured).
///
/// # Errors
/// [`InverseError::ModelMisses`] when the model's prediction of the run played is farther from
/// what was measured than [`MODEL_MISS`] extents.
pub fn learn(
    dynamic: Dynamic<'_>,
    time: &[f64],
    targets: &[f64],
    previous: &[f64],
    measured: &[f64],
    gain: f64,
    options: &PlanOptions,
) -> Result<PathPlan, InverseError> {
    let q = dynamic.model.outputs().len();
    let along = dynamic.along(time);
    let predicted = along.predict(previous);
    let (miss, extent) = (
        rms(&distances(&predicted, measured, q)),
        run_extent(targets, measured, q) + options.inverse.reach,
    );
    if miss.is_nan() || miss > MODEL_MISS * extent {
        return Err(InverseError::ModelMisses { miss, extent });
    }
    let error: Vec<f64> = targets.iter().zip(measured).map(|(t, m)| t - m).collect();
    let error = smooth_rows(&error, q, rows_in(ERROR_SMOOTHING_S, time));
    // A finger slower than the model shows each command's effect later: the error at k + late
    // is what the commands at k left.
    let late = lateness(&predicted, measured, q, rows_in(MAX_LATE_S, time));
    let n = error.len() / q;
    let error: Vec<f64> = (0..n)
        .flat_map(|k| {
            let j = (k as i64 + late).clamp(0, n as i64 - 1) as usize;
            &error[j * q..(j + 1) * q]
        })
        .copied()
        .collect();
    let reference: Vec<f64> = predicted
        .iter()
        .zip(&error)
        .map(|(p, e)| p + gain * e)
        .collect();
    Ok(refine(&along, &reference, previous.to_vec(), options))
}

/// The most the plant's outputs may lag (or lead) the model's prediction of them (s).
const MAX_LATE_S: f64 = 0.3;

/// How many rows the outputs `measured` lag the model's prediction of them (negative: lead),
/// within ±`reach`: the shift that brings them closest (mean squared distance over the rows
/// both cover).
fn lateness(predicted: &[f64], measured: &[f64], q: usize, reach: usize) -> i64 {
    let n = predicted.len() / q;
    let cost = |shift: i64| -> f64 {
        let rows = (0..n as i64).filter(|&k| (0..n as i64).contains(&(k + shift)));
        let (sum, count) = rows.fold((0.0, 0usize), |(sum, count), k| {
            let (a, b) = (k as usize * q, (k + shift) as usize * q);
            let d = squared_distance(&predicted[a..a + q], &measured[b..b + q]);
            (sum + d, count + 1)
        });
        sum / count.max(1) as f64
    };
    let reach = reach.min(n / 4) as i64;
    (-reach..=reach)
        .min_by(|&a, &b| cost(a).total_cmp(&cost(b)).then(a.abs().cmp(&b.abs())))
        .unwrap_or(0)
}

/// The RMS distance of the targets and of the outputs measured from the targets' mean.
fn run_extent(targets: &[f64], measured: &[f64], q: usize) -> f64 {
    let n = (targets.len() / q).max(1);
    let mean: Vec<f64> = (0..q)
        .map(|o| targets.iter().skip(o).step_by(q).sum::<f64>() / n as f64)
        .collect();
    let centre: Vec<f64> = mean.iter().copied().cycle().take(targets.len()).collect();
    rms(&distances(targets, &centre, q)) + rms(&distances(measured, &centre, q))
}

/// A centred moving average of each column over ±`half` rows (fewer at the ends): zero phase.
fn smooth_rows(values: &[f64], q: usize, half: usize) -> Vec<f64> {
    let n = values.len() / q;
    let mut out = vec![0.0; values.len()];
    for k in 0..n {
        let (lo, hi) = (k.saturating_sub(half), (k + half).min(n - 1));
        for o in 0..q {
            let sum: f64 = (lo..=hi).map(|j| values[j * q + o]).sum();
            out[k * q + o] = sum / (hi - lo + 1) as f64;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moving_average_keeps_a_line_and_flattens_a_spike() {
        let line: Vec<f64> = (0..10).map(f64::from).collect();
        assert_eq!(smooth_rows(&line, 1, 2)[5], 5.0);
        let mut spike = vec![0.0; 9];
        spike[4] = 5.0;
        assert_eq!(smooth_rows(&spike, 1, 2)[4], 1.0);
    }
}
