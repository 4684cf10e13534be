//! `handcap export`: a fitted model in a form a controller embeds.

use std::path::PathBuf;

use anyhow::Context;

use crate::fsio;
use crate::model::export;
use crate::model::file::ModelFile;
use crate::model::{Predict, StoredModel};
use crate::pipeline::outputs::{self, Output};

#[derive(clap::Args)]
pub struct Args {
    /// Model file written by `handcap model`
    model: PathBuf,
    /// C99 header to write (only <math.h>): handcap_reset, handcap_step (a history model's
    /// filters advanced by dt_s, then the outputs), handcap_predict and handcap_jacobian (the
    /// settled map), with the model's numbers
    #[arg(long = "c", value_name = "HEADER")]
    c: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    outputs::check(&[&a.model], &[Output::new(&a.c, "--c")])?;
    let file = ModelFile::load(&a.model)?;
    let source = a.model.file_name().map_or_else(
        || a.model.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let header = export::c_header(&file, &source);
    fsio::write_bytes(&a.c, header.as_bytes())
        .with_context(|| format!("writing {}", a.c.display()))?;
    let StoredModel::Msvr(m) = &file.model;
    let steady = file.steady_state();
    println!(
        "wrote {} ({} kernel centres, {} → {}{})",
        a.c.display(),
        m.support_vector_count(),
        steady.inputs().join(","),
        steady.outputs().join(","),
        file.history()
            .map_or(String::new(), |h| format!("; input history {}", h.memory))
    );
    Ok(())
}
