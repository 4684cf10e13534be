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
mod files;
pub mod flash;
pub mod motion;
mod regulator;
pub mod source;
pub mod url;

use files::SessionFiles;
use flash::FlashState;
use regulator::{drive, drive_streaming, run_command, CommandEnd};
use source::{film, CameraEnd, Grabbed};

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::fsio;
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
    #[error("cannot open the {side} camera {camera:?}: {why}; {hint}")]
    NotOpened {
        side: &'static str,
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
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    #[error("the {thread} thread failed ({message}); what was recorded until then is kept and listed in {}", out.display())]
    ThreadFailed {
        thread: String,
        message: String,
        out: PathBuf,
    },
}

/// What a session does.
#[derive(Clone, Debug)]
pub struct CaptureOptions {
    /// The left and right camera (see the module docs).
    pub sources: [String; 2],
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
}

/// How the regulator is told each step.
#[derive(Clone, Debug)]
pub enum Regulator {
    /// A command run per step, `{p1} {p2} {p3}` and `{step}` filled in (`--set-pressure`).
    PerStep(String),
    /// One process kept running, a line per step on its input (`--regulator`).
    Streaming(String),
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
        side: Side,
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
    pub frames: [usize; 2],
    /// Of them, those stamped by the camera's driver (a V4L2 device), not at grab time.
    pub by_driver: [usize; 2],
    /// Frames per second over the session, each camera.
    pub fps: [f64; 2],
    /// Frames each camera dropped ([`crate::frame_times::dropped`]).
    pub drops: [usize; 2],
    /// Frames each camera stamped late ([`crate::frame_times::late`]: they waited in a queue, a
    /// busy machine or network), and the latest of them (ms).
    pub late: [usize; 2],
    pub late_max_ms: [f64; 2],
    /// Median |left − right| time of nearest frames (ms).
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
    /// Per camera: the settings the backend refused.
    pub refused: [Vec<String>; 2],
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
    rows: &[(Side, usize, f64)],
    by_driver: [usize; 2],
    steps: &[regulator::Commanded],
    judge: Option<&calibration::Judge>,
) -> Stats {
    let mut took: Vec<f64> = steps.iter().map(|c| c.end_s - c.time_s).collect();
    let over_hold = steps
        .iter()
        .filter(|c| c.end_s - c.time_s >= c.step.hold_s)
        .count();
    let command_ms =
        crate::stats::quantiles(&mut took, [0.5, 1.0]).map_or([0.0; 2], |q| q.map(|t| 1e3 * t));
    let mut late: Vec<f64> = steps
        .iter()
        .filter_map(|c| c.scheduled_s.map(|due| c.time_s - due))
        .collect();
    let command_late_ms =
        crate::stats::quantiles(&mut late, [0.5, 1.0]).map_or([0.0; 2], |q| q.map(|t| 1e3 * t));
    let times =
        |side: Side| -> Vec<f64> { rows.iter().filter(|r| r.0 == side).map(|r| r.2).collect() };
    let (l, r) = (times(Side::Left), times(Side::Right));
    let ((fl, dl, ll, ml), (fr, dr, lr, mr)) = (camera_figures(&l), camera_figures(&r));
    Stats {
        frames: [l.len(), r.len()],
        by_driver,
        fps: [fl, fr],
        drops: [dl, dr],
        late: [ll, lr],
        late_max_ms: [ml, mr],
        skew_ms: 1e3 * crate::frame_times::skew(&l, &r),
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

/// Films a session into `out` (`frames/`, `frames/frames.csv`, `pressures.csv` when a protocol
/// runs, `capture.json`); `live(stats)` about once a second; `interrupt` is Ctrl-C.
///
/// # Errors
/// [`CaptureError`]: a camera that does not open, `out` holding a capture, a file that cannot
/// be written. A camera that stops or a failing command end the session normally, said in
/// [`CaptureSummary::ending`].
pub fn capture(
    out: &Path,
    options: &CaptureOptions,
    live: &(dyn Fn(&Stats) + Sync),
    interrupt: &AtomicBool,
) -> Result<CaptureSummary, CaptureError> {
    let frames_dir = out.join("frames");
    let taken = |name: &str| {
        ["jpg", "png"]
            .iter()
            .any(|ext| out.join(format!("calib/left_{name}.{ext}")).exists())
    };
    let exists = match &options.calibration {
        None => frames_dir
            .join("frames.csv")
            .exists()
            .then_some("a capture (frames/frames.csv)"),
        Some(c) if c.reference => taken("ref").then_some("a reference pair (calib/left_ref)"),
        Some(_) => taken("00").then_some("calibration pairs (calib/left_00)"),
    };
    if let Some(what) = exists {
        return Err(CaptureError::Exists(out.to_path_buf(), what));
    }
    // The backends' own warnings (GStreamer trying a file name as a pipeline, …) would bury
    // handcap's one line; what failed is said there.
    let _ = opencv::core::set_log_level(opencv::core::LogLevel::LOG_LEVEL_SILENT);
    let cameras = [
        source::open(Side::Left, &options.sources[0], options)?,
        source::open(Side::Right, &options.sources[1], options)?,
    ];
    if options.calibration.is_none() {
        std::fs::create_dir_all(&frames_dir).map_err(|source| CaptureError::Write {
            path: frames_dir.clone(),
            source,
        })?;
    }
    let refused = [cameras[0].refused(), cameras[1].refused()];
    let can_stall = [cameras[0].live(), cameras[1].live()];
    let mut session = SessionFiles::new(out, options);

    let start_unix_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64());
    let start_monotonic_s = monotonic_s();
    let clock = Clock {
        start: Instant::now(),
        start_monotonic_s,
    };
    let mut judge = options
        .calibration
        .clone()
        .map(|spec| calibration::Judge::new(spec, out))
        .transpose()?;
    let stop = AtomicBool::new(false);
    let log = std::sync::Mutex::new(Vec::new());
    let (tx, rx) = mpsc::channel::<Grabbed>();
    let mut rows: Vec<(Side, usize, f64)> = Vec::new();
    let mut by_driver = [0; 2];
    let mut ending = None;
    let mut failure = None;
    let flash_state = std::sync::Mutex::new(FlashState::Waiting);
    let mut watch = options.flash.as_ref().map(|_| flash::Watch::default());
    let mut flash = None;
    std::thread::scope(|scope| {
        let mut filming = Vec::new();
        for (side, camera) in [Side::Left, Side::Right].into_iter().zip(cameras) {
            let tx = tx.clone();
            let (clock, stop) = (&clock, &stop);
            // A calibration capture measures the motion its judge needs.
            let meter = judge.is_some().then(motion::Meter::default);
            filming.push((
                side,
                scope.spawn(move || film(side, camera, clock, &tx, stop, meter)),
            ));
        }
        drop(tx);
        // The flash first, then the protocol, on one thread; a flash alone has its own.
        let flash_state = &flash_state;
        let fire = move |clock: &Clock, stop: &AtomicBool| {
            if let Some(command) = &options.flash {
                flash::fire(command, clock, stop, flash_state);
            }
        };
        let driving = options.protocol.as_ref().map(|(steps, regulator)| {
            let (clock, stop, log) = (&clock, &stop, &log);
            scope.spawn(move || {
                fire(clock, stop);
                let failed = matches!(*flash_state.lock().expect("flash"), FlashState::Failed(_));
                if failed {
                    return None;
                }
                match regulator {
                    Regulator::PerStep(template) => drive(steps, template, clock, log, stop),
                    Regulator::Streaming(command) => {
                        drive_streaming(steps, command, clock, log, stop)
                    }
                }
            })
        });
        let flashing = options.protocol.is_none().then(|| {
            let (clock, stop) = (&clock, &stop);
            scope.spawn(move || fire(clock, stop))
        });
        let mut last_shown = 0.0;
        // The first frame may take a while longer: a device warms up.
        let mut last_seen = [options.stall_s; 2];
        let mut received = [0usize; 2];
        let mut latest: [Option<Grabbed>; 2] = [None, None];
        let mut last_look = 0.0;
        let store = |grabbed: &Grabbed| -> Result<(), CaptureError> {
            let name = format!(
                "{}_{:05}.{}",
                grabbed.side.name(),
                grabbed.index,
                grabbed.frame.extension
            );
            let path = frames_dir.join(name);
            fsio::write_bytes(&path, &grabbed.frame.bytes)
                .map_err(|source| CaptureError::Write { path, source })
        };
        loop {
            // Every frame waiting, not just one: after a slow moment here (a board search on a
            // busy machine) the cameras' latest frames are what says whether they stalled.
            let mut arrived = Vec::new();
            match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(grabbed) => {
                    arrived.push(grabbed);
                    arrived.extend(rx.try_iter());
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    // Both cameras ended: the protocol stops too.
                    stop.store(true, Ordering::SeqCst);
                    break;
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
            }
            let flash_now = flash_state.lock().expect("flash").clone();
            let fired = match flash_now {
                FlashState::Fired(times) => Some(times),
                _ => None,
            };
            for grabbed in arrived {
                last_seen[grabbed.side as usize] = grabbed.frame.time_s;
                received[grabbed.side as usize] += 1;
                if let Some(watch) = watch.as_mut() {
                    let (time_s, bytes) = (grabbed.frame.time_s, &grabbed.frame.bytes);
                    watch.add(grabbed.side, time_s, bytes, fired);
                }
                if let Some(judge) = judge.as_mut() {
                    // A calibration capture keeps only each camera's latest frame, and its
                    // motion.
                    if let Some(change) = grabbed.change {
                        judge.motion.add(grabbed.side, grabbed.frame.time_s, change);
                    }
                    let side = grabbed.side as usize;
                    latest[side] = Some(grabbed);
                } else if let Err(e) = store(&grabbed) {
                    failure = Some(e);
                    stop.store(true, Ordering::SeqCst);
                } else {
                    rows.push((grabbed.side, grabbed.index, grabbed.frame.time_s));
                    by_driver[grabbed.side as usize] += usize::from(grabbed.frame.by_driver);
                }
            }
            let now = clock.now_s();
            if let (Some(times), true) = (fired, watch.is_some()) {
                if now > times[1] + flash::WATCH_S {
                    flash = watch.take().map(|w| w.measure(times));
                }
            }
            if let (Some(judge), [Some(l), Some(r)]) = (judge.as_mut(), &latest) {
                if now - last_look >= calibration::BOARD_EVERY_S && !stop.load(Ordering::SeqCst) {
                    last_look = now;
                    if let Err(e) = judge.look(l, r, now) {
                        failure = Some(e);
                        stop.store(true, Ordering::SeqCst);
                    }
                    if judge.done() {
                        ending = Some(Ending::PairsTaken);
                        stop.store(true, Ordering::SeqCst);
                    }
                }
            }
            if !stop.load(Ordering::SeqCst) {
                let stalled = [Side::Left, Side::Right].into_iter().find(|s| {
                    can_stall[*s as usize] && now - last_seen[*s as usize] > options.stall_s
                });
                ending = if interrupt.load(Ordering::SeqCst) {
                    Some(Ending::Interrupted)
                } else if options.duration_s.is_some_and(|d| now >= d) {
                    Some(Ending::Duration)
                } else if let Some(side) = stalled {
                    Some(Ending::CameraStopped {
                        side,
                        time_s: last_seen[side as usize],
                        frames: received[side as usize],
                    })
                } else if let FlashState::Failed(message) = &flash_now {
                    Some(Ending::FlashFailed {
                        message: message.clone(),
                    })
                } else if driving.as_ref().is_some_and(|d| d.is_finished()) {
                    Some(Ending::ProtocolDone)
                } else {
                    None
                };
                // A camera whose stream ended says so when joined.
                if ending.is_some() || filming.iter().any(|(_, t)| t.is_finished()) {
                    stop.store(true, Ordering::SeqCst);
                }
            }
            if now - last_shown >= 1.0 && failure.is_none() {
                last_shown = now;
                let log = log.lock().expect("log").clone();
                let so_far = CaptureSummary {
                    ending: Ending::Filming,
                    on_abort: None,
                    stats: stats(&rows, by_driver, &log, judge.as_ref()),
                    flash: flash.clone(),
                    refused: refused.clone(),
                    start_monotonic_s,
                    start_unix_s,
                };
                live(&so_far.stats);
                if let Err(e) = session.write(&rows, &log, &so_far) {
                    failure = Some(e);
                    stop.store(true, Ordering::SeqCst);
                }
            }
        }
        let failed = |thread: String, payload: Box<dyn std::any::Any + Send>| {
            let message = payload
                .downcast_ref::<&str>()
                .map(|m| m.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic".into());
            Ending::ThreadFailed { thread, message }
        };
        for (side, thread) in filming {
            match thread.join() {
                Ok(CameraEnd::Failed { time_s, frames }) => {
                    ending.get_or_insert(Ending::CameraStopped {
                        side,
                        time_s,
                        frames,
                    });
                }
                Ok(CameraEnd::Stopped) => {}
                Err(payload) => ending = Some(failed(format!("{} camera", side.name()), payload)),
            }
        }
        if let Some(driving) = driving {
            match driving.join() {
                Ok(Some(e @ Ending::CommandFailed { .. })) => ending = Some(e),
                Ok(_) => {}
                Err(payload) => ending = Some(failed("protocol".into(), payload)),
            }
        }
        if let Some(Err(payload)) = flashing.map(|f| f.join()) {
            ending = Some(failed("flash".into(), payload));
        }
    });
    // A file that could not be written ends the session as a failing command does: the
    // regulator vented, the session's files written as far as the disk allows.
    if let Some(e) = failure {
        ending = Some(Ending::WriteFailed {
            message: e.to_string(),
        });
    }
    if let (Some(watch), FlashState::Fired(times)) =
        (&watch, flash_state.into_inner().expect("flash"))
    {
        flash = Some(watch.measure(times));
    }
    rows.sort_by_key(|r| (r.0 as u8, r.1));
    let log = log.into_inner().expect("log");
    let ending = ending.unwrap_or(Ending::Interrupted);
    // The regulator left at the last step's pressures: the user's command vents it.
    let on_abort = match (&options.on_abort, &options.protocol) {
        (Some(command), Some(_)) if ending.aborted() => Some(
            match run_command(command, &AtomicBool::new(false), COMMAND_TIMEOUT_S) {
                Ok(CommandEnd::Done) => "done".to_string(),
                Ok(CommandEnd::Failed(why)) => format!("`{command}` {why}"),
                Ok(CommandEnd::Stopped) => unreachable!("nothing stops it"),
                Err(e) => format!("`{command}` could not run: {e}"),
            },
        ),
        _ => None,
    };
    let summary = CaptureSummary {
        ending,
        on_abort,
        stats: stats(&rows, by_driver, &log, judge.as_ref()),
        flash,
        refused,
        start_monotonic_s,
        start_unix_s,
    };
    // After a write failure the disk may take some files and not others: the failure is said
    // already, and what could be written is.
    if let Err(e) = session.finish(&rows, &log, &summary) {
        if !matches!(summary.ending, Ending::WriteFailed { .. }) {
            return Err(e);
        }
    }
    if let Ending::ThreadFailed { thread, message } = &summary.ending {
        return Err(CaptureError::ThreadFailed {
            thread: thread.clone(),
            message: message.clone(),
            out: out.to_path_buf(),
        });
    }
    Ok(summary)
}
