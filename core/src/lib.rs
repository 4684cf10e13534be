//! handcap's modelling core: what `handcap model`, `predict` and `inverse` do, as a library that
//! builds anywhere (pure Rust: no OpenCV, no C toolchain beyond Rust's own).
//!
//! - [`data`]: datasets with named columns, CSV read and written with errors that name file and
//!   line;
//! - [`model`]: the [`model::Predict`] / [`model::Differentiable`] contracts and metrics; the
//!   model seam ([`model::ModelSpec`] → [`model::StoredModel`]); multi-output SVR
//!   ([`model::msvr`], exact or on a reduced basis) and its tuning; input history for time
//!   series ([`model::history`]); the previous physics model ([`model::previous`]); the inverse
//!   ([`model::inverse`]); the model file ([`model::file`]);
//! - [`search`]: the hyper-parameter searches (the paper's ant colony, ACO_R, a grid);
//! - [`stats`], [`fsio`] (atomic writes), [`provenance`], [`hand`] (the micro-hand's design values),
//!   [`control`] (long work stopped and watched from outside).
//!
//! The `handcap` command (stereo capture, calibration and triangulation through OpenCV, the
//! demo and the reports) re-exports these modules under the same paths.
//!
//! # Conventions
//!
//! - Units are in names: `_mm`, `_kpa`, `_s`. Lengths are millimetres, pressures kPa.
//! - Matrices of samples are row-major, one row per sample: inputs `n × d`, outputs `n × q`.
//! - Every random choice takes an explicit seed, and the same call gives the same bytes.
//! - Files are written atomically (temporary file, then rename).

/// The seed every command uses when none is given (the paper's year).
pub const DEFAULT_SEED: u64 = 2020;

pub mod control;
pub mod data;
pub mod fsio;
pub mod hand;
pub mod model;
pub mod monitor;
pub mod provenance;
pub mod search;
pub mod select;
pub mod stats;
