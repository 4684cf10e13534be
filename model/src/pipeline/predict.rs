//! The predict stage: a fitted model's outputs for a file of inputs, with the interval radius
//! at a level when asked.

use std::fmt;
use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::PipelineError;
use crate::data::{self, Columns};
use crate::model::file::ModelFile;
use crate::model::interval::RowRadii;

/// What [`run`] wrote.
pub struct Predicted {
    pub out: PathBuf,
    pub rows: usize,
    /// The interval's radii, when asked.
    pub interval: Option<RowRadii>,
    /// Rows outside the training range, said when there are some.
    pub warning: Option<String>,
}

/// Writes `out`: the inputs of `inputs` (and the columns beside them) with the model's
/// outputs, and each row's `interval_radius` at `level`.
///
/// # Errors
/// An output that would replace an input, an unreadable model or inputs file, a model without
/// intervals asked for one.
pub fn run(
    model: &Path,
    inputs: &Path,
    out: &Path,
    level: Option<f64>,
) -> Result<Predicted, PipelineError> {
    outputs::check(&[model, inputs], &[Output::new(out, "the predictions")])?;
    let file = ModelFile::load(model)?;
    let interval_error = |e| PipelineError::Input(format!("{}: interval: {e}", model.display()));
    if let Some(level) = level {
        file.interval_radius(level).map_err(interval_error)?;
    }
    let predictor = file.model.predictor();
    let (given, x) = file.read_inputs(inputs)?;
    let warning = predictor.range_warning(&x);
    let y = predictor.predict(&x)?;
    let interval = level
        .map(|level| file.interval_radii(level, &x))
        .transpose()
        .map_err(interval_error)?;
    let column = interval
        .as_ref()
        .map(|i| Columns::new(vec!["interval_radius".into()], i.radii.clone()));
    let mut blocks = vec![&given, &y];
    blocks.extend(&column);
    data::write_csv(out, &blocks)?;
    Ok(Predicted {
        out: out.to_path_buf(),
        rows: x.rows(),
        interval,
        warning,
    })
}

impl fmt::Display for Predicted {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "wrote {} ({} rows", self.out.display(), self.rows)?;
        if let Some(interval) = &self.interval {
            write!(f, "; {interval}")?;
        }
        write!(f, ")")
    }
}
