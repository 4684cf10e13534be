//! The ε-tube and its loss, shared by both MSVR solvers (exact [`super::irwls`], reduced-basis
//! [`super::reduced`]): what a row's residual norm costs, its part in a reweighted
//! least-squares step, and the exact line search along a step.
//!
//! A row may carry a weight wᵢ > 0 ([`RowWeights`]): its loss counts wᵢ times, C wᵢ L(uᵢ), as
//! wᵢ copies of the row would when wᵢ is whole (a lab weighting the runs it is learning on
//! against the session the model was fitted on).
//!
//! With uᵢ = ‖yᵢ − f(xᵢ)‖₂ the residual norm of row i, the [`Loss`] is
//! - quadratic (the paper's, Sánchez-Fernández et al. 2004, eqs. 11-12): L(u) = 0 for u ≤ ε and
//!   (u − ε)² above;
//! - robust: the same up to u = ε + δ, δ = [`ROBUST_ZONE`] ε, and linear beyond with the slope
//!   it has there, L(u) = δ (2(u − ε) − δ) (Huber's loss outside the tube). A row far from the
//!   others' surface — a transient caught mid-move, a marker lost for a frame, hysteresis — pulls
//!   the fit with a force capped at 2Cδ instead of one growing with its distance. Measured on a
//!   real tendon arm's time series (`notes/realdata.md`), the quadratic loss was pulled to twice
//!   the held-out error of scikit-learn's (linear-loss) SVR; the robust loss ends below it.

use faer::MatRef;
use serde::{Deserialize, Serialize};

/// Smallest line-search step tried before concluding that no step lowers F.
const MIN_STEP: f64 = 1.0 / (1u64 << 40) as f64;
/// Longest step along the line, in units of the IRWLS step.
const MAX_STEP: f64 = 4.0;

/// Width of the robust loss's quadratic zone beyond the tube, in units of ε: the tube and the
/// zone both follow the noise's scale, so the search's ε sets both. Measured: 3, 10 and 30 give
/// 16.9, 13.8 and 14.9 mm on the tendon arm and 4.02, 3.86 and 4.16 mm on the soft trunk
/// (ACO_R, 120 candidates, held-out rows).
pub const ROBUST_ZONE: f64 = 10.0;

/// The loss of a residual norm outside the tube (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Loss {
    /// (u − ε)²: the paper's.
    #[default]
    Quadratic,
    /// Quadratic for [`ROBUST_ZONE`] ε beyond the tube, linear further out.
    Robust,
}

impl std::fmt::Display for Loss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Loss::Quadratic => "quadratic",
            Loss::Robust => "robust",
        })
    }
}

/// Each row's weight in the data term C Σᵢ wᵢ L(uᵢ), indexed like the problem's targets
/// (`None`: every row 1).
#[derive(Clone, Copy, Debug, Default)]
pub struct RowWeights<'a>(pub Option<&'a [f64]>);

impl RowWeights<'_> {
    /// Row `i`'s weight.
    pub fn of(self, i: usize) -> f64 {
        self.0.map_or(1.0, |w| w[i])
    }
}

/// The penalty C, the tube's radius ε and the loss beyond it: C Σᵢ L(uᵢ) is the data term of
/// both solvers' objective.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tube {
    pub c: f64,
    pub epsilon: f64,
    pub loss: Loss,
}

impl Tube {
    /// Width δ of the quadratic zone beyond the tube (∞ for the quadratic loss).
    fn zone(&self) -> f64 {
        match self.loss {
            Loss::Quadratic => f64::INFINITY,
            Loss::Robust => ROBUST_ZONE * self.epsilon,
        }
    }

    /// The loss of a residual norm (without the factor C).
    pub fn loss(&self, u: f64) -> f64 {
        let (excess, zone) = (u - self.epsilon, self.zone());
        if excess <= 0.0 {
            0.0
        } else if excess <= zone {
            excess * excess
        } else {
            zone * (2.0 * excess - zone)
        }
    }

    /// C Σᵢ wᵢ L(uᵢ) over the rows of a residual matrix.
    pub fn data_term(&self, resid: MatRef<f64>, weights: RowWeights) -> f64 {
        self.c
            * (0..resid.nrows())
                .map(|i| weights.of(i) * self.loss(row_norm(resid, i)))
                .sum::<f64>()
    }

    /// A row's part in a reweighted least-squares step, `None` inside the tube: its inverse
    /// weight 1/aᵢ and the share of its residual its target is pulled in by
    /// (y'ᵢ = yᵢ − shrink · rᵢ), for a row of weight `w`. In the quadratic zone 1/(2Cw) and
    /// ε/uᵢ (the target at the tube's edge: weight 2Cw with the shifted target has the loss's
    /// gradient and is exact along the residual), in the robust loss's linear part
    /// uᵢ/(2Cwδ) and 0 (the target itself: the usual majoriser of a norm, which does not
    /// overshoot).
    pub fn step_row(&self, u: f64, w: f64) -> Option<(f64, f64)> {
        let (excess, zone) = (u - self.epsilon, self.zone());
        (excess > 0.0).then(|| {
            if excess > zone {
                (u / (2.0 * self.c * w * zone), 0.0)
            } else {
                (self.quadratic_inverse_weight(w), self.epsilon / u)
            }
        })
    }

    /// 1/aᵢ of a row of weight `w` in the loss's quadratic zone: 1/(2Cw).
    pub fn quadratic_inverse_weight(&self, w: f64) -> f64 {
        0.5 / (self.c * w)
    }

    /// L′(u) / u: the loss's pull on a residual vector per unit of its length.
    fn pull(&self, u: f64) -> f64 {
        2.0 * (u - self.epsilon).min(self.zone()) / u
    }

    /// The exact line search of both solvers. Along a step the residuals are r − t g and the
    /// regulariser (twice its value) is q0 + 2 t q1 + t² q2, so F(t) = ½(q0 + 2tq1 + t²q2) +
    /// C Σ wᵢ L(‖rᵢ − t gᵢ‖) is convex in t and costs O(nq). Returns the step t ∈ (0, 4] minimising
    /// it (from F′ by regula falsi) and F there, halved back towards 0 should rounding make it
    /// worse than `current`; `None` when no step down to 2⁻⁴⁰ lowers F.
    pub fn step_along(
        &self,
        resid: MatRef<f64>,
        g: MatRef<f64>,
        [q0, q1, q2]: [f64; 3],
        current: f64,
        weights: RowWeights,
    ) -> Option<(f64, f64)> {
        let (n, q) = resid.shape();
        let along = |t: f64| {
            let (mut loss, mut slope) = (0.0, q1 + t * q2);
            for i in 0..n {
                let e = |j: usize| resid[(i, j)] - t * g[(i, j)];
                let u = (0..q).map(|j| e(j) * e(j)).sum::<f64>().sqrt();
                let w = weights.of(i);
                loss += w * self.loss(u);
                if u > self.epsilon {
                    let along = (0..q).map(|j| e(j) * g[(i, j)]).sum::<f64>();
                    slope -= self.c * w * self.pull(u) * along;
                }
            }
            (0.5 * (q0 + t * (2.0 * q1 + t * q2)) + self.c * loss, slope)
        };
        let mut t = minimise_convex(|t| along(t).1, MAX_STEP);
        loop {
            let f = along(t).0;
            if f <= current {
                return Some((t, f));
            }
            // Only rounding can make the minimiser worse than t = 0: back off towards it.
            t *= 0.5;
            if t.is_nan() || t < MIN_STEP {
                return None;
            }
        }
    }
}

/// Σᵢⱼ aᵢⱼ bᵢⱼ.
pub fn frobenius_dot(a: MatRef<f64>, b: MatRef<f64>) -> f64 {
    (0..a.ncols())
        .map(|j| {
            a.col(j)
                .iter()
                .zip(b.col(j).iter())
                .map(|(x, y)| x * y)
                .sum::<f64>()
        })
        .sum()
}

/// ‖row i‖₂.
pub fn row_norm(m: MatRef<f64>, i: usize) -> f64 {
    (0..m.ncols())
        .map(|j| m[(i, j)] * m[(i, j)])
        .sum::<f64>()
        .sqrt()
}

/// The minimiser on [0, hi] of a convex function given its non-decreasing derivative `slope`:
/// 0 if the function does not fall at 0, hi if it still falls at hi, else the root of the slope
/// by regula falsi with the Illinois modification (bisection when a secant leaves the bracket),
/// to a relative width of 1e-6.
fn minimise_convex(slope: impl Fn(f64) -> f64, hi: f64) -> f64 {
    let (mut a, mut b) = (0.0, hi);
    let (mut fa, mut fb) = (slope(a), slope(b));
    if fa.is_nan() || fa >= 0.0 {
        return 0.0;
    }
    if fb <= 0.0 {
        return b;
    }
    let mut moved_b_last = None;
    for _ in 0..200 {
        if b - a <= 1e-6 * b {
            break;
        }
        let secant = (a * fb - b * fa) / (fb - fa);
        let t = if secant > a && secant < b {
            secant
        } else {
            0.5 * (a + b)
        };
        let ft = slope(t);
        if ft == 0.0 {
            return t;
        }
        let moved_b = ft > 0.0;
        if moved_b {
            (b, fb) = (t, ft);
        } else {
            (a, fa) = (t, ft);
        }
        // Illinois: an end kept twice in a row has its slope halved, so it moves next time.
        match (moved_b_last, moved_b) {
            (Some(true), true) => fa *= 0.5,
            (Some(false), false) => fb *= 0.5,
            _ => {}
        }
        moved_b_last = Some(moved_b);
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimise_convex_finds_the_minimum_and_the_ends() {
        // F = (t − 1.3)²: slope 2(t − 1.3).
        let t = minimise_convex(|t| 2.0 * (t - 1.3), 4.0);
        assert!((t - 1.3).abs() < 1e-5, "{t}");
        assert_eq!(minimise_convex(|t| t - 9.0, 4.0), 4.0);
        assert_eq!(minimise_convex(|t| t + 1.0, 4.0), 0.0);
        // A slope that is exactly zero at the secant point (a linear slope) ends there at once:
        // regression for a stall that kept the bracket's far end and returned its midpoint.
        assert_eq!(minimise_convex(|t| t - 1.0, 4.0), 1.0);
        // A kinked convex function: slope jumps from −1 to +3 at 0.7.
        let t = minimise_convex(|t| if t < 0.7 { -1.0 } else { 3.0 }, 4.0);
        assert!((t - 0.7).abs() < 1e-5, "{t}");
    }

    #[test]
    fn the_robust_loss_is_continuous_and_linear_beyond_its_zone() {
        let tube = Tube {
            c: 1.0,
            epsilon: 0.1,
            loss: Loss::Robust,
        };
        let edge = 0.1 + ROBUST_ZONE * 0.1;
        assert_eq!(tube.loss(0.05), 0.0);
        assert!((tube.loss(edge) - (ROBUST_ZONE * 0.1f64).powi(2)).abs() < 1e-12);
        let slope = (tube.loss(edge + 2.0) - tube.loss(edge + 1.0)) / 1.0;
        assert!((slope - 2.0 * ROBUST_ZONE * 0.1).abs() < 1e-12, "{slope}");
    }
}
