//! `handcap capture`: two cameras filmed on their own threads, every frame stamped on one
//! clock as near its exposure as its source tells and written in the layout `triangulate`
//! reads; optionally a pressure protocol driven by the lab's own command, logged on the same
//! clock.
//!
//! # The clock
//! `time_s` in `frames.csv` and `pressures.csv` is seconds since the session began on the
//! host's monotonic clock (Linux `CLOCK_MONOTONIC`: Python's `time.monotonic()`, C's
//! `clock_gettime(CLOCK_MONOTONIC)`). `capture.json` records that clock's reading at the start
//! (`start_monotonic_s`) and the wall-clock time (`start_unix_s`), so a program that logs the
//! regulator itself writes `time.monotonic() - start_monotonic_s`.
//!
//! # Cameras
//! Each `--left`/`--right` is a device index (`0`), a device path (`/dev/video2`), a video file
//! (played at its own frame rate, standing in for a camera), or anything else OpenCV opens (a
//! URL, a GStreamer pipeline), each read through its kind of `source::FrameSource`. Devices
//! are asked for MJPG at the size and rate given and for fixed exposure, white balance and
//! focus; what the backend refuses is said. A stream URL (`http://…`, `rtsp://…`) is read by
//! FFmpeg with the server's settings. Frames are kept as they come: a camera's, a Motion-JPEG
//! file's or a Motion-JPEG stream's JPEG bytes as `.jpg` without decoding or re-encoding,
//! anything else decoded and written losslessly as `.png`, written off the cameras' threads.
//!
//! # Ending
//! The protocol's end, `--duration`, Ctrl-C (or SIGTERM, SIGHUP), a camera that stops
//! delivering (for [`STALL_S`], or its stream ends), a pressure command that fails or runs over
//! [`COMMAND_TIMEOUT_S`], or a thread of the session that panics: every frame finished by then
//! is written and listed, the logs are complete, and `capture.json` says how it ended. The
//! session's files are also rewritten every second while filming ([`Ending::Filming`]).

pub mod calibration;
pub mod dialect;
mod files;
pub mod flash;
pub mod line;
pub mod motion;
mod regulator;
pub mod serial;
mod session;
pub mod source;
pub mod sync_led;
pub mod url;
pub mod view;

pub use session::capture;
use source::Grabbed;

use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;

use crate::session::protocol;
use crate::stereo::Side;

/// The session's description and summary, in the session's folder.
pub const CAPTURE_FILE: &str = "capture.json";

/// A live camera (a device or a stream, not a video file) that delivers nothing for this long
/// has stopped (s): `--stall-s`'s default.
pub const STALL_S: f64 = 2.0;
/// Longest a stream may take to open and send its first frame (s): a server that answers with
/// headers and no frames is refused, not waited on.
pub const STREAM_OPEN_S: f64 = 5.0;

/// Errors of capturing.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error("cannot open the {name} camera {camera:?}: {why}; {hint}")]
    NotOpened {
        /// The camera's name in the session.
        name: String,
        /// The source, its password hidden ([`url::redact`]).
        camera: String,
        why: String,
        /// What to check: the devices found for a device, the URL for a stream.
        hint: String,
    },
    #[error("{0} already holds {1}; choose another --out")]
    Exists(PathBuf, &'static str),
    #[error(transparent)]
    Protocol(#[from] crate::data::DataError),
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{first}; the session stopped{}, and its lists could not be written either ({lists}): images on disk may be unlisted and commands unlogged; free space, or film to another disk", if *vented { " and the abort command ran" } else { "" })]
    ListsLost {
        /// The write failure that stopped the session.
        first: String,
        lists: Box<CaptureError>,
        vented: bool,
    },
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    #[error("the {thread} thread failed ({message}); what was recorded until then is kept and listed in {}", out.display())]
    ThreadFailed {
        thread: String,
        message: String,
        out: PathBuf,
    },
}

/// A camera of the session: its name (`left` and `right` for a pair) and what it films from
/// (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Source {
    pub name: String,
    pub source: String,
}

impl Source {
    /// The cameras of `--left`/`--right`, or of `--camera NAME=SOURCE` repeated (`named`):
    /// names of lower-case letters and digits, a letter first, each once; two cameras or more.
    ///
    /// # Errors
    /// What is wrong, in words naming the option.
    pub fn list(
        left: &Option<String>,
        right: &Option<String>,
        named: &[String],
    ) -> Result<Vec<Source>, String> {
        let source = |name: &str, source: &str| Source {
            name: name.into(),
            source: source.into(),
        };
        let sources: Vec<Source> = match (left.as_deref(), right.as_deref(), named) {
            (Some(l), Some(r), []) => return Ok(vec![source("left", l), source("right", r)]),
            (None, None, [_, _, ..]) => named
                .iter()
                .map(|given| {
                    let (name, from) = given.split_once('=').ok_or_else(|| {
                        format!("--camera {given}: give NAME=SOURCE (cam1=/dev/video0, say)")
                    })?;
                    let word = crate::session::frames::is_camera_name(name);
                    if !word || from.trim().is_empty() {
                        return Err(format!("--camera {given}: give NAME=SOURCE, the name of lower-case letters and digits (a letter first), the source not empty"));
                    }
                    Ok(source(name, from))
                })
                .collect::<Result<_, String>>()?,
            (None, None, [_]) => {
                return Err("--camera names one camera: a tip takes two or more; repeat --camera NAME=SOURCE for each".into())
            }
            (None, None, []) | (Some(_), None, []) | (None, Some(_), []) => {
                return Err("give --left and --right (a pair), or --camera NAME=SOURCE for each of two or more cameras".into())
            }
            _ => return Err("--camera names every camera: leave out --left and --right".into()),
        };
        if let Some(twice) = sources
            .iter()
            .enumerate()
            .find(|(i, s)| sources[..*i].iter().any(|t| t.name == s.name))
        {
            return Err(format!(
                "--camera {} is named twice: give each camera its own name",
                twice.1.name
            ));
        }
        Ok(sources)
    }
}

/// What a session does.
#[derive(Clone, Debug)]
pub struct CaptureOptions {
    /// The cameras, in order: a pair's `left` and `right`, or more.
    pub sources: Vec<Source>,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    /// Steps to drive, and how the regulator is told them.
    pub protocol: Option<(Vec<protocol::Step>, Regulator)>,
    /// Stop after this long (s).
    pub duration_s: Option<f64>,
    /// A live camera silent this long has stopped (s; [`STALL_S`] by default).
    pub stall_s: f64,
    /// Instead of the finger's frames: chessboard pairs for `calibrate` ([`calibration`]).
    pub calibration: Option<BoardPairs>,
    /// Command run once when a protocol's session ends early (see [`Ending::aborted`]), e.g.
    /// to vent the regulator.
    pub on_abort: Option<String>,
    /// Command that switches on a light both cameras see, run before the protocol: each
    /// camera's latency is measured from it ([`flash`]).
    pub flash: Option<String>,
    /// Blink the serial board's LED at the session's start and end: each camera's delay is
    /// measured from the frames that saw it ([`sync_led`]).
    pub sync_led: bool,
    /// A page the session is watched on as it runs ([`view`]).
    pub view: Option<std::sync::Arc<view::View>>,
}

impl CaptureOptions {
    /// Whether the cameras are a pair, `left` and `right`.
    pub fn is_pair(&self) -> bool {
        let names: Vec<&str> = self.sources.iter().map(|s| s.name.as_str()).collect();
        names == ["left", "right"]
    }

    /// Settings that cannot work, named as `field=value`.
    ///
    /// # Errors
    /// What is wrong and what to do, in words.
    pub fn check(&self) -> Result<(), String> {
        for (name, value) in [
            ("fps", self.fps),
            ("width", f64::from(self.width)),
            ("height", f64::from(self.height)),
        ] {
            if value.is_nan() || value <= 0.0 {
                return Err(format!("{name}={value} must be positive"));
            }
        }
        let sources = &self.sources;
        let same = (0..sources.len()).find_map(|i| {
            let b = sources[..i]
                .iter()
                .find(|b| b.source.trim() == sources[i].source.trim())?;
            Some((b, &sources[i]))
        });
        if let Some((a, b)) = same {
            return Err(format!(
                "the {} and {} cameras are the same source ({}); give each camera its own",
                a.name,
                b.name,
                url::redact(&a.source)
            ));
        }
        if !self.is_pair() {
            let pairs_only = [
                (self.calibration.is_some(), "--calib", "save each camera's board views as calib/<camera>_NN.jpg (one NN an instant) for handcap calibrate"),
                (self.flash.is_some(), "--flash", "film without it; triangulate --per-frame measures each camera's clock from the motion"),
                (self.sync_led, "--sync-led", "film without it; triangulate --per-frame measures each camera's clock from the motion"),
                (self.view.is_some(), "--view", "film without it"),
            ];
            if let Some((_, option, instead)) = pairs_only.into_iter().find(|p| p.0) {
                return Err(format!(
                    "{option} is built for a pair (--left, --right): with more cameras, {instead}"
                ));
            }
        }
        if self.stall_s.is_nan() || self.stall_s <= 0.0 {
            return Err(format!(
                "stall_s={}: give a positive number of seconds",
                self.stall_s
            ));
        }
        if let Some(d) = self.duration_s.filter(|&d| d.is_nan() || d <= 0.0) {
            return Err(format!("duration_s={d} must be positive"));
        }
        match &self.protocol {
            _ if !self.sync_led => {}
            Some((_, Regulator::Serial(_, _, Some(d)))) if !d.has_led() => {
                return Err("--sync-led blinks the board's LED: give the dialect led_on and led_off lines".into())
            }
            Some((_, Regulator::Serial(..))) => {}
            _ => return Err("--sync-led blinks the serial board's LED: give --protocol and --regulator serial:PATH".into()),
        }
        if let Some(c) = &self.calibration {
            c.board.check().map_err(|e| e.to_string())?;
            if c.pairs == 0 {
                return Err("pairs=0: take at least 1".into());
            }
        }
        Ok(())
    }
}

/// How the regulator is told each step.
#[derive(Clone, Debug)]
pub enum Regulator {
    /// A command run per step, `{p1} {p2} {p3}` and `{step}` filled in (`--set-pressure`).
    PerStep(String),
    /// One process kept running, a line per step on its input (`--regulator`).
    Streaming(String),
    /// A board on a serial line speaking handcap's line protocol (`--regulator
    /// serial:PATH[@BAUD]`), or another firmware's commands (`--dialect`): the device, the
    /// baud rate and the dialect.
    Serial(String, u32, Option<dialect::Dialect>),
}

/// What a calibration capture collects: still pairs of `board` where it stands somewhere new,
/// `pairs` of them into `OUT/calib/left_NN.jpg`, `right_NN.jpg`; or, as the `reference`, one
/// still pair as `left_ref`, `right_ref` (the board at the finger's base).
#[derive(Clone, Debug)]
pub struct BoardPairs {
    pub board: crate::calib::BoardSpec,
    pub pairs: usize,
    pub reference: bool,
}

/// How a session ended.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Ending {
    /// Still filming when the session's files were written (they are rewritten every second,
    /// so a session killed outright keeps what it had).
    Filming,
    ProtocolDone,
    Duration,
    Interrupted,
    /// A camera stopped delivering at `time_s`, after `frames` frames.
    CameraStopped {
        camera: String,
        time_s: f64,
        frames: usize,
    },
    /// A calibration capture has its pairs.
    PairsTaken,
    /// The pressure command failed at a step.
    CommandFailed {
        step: usize,
        message: String,
    },
    /// The flash command failed.
    FlashFailed {
        message: String,
    },
    /// A file could not be written (a full disk, a lost mount): everything before it is kept
    /// and listed as far as the disk allows, and `--on-abort` runs.
    WriteFailed {
        message: String,
    },
    /// A thread of the session (a camera's, the protocol's, the flash's) panicked.
    ThreadFailed {
        thread: String,
        message: String,
    },
}

impl Ending {
    /// Whether the session ended before its protocol did: stopped by the user or a signal, a
    /// camera, a failing command or thread.
    pub fn aborted(&self) -> bool {
        matches!(
            self,
            Ending::Interrupted
                | Ending::CameraStopped { .. }
                | Ending::CommandFailed { .. }
                | Ending::FlashFailed { .. }
                | Ending::WriteFailed { .. }
                | Ending::ThreadFailed { .. }
        )
    }
}

/// Live and final figures of a session.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Stats {
    /// Per camera, in the session's order.
    pub frames: Vec<usize>,
    /// Of them, those stamped by the camera's driver (a V4L2 device), not at grab time.
    pub by_driver: Vec<usize>,
    /// Frames per second over the session, each camera.
    pub fps: Vec<f64>,
    /// Frames each camera dropped ([`crate::frame_times::dropped`]).
    pub drops: Vec<usize>,
    /// Frames each camera stamped late ([`crate::frame_times::late`]: they waited in a queue, a
    /// busy machine or network), and the latest of them (ms).
    pub late: Vec<usize>,
    pub late_max_ms: Vec<f64>,
    /// Median |left − right| time of nearest frames (ms); with more cameras, the largest of
    /// each camera's from the first.
    pub skew_ms: f64,
    pub steps_done: usize,
    /// Steps whose `--set-pressure` command returned only after the step's hold was over: the
    /// next command followed at once, so the finger never settled in them and triangulate
    /// finds no row there.
    pub over_hold: usize,
    /// How long the commands took (ms): median and longest; 0, 0 before the first.
    pub command_ms: [f64; 2],
    /// How late a streaming regulator's lines went out after they were due (ms): median and
    /// latest; 0, 0 for commands per step.
    pub command_late_ms: [f64; 2],
    /// A calibration capture's pairs taken, and why the last candidate was not.
    pub board_pairs: usize,
    pub board_refused: String,
    /// A calibration capture's right camera delay behind the left, seen in the board's motion
    /// ([`motion`], ms), when measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub board_delay_ms: Option<f64>,
}

/// What a session did and wrote.
#[derive(Clone, Debug, Serialize)]
pub struct CaptureSummary {
    pub ending: Ending,
    /// What the `on_abort` command did, when it ran: `done`, or why it failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub on_abort: Option<String>,
    pub stats: Stats,
    /// Each camera's latency from the flash, once measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flash: Option<flash::FlashLatency>,
    /// Each camera's delay from the LED's blinks, once measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sync_led: Option<sync_led::SyncLed>,
    /// Per camera: the settings the backend refused.
    pub refused: Vec<Vec<String>>,
    pub start_monotonic_s: f64,
    pub start_unix_s: f64,
}

/// Longest a `--set-pressure` command may run (s): a regulator that does not answer ends the
/// session instead of holding it.
pub const COMMAND_TIMEOUT_S: f64 = 10.0;

/// The session's clock: seconds since it began, on the host's monotonic clock.
struct Clock {
    start: Instant,
    /// The host's monotonic clock at `start` (s).
    start_monotonic_s: f64,
}

impl Clock {
    fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }
}

/// The host's `CLOCK_MONOTONIC` (s).
fn monotonic_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write into; CLOCK_MONOTONIC always exists on Linux.
    unsafe {
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Figures of one camera's times ([`crate::frame_times`]): frames per second, frames
/// dropped, frames stamped late and the latest (ms).
fn camera_figures(times: &[f64]) -> (f64, usize, usize, f64) {
    if times.len() < 2 {
        return (0.0, 0, 0, 0.0);
    }
    let fps = (times.len() - 1) as f64 / (times[times.len() - 1] - times[0]).max(1e-9);
    let period = crate::frame_times::period(times);
    let late: Vec<f64> = crate::frame_times::late(times, period)
        .into_iter()
        .flatten()
        .collect();
    let latest = late.iter().copied().fold(0.0, f64::max);
    (
        fps,
        crate::frame_times::dropped(times, period),
        late.len(),
        1e3 * latest,
    )
}

/// The session's figures so far, over every row: recomputed each second while filming (an
/// hour's 216 000 rows at 30 fps take about 14 ms).
fn stats(
    rows: &[(usize, usize, f64)],
    by_driver: &[usize],
    steps: &[regulator::Commanded],
    judge: Option<&calibration::Judge>,
) -> Stats {
    let mut took: Vec<f64> = steps.iter().map(|c| c.end_s - c.time_s).collect();
    // A command run per step that returned after its hold; a streamed line's write is not
    // the regulator's action (its lateness is `command_late_ms`).
    let over_hold = steps
        .iter()
        .filter(|c| c.scheduled_s.is_none() && c.end_s - c.time_s >= c.step.hold_s)
        .count();
    let command_ms =
        crate::stats::quantiles(&mut took, [0.5, 1.0]).map_or([0.0; 2], |q| q.map(|t| 1e3 * t));
    let mut late: Vec<f64> = steps
        .iter()
        .filter_map(|c| c.scheduled_s.map(|due| c.time_s - due))
        .collect();
    let command_late_ms =
        crate::stats::quantiles(&mut late, [0.5, 1.0]).map_or([0.0; 2], |q| q.map(|t| 1e3 * t));
    let times: Vec<Vec<f64>> = (0..by_driver.len())
        .map(|c| rows.iter().filter(|r| r.0 == c).map(|r| r.2).collect())
        .collect();
    let figures: Vec<_> = times.iter().map(|t| camera_figures(t)).collect();
    // The largest of the other cameras' skews from the first.
    let skew_ms = times[1..]
        .iter()
        .map(|t| 1e3 * crate::frame_times::skew(&times[0], t))
        .fold(0.0, f64::max);
    Stats {
        frames: times.iter().map(Vec::len).collect(),
        by_driver: by_driver.to_vec(),
        fps: figures.iter().map(|f| f.0).collect(),
        drops: figures.iter().map(|f| f.1).collect(),
        late: figures.iter().map(|f| f.2).collect(),
        late_max_ms: figures.iter().map(|f| f.3).collect(),
        skew_ms,
        steps_done: steps.len(),
        over_hold,
        command_ms,
        command_late_ms,
        board_pairs: judge.map_or(0, |j| j.taken),
        board_refused: judge.map_or_else(String::new, |j| j.refused.clone()),
        board_delay_ms: judge
            .and_then(|j| j.delay)
            .map(|d| 1e3 * d.right_minus_left_s),
    }
}

#[cfg(test)]
mod tests {
    use super::regulator::Commanded;
    use crate::session::protocol::Step;

    /// An hour's streamed session exited 1 as "unsettled" because one 33 ms line took 52 ms to
    /// write on a busy machine: only a command run per step is over its hold.
    #[test]
    fn only_a_command_per_step_that_outlasts_its_hold_is_unsettled() {
        let step = Step {
            step: 0,
            phase: "dyn".into(),
            pressures: [10.0; 3],
            hold_s: 1.0 / 30.0,
            line: 2,
        };
        let mut streamed = Commanded::streamed(1.0, 1.0, &step);
        streamed.end_s = 1.052;
        let per_step = Commanded {
            end_s: 1.052,
            scheduled_s: None,
            ..streamed.clone()
        };
        let stats = |log: &[Commanded]| super::stats(&[], &[0; 2], log, None);
        assert_eq!(stats(&[streamed]).over_hold, 0);
        assert_eq!(stats(&[per_step]).over_hold, 1);
    }
}
