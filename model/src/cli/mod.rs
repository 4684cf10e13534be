//! The command line: one file per subcommand turns arguments into a library call and prints the
//! result ([`crate::pipeline`] does the work). Nothing below this module prints. Here the
//! modelling commands ([`Modelling`]) and what every command shares (one-line errors, exit
//! codes, progress, Ctrl-C); the `handcap` library's command line adds the camera commands.

mod export;
mod inverse;
pub use inverse::PlanArgs;
mod model;
mod monitor;
pub use monitor::SettingsArgs as MonitorArgs;
mod predict;
pub mod protocol;

use std::collections::HashMap;
use std::ffi::OsStr;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, Once};

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use crate::pipeline::{Event, Session, Task};

/// The commands that model (no camera, no OpenCV): what the `handcap` binary runs itself.
/// Every subcommand takes negative numbers as values (`--c -1` is refused by its own check,
/// saying why, not taken for a flag).
// Parsed once per process: the size of its largest variant (model's flags) costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
pub enum Modelling {
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
    /// Replay a triangulated session against a model: an online band and alarms when the
    /// finger changed or a camera moved
    Monitor(monitor::Args),
    /// The paper's pressure protocol → protocol.csv, for `capture --protocol`
    #[command(allow_negative_numbers = true)]
    Protocol(protocol::Args),
}

impl Modelling {
    /// Runs the command.
    ///
    /// # Errors
    /// The command's own.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Modelling::Model(a) => model::run(a),
            Modelling::Predict(a) => predict::run(a),
            Modelling::Inverse(a) => inverse::run(a),
            Modelling::Export(a) => export::run(a),
            Modelling::Monitor(a) => monitor::run(a),
            Modelling::Protocol(a) => protocol::run(a),
        }
    }
}

/// The `handcap` binary's own command line: the modelling commands alone (it hands every
/// other to `handcap-cameras`, whose command line has them all).
#[derive(Parser)]
#[command(
    name = "handcap",
    version,
    about = "Model a soft actuator's pressure → tip map: fit, predict, invert, export, monitor (the camera commands are in handcap-cameras, installed beside handcap)"
)]
pub struct Light {
    #[command(subcommand)]
    pub command: Modelling,
}

/// Whether `arg` (the first argument) names a modelling command.
pub fn is_light(arg: &OsStr) -> bool {
    arg.to_str()
        .is_some_and(<Modelling as Subcommand>::has_subcommand)
}

/// An error in how the command was called (exit 2, as clap's own).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Usage(pub String);

/// `Err(Usage)` with a formatted message.
#[macro_export]
#[doc(hidden)]
macro_rules! usage {
    ($($arg:tt)*) => {
        return Err($crate::cli::Usage(format!($($arg)*)).into())
    };
}
pub use crate::usage;

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
    said(&line.replace('\n', " "))
}

/// Prints `warning: text` on stderr, long numbers shortened as in errors ([`one_line`]).
pub fn warn(text: &str) {
    eprintln!("warning: {}", short_numbers(text));
}

/// Prints `note: text` on stderr, as [`said`].
pub fn note(text: &str) {
    eprintln!("note: {}", said(text));
}

/// `text` as the command line says it: parameters named as flags, long numbers shortened.
pub fn said(text: &str) -> String {
    short_numbers(&flags(text))
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
    hysteresis_kpa baseline_mm distance_mm fov_deg groups time no_images dynamic model weight \
    loss";

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

/// A command line `C`: parses it, runs it with `run` and turns its outcome into the exit code,
/// every error on one line.
pub fn main<C: Parser>(run: impl FnOnce(C) -> anyhow::Result<()>) -> ExitCode {
    restore_sigpipe();
    let args = match C::try_parse() {
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
    finish(run(args))
}

/// The exit code of an outcome, its error said on one line.
pub fn finish(outcome: anyhow::Result<()>) -> ExitCode {
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            crate::pipeline::outputs::remove_empty_made_folders();
            eprintln!("handcap: {}", one_line(&e));
            ExitCode::from(exit_code(&e))
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
            Event::Note(line) => println!("{}", said(&line)),
            Event::Stage { step, of, text } => println!("[{step}/{of}] {text}"),
            Event::StageTime { name, seconds } => println!("      {name} done in {seconds:.1} s"),
            Event::Fitted(f) => print!("{}", said(&f.to_string())),
            Event::Outcome(o) => print!("{}", said(&o.to_string())),
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
pub fn with_session<T>(work: impl FnOnce(&Session) -> T) -> T {
    let ui = Ui::default();
    let events = |e: Event| ui.show(e);
    let session = Session {
        command: std::env::args().collect(),
        interrupt: interrupt_flag(),
        events: &events,
    };
    work(&session)
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
        super::Light::command().debug_assert();
    }
}
