//! Command-line front end: one file per subcommand turns arguments into a library call and
//! prints the result ([`crate::pipeline`] does the work). Nothing below this module prints.
//! The camera commands are here; the modelling commands and what every command shares are
//! `handcap_model`'s command line, re-exported.

mod board;
mod calibrate;
mod capture;
mod demo;
mod follow;
mod lab;
mod synth;
mod triangulate;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub use handcap_model::cli::{
    exit_code, finish, finite, flags, level, one_line, with_session, Modelling, MonitorArgs, Usage,
};
pub(crate) use handcap_model::cli::{protocol, usage};

/// Model a soft pneumatic micro-hand from two webcams and a pressure log: calibrate the
/// cameras, fit the pressure → tip map (MSVR, the method of Kawamura & Deng 2020), and generate
/// all of it from a virtual micro-hand.
#[derive(Parser)]
#[command(name = "handcap", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Every subcommand takes negative numbers as values (`--c -1` is refused by its own check,
/// saying why, not taken for a flag).
#[derive(Subcommand)]
pub enum Command {
    /// Virtual micro-hand and stereo rig → images, pressure log, datasets, ground truth
    #[command(allow_negative_numbers = true)]
    Synth(synth::Args),
    /// Stereo calibration from chessboard or ChArUco image pairs → OpenCV YAML
    #[command(allow_negative_numbers = true)]
    Calibrate(calibrate::Args),
    /// Red tip in each frame pair → 3-D tip in the hand frame → one dataset row per pressure step
    #[command(allow_negative_numbers = true)]
    Triangulate(triangulate::Args),
    #[command(flatten)]
    Modelling(Modelling),
    /// The whole pipeline on the built-in virtual micro-hand, with a report
    #[command(allow_negative_numbers = true)]
    Demo(demo::Args),
    /// Two cameras → frames + frames.csv on one clock, optionally driving a pressure protocol
    #[command(allow_negative_numbers = true)]
    Capture(capture::Args),
    /// A calibration board to print (chessboard or ChArUco, SVG at true size) and its board.yml
    #[command(allow_negative_numbers = true)]
    Board(board::Args),
    /// The virtual micro-hand in real time, for `capture` to film: two cameras as Motion-JPEG
    /// streams on 127.0.0.1, the regulator board on a pseudo-terminal (handcap's line
    /// protocol), the truth in OUT/truth/
    #[command(allow_negative_numbers = true)]
    Lab(lab::Args),
    /// A path followed through the regulator while the cameras film, each repetition
    /// triangulated per frame and learned from (inverse --previous --measured): the loop
    /// closed by one command, scored against the target (and a lab's truth)
    #[command(allow_negative_numbers = true)]
    Follow(follow::Args),
}

/// The `handcap-cameras` binary: every command. (`handcap` runs the modelling commands itself,
/// from `handcap_model` alone, and hands the others here: they call OpenCV, about 250 shared
/// objects and 0.2 s to load.)
pub fn main() -> ExitCode {
    handcap_model::cli::main(|cli: Cli| run(cli.command))
}

/// Runs a command.
///
/// # Errors
/// The command's own.
pub fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Synth(a) => synth::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Triangulate(a) => triangulate::run(a),
        Command::Modelling(m) => m.run(),
        Command::Demo(a) => demo::run(a),
        Command::Capture(a) => capture::run(a),
        Command::Board(a) => board::run(a),
        Command::Lab(a) => lab::run(a),
        Command::Follow(a) => follow::run(a),
    }
}

/// A LEFT,RIGHT flag's values (one value serves both cameras); `None` when not given.
///
/// # Errors
/// A usage error naming `flag` for more than two values.
pub fn left_right(flag: &str, values: &[f64]) -> anyhow::Result<Option<[f64; 2]>> {
    Ok(match *values {
        [] => None,
        [both] => Some([both; 2]),
        [left, right] => Some([left, right]),
        _ => usage!("{flag} takes LEFT,RIGHT or one value for both"),
    })
}

/// Prints the files a stage wrote.
fn print_written(files: &[std::path::PathBuf]) {
    for f in files {
        println!("wrote {}", f.display());
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_command_line_is_consistent() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
