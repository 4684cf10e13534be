//! The stages as library calls: each reads its input files, does its work, writes its output
//! files atomically and returns what it did. The command line (and any other front end: a
//! capture program, a notebook binding) only turns its arguments into these calls and shows
//! the [`Event`]s they report.
//!
//! Here the modelling stages (`fit`, `predict`, `inverse`, `trajectory`, `export`) and what
//! every stage shares; the `handcap` library adds the camera stages (`synth`, `calibrate`,
//! `triangulate`, the demo) beside them, under the same `pipeline` path.
//!
//! Every stage takes a [`Session`]: the command line (recorded in provenance), the interrupt
//! flag (Ctrl-C: long work stops at its next checkpoint and keeps what it finished) and the
//! callback that receives progress and results. Nothing here prints.

pub mod export;
pub mod fit;
pub mod inverse;
pub mod monitor;
pub mod outputs;
pub mod predict;
pub mod trajectory;

use std::sync::atomic::{AtomicBool, Ordering};

use crate::provenance::Provenance;
use crate::search::IterationRecord;

/// A long task that reports `(done, total)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Task {
    /// Rendering the virtual capture's images.
    Render,
    /// Finding chessboard corners.
    Detect,
    /// Finding the tip in frames.
    Frames,
    /// The final fit's solver iterations (of its cap).
    Fit,
}

/// What a stage reports while it works.
pub enum Event<'a> {
    /// Progress of a counted task.
    Count {
        task: Task,
        done: usize,
        total: usize,
    },
    /// A counted task ended.
    Finished(Task),
    /// A search iteration ended; `cap` is the most iterations the search runs.
    Iteration {
        record: &'a IterationRecord,
        cap: usize,
    },
    /// A search ended.
    SearchEnded,
    /// A sentence for the user (e.g. rows left out of a file).
    Note(String),
    /// The demo starts stage `step` of `of`.
    Stage {
        step: usize,
        of: usize,
        text: String,
    },
    /// A stage ended after `seconds`.
    StageTime {
        name: &'a str,
        seconds: f64,
    },
    /// A stage's outcome, for a front end that shows each as it comes (the demo): a fit, or
    /// any other stage's (a calibration, a triangulation) as the text it shows.
    Fitted(&'a fit::FitOutcome),
    Outcome(&'a dyn std::fmt::Display),
}

/// What every stage is handed by its caller.
pub struct Session<'a> {
    /// The command line, for provenance.
    pub command: Vec<String>,
    /// Set by Ctrl-C.
    pub interrupt: &'a AtomicBool,
    /// Receives progress and results; called from worker threads too.
    pub events: &'a (dyn Fn(Event) + Sync),
}

impl Session<'_> {
    #[doc(hidden)]
    pub fn emit(&self, event: Event) {
        (self.events)(event);
    }

    #[doc(hidden)]
    pub fn interrupted(&self) -> bool {
        self.interrupt.load(Ordering::SeqCst)
    }

    /// A `(done, total)` callback for `task`.
    #[doc(hidden)]
    pub fn counter(&self, task: Task) -> impl Fn(usize, usize) + Sync + '_ {
        move |done, total| self.emit(Event::Count { task, done, total })
    }

    /// Provenance of this run, with `seed` when it draws random numbers.
    #[doc(hidden)]
    pub fn provenance(&self, seed: Option<u64>) -> Provenance {
        Provenance::new(self.command.clone(), seed)
    }
}

/// Creates the directory a file is written into, when it has one.
#[doc(hidden)]
pub fn create_parent(path: &std::path::Path) -> std::io::Result<()> {
    match path.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(parent) => std::fs::create_dir_all(parent),
        None => Ok(()),
    }
}

/// Errors of a stage: the failing library's own, or a file the stage itself writes.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A camera stage's own error (synth, capture, calibration, the rig, triangulation, the
    /// session's files), as the `handcap` library converts it.
    #[error(transparent)]
    Camera(Box<dyn std::error::Error + Send + Sync>),
    #[error(transparent)]
    Data(#[from] crate::data::DataError),
    #[error(transparent)]
    Msvr(#[from] crate::model::msvr::MsvrError),
    #[error(transparent)]
    Tune(#[from] crate::select::tune::TuneError),
    #[error(transparent)]
    Select(crate::select::SelectError),
    #[error(transparent)]
    Folds(#[from] crate::select::folds::FoldsError),
    #[error(transparent)]
    Previous(#[from] crate::model::previous::PreviousError),
    #[error(transparent)]
    Model(#[from] crate::model::ModelError),
    #[error(transparent)]
    Inverse(#[from] crate::model::inverse::InverseError),
    #[error(transparent)]
    ModelFile(#[from] crate::model::file::ModelFileError),
    #[error(transparent)]
    Report(#[from] crate::report::ReportError),
    #[error("{path}: {source}")]
    Io {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
    /// A request that cannot be carried out as asked: settings that contradict each other or
    /// the data, an output that would replace an input (a front end's usage error).
    #[error("{0}")]
    Request(String),
    /// An input file whose content cannot be used (the file, and the line where there is one).
    #[error("{0}")]
    Input(String),
    /// An input or output place that cannot be used (not a directory, not writable).
    #[error("{0}")]
    Place(String),
    /// A session that ended before its work did (a camera lost, a command failed); what it
    /// recorded is kept.
    #[error("{0}")]
    Stopped(String),
    /// Ctrl-C stopped the work; what was finished is kept.
    #[error("{0}")]
    Interrupted(String),
    /// A failure after the main result was written.
    #[error("{source} (written all the same: {})", written.display())]
    Partial {
        source: Box<PipelineError>,
        written: std::path::PathBuf,
    },
    /// A demo result that contradicts the ground truth it is checked against.
    #[error("{0}")]
    Check(String),
}

/// The error for an I/O failure on `path`.
#[doc(hidden)]
pub fn io_error(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> PipelineError + '_ {
    move |source| PipelineError::Io {
        path: path.to_path_buf(),
        source,
    }
}
