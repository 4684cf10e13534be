//! `handcap demo`: the whole pipeline on the built-in virtual micro-hand, checked against its
//! ground truth, with one report a lab can read (`crate::pipeline::demo`).

use std::path::PathBuf;

use crate::pipeline::demo::{self, DemoConfig};

use super::synth::FrameArgs;

#[derive(clap::Args)]
pub struct Args {
    /// Output directory
    #[arg(long, default_value = "handcap-demo")]
    out: PathBuf,
    /// Seed of every random choice
    #[arg(long, default_value_t = crate::DEFAULT_SEED)]
    seed: u64,
    /// A reduced run for a first look and the tests: 8 board pairs, a 125 kPa grid and 50 kPa
    /// sweeps, a short search, 20 inverse targets
    #[arg(long)]
    quick: bool,
    /// How many cameras film it: 2, a pair; 3 to 8 on an arc around the finger (synth
    /// --cameras), calibrated and triangulated as more cameras, without the pair's finger in
    /// motion
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(2..=8))]
    cameras: u8,
    #[command(flatten)]
    frames: FrameArgs,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let (format, realism) = a.frames.look();
    let config = DemoConfig {
        seed: a.seed,
        quick: a.quick,
        format,
        realism,
        cameras: a.cameras.into(),
    };
    print!("{}", super::with_session(|s| demo::run(&a.out, config, s))?);
    Ok(())
}
