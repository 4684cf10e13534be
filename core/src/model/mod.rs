//! Models of an actuator's input → output map, the contract they share, and error metrics.
//!
//! [`msvr`] is the multi-output support vector regression of the paper; [`previous`] is the
//! physics-based model it is compared with. Every model implements
//! [`Predict`], so evaluation, reports and the command line treat them alike.

pub mod export;
pub mod file;
pub mod history;
pub mod interval;
pub mod inverse;
pub mod msvr;
pub mod previous;
pub mod spec;
pub mod trajectory;

pub use spec::{ModelSpec, StoredModel};

use rayon::prelude::*;

use crate::data::{Columns, Dataset};

/// Errors of using a fitted model.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ModelError {
    #[error("inputs are ({found}) but the model was fitted on ({expected}); give the same columns in the same order")]
    InputMismatch { expected: String, found: String },
    #[error("outputs are ({found}) but the model predicts ({expected})")]
    OutputMismatch { expected: String, found: String },
    #[error("input row {row}: the model predicts a non-finite {output} (its coefficients are out of range); fit the model again")]
    NonFinite { row: usize, output: String },
}

/// A fitted model: named inputs in, named outputs out.
pub trait Predict: Sync {
    /// Input column names, in the order `predict_row` expects them.
    fn inputs(&self) -> &[String];
    /// Output column names, in the order `predict_row` writes them.
    fn outputs(&self) -> &[String];
    /// Predicts one sample: `x.len() == inputs().len()`, `out.len() == outputs().len()`.
    fn predict_row(&self, x: &[f64], out: &mut [f64]);

    /// Each input's training minimum and maximum, where the model knows them.
    fn training_range(&self) -> Option<(&[f64], &[f64])> {
        None
    }

    /// The rows of `x` (the model's inputs) outside the training range by more than 1 % of it,
    /// and the farthest value: (column, value), measured in training ranges.
    fn outside(&self, x: &Columns) -> Outside {
        let mut out = Outside::default();
        let Some((min, max)) = self.training_range() else {
            return out;
        };
        let mut farthest = 0.0;
        for row in x.iter_rows() {
            let mut outside = false;
            for (j, &v) in row.iter().enumerate() {
                let s = (v - min[j]) / (max[j] - min[j]);
                let beyond = (-s).max(s - 1.0);
                if beyond > 0.01 {
                    outside = true;
                    if beyond > farthest {
                        farthest = beyond;
                        out.farthest = Some((j, v));
                    }
                }
            }
            out.rows += usize::from(outside);
        }
        out
    }

    /// What to say of rows of `x` (the model's inputs) outside the training range, when there
    /// are some ([`Self::outside`]).
    fn range_warning(&self, x: &Columns) -> Option<String> {
        let outside = self.outside(x);
        let ((j, v), (min, max)) = outside.farthest.zip(self.training_range())?;
        Some(format!(
            "{} of {} rows lie outside the training range (farthest: {} = {v}, trained on {} to {}); far from its data an RBF model flattens to a constant, so those predictions are guesses",
            outside.rows,
            x.rows(),
            self.inputs()[j],
            min[j],
            max[j]
        ))
    }

    /// Predicts every row of `x`, in parallel.
    ///
    /// # Errors
    /// [`ModelError::InputMismatch`] when `x` does not have the model's input columns in order;
    /// [`ModelError::NonFinite`] (1-based row) when a prediction is not a finite number.
    fn predict(&self, x: &Columns) -> Result<Columns, ModelError> {
        if x.names != self.inputs() {
            return Err(ModelError::InputMismatch {
                expected: self.inputs().join(","),
                found: x.names_list(),
            });
        }
        let q = self.outputs().len();
        let mut values = vec![0.0; x.rows() * q];
        values
            .par_chunks_mut(q)
            .zip(x.values.par_chunks(x.width()))
            .with_min_len(64)
            .for_each(|(out, row)| self.predict_row(row, out));
        if let Some(k) = values.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::NonFinite {
                row: k / q + 1,
                output: self.outputs()[k % q].clone(),
            });
        }
        Ok(Columns::new(self.outputs().to_vec(), values))
    }
}

/// A model whose outputs have an analytic Jacobian with respect to its inputs.
pub trait Differentiable: Predict {
    /// The outputs at `x` into `out` and ∂outᵢ/∂xⱼ into `jacobian` (`q × d`, row-major).
    fn predict_with_jacobian(&self, x: &[f64], out: &mut [f64], jacobian: &mut [f64]);

    /// The Jacobian at every row of `x` (the model's inputs, `n × d` row-major): `n × q × d`,
    /// rows in parallel.
    fn jacobians(&self, x: &[f64]) -> Vec<f64> {
        let (d, q) = (self.inputs().len(), self.outputs().len());
        let mut jac = vec![0.0; x.len() / d * q * d];
        jac.par_chunks_mut(q * d)
            .zip(x.par_chunks(d))
            .with_min_len(64)
            .for_each(|(j, row)| self.predict_with_jacobian(row, &mut vec![0.0; q], j));
        jac
    }
}

/// Inputs outside a model's training range ([`Predict::outside`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Outside {
    pub rows: usize,
    /// The farthest value: its column and the value.
    pub farthest: Option<(usize, f64)>,
}

/// Prediction errors on one dataset, in the outputs' units (mm for the micro-hand).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Errors {
    pub rows: usize,
    /// Mean over samples and outputs of |y − ŷ| (the paper's MAE).
    pub mae: f64,
    /// Mean over samples of ‖y − ŷ‖₂ (the tip's Euclidean error).
    pub euclid: f64,
    /// Largest ‖y − ŷ‖₂ over samples.
    pub max_euclid: f64,
    /// MAE of each output column.
    pub per_output_mae: Vec<f64>,
}

/// Errors of `predicted` against `truth` (same shape).
///
/// # Panics
/// If the shapes differ or there are no rows.
pub fn errors(truth: &Columns, predicted: &Columns) -> Errors {
    assert_eq!(truth.width(), predicted.width(), "output widths differ");
    assert_eq!(truth.rows(), predicted.rows(), "row counts differ");
    let (n, q) = (truth.rows(), truth.width());
    assert!(n > 0, "no rows to compare");
    let mut per_output = vec![0.0; q];
    let (mut euclid, mut max_euclid) = (0.0, 0.0f64);
    for (t, p) in truth.iter_rows().zip(predicted.iter_rows()) {
        let mut sq = 0.0;
        for j in 0..q {
            let d = t[j] - p[j];
            per_output[j] += d.abs();
            sq += d * d;
        }
        euclid += sq.sqrt();
        max_euclid = max_euclid.max(sq.sqrt());
    }
    let per_output_mae: Vec<f64> = per_output.iter().map(|s| s / n as f64).collect();
    Errors {
        rows: n,
        mae: per_output_mae.iter().sum::<f64>() / q as f64,
        euclid: euclid / n as f64,
        max_euclid,
        per_output_mae,
    }
}

/// Predicts a dataset's inputs and scores them against its outputs.
///
/// # Errors
/// [`ModelError`] when the dataset's columns are not the model's.
pub fn evaluate(model: &dyn Predict, data: &Dataset) -> Result<Errors, ModelError> {
    Ok(evaluate_predicting(model, data)?.0)
}

/// [`evaluate`], with the predictions it scored (for what else they are measured by).
///
/// # Errors
/// As [`evaluate`].
pub fn evaluate_predicting(
    model: &dyn Predict,
    data: &Dataset,
) -> Result<(Errors, Columns), ModelError> {
    if data.outputs.names != model.outputs() {
        return Err(ModelError::OutputMismatch {
            expected: model.outputs().join(","),
            found: data.outputs.names_list(),
        });
    }
    let predicted = model.predict(&data.inputs)?;
    Ok((errors(&data.outputs, &predicted), predicted))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cols(values: &[f64]) -> Columns {
        Columns::new(vec!["a".into(), "b".into()], values.to_vec())
    }

    #[test]
    fn errors_by_hand() {
        let truth = cols(&[0.0, 0.0, 1.0, 1.0]);
        let pred = cols(&[3.0, 4.0, 1.0, 0.0]);
        let e = errors(&truth, &pred);
        assert_eq!(e.per_output_mae, vec![1.5, 2.5]);
        assert_eq!(e.mae, 2.0);
        assert_eq!(e.euclid, 3.0); // (5 + 1) / 2
        assert_eq!(e.max_euclid, 5.0);
    }
}
