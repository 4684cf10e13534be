//! `handcap predict`: a fitted model's outputs for new inputs.

use std::path::PathBuf;

use crate::pipeline::predict;

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
    /// Also write `interval_radius`: the radius (output units) of the sphere around each
    /// prediction that holds the truth this share of the time (conformal, e.g. 0.9; wider
    /// where the row's inputs are far from the training rows)
    #[arg(long, value_name = "LEVEL", allow_hyphen_values = true, value_parser = super::level)]
    interval: Option<f64>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let done = predict::run(&a.model, &a.inputs, &a.out, a.interval)?;
    if let Some(warning) = &done.warning {
        super::warn(warning);
    }
    println!("{}", super::said(&done.to_string()));
    Ok(())
}
