//! The virtual micro-hand and its measurement protocol: ground-truth data with no hardware.
//!
//! [`plant`] maps pressures to the tip; this module drives it through the paper's protocol —
//! a training grid on all three muscles and the two test sweeps of Figures 9-14 — and adds
//! seeded measurement noise. [`capture`] films the same protocol with the virtual stereo rig of
//! [`camera`], rendered by [`render`].
//!
//! Output of `handcap synth --out DIR --no-images` (all CSV with columns
//! `P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm`, hand frame):
//! - `train.csv`: every combination of 0-250 kPa in 50 kPa steps (216 steps),
//! - `sweep_a.csv`: P1 = P2 = 0, P3 = 0-250 kPa in 10 kPa steps,
//! - `sweep_b.csv`: P1 = 0, P2 = P3 = 0-250 kPa in 10 kPa steps,
//! - `manifest.json`: the plant's constants, the noise, the seed and the provenance.

pub mod camera;
pub mod canvas;
pub mod capture;
pub mod clutter;
pub mod dynamics;
pub mod faults;
pub mod image_format;
pub mod plant;
pub mod quick;
pub mod render;
pub mod scene;

use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::data::{self, names, Columns, DataError, HAND_INPUTS, HAND_OUTPUTS};
use crate::provenance::Provenance;
use plant::{Plant, PlantError, PlantParams};

/// Default tip measurement noise (mm, standard deviation per coordinate): what two 720p webcams
/// at 150-200 mm achieve on a sub-pixel centroid (see `notes/stereo.md`).
pub const DEFAULT_NOISE_MM: f64 = 0.02;

/// Errors of generating a synthetic capture.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error(transparent)]
    Plant(#[from] PlantError),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("measurement noise must be finite and ≥ 0 mm, got {0}")]
    BadNoise(f64),
    #[error("hysteresis width must be finite and ≥ 0 kPa, got {0}")]
    BadHysteresis(f64),
    #[error("capture settings: {0}")]
    BadCapture(String),
    #[error(transparent)]
    Protocol(#[from] crate::session::protocol::ProtocolError),
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// How to generate a synthetic capture.
#[derive(Clone, Debug, Serialize)]
pub struct SynthConfig {
    pub seed: u64,
    /// Standard deviation of the tip measurement noise per coordinate (mm).
    pub noise_mm: f64,
    /// Pressure step of the training grid (kPa).
    pub grid_step_kpa: f64,
    /// Pressure step of the two test sweeps (kPa).
    pub sweep_step_kpa: f64,
    pub plant: PlantParams,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            seed: crate::DEFAULT_SEED,
            noise_mm: DEFAULT_NOISE_MM,
            grid_step_kpa: 50.0,
            sweep_step_kpa: 10.0,
            plant: PlantParams::default(),
        }
    }
}

/// A named sequence of pressure steps and the measured tip at each.
#[derive(Clone, Debug)]
pub struct Recording {
    /// File stem: `train`, `sweep_a`, `sweep_b`.
    pub name: &'static str,
    pub pressures: Columns,
    /// Measured tip (truth plus noise), hand frame.
    pub tips: Columns,
    /// Exact tip, hand frame.
    pub truth: Columns,
}

/// Runs the protocol on the plant and adds seeded noise. Each recording starts from rest.
///
/// # Errors
/// [`SynthError::BadNoise`], [`SynthError::BadHysteresis`], [`SynthError::Protocol`], or a plant
/// error.
pub fn record(config: &SynthConfig) -> Result<Vec<Recording>, SynthError> {
    if !(config.noise_mm >= 0.0 && config.noise_mm.is_finite()) {
        return Err(SynthError::BadNoise(config.noise_mm));
    }
    let hysteresis = config.plant.hysteresis_kpa;
    if !(hysteresis >= 0.0 && hysteresis.is_finite()) {
        return Err(SynthError::BadHysteresis(hysteresis));
    }
    let plant = Plant::new(config.plant.clone());
    let noise =
        Normal::new(0.0, config.noise_mm).map_err(|_| SynthError::BadNoise(config.noise_mm))?;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    crate::session::protocol::designed(config.grid_step_kpa, config.sweep_step_kpa)?
        .into_iter()
        .map(|(name, steps)| {
            let truth = plant.run(&steps)?;
            let measured: Vec<f64> = truth
                .iter()
                .flatten()
                .map(|&v| v + noise.sample(&mut rng))
                .collect();
            Ok(Recording {
                name,
                pressures: Columns::new(names(&HAND_INPUTS), steps.concat()),
                tips: Columns::new(names(&HAND_OUTPUTS), measured),
                truth: Columns::new(names(&HAND_OUTPUTS), truth.concat()),
            })
        })
        .collect()
}

/// What `manifest.json` records about a synthetic capture.
#[derive(Serialize)]
struct Manifest<'a> {
    format: &'static str,
    config: &'a SynthConfig,
    files: Vec<String>,
    /// The rendered camera session, when images were written.
    capture: Option<(&'a capture::CaptureConfig, &'a capture::CaptureSummary)>,
    provenance: &'a Provenance,
}

/// Records the protocol and writes `<name>.csv` per recording plus `manifest.json` into `dir`.
/// Returns the paths of the CSV files.
///
/// # Errors
/// As [`record`], and when a file cannot be written.
pub fn write_datasets(
    dir: &Path,
    config: &SynthConfig,
    provenance: &Provenance,
) -> Result<Vec<PathBuf>, SynthError> {
    std::fs::create_dir_all(dir).map_err(|source| SynthError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut paths = Vec::new();
    for rec in record(config)? {
        let path = dir.join(format!("{}.csv", rec.name));
        data::write_csv(&path, &[&rec.pressures, &rec.tips])?;
        paths.push(path);
    }
    write_manifest(dir, config, &paths, None, provenance)?;
    Ok(paths)
}

/// Writes `dir/manifest.json`: the configuration, the dataset files, the capture if any, and
/// the provenance.
///
/// # Errors
/// [`SynthError::Write`].
pub fn write_manifest(
    dir: &Path,
    config: &SynthConfig,
    datasets: &[PathBuf],
    capture: Option<(&capture::CaptureConfig, &capture::CaptureSummary)>,
    provenance: &Provenance,
) -> Result<(), SynthError> {
    let manifest = Manifest {
        format: "handcap-synth/1",
        config,
        files: datasets
            .iter()
            .filter_map(|p| p.file_name())
            .map(|f| f.to_string_lossy().into_owned())
            .collect(),
        capture,
        provenance,
    };
    let path = dir.join("manifest.json");
    let json = serde_json::to_vec_pretty(&manifest).expect("manifest serialises");
    crate::fsio::write_bytes(&path, &json).map_err(|source| SynthError::Write { path, source })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::protocol::ProtocolError;

    #[test]
    fn noise_is_seeded_and_of_the_stated_size() {
        let config = SynthConfig::default();
        let a = record(&config).unwrap();
        let b = record(&config).unwrap();
        assert_eq!(a[0].tips, b[0].tips);
        let residuals: Vec<f64> = a[0]
            .tips
            .values
            .iter()
            .zip(&a[0].truth.values)
            .map(|(m, t)| m - t)
            .collect();
        let sd = (residuals.iter().map(|r| r * r).sum::<f64>() / residuals.len() as f64).sqrt();
        assert!((sd - 0.02).abs() < 0.003, "noise sd {sd} mm, expected 0.02");
        let other = record(&SynthConfig { seed: 7, ..config }).unwrap();
        assert_ne!(a[0].tips, other[0].tips);
    }

    #[test]
    fn bad_steps_and_noise_are_rejected() {
        for step in [0.0, -10.0, 30.0, f64::NAN] {
            let config = SynthConfig {
                grid_step_kpa: step,
                ..SynthConfig::default()
            };
            assert!(
                matches!(
                    record(&config),
                    Err(SynthError::Protocol(ProtocolError::BadStep {
                        flag: "grid-step-kpa",
                        ..
                    }))
                ),
                "{step}"
            );
        }
        let config = SynthConfig {
            noise_mm: -0.1,
            ..SynthConfig::default()
        };
        assert!(matches!(record(&config), Err(SynthError::BadNoise(_))));
        let mut config = SynthConfig::default();
        config.plant.hysteresis_kpa = -5.0;
        assert!(matches!(record(&config), Err(SynthError::BadHysteresis(_))));
    }
}
