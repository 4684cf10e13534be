//! Kernel ridge regression (scikit-learn's `KernelRidge`, with an intercept): the squared loss
//! and no tube. It is MSVR with ε = 0 and the quadratic loss, whose iteratively reweighted
//! solve is then one linear solve (the weights never change: the solver stops at its second
//! iteration), so it is fitted by the same code; its search moves C (the ridge is 1/(2C)) and
//! σ only.

use super::Kind;
use crate::model::msvr::{Loss, MsvrParams};

/// Kernel ridge regression.
pub struct Krr;

impl Kind for Krr {
    fn name(&self) -> &'static str {
        "krr"
    }

    fn title(&self) -> &'static str {
        "kernel ridge"
    }

    fn description(&self) -> &'static str {
        "kernel ridge regression"
    }

    fn axes(&self) -> &'static [&'static str] {
        &["c", "sigma"]
    }

    fn fixed_loss(&self) -> Option<Loss> {
        Some(Loss::Quadratic)
    }

    fn solver(&self, params: MsvrParams) -> MsvrParams {
        MsvrParams {
            epsilon: 0.0,
            ..params.loss(Loss::Quadratic)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::Family;
    use crate::model::msvr::{Loss, MsvrParams};

    /// Kernel ridge is MSVR with ε = 0 and the quadratic loss: its fit is the closed form
    /// [K + I/(2C), 1; 1ᵀ, 0] [β; b] = [y; 0] on the scaled inputs, solved here apart.
    #[test]
    fn kernel_ridge_is_the_closed_form_with_an_intercept() {
        use crate::data::{Columns, Dataset};
        use crate::model::ModelSpec;
        use nalgebra::{DMatrix, DVector};
        let n = 30;
        let x: Vec<f64> = (0..n).map(|i| 2.0 + 0.37 * i as f64).collect();
        let y: Vec<f64> = x
            .iter()
            .flat_map(|v| [(v / 2.0).sin() + 0.1 * (7.0 * v).cos(), 3.0 + 0.2 * v])
            .collect();
        let data = Dataset {
            source: "inline".into(),
            inputs: Columns::new(vec!["p".into()], x.clone()),
            outputs: Columns::new(vec!["a".into(), "b".into()], y.clone()),
            weights: None,
        };
        let (c, sigma) = (40.0, 0.15);
        let params = Family::KRR.solver(MsvrParams::new(c, 0.3, sigma).loss(Loss::Robust));
        assert_eq!((params.epsilon, params.loss), (0.0, Loss::Quadratic));
        let model = ModelSpec::Msvr(params).fit(&data).unwrap();
        assert!(
            model.diagnostics().iterations <= 2,
            "{:?}",
            model.diagnostics()
        );
        let (lo, hi) = (x[0], x[n - 1]);
        let s: Vec<f64> = x.iter().map(|v| (v - lo) / (hi - lo)).collect();
        let k = |a: f64, b: f64| (-(a - b).powi(2) / (2.0 * sigma * sigma)).exp();
        let mut system = DMatrix::zeros(n + 1, n + 1);
        for i in 0..n {
            for j in 0..n {
                system[(i, j)] = k(s[i], s[j]);
            }
            system[(i, i)] += 1.0 / (2.0 * c);
            system[(i, n)] = 1.0;
            system[(n, i)] = 1.0;
        }
        let lu = system.lu();
        for out in 0..2 {
            let mut rhs = DVector::zeros(n + 1);
            for i in 0..n {
                rhs[i] = y[2 * i + out];
            }
            let solution = lu.solve(&rhs).unwrap();
            for probe in [2.5, 6.1, 12.0] {
                let sp = (probe - lo) / (hi - lo);
                let expected = solution[n] + (0..n).map(|i| solution[i] * k(sp, s[i])).sum::<f64>();
                let mut got = [0.0; 2];
                model.predictor().predict_row(&[probe], &mut got);
                assert!(
                    (got[out] - expected).abs() < 1e-6,
                    "output {out} at {probe}: {} against the closed form's {expected}",
                    got[out]
                );
            }
        }
    }
}
