//! `handcap protocol`: a pressure protocol as `protocol.csv`, for `capture --protocol`: the
//! paper's steps, or with `--dynamic` random excitation at a command rate.

use std::path::PathBuf;

use crate::fsio;
use crate::pipeline::outputs::{self, Output};
use crate::session::protocol::{self, DynamicDesign};

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
    /// Random excitation instead of held steps: trials of rate-limited APRBS commands on each
    /// muscle, with rest holds at 0, 0, 0 kPa first, between trials and last
    #[arg(long, conflicts_with_all = ["grid_step_kpa", "sweep_step_kpa", "hold_s"])]
    dynamic: bool,
    #[command(flatten)]
    design: DynamicArgs,
    /// Highest dynamic command (kPa)
    #[arg(long, requires = "dynamic", default_value_t = DynamicDesign::default().max_kpa, value_parser = super::finite)]
    max_kpa: f64,
    /// Seed of the dynamic excitation
    #[arg(long, requires = "dynamic", default_value_t = crate::DEFAULT_SEED)]
    seed: u64,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(why) = protocol::bad_hold(a.hold_s) {
        super::usage!("--hold-s: {why}");
    }
    outputs::check(&[], &[Output::new(&a.out, "--out")])?;
    let steps = if a.dynamic {
        protocol::dynamic(&a.design.with(a.seed, a.max_kpa))?
    } else {
        protocol::paper_steps(a.grid_step_kpa, a.sweep_step_kpa, a.hold_s)?
    };
    fsio::write_bytes(&a.out, protocol::protocol_csv(&steps).as_bytes())?;
    let (_, seconds) = protocol::start_times(&steps);
    if a.dynamic {
        println!(
            "wrote {} ({} commands at {} Hz in {} trials, {seconds:.0} s with the rest holds; seed {})",
            a.out.display(),
            steps.len(),
            a.design.rate_hz,
            a.design.trials,
            a.seed
        );
    } else {
        println!(
            "wrote {} ({} steps, {seconds:.0} s at {} s a step)",
            a.out.display(),
            steps.len(),
            a.hold_s
        );
    }
    Ok(())
}

/// A dynamic excitation's length, rate and trials (protocol and synth).
#[derive(clap::Args)]
pub struct DynamicArgs {
    /// Length of each dynamic trial (s)
    #[arg(long, requires = "dynamic", default_value_t = DynamicDesign::default().duration_s, value_parser = super::finite)]
    duration_s: f64,
    /// Dynamic commands per second (at most 200)
    #[arg(long, requires = "dynamic", default_value_t = DynamicDesign::default().rate_hz, value_parser = super::finite)]
    rate_hz: f64,
    /// Dynamic trials (phases dyn_1 … dyn_N)
    #[arg(long, requires = "dynamic", default_value_t = DynamicDesign::default().trials)]
    trials: usize,
}

impl DynamicArgs {
    /// The design, seeded, commands up to `max_kpa`.
    pub fn with(&self, seed: u64, max_kpa: f64) -> DynamicDesign {
        DynamicDesign {
            duration_s: self.duration_s,
            rate_hz: self.rate_hz,
            trials: self.trials,
            seed,
            max_kpa,
        }
    }
}
