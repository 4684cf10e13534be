//! The model seam: what front ends (the command line, the Python binding, the demo) ask for and
//! what they get back, without naming a model's internals.
//!
//! A [`ModelSpec`] says which model to fit and with what settings; [`ModelSpec::fit`] turns a
//! dataset into a [`StoredModel`], which the model file holds and which hands out its
//! [`Predict`]or and, for the inverse, its [`Differentiable`] form. A new kind of model is a
//! variant in each enum and nothing else in the fit stage, the report, predict, inverse or the
//! demo.

use serde::{Deserialize, Serialize};

use super::msvr::{FitDiagnostics, Msvr, MsvrError, MsvrParams};
use super::{Differentiable, Predict};
use crate::data::Dataset;

/// Which model to fit, with its settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", content = "params", rename_all = "snake_case")]
pub enum ModelSpec {
    /// Multi-output SVR (exact or on a reduced basis, as its parameters say).
    Msvr(MsvrParams),
}

impl ModelSpec {
    /// The settings by name, as reports show them.
    pub fn settings(&self) -> Vec<(&'static str, String)> {
        match self {
            ModelSpec::Msvr(p) => vec![
                ("model", "MSVR".into()),
                ("C", p.c.to_string()),
                ("ε", p.epsilon.to_string()),
                ("σ", p.sigma.to_string()),
                ("loss", p.loss.to_string()),
                ("basis", p.basis.to_string()),
            ],
        }
    }

    /// Fits the model to `data` in memory, using every core.
    ///
    /// # Errors
    /// The model's own: bad parameters, too few rows, a constant input, a failed solve.
    pub fn fit(&self, data: &Dataset) -> Result<StoredModel, MsvrError> {
        Ok(self.fit_predicting(data)?.0)
    }

    /// [`ModelSpec::fit`], with the model's predictions of the training rows when the fit
    /// made them on the way.
    ///
    /// # Errors
    /// As [`ModelSpec::fit`].
    pub fn fit_predicting(
        &self,
        data: &Dataset,
    ) -> Result<(StoredModel, Option<crate::data::Columns>), MsvrError> {
        match self {
            ModelSpec::Msvr(params) => {
                let (model, fitted) = params.check()?.fit_predicting(data, faer::Par::rayon(0))?;
                Ok((StoredModel::Msvr(model), fitted))
            }
        }
    }
}

/// A fitted model, as the model file holds it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", content = "model", rename_all = "snake_case")]
pub enum StoredModel {
    Msvr(Msvr),
}

impl StoredModel {
    /// The model's predictions.
    pub fn predictor(&self) -> &dyn Predict {
        match self {
            StoredModel::Msvr(m) => m,
        }
    }

    /// The model with its Jacobian (for the inverse).
    pub fn differentiable(&self) -> &dyn Differentiable {
        match self {
            StoredModel::Msvr(m) => m,
        }
    }

    /// The settings it was fitted with.
    pub fn spec(&self) -> ModelSpec {
        match self {
            StoredModel::Msvr(m) => ModelSpec::Msvr(m.params),
        }
    }

    /// How its fit went.
    pub fn diagnostics(&self) -> &FitDiagnostics {
        match self {
            StoredModel::Msvr(m) => &m.fit,
        }
    }
}
