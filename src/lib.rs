//! handcap: a validated model of a soft pneumatic actuator from two webcams and a pressure log.
//!
//! The first target is the 3-DOF micro-hand of Kawamura & Deng (Micromachines 2020, 11, 792):
//! a 50 mm finger of three McKibben muscles driven by pressures P1, P2, P3 (0-250 kPa).
//! The pipeline is `synth → calibrate → triangulate → model`; each stage reads and writes files
//! a user can open. This build has the virtual plant and stereo capture ([`synth`]), stereo
//! calibration ([`calib`]), the tip's triangulation into datasets ([`triangulate`], with the
//! OpenCV geometry in [`stereo`]), the data layer ([`data`]), the multi-output SVR ([`model::msvr`])
//! with its hyper-parameter searches ([`search`]), the previous physics model it is compared
//! with ([`model::previous`]), the inverse model for feed-forward control ([`model::inverse`])
//! and the reports ([`report`]).
//!
//! # Conventions
//!
//! - Units are in names: `_mm`, `_kpa`, `_px`, `_rad`, `_s`. Lengths are millimetres, pressures
//!   kPa, angles radians (degrees only in reports).
//! - Hand frame (every dataset): origin at the tip at zero pressure; z along the finger axis from
//!   the tip towards the base (contraction is +z); x from muscle 1 towards muscle 3; y completes a
//!   right-handed frame (towards muscle 2).
//! - Matrices of samples are row-major, one row per sample: inputs `n × d`, outputs `n × q`.
//! - Every random choice takes an explicit seed, and the same command writes the same bytes.
//! - Files are written atomically (temporary file, then rename) and never over an input.

// The modelling core is its own crate (it builds without OpenCV), and so are the modelling
// commands, their reports and figures (the `handcap` binary is built from that crate alone);
// their modules keep their paths.
pub use handcap_core::{
    control, data, fsio, hand, model, monitor, provenance, search, select, stats, DEFAULT_SEED,
};
pub use handcap_model::{plot, report, BUILD_ID_VAR};

/// This build's identity: the version and a hash of the sources (`build.rs`). `handcap` and
/// the `handcap-cameras` it hands commands to must share it.
pub const BUILD_ID: &str = env!("HANDCAP_BUILD_ID");

pub mod calib;
pub mod capture;
pub mod cli;
mod cv;
pub mod frame_times;
pub mod geometry;
mod http;
pub mod image;
pub mod lab;
pub mod opencv_yaml;
pub mod pipeline;
mod priority;
pub mod session;
pub mod stereo;
pub mod synth;
pub mod triangulate;
pub mod video;
