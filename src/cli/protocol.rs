//! `handcap protocol`: the paper's pressure protocol as `protocol.csv`, for `capture --protocol`.

use std::path::PathBuf;

use crate::fsio;
use crate::pipeline::outputs::{self, Output};
use crate::session::protocol;

#[derive(clap::Args)]
pub struct Args {
    /// File to write (step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s)
    #[arg(long, default_value = "protocol.csv")]
    out: PathBuf,
    /// Pressure step of the training grid (kPa)
    #[arg(long, default_value_t = 50.0)]
    grid_step_kpa: f64,
    /// Pressure step of the two sweeps (kPa)
    #[arg(long, default_value_t = 10.0)]
    sweep_step_kpa: f64,
    /// How long each step is held (s): the finger settles, then the cameras film it
    #[arg(long, default_value_t = 0.3, value_parser = super::finite)]
    hold_s: f64,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(why) = protocol::bad_hold(a.hold_s) {
        super::usage!("--hold-s: {why}");
    }
    outputs::check(&[], &[Output::new(&a.out, "--out")])?;
    let text = protocol::paper_protocol(a.grid_step_kpa, a.sweep_step_kpa, a.hold_s)?;
    fsio::write_bytes(&a.out, text.as_bytes())?;
    let steps = text.lines().count() - 1;
    println!(
        "wrote {} ({steps} steps, {:.0} s at {} s a step)",
        a.out.display(),
        steps as f64 * a.hold_s,
        a.hold_s
    );
    Ok(())
}
