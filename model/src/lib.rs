//! handcap's modelling commands and what they need, without OpenCV: the command line of
//! `model`, `predict`, `inverse`, `export` and `protocol` (and the parts every command shares:
//! errors on one line, progress, Ctrl-C), their stages ([`pipeline`]), the model report, the
//! figures and the pressure protocols. The `handcap` binary is built from this crate alone, so
//! it links no OpenCV library; the `handcap` library re-exports every module here at the same
//! path and adds the camera commands (`handcap-cameras`).
//!
//! The conventions are the `handcap` crate's (frames, units, shapes, seeds, atomic files).

// The modelling core, at the paths the modules here use.
pub use handcap_core::{
    control, data, fsio, hand, model, monitor, provenance, search, select, stats, DEFAULT_SEED,
};

pub mod cli;
pub mod pipeline;
pub mod plot;
pub mod report;
pub mod session;

/// The environment variable in which `handcap` tells `handcap-cameras` its build's identity
/// (`HANDCAP_BUILD_ID`, made by the `handcap` package's `build.rs`; not that name: cargo sets it
/// for `cargo run` and `cargo test` too).
pub const BUILD_ID_VAR: &str = "HANDCAP_HANDED_BY";
