//! `handcap synth`: the virtual micro-hand's datasets.

use std::path::PathBuf;

use anyhow::{bail, Context};

use handcap::provenance::Provenance;
use handcap::synth::{self, plant::PlantParams, SynthConfig};

#[derive(clap::Args)]
pub struct Args {
    /// Output directory (created if missing; files in it are replaced atomically)
    #[arg(long)]
    out: PathBuf,
    /// Write only the pressure → tip datasets, no camera images
    #[arg(long)]
    no_images: bool,
    /// Seed of every random choice (measurement noise)
    #[arg(long, default_value_t = synth::DEFAULT_SEED)]
    seed: u64,
    /// Tip measurement noise, standard deviation per coordinate (mm)
    #[arg(long, default_value_t = synth::DEFAULT_NOISE_MM)]
    noise_mm: f64,
    /// Width of the muscles' pressure hysteresis (kPa); 0 turns it off
    #[arg(long, default_value_t = 0.0)]
    hysteresis_kpa: f64,
    /// Pressure step of the training grid (kPa)
    #[arg(long, default_value_t = 50.0)]
    grid_step_kpa: f64,
    /// Pressure step of the two test sweeps (kPa)
    #[arg(long, default_value_t = 10.0)]
    sweep_step_kpa: f64,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if !a.no_images {
        bail!("rendering camera images is not part of this build yet; pass --no-images to write the datasets only");
    }
    let config = SynthConfig {
        seed: a.seed,
        noise_mm: a.noise_mm,
        grid_step_kpa: a.grid_step_kpa,
        sweep_step_kpa: a.sweep_step_kpa,
        plant: PlantParams {
            hysteresis_kpa: a.hysteresis_kpa,
            ..PlantParams::default()
        },
    };
    let provenance = Provenance::new(super::command_line(), Some(a.seed));
    let paths = synth::write_datasets(&a.out, &config, &provenance)
        .with_context(|| format!("synth into {}", a.out.display()))?;
    for p in &paths {
        println!("wrote {}", p.display());
    }
    Ok(())
}
