//! Command-line front end: one file per subcommand turns arguments into a library call and
//! prints the result. Nothing below this module prints.

mod calibrate;
mod demo;
mod inverse;
mod model;
mod predict;
mod synth;
mod triangulate;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use clap::{Parser, Subcommand};

/// Model a soft pneumatic micro-hand from two webcams and a pressure log: calibrate the
/// cameras, fit the pressure → tip map (MSVR, the method of Kawamura & Deng 2020), and generate
/// all of it from a virtual micro-hand.
#[derive(Parser)]
#[command(name = "handcap", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Virtual micro-hand and stereo rig → images, pressure log, datasets, ground truth
    Synth(synth::Args),
    /// Stereo calibration from chessboard image pairs → OpenCV YAML
    Calibrate(calibrate::Args),
    /// Red tip in each frame pair → 3-D tip in the hand frame → one dataset row per pressure step
    Triangulate(triangulate::Args),
    /// Fit MSVR to a CSV dataset, report held-out errors, write the model file
    Model(model::Args),
    /// Predict outputs of a fitted model for the inputs in a CSV file
    Predict(predict::Args),
    /// Inputs (pressures) that put a fitted model's tip at a target, for feed-forward control
    Inverse(inverse::Args),
    /// The whole pipeline on the built-in virtual micro-hand, with a report
    Demo(demo::Args),
}

/// Runs the chosen subcommand.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Synth(a) => synth::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Triangulate(a) => triangulate::run(a),
        Command::Model(a) => model::run(a),
        Command::Predict(a) => predict::run(a),
        Command::Inverse(a) => inverse::run(a),
        Command::Demo(a) => demo::run(a),
    }
}

/// Ctrl-C sets this; long work (a search, rendering) stops at its next checkpoint and keeps
/// what it finished.
fn interrupt_flag() -> Arc<AtomicBool> {
    static FLAG: std::sync::OnceLock<Arc<AtomicBool>> = std::sync::OnceLock::new();
    FLAG.get_or_init(|| {
        let flag = Arc::new(AtomicBool::new(false));
        let handler_flag = Arc::clone(&flag);
        // Without a handler (another one is installed) Ctrl-C just ends the process.
        let _ = ctrlc::set_handler(move || handler_flag.store(true, Ordering::SeqCst));
        flag
    })
    .clone()
}

/// A progress bar for library work that reports `(done, total)`.
struct Counter(indicatif::ProgressBar);

impl Counter {
    fn new(template: &str) -> Self {
        Counter(
            indicatif::ProgressBar::new(0).with_style(
                indicatif::ProgressStyle::with_template(template).expect("valid template"),
            ),
        )
    }

    /// The callback the library reports to.
    fn update(&self, done: usize, total: usize) {
        self.0.set_length(total as u64);
        self.0.set_position(done as u64);
    }

    fn finish(&self) {
        self.0.finish_and_clear();
    }
}

/// The command line as typed, for provenance.
fn command_line() -> Vec<String> {
    std::env::args().collect()
}
