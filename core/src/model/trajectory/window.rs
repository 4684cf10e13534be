//! The receding windows [`super::plan`] and [`super::learn`] solve: projected
//! Levenberg-Marquardt over each window's commands, the box and the rate limit, and the
//! smoothness weighed over time.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::{median_step, rows_in, Along, PathPlan, PlanOptions, MIN_WINDOW_S, SMOOTHNESS_STEP_S};
use crate::model::inverse;
use crate::model::msvr::kernel::squared_distance;

/// Projected Levenberg-Marquardt on receding windows from `u`.
pub(super) fn refine(
    along: &Along<'_, '_>,
    targets: &[f64],
    mut u: Vec<f64>,
    options: &PlanOptions,
) -> PathPlan {
    let n = along.time.len();
    let window = (4 * along.dynamic.memory_rows(along.time))
        .max(rows_in(MIN_WINDOW_S, along.time))
        .min(n);
    let keep = if window == n { n } else { window / 2 };
    let smooth = smoothness_weights(options, along.time);
    project(&mut u, along.time, 0, options);
    let mut s = 0;
    while s < n {
        let e = (s + window).min(n);
        let rows = Window {
            along,
            targets,
            rows: (s, e),
            smooth: &smooth,
        };
        solve_window(&rows, &mut u, options);
        s = if e == n { n } else { s + keep };
    }
    along.finish(targets, u, options.inverse.reach)
}

/// The cost of the window's rows: squared output errors and the smoothness term.
struct Window<'a, 'b> {
    along: &'b Along<'a, 'b>,
    targets: &'b [f64],
    rows: (usize, usize),
    /// λ (Δ₀/Δt)² / range² per input ([`smoothness_weights`]).
    smooth: &'b [f64],
}

impl Window<'_, '_> {
    fn cost(&self, u: &[f64]) -> f64 {
        let dynamic = self.along.dynamic;
        let (d, q) = (dynamic.d(), dynamic.model.outputs().len());
        let (s, e) = self.rows;
        let mut out = vec![0.0; q];
        let mut cost = 0.0;
        for k in s..e {
            dynamic
                .model
                .predict_row(&self.along.features(u, k), &mut out);
            cost += squared_distance(&out, &self.targets[k * q..(k + 1) * q]);
            if k > 0 {
                for i in 0..d {
                    cost += self.smooth[i] * (u[k * d + i] - u[(k - 1) * d + i]).powi(2);
                }
            }
        }
        cost
    }

    /// The Gauss-Newton normal matrix and gradient over the window's commands.
    fn normal(&self, u: &[f64]) -> (DMatrix<f64>, DVector<f64>) {
        let dynamic = self.along.dynamic;
        let (d, q) = (dynamic.d(), dynamic.model.outputs().len());
        let (s, e) = self.rows;
        let m = (e - s) * d;
        let features = dynamic.width();
        let per_row: Vec<(Vec<f64>, Vec<f64>)> = (s..e)
            .into_par_iter()
            .map(|k| {
                let (mut out, mut g) = (vec![0.0; q], vec![0.0; q * features]);
                dynamic
                    .model
                    .predict_with_jacobian(&self.along.features(u, k), &mut out, &mut g);
                (out, g)
            })
            .collect();
        let mut a = DMatrix::zeros(m, m);
        let mut grad = DVector::zeros(m);
        let mut jac = DMatrix::zeros(q, m);
        for (k, (out, g)) in (s..e).zip(&per_row) {
            jac.fill(0.0);
            // ∂y_k/∂u_j: the present block at j = k, each memory block through its weights.
            let mut columns = vec![k];
            for o in 0..q {
                for i in 0..d {
                    jac[(o, (k - s) * d + i)] += g[o * features + i];
                }
            }
            for (b, w) in self.along.weights.iter().enumerate() {
                for &(j, w) in &w[k] {
                    if j < s {
                        continue;
                    }
                    columns.push(j);
                    for o in 0..q {
                        for i in 0..d {
                            jac[(o, (j - s) * d + i)] += w * g[o * features + d * (1 + b) + i];
                        }
                    }
                }
            }
            columns.sort_unstable();
            columns.dedup();
            let r: Vec<f64> = out
                .iter()
                .zip(&self.targets[k * q..(k + 1) * q])
                .map(|(a, b)| a - b)
                .collect();
            let cols: Vec<usize> = columns
                .iter()
                .flat_map(|&j| ((j - s) * d..(j - s + 1) * d).collect::<Vec<_>>())
                .collect();
            for &c1 in &cols {
                for o in 0..q {
                    grad[c1] += jac[(o, c1)] * r[o];
                }
                for &c2 in &cols {
                    let mut v = 0.0;
                    for o in 0..q {
                        v += jac[(o, c1)] * jac[(o, c2)];
                    }
                    a[(c1, c2)] += v;
                }
            }
        }
        // Smoothness: λ/range² (u_k − u_{k−1})², u_{s−1} held where it was committed.
        for k in s.max(1)..e {
            for i in 0..d {
                let w = self.smooth[i];
                let diff = u[k * d + i] - u[(k - 1) * d + i];
                let c = (k - s) * d + i;
                grad[c] += w * diff;
                a[(c, c)] += w;
                if k > s {
                    let p = c - d;
                    grad[p] -= w * diff;
                    a[(p, p)] += w;
                    a[(c, p)] -= w;
                    a[(p, c)] -= w;
                }
            }
        }
        (a, grad)
    }
}

/// Each input's weight on its squared successive differences along rows of `time`:
/// λ (Δ₀/Δt)² / range².
fn smoothness_weights(options: &PlanOptions, time: &[f64]) -> Vec<f64> {
    let per_step = options.smoothness * (SMOOTHNESS_STEP_S / median_step(time)).powi(2);
    let (lower, upper) = (&options.inverse.lower, &options.inverse.upper);
    lower
        .iter()
        .zip(upper)
        .map(|(l, u)| per_step / (u - l).max(1e-12).powi(2))
        .collect()
}

/// Projected Levenberg-Marquardt over the commands of the window's rows (the others held).
fn solve_window(window: &Window<'_, '_>, u: &mut [f64], options: &PlanOptions) {
    let d = window.along.dynamic.d();
    let (lower, upper) = (&options.inverse.lower, &options.inverse.upper);
    let (s, e) = window.rows;
    let mut cost = window.cost(u);
    let mut mu = 1e-3;
    for _ in 0..options.max_iter {
        let (a, grad) = window.normal(u);
        let free: Vec<usize> = (0..(e - s) * d)
            .filter(|&c| {
                let i = c % d;
                !inverse::held_at_bound(u[s * d + c], lower[i], upper[i], grad[c])
            })
            .collect();
        if free.is_empty() {
            break;
        }
        let (a, grad) = (
            a.select_rows(&free).select_columns(&free),
            grad.select_rows(&free),
        );
        let mut improved = false;
        while mu < 1e12 {
            let Some(step) = inverse::damped_step(&a, &grad, mu) else {
                mu *= 4.0;
                continue;
            };
            let mut trial = u.to_vec();
            for (p, &c) in free.iter().enumerate() {
                trial[s * d + c] += step[p];
            }
            project(&mut trial, window.along.time, s, options);
            let next = window.cost(&trial);
            if next < cost {
                let done = cost - next < 1e-6 * cost;
                u.copy_from_slice(&trial);
                cost = next;
                mu = (mu / 3.0).max(1e-9);
                improved = !done;
                break;
            }
            mu *= 4.0;
        }
        if !improved {
            break;
        }
    }
}

/// The box and the rate limit, rows from `from` on, in time order. The first row leaves rest
/// (every input 0) one step before it, so its change from rest is limited as every other row's
/// (where the box excludes what the limit allows, the box wins there).
pub(super) fn project(u: &mut [f64], time: &[f64], from: usize, options: &PlanOptions) {
    let (lower, upper) = (&options.inverse.lower, &options.inverse.upper);
    let d = lower.len();
    let first_step = time.get(1).map_or(f64::INFINITY, |t1| t1 - time[0]);
    for k in from..time.len() {
        for i in 0..d {
            let mut v = u[k * d + i].clamp(lower[i], upper[i]);
            if let Some(rate) = &options.rate {
                let (last, dt) = match k {
                    0 => (0.0, first_step),
                    _ => (u[(k - 1) * d + i], time[k] - time[k - 1]),
                };
                let step = rate[i] * dt;
                v = v.clamp(last - step, last + step);
                if k == 0 {
                    v = v.clamp(lower[i], upper[i]);
                }
            }
            u[k * d + i] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::inverse::InverseOptions;

    /// A ramp of the same speed costs the same beside each row's squared error at 30 Hz and at
    /// 120 Hz: the smoothness is weighed over time (with λ per row, 120 Hz would weigh the ramp
    /// a sixteenth as much against the error).
    #[test]
    fn smoothness_weighs_a_ramp_the_same_at_any_sampling_rate() {
        let options = PlanOptions {
            inverse: InverseOptions {
                lower: vec![0.0],
                upper: vec![100.0],
                grid: 1,
                starts: 1,
                max_iter: 1,
                reach: 1.0,
            },
            rate: None,
            smoothness: 0.1,
            max_iter: 1,
        };
        let per_row = |hz: f64| {
            let time: Vec<f64> = (0..=hz as usize).map(|k| k as f64 / hz).collect();
            let w = smoothness_weights(&options, &time)[0];
            let step = 50.0 / hz; // 50 kPa/s
            w * step * step
        };
        let (slow, fast) = (per_row(30.0), per_row(120.0));
        assert!((slow - fast).abs() < 1e-12 * slow, "{slow} against {fast}");
        assert!((slow - 0.1 * (50.0_f64 / 30.0 / 100.0).powi(2)).abs() < 1e-15);
    }
}
