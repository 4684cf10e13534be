//! The stages as library calls: each reads its input files, does its work, writes its output
//! files atomically and returns what it did. The command line (and any other front end: a
//! capture program, a notebook binding) only turns its arguments into these calls and shows
//! the [`Event`]s they report.
//!
//! `synth → calibrate → triangulate → fit`, and [`demo`] composes them on the virtual
//! micro-hand with checks against its ground truth.
//!
//! Every stage takes a [`Session`]: the command line (recorded in provenance), the interrupt
//! flag (Ctrl-C: long work stops at its next checkpoint and keeps what it finished) and the
//! callback that receives progress and results. Nothing here prints.

pub mod calibrate;
pub mod capture;
pub mod demo;
mod demo_checks;
pub mod demo_dynamic;
mod demo_plan;
mod demo_report;
pub mod demo_summary;
pub mod follow;
pub mod synth;
pub mod triangulate;

// The modelling stages and what every stage shares, from the OpenCV-free crate.
pub use handcap_model::pipeline::{
    create_parent, export, fit, inverse, io_error, monitor, outputs, predict, trajectory, Event,
    PipelineError, Session, Task,
};

/// The camera stages' errors, each a [`PipelineError::Camera`] (shown as itself).
macro_rules! camera_errors {
    ($($error:ty),*) => {$(
        impl From<$error> for PipelineError {
            fn from(e: $error) -> Self {
                PipelineError::Camera(Box::new(e))
            }
        }
    )*};
}
camera_errors!(
    crate::synth::SynthError,
    crate::capture::CaptureError,
    crate::calib::CalibError,
    crate::stereo::StereoError,
    crate::triangulate::TriangulateError,
    crate::session::SessionError
);
