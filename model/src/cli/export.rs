//! `handcap export`: a fitted model in a form a controller embeds.

use std::path::PathBuf;

use crate::pipeline::export;

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
    println!("{}", export::run(&a.model, &a.c)?);
    Ok(())
}
