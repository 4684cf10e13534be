//! A session: the protocol it drives ([`protocol`]) and its files, one writer and one reader
//! each: the frames (`frames/frames.csv` and the images or videos it lists, [`frames`]) and
//! the regulator's log (`pressures.csv`, [`pressures`]). `capture` and `synth` write them;
//! `calibrate` and `triangulate` read them.

pub mod frames;
pub mod pressures;
pub use handcap_model::session::protocol;

use std::path::PathBuf;

/// Errors of reading a session's files.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error(transparent)]
    Input(#[from] crate::data::DataError),
    #[error("no image of the frames listed in {0}/frames.csv was found (expected left_00000.png, right_00000.png, …)")]
    NoImages(PathBuf),
    #[error("{path}: {message}")]
    Video { path: PathBuf, message: String },
}
