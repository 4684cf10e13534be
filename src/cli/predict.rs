//! `handcap predict`: a fitted model's outputs for new inputs.

use std::path::PathBuf;

use handcap::data;
use handcap::model::file::ModelFile;
use handcap::pipeline::outputs::{self, Output};

#[derive(clap::Args)]
pub struct Args {
    /// Model file written by `handcap model`
    model: PathBuf,
    /// CSV with the model's input columns (other columns are ignored; a model with input
    /// history also needs its time column, and group column if it has one)
    inputs: PathBuf,
    /// CSV to write: the input columns, then one column per model output
    #[arg(long)]
    out: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    outputs::check(&[&a.model, &a.inputs], &[Output::new(&a.out, "--out")])?;
    let file = ModelFile::load(&a.model)?;
    let model = file.model.predictor();
    let (given, x) = file.read_inputs(&a.inputs)?;
    let outside = model.outside(&x);
    if let (Some((j, v)), Some((min, max))) = (outside.farthest, model.training_range()) {
        eprintln!(
            "warning: {} of {} rows lie outside the training range (farthest: {} = {v}, trained on {}-{}); far from its data an RBF model flattens to a constant, so those predictions are guesses",
            outside.rows,
            x.rows(),
            model.inputs()[j],
            min[j],
            max[j]
        );
    }
    let y = model.predict(&x)?;
    data::write_csv(&a.out, &[&given, &y])?;
    println!("wrote {} ({} rows)", a.out.display(), x.rows());
    Ok(())
}
