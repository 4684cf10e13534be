//! Command-line front end: one file per subcommand turns arguments into a library call and
//! prints the result ([`crate::pipeline`] does the work). Nothing below this module prints.

mod board;
mod calibrate;
mod capture;
mod demo;
mod export;
mod inverse;
mod model;
mod predict;
mod protocol;
mod synth;
mod triangulate;

use std::collections::HashMap;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, Once};

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use crate::pipeline::{Event, Session, Task};

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
    /// Fit MSVR to a CSV dataset, report held-out errors, write the model file
    #[command(allow_negative_numbers = true)]
    Model(model::Args),
    /// Predict outputs of a fitted model for the inputs in a CSV file
    #[command(allow_negative_numbers = true)]
    Predict(predict::Args),
    /// Inputs (pressures) that put a fitted model's tip at a target, for feed-forward control
    #[command(allow_negative_numbers = true)]
    Inverse(inverse::Args),
    /// A fitted model as a self-contained C header, for a controller to embed
    Export(export::Args),
    /// The whole pipeline on the built-in virtual micro-hand, with a report
    #[command(allow_negative_numbers = true)]
    Demo(demo::Args),
    /// Two cameras → frames + frames.csv on one clock, optionally driving a pressure protocol
    #[command(allow_negative_numbers = true)]
    Capture(capture::Args),
    /// The paper's pressure protocol → protocol.csv, for `capture --protocol`
    #[command(allow_negative_numbers = true)]
    Protocol(protocol::Args),
    /// A calibration board to print (chessboard or ChArUco, SVG at true size) and its board.yml
    #[command(allow_negative_numbers = true)]
    Board(board::Args),
}

/// An error in how the command was called (exit 2, as clap's own).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Usage(pub String);

/// `Err(Usage)` with a formatted message.
macro_rules! usage {
    ($($arg:tt)*) => {
        return Err($crate::cli::Usage(format!($($arg)*)).into())
    };
}
pub(crate) use usage;

/// The exit code of an error: 2 usage, 130 interrupted, 1 anything else.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    use crate::pipeline::PipelineError;
    if e.is::<Usage>() || matches!(e.downcast_ref(), Some(PipelineError::Request(_))) {
        2
    } else if matches!(e.downcast_ref(), Some(PipelineError::Interrupted(_)))
        || e.chain().any(|c| {
            matches!(
                c.downcast_ref(),
                Some(crate::model::msvr::MsvrError::Interrupted)
            )
        })
    {
        130
    } else {
        1
    }
}

/// The error on one line: its message, then each cause the message does not already contain
/// (an I/O error wrapped with its path is said once, not twice), parameters named as flags.
pub fn one_line(e: &anyhow::Error) -> String {
    let mut line = e.to_string();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !line.contains(&text) {
            line = format!("{line}: {text}");
        }
    }
    short_numbers(&flags(&line.replace('\n', " ")))
}

/// `text` with every number longer than [`LONG_NUMBER`] characters written in scientific
/// notation (Rust writes 1e-300 as 300 digits): σ = 1e-300 is said as `1e-300`.
fn short_numbers(text: &str) -> String {
    let is_digit = |c: char| c.is_ascii_digit() || c == '.';
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(start) = rest.find(|c: char| c.is_ascii_digit()) {
        let len = rest[start..]
            .find(|c| !is_digit(c))
            .unwrap_or(rest.len() - start);
        let number = &rest[start..start + len];
        out.push_str(&rest[..start]);
        match number.parse::<f64>() {
            Ok(v) if len > LONG_NUMBER => out.push_str(&format!("{v:e}")),
            _ => out.push_str(number),
        }
        rest = &rest[start + len..];
    }
    out.push_str(rest);
    out
}

/// The longest number a message writes as it is (characters).
const LONG_NUMBER: usize = 24;

/// The library's parameter names (`field=value`, as the Python estimator takes them) set by a
/// flag of the same name here (`max_kpa` → `--max-kpa`): the one place the command line maps
/// them, with [`RENAMED`].
const FIELDS: &str =
    "c epsilon sigma basis folds folds_by history fitness budget max_rows intervals \
    pressures max_kpa reach gain max_rate smoothness board square_mm marker_mm \
    dictionary fps width height stall_s duration_s pairs settle_s search search_on \
    hysteresis_kpa baseline_mm distance_mm groups time no_images dynamic";

/// The parameters whose flag has another name.
const RENAMED: [(&str, &str); 1] = [("groups", "--group-by")];

/// `text` with each `field=value` of [`FIELDS`] written as the flag (`basis=exact` →
/// `--basis exact`; `intervals=true` → `--intervals`).
pub fn flags(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    'scan: while !rest.is_empty() {
        let at_boundary = out
            .chars()
            .last()
            .is_none_or(|c| !(c.is_alphanumeric() || c == '_' || c == '-'));
        if at_boundary {
            for field in FIELDS.split_whitespace() {
                let Some(value) = rest.strip_prefix(field).and_then(|r| r.strip_prefix('=')) else {
                    continue;
                };
                let flag = RENAMED.iter().find(|(f, _)| *f == field).map_or_else(
                    || format!("--{}", field.replace('_', "-")),
                    |(_, flag)| flag.to_string(),
                );
                let flag = flag.as_str();
                if let Some(after) = value.strip_prefix("true") {
                    out.push_str(flag);
                    rest = after;
                } else if value.is_empty() || value.starts_with(' ') {
                    // `field=` alone names the parameter without a value.
                    out.push_str(flag);
                    rest = value;
                } else {
                    out.push_str(flag);
                    out.push(' ');
                    rest = value;
                }
                continue 'scan;
            }
        }
        let c = rest.chars().next().expect("not empty");
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
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

/// A number that is finite (not NaN or infinite), for flags.
pub fn finite(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(format!("{v} is not a finite number")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// A coverage level strictly between 0 and 1 (0.9 for 90 %), for `--interval`.
pub fn level(s: &str) -> Result<f64, String> {
    match finite(s)? {
        v if v > 0.0 && v < 1.0 => Ok(v),
        v => Err(format!(
            "{v} is not a level in (0, 1); give e.g. 0.9 for a 90 % interval"
        )),
    }
}

/// The `handcap` command: parses the command line, runs the command and turns its outcome
/// into the exit code. The modelling commands (`model`, `predict`, `inverse`) and `protocol`
/// run here; `cameras` runs the others, which call OpenCV: the `handcap` binary hands them to
/// `handcap-cameras` beside it, so that the modelling commands start without loading OpenCV's
/// libraries (about 250 shared objects, 0.2 s).
pub fn main(cameras: fn(Command) -> anyhow::Result<()>) -> ExitCode {
    restore_sigpipe();
    let args = match Cli::try_parse() {
        Ok(args) => args,
        // clap's refusal on one line, as every handcap error: its message, without the usage
        // and the pointer to --help that follow it.
        Err(e) if e.use_stderr() => {
            let text = e.render().to_string();
            let message: Vec<&str> = text
                .lines()
                .take_while(|l| !l.trim().is_empty() && !l.starts_with("Usage:"))
                .map(str::trim)
                .collect();
            eprintln!(
                "handcap: {}; see --help",
                message.join(" ").trim_start_matches("error: ")
            );
            return ExitCode::from(2);
        }
        Err(e) => e.exit(),
    };
    let outcome = match args.command {
        Command::Model(a) => model::run(a),
        Command::Predict(a) => predict::run(a),
        Command::Inverse(a) => inverse::run(a),
        Command::Export(a) => export::run(a),
        Command::Protocol(a) => protocol::run(a),
        other => cameras(other),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("handcap: {}", one_line(&e));
            ExitCode::from(exit_code(&e))
        }
    }
}

/// Runs a command that calls OpenCV (every one but those [`main`] runs itself).
///
/// # Errors
/// The command's own.
pub fn run_cameras(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Synth(a) => synth::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Triangulate(a) => triangulate::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Capture(a) => capture::run(a),
        Command::Board(a) => board::run(a),
        Command::Model(_)
        | Command::Predict(_)
        | Command::Inverse(_)
        | Command::Export(_)
        | Command::Protocol(_) => {
            unreachable!("`main` runs the modelling commands itself")
        }
    }
}

/// Lets a closed pipe end the process quietly (`handcap triangulate … | head`), as other
/// command-line tools do, instead of the Rust default (ignore SIGPIPE, then panic on the write).
fn restore_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first thing in `main`, before any thread starts; SIG_DFL is a valid
    // disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Ctrl-C, SIGTERM and SIGHUP (a closed terminal, `timeout`, a service stopped) set this; long
/// work (a search, rendering, filming) stops at its next checkpoint and keeps what it finished.
fn interrupt_flag() -> &'static AtomicBool {
    static INTERRUPTED: AtomicBool = AtomicBool::new(false);
    static HANDLER: Once = Once::new();
    HANDLER.call_once(|| {
        // Without a handler (another one is installed) Ctrl-C just ends the process.
        // The flag ends a search (its best kept) or a capture; the core's stop ends the fits
        // running (a second Ctrl-C ends the fit of the search's best).
        let _ = ctrlc::set_handler(|| {
            INTERRUPTED.store(true, Ordering::SeqCst);
            crate::control::request_stop();
        });
    });
    &INTERRUPTED
}

/// Shows the pipeline's events: a progress bar per counted task and for a search, sentences
/// and stage lines as they come. Where the bars cannot show (stderr not a terminal: a log
/// file, a pipe, a batch job), a search's progress is a line after its first iteration and at
/// most every [`LOG_EVERY_S`] after.
#[derive(Default)]
struct Ui {
    bars: Mutex<HashMap<Task, ProgressBar>>,
    search: Mutex<Option<ProgressBar>>,
    search_logged: Mutex<Option<std::time::Instant>>,
}

/// Seconds between two lines of a search's progress in a log.
const LOG_EVERY_S: f64 = 10.0;

impl Ui {
    fn show(&self, event: Event) {
        match event {
            Event::Count { task, done, total } => {
                let mut bars = self.bars.lock().expect("progress bars");
                let bar = bars.entry(task).or_insert_with(|| bar(template(task), 0));
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            }
            Event::Finished(task) => {
                if let Some(bar) = self.bars.lock().expect("progress bars").remove(&task) {
                    bar.finish_and_clear();
                }
            }
            Event::Iteration { record: r, cap } => {
                let mut search = self.search.lock().expect("search bar");
                let bar = search.get_or_insert_with(|| {
                    bar("search {bar:30} {pos}/{len} iterations  {msg}", cap as u64)
                });
                let best = format!("best {:.5} ({})", r.best_fitness, r.best);
                bar.set_position(r.iteration as u64);
                bar.set_message(best.clone());
                let mut logged = self.search_logged.lock().expect("search log");
                let due = logged.is_none_or(|t| t.elapsed().as_secs_f64() >= LOG_EVERY_S);
                if due && !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
                    println!("search: iteration {} of at most {cap}, {best}", r.iteration);
                    *logged = Some(std::time::Instant::now());
                }
            }
            Event::SearchEnded => {
                if let Some(bar) = self.search.lock().expect("search bar").take() {
                    bar.finish_and_clear();
                }
                *self.search_logged.lock().expect("search log") = None;
            }
            Event::Note(line) => println!("{}", flags(&line)),
            Event::Stage { step, of, text } => println!("[{step}/{of}] {text}"),
            Event::StageTime { name, seconds } => println!("      {name} done in {seconds:.1} s"),
            Event::Calibrated(c) => print!("{}", flags(&c.to_string())),
            Event::Triangulated(t) => print!("{}", flags(&t.to_string())),
            Event::Fitted(f) => print!("{}", flags(&f.to_string())),
        }
    }
}

fn template(task: Task) -> &'static str {
    match task {
        Task::Render => "render {bar:30} {pos}/{len} images  {elapsed}",
        Task::Detect => "detect {bar:30} {pos}/{len} images",
        Task::Frames => "frames {bar:30} {pos}/{len} ({per_sec}, {eta})",
        Task::Fit => "fit: solver iteration {pos} (at most {len})  {elapsed}",
    }
}

fn bar(template: &str, len: u64) -> ProgressBar {
    ProgressBar::new(len)
        .with_style(ProgressStyle::with_template(template).expect("valid template"))
}

/// Runs `work` with a session of this process: its command line, Ctrl-C and the terminal.
fn with_session<T>(work: impl FnOnce(&Session) -> T) -> T {
    let ui = Ui::default();
    let events = |e: Event| ui.show(e);
    let session = Session {
        command: std::env::args().collect(),
        interrupt: interrupt_flag(),
        events: &events,
    };
    work(&session)
}

/// Prints the files a stage wrote.
fn print_written(files: &[std::path::PathBuf]) {
    for f in files {
        println!("wrote {}", f.display());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hostile probe 11 (issue 61): numbers were printed in full (σ = 1e-300 as 300 digits).
    #[test]
    fn hostile_long_numbers_are_said_short() {
        let tiny = format!("sigma={} must be positive", 1e-300);
        assert!(tiny.len() > 300);
        assert_eq!(short_numbers(&tiny), "sigma=1e-300 must be positive");
        let huge = format!("line 12: {} kPa", 1e300);
        assert_eq!(short_numbers(&huge), "line 12: 1e300 kPa");
        let plain = "frames/left_00012.png: 3.25 px at 1280 x 720";
        assert_eq!(short_numbers(plain), plain);
    }
    #[test]
    fn parameters_are_named_as_flags() {
        assert_eq!(
            super::flags("give basis=3 or fewer, or basis=auto (folds_by=run: 2 groups)"),
            "give --basis 3 or fewer, or --basis auto (--folds-by run: 2 groups)"
        );
        assert_eq!(
            super::flags("fit it with intervals=true; epsilon=0.5, c=10, basic=1"),
            "fit it with --intervals; --epsilon 0.5, --c 10, basic=1"
        );
        assert_eq!(
            super::flags("hysteresis_kpa= applies to search=grid"),
            "--hysteresis-kpa applies to --search grid"
        );
    }

    #[test]
    fn the_command_line_is_consistent() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
