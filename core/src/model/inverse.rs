//! The inverse model: the inputs (pressures) that put a fitted MSVR's outputs (the tip) at a
//! target, for feed-forward control.
//!
//! Bounded least squares, min ‖f(x) − target‖² for `lower ≤ x ≤ upper`:
//! 1. Starts: the model on a grid of `grid` values per input over the box; the `starts` best
//!    grid points (the nearest tips) start a local search each.
//! 2. Local search: projected Levenberg-Marquardt with the model's analytic Jacobian
//!    ([`Differentiable::predict_with_jacobian`]). An input at a bound whose gradient points outwards is
//!    held there; the others take the damped Gauss-Newton step, clipped to the box. A step that
//!    lowers the error is taken and the damping relaxed, otherwise the damping grows.
//! 3. The best local result. The target counts as reached when the model's tip is within
//!    `reach` of it; otherwise the result is the nearest point the model can reach inside the
//!    box (from the starts tried), which is what a user should be told.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::{Differentiable, Predict};

/// Settings of the inverse search.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct InverseOptions {
    /// Box of the inputs.
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// Grid values per input for the starts.
    pub grid: usize,
    /// Local searches from the best grid points.
    pub starts: usize,
    /// Iterations of each local search at most.
    pub max_iter: usize,
    /// A target is reached when the model's output is this close (output units).
    pub reach: f64,
}

impl InverseOptions {
    /// The box a model can be trusted in: its training range, intersected with `[lo, hi]` for
    /// the inputs `cap` selects (e.g. the pressures, within 0 and the regulator's limit).
    ///
    /// # Panics
    /// If the model does not know its training range.
    pub fn within_training_range(
        model: &dyn Predict,
        cap: impl Fn(&str) -> Option<(f64, f64)>,
    ) -> Self {
        let (min, max) = model
            .training_range()
            .expect("a model the inverse solves knows its training range");
        let (mut lower, mut upper) = (min.to_vec(), max.to_vec());
        for (j, name) in model.inputs().iter().enumerate() {
            if let Some((lo, hi)) = cap(name) {
                lower[j] = lower[j].max(lo);
                upper[j] = upper[j].min(hi);
            }
        }
        InverseOptions {
            lower,
            upper,
            grid: 6,
            starts: 6,
            max_iter: 100,
            reach: 0.01,
        }
    }
}

/// The answer for one target.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct InverseSolution {
    pub inputs: Vec<f64>,
    /// The model's outputs at those inputs.
    pub achieved: Vec<f64>,
    /// Euclidean distance from the target (output units).
    pub error: f64,
    pub reached: bool,
}

/// Errors of an inverse problem.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InverseError {
    #[error("the target has {got} values but the model has {want} outputs")]
    TargetSize { got: usize, want: usize },
    #[error("target {value:e} is not a position (not finite, or beyond ±1e100, which no model gives): give finite numbers in the outputs' units")]
    TargetValue { value: f64 },
    #[error("input {name}: empty box [{lower}, {upper}]")]
    EmptyBox {
        name: String,
        lower: f64,
        upper: f64,
    },
    /// Learning from a run the model does not describe: its prediction of the commands played
    /// is farther from what was measured than [`super::trajectory::MODEL_MISS`] times the run's
    /// own extent.
    #[error("the model predicts the run played {miss:.3e} (RMS) from what was measured, more than {} times the run's extent ({extent:.3e}): learning from it would chase the model's error; fit the model on this finger again", super::trajectory::MODEL_MISS)]
    ModelMisses { miss: f64, extent: f64 },
}

/// Solves for the inputs that put `model`'s outputs at `target`.
///
/// # Errors
/// [`InverseError`] for a target of the wrong size, a value no model gives (its distances
/// would overflow: 1e300 was said to be "inf away"), or an empty box.
pub fn solve(
    model: &dyn Differentiable,
    target: &[f64],
    options: &InverseOptions,
) -> Result<InverseSolution, InverseError> {
    let (d, q) = (model.inputs().len(), model.outputs().len());
    if target.len() != q {
        return Err(InverseError::TargetSize {
            got: target.len(),
            want: q,
        });
    }
    let largest = super::msvr::LARGEST_NUMBER;
    if let Some(&value) = target
        .iter()
        .find(|v| !(v.is_finite() && v.abs() <= largest))
    {
        return Err(InverseError::TargetValue { value });
    }
    for j in 0..d {
        let ordered = options.lower[j] <= options.upper[j];
        if !ordered {
            return Err(InverseError::EmptyBox {
                name: model.inputs()[j].clone(),
                lower: options.lower[j],
                upper: options.upper[j],
            });
        }
    }
    let distance = |x: &[f64]| -> f64 {
        let mut out = vec![0.0; q];
        model.predict_row(x, &mut out);
        out.iter()
            .zip(target)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    // 1. The grid's best points.
    let n = options.grid.max(2);
    let mut grid: Vec<(f64, Vec<f64>)> = (0..n.pow(d as u32))
        .map(|mut k| {
            let x: Vec<f64> = (0..d)
                .map(|j| {
                    let i = k % n;
                    k /= n;
                    options.lower[j]
                        + (options.upper[j] - options.lower[j]) * i as f64 / (n - 1) as f64
                })
                .collect();
            (distance(&x), x)
        })
        .collect();
    grid.sort_by(|a, b| a.0.total_cmp(&b.0));
    // 2-3. A local search from each; the best.
    let best = grid
        .iter()
        .take(options.starts.max(1))
        .map(|(_, x)| local_search(model, target, x.clone(), options))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("at least one start");
    let x = best.1;
    let mut achieved = vec![0.0; q];
    model.predict_row(&x, &mut achieved);
    let error = best.0.sqrt();
    Ok(InverseSolution {
        inputs: x,
        achieved,
        error,
        reached: error <= options.reach,
    })
}

/// One planned target of a feed-forward check.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlannedTarget {
    /// The inputs that produced the target on the real (here: virtual) plant.
    pub source_inputs: Vec<f64>,
    pub target: Vec<f64>,
    pub solution: InverseSolution,
    /// The plant's outputs at the planned inputs, and their distance from the target.
    pub plant: Vec<f64>,
    pub plant_error: f64,
}

/// Sensorless feed-forward, measured: each `source_inputs` row is run through `plant` to give
/// a reachable target, the inverse model plans inputs for it, and the plant runs them.
///
/// # Errors
/// [`InverseError`] as [`solve`]; a plant failure is the closure's to report (it returns
/// `None`, and the row is skipped).
pub fn feedforward_check(
    model: &dyn Differentiable,
    plant: impl Fn(&[f64]) -> Option<Vec<f64>> + Sync,
    source_inputs: &[Vec<f64>],
    options: &InverseOptions,
) -> Result<Vec<PlannedTarget>, InverseError> {
    use rayon::prelude::*;
    let rows: Vec<Option<PlannedTarget>> = source_inputs
        .par_iter()
        .map(|p| {
            let Some(target) = plant(p) else {
                return Ok(None);
            };
            let solution = solve(model, &target, options)?;
            let Some(reached) = plant(&solution.inputs) else {
                return Ok(None);
            };
            let plant_error = reached
                .iter()
                .zip(&target)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            Ok(Some(PlannedTarget {
                source_inputs: p.clone(),
                target,
                solution,
                plant: reached,
                plant_error,
            }))
        })
        .collect::<Result<_, InverseError>>()?;
    Ok(rows.into_iter().flatten().collect())
}

/// Whether a bounded input at `v` stays where it is in a projected step: at a bound, with the
/// descent direction −`g` pointing out of the box.
pub(super) fn held_at_bound(v: f64, lower: f64, upper: f64, g: f64) -> bool {
    (v <= lower && g > 0.0) || (v >= upper && g < 0.0)
}

/// The damped Gauss-Newton step s of Levenberg-Marquardt, (H + μ (diag H + 10⁻¹²)) s = −g, over
/// the free inputs' normal matrix `h` and gradient `g`; `None` when that is not positive definite.
pub(super) fn damped_step(h: &DMatrix<f64>, g: &DVector<f64>, mu: f64) -> Option<DVector<f64>> {
    let mut damped = h.clone();
    for k in 0..h.nrows() {
        damped[(k, k)] += mu * (h[(k, k)] + 1e-12);
    }
    damped.cholesky().map(|c| c.solve(&(-g)))
}

/// Projected Levenberg-Marquardt from `x`; returns (squared error, inputs).
fn local_search(
    model: &dyn Differentiable,
    target: &[f64],
    mut x: Vec<f64>,
    o: &InverseOptions,
) -> (f64, Vec<f64>) {
    let (d, q) = (x.len(), target.len());
    let (mut out, mut jac) = (vec![0.0; q], vec![0.0; q * d]);
    let eval = |x: &[f64], out: &mut [f64], jac: &mut [f64]| -> f64 {
        model.predict_with_jacobian(x, out, jac);
        out.iter().zip(target).map(|(a, b)| (a - b).powi(2)).sum()
    };
    let mut cost = eval(&x, &mut out, &mut jac);
    let mut lambda = 1e-3;
    for _ in 0..o.max_iter {
        if cost < 1e-14 {
            break;
        }
        let j = DMatrix::from_row_slice(q, d, &jac);
        let r = DVector::from_iterator(q, out.iter().zip(target).map(|(a, b)| a - b));
        let g = j.transpose() * &r;
        let free: Vec<usize> = (0..d)
            .filter(|&k| !held_at_bound(x[k], o.lower[k], o.upper[k], g[k]))
            .collect();
        if free.is_empty() {
            break;
        }
        let jf = j.select_columns(&free);
        let gf = jf.transpose() * &r;
        let h = jf.transpose() * &jf;
        let mut improved = false;
        for _ in 0..20 {
            let Some(step) = damped_step(&h, &gf, lambda) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = x.clone();
            for (k, &i) in free.iter().enumerate() {
                trial[i] = (x[i] + step[k]).clamp(o.lower[i], o.upper[i]);
            }
            let (mut t_out, mut t_jac) = (vec![0.0; q], vec![0.0; q * d]);
            let t_cost = eval(&trial, &mut t_out, &mut t_jac);
            if t_cost < cost {
                let moved = trial
                    .iter()
                    .zip(&x)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                (x, out, jac, cost) = (trial, t_out, t_jac, t_cost);
                lambda = (lambda / 3.0).max(1e-9);
                improved = moved > 1e-10;
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    (cost, x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Columns, Dataset};
    use crate::model::msvr::{Msvr, MsvrParams};

    /// An MSVR of a smooth 3 → 3 map on a 6³ grid over [0, 250]³.
    fn model() -> (Msvr, impl Fn(&[f64]) -> [f64; 3]) {
        let f = |p: &[f64]| {
            let s: Vec<f64> = p.iter().map(|v| v / 250.0).collect();
            [
                3.0 * (s[2] - s[0]) + 0.5 * s[1] * s[2],
                2.0 * s[1] - (s[0] + s[2]) + 0.3 * s[0] * s[0],
                1.5 * (s[0] + s[1] + s[2]) - 0.4 * s[1] * s[1],
            ]
        };
        let (mut x, mut y) = (Vec::new(), Vec::new());
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..6 {
                    let p = [i as f64 * 50.0, j as f64 * 50.0, k as f64 * 50.0];
                    x.extend(p);
                    y.extend(f(&p));
                }
            }
        }
        let data = Dataset {
            source: "generated".into(),
            inputs: Columns::new(crate::data::names(&crate::data::HAND_INPUTS), x),
            outputs: Columns::new(crate::data::names(&crate::data::HAND_OUTPUTS), y),
            weights: None,
        };
        let m = MsvrParams::new(1000.0, 0.001, 0.5)
            .check()
            .unwrap()
            .fit(&data)
            .unwrap();
        (m, f)
    }

    #[test]
    fn the_jacobian_is_the_derivative_of_the_prediction() {
        let (m, _) = model();
        let x = [73.0, 141.0, 12.5];
        let (mut out, mut jac) = (vec![0.0; 3], vec![0.0; 9]);
        m.predict_with_jacobian(&x, &mut out, &mut jac);
        let mut plain = vec![0.0; 3];
        m.predict_row(&x, &mut plain);
        assert_eq!(out, plain);
        for j in 0..3 {
            let h = 1e-4;
            let (mut up, mut down) = (x, x);
            up[j] += h;
            down[j] -= h;
            let (mut fu, mut fd) = (vec![0.0; 3], vec![0.0; 3]);
            m.predict_row(&up, &mut fu);
            m.predict_row(&down, &mut fd);
            for o in 0..3 {
                let numeric = (fu[o] - fd[o]) / (2.0 * h);
                assert!(
                    (numeric - jac[o * 3 + j]).abs() < 1e-7 * (1.0 + numeric.abs()),
                    "∂f{o}/∂x{j}: {numeric} vs {}",
                    jac[o * 3 + j]
                );
            }
        }
    }

    #[test]
    fn reachable_targets_are_reached_and_others_get_the_nearest_point() {
        let (m, f) = model();
        let options = InverseOptions::within_training_range(&m, |_| Some((0.0, 250.0)));
        for p in [[30.0, 200.0, 110.0], [0.0, 0.0, 250.0], [240.0, 15.0, 60.0]] {
            let mut target = vec![0.0; 3];
            m.predict_row(&p, &mut target);
            let s = solve(&m, &target, &options).unwrap();
            assert!(s.reached && s.error < 1e-4, "{p:?}: {s:?}");
            assert!(s.inputs.iter().all(|&v| (0.0..=250.0).contains(&v)));
            let truth = f(&s.inputs);
            let err: f64 = truth
                .iter()
                .zip(&target)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(err < 0.05, "the map at the answer is {err} from the target");
        }
        // Far outside: not reached, the nearest point is on the boundary of the box.
        let s = solve(&m, &[50.0, 0.0, 0.0], &options).unwrap();
        assert!(!s.reached && s.error > 40.0, "{s:?}");
        assert!(s.inputs.iter().any(|&v| v == 0.0 || v == 250.0), "{s:?}");
        // A tighter pressure cap is respected.
        let capped = InverseOptions::within_training_range(&m, |_| Some((0.0, 100.0)));
        let s = solve(&m, &[0.0, 0.0, 4.0], &capped).unwrap();
        assert!(
            s.inputs.iter().all(|&v| (0.0..=100.0).contains(&v)),
            "{s:?}"
        );
        assert_eq!(
            solve(&m, &[1.0, 2.0], &options),
            Err(InverseError::TargetSize { got: 2, want: 3 })
        );
    }
}
