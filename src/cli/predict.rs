//! `handcap predict`: a fitted model's outputs for new inputs.

use std::path::PathBuf;

use anyhow::bail;

use handcap::data;
use handcap::fsio;
use handcap::model::file::{ModelFile, StoredModel};
use handcap::model::Predict;

#[derive(clap::Args)]
pub struct Args {
    /// Model file written by `handcap model`
    model: PathBuf,
    /// CSV with the model's input columns (other columns are ignored)
    inputs: PathBuf,
    /// CSV to write: the input columns, then one column per model output
    #[arg(long)]
    out: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if fsio::is_same_file_as_any(&a.out, &[&a.model, &a.inputs]) {
        bail!(
            "--out {} is one of the input files; choose another name",
            a.out.display()
        );
    }
    let file = ModelFile::load(&a.model)?;
    let StoredModel::Msvr(model) = &file.model;
    let x = data::read_columns(&a.inputs, model.inputs())?;
    let y = model.predict(&x)?;
    data::write_csv(&a.out, &[&x, &y])?;
    println!("wrote {} ({} rows)", a.out.display(), x.rows());
    Ok(())
}
