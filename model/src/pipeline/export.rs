//! The export stage: a fitted model as a self-contained C header a controller embeds.

use std::fmt;
use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::{io_error, PipelineError};
use crate::fsio;
use crate::model::export;
use crate::model::file::ModelFile;
use crate::model::{Predict, StoredModel};

/// What [`run`] wrote.
pub struct Exported {
    pub header: PathBuf,
    pub centres: usize,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    /// The input history the header carries, when the model has one.
    pub history: Option<String>,
}

/// Writes `model` as the C header `header`.
///
/// # Errors
/// An output that would replace an input, an unreadable model, a file that cannot be written.
pub fn run(model: &Path, header: &Path) -> Result<Exported, PipelineError> {
    outputs::check(&[model], &[Output::new(header, "the C header")])?;
    let file = ModelFile::load(model)?;
    let source = model.file_name().map_or_else(
        || model.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let text = export::c_header(&file, &source);
    fsio::write_bytes(header, text.as_bytes()).map_err(io_error(header))?;
    let StoredModel::Msvr(m) = &file.model;
    let steady = file.steady_state();
    Ok(Exported {
        header: header.to_path_buf(),
        centres: m.support_vector_count(),
        inputs: steady.inputs().to_vec(),
        outputs: steady.outputs().to_vec(),
        history: file.history().map(|h| h.memory.to_string()),
    })
}

impl fmt::Display for Exported {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(
            f,
            "wrote {} ({} kernel centres, {} → {}{})",
            self.header.display(),
            self.centres,
            self.inputs.join(","),
            self.outputs.join(","),
            self.history
                .as_ref()
                .map_or(String::new(), |h| format!("; input history {h}"))
        )
    }
}
