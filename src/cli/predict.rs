//! `handcap predict`: a fitted model's outputs for new inputs.

use std::path::PathBuf;

use anyhow::Context;

use crate::data::{self, Columns};
use crate::model::file::ModelFile;
use crate::pipeline::outputs::{self, Output};

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
    /// prediction that holds the truth this share of the time (conformal, e.g. 0.9)
    #[arg(long, value_name = "LEVEL", allow_hyphen_values = true, value_parser = super::level)]
    interval: Option<f64>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    outputs::check(&[&a.model, &a.inputs], &[Output::new(&a.out, "--out")])?;
    let file = ModelFile::load(&a.model)?;
    let radius = a
        .interval
        .map(|level| file.interval_radius(level))
        .transpose()
        .with_context(|| format!("{}: --interval", a.model.display()))?;
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
    let mut blocks = vec![&given, &y];
    let interval = radius.map(|r| Columns::new(vec!["interval_radius".into()], vec![r; x.rows()]));
    blocks.extend(&interval);
    data::write_csv(&a.out, &blocks)?;
    match (a.interval, radius) {
        (Some(level), Some(r)) => println!(
            "wrote {} ({} rows; {} % interval radius {r:.4}, the same for every row: marginal coverage over rows like the held-out ones)",
            a.out.display(),
            x.rows(),
            level * 100.0
        ),
        _ => println!("wrote {} ({} rows)", a.out.display(), x.rows()),
    }
    Ok(())
}
