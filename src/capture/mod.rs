//! `handcap capture`: two cameras filmed on their own threads, every frame stamped with one
//! clock at grab time and written in the layout `triangulate` reads; optionally a pressure
//! protocol driven by the lab's own command, logged on the same clock.
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
//! URL, a GStreamer pipeline). Devices are asked for MJPG at the size and rate given and for
//! fixed exposure, white balance and focus; what the backend refuses is said. A stream URL
//! (`http://…`, `rtsp://…`) is read by FFmpeg with the server's settings. Frames are kept as
//! they come: a camera's, a Motion-JPEG file's or a Motion-JPEG stream's JPEG bytes as `.jpg`
//! without decoding or re-encoding, anything else decoded and written losslessly as `.png`.
//!
//! # Ending
//! The protocol's end, `--duration`, Ctrl-C (or SIGTERM, SIGHUP), a camera that stops
//! delivering (for [`STALL_S`], or its stream ends), a pressure command that fails or runs over
//! [`COMMAND_TIMEOUT_S`], or a thread of the session that panics: every frame finished by then
//! is written and listed, the logs are complete, and `capture.json` says how it ended. The
//! session's files are also rewritten every second while filming ([`Ending::Filming`]).

use crate::session::protocol;
pub mod url;
use url::redact;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use opencv::core::{Mat, Vector};
use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};
use serde::Serialize;

use crate::fsio;
use crate::session::frames::frames_csv;
use crate::session::pressures::Logged;
use crate::stereo::Side;

/// A camera that delivers nothing for this long has stopped (s).
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
    /// Steps to drive, and the command that sets each step's pressures.
    pub protocol: Option<(Vec<protocol::Step>, String)>,
    /// Stop after this long (s).
    pub duration_s: Option<f64>,
    /// Instead of the finger's frames: chessboard pairs for `calibrate` ([`calibration`]).
    pub calibration: Option<BoardPairs>,
    /// Command run once when a protocol's session ends early (see [`Ending::aborted`]), e.g.
    /// to vent the regulator.
    pub on_abort: Option<String>,
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
    /// A thread of the session (a camera's, the protocol's) panicked.
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
                | Ending::ThreadFailed { .. }
        )
    }
}

/// Live and final figures of a session.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Stats {
    pub frames: [usize; 2],
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
    /// A calibration capture's pairs taken, and why the last candidate was not.
    pub board_pairs: usize,
    pub board_refused: String,
}

/// What a session did and wrote.
#[derive(Clone, Debug, Serialize)]
pub struct CaptureSummary {
    pub ending: Ending,
    /// What the `on_abort` command did, when it ran: `done`, or why it failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub on_abort: Option<String>,
    pub stats: Stats,
    /// Per camera: the settings the backend refused.
    pub refused: [Vec<String>; 2],
    pub start_monotonic_s: f64,
    pub start_unix_s: f64,
}

/// The session's clock: seconds since it began, on the host's monotonic clock.
struct Clock {
    start: Instant,
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

/// An opened camera.
struct Camera {
    capture: VideoCapture,
    /// A file's frame period: frames are handed out at its rate, as a camera would.
    pace_s: Option<f64>,
    refused: Vec<String>,
}

/// The video devices on this machine, for the message when a camera does not open.
fn devices() -> String {
    let mut found: Vec<String> = std::fs::read_dir("/dev")
        .map(|d| {
            d.flatten()
                .map(|e| e.path().display().to_string())
                .filter(|p| p.starts_with("/dev/video"))
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    if found.is_empty() {
        "none (no /dev/video*)".into()
    } else {
        found.join(", ")
    }
}

fn open_camera(side: Side, source: &str, o: &CaptureOptions) -> Result<Camera, CaptureError> {
    let device = source.parse::<i32>().is_ok() || source.starts_with("/dev/");
    let not_opened = |why: String| CaptureError::NotOpened {
        side: side.name(),
        camera: redact(source),
        why,
        hint: if device {
            format!("cameras found: {}", devices())
        } else if source.contains("://") {
            "check that the stream plays (e.g. `ffplay URL`) and that the address, port and credentials are right".into()
        } else {
            "give a device index (0), a device path (/dev/video0), a video file or a stream URL"
                .into()
        },
    };
    let file = Path::new(source).is_file();
    let stream = !device && source.contains("://");
    let opening = Instant::now();
    let opened = if let Ok(index) = source.parse::<i32>() {
        VideoCapture::new(index, videoio::CAP_ANY)
    } else if stream {
        // FFmpeg's own waits are 30 s; a stream gives up within the stall's time instead, so
        // a stopped server ends the session promptly and Ctrl-C is never kept waiting.
        let ms = |s: f64| (1e3 * s).round() as i32;
        let params = opencv::core::Vector::<i32>::from_slice(&[
            videoio::CAP_PROP_OPEN_TIMEOUT_MSEC,
            ms(STREAM_OPEN_S),
            videoio::CAP_PROP_READ_TIMEOUT_MSEC,
            ms(STALL_S),
        ]);
        VideoCapture::from_file_with_params(source, videoio::CAP_FFMPEG, &params)
    } else if file {
        VideoCapture::from_file(source, videoio::CAP_FFMPEG)
    } else {
        VideoCapture::from_file(source, videoio::CAP_ANY)
    };
    let mut capture = opened.map_err(|e| not_opened(e.message))?;
    if !capture.is_opened().unwrap_or(false) {
        return Err(not_opened(if stream {
            let waited = opening.elapsed().as_secs_f64() >= STREAM_OPEN_S - 0.5;
            let answer = url::answer(source).map_or(String::new(), |a| format!("; {a}"));
            if waited {
                format!("it did not open and send a frame within {STREAM_OPEN_S} s{answer}")
            } else {
                format!("it did not open{answer}")
            }
        } else {
            "OpenCV cannot open it".into()
        }));
    }
    let mut refused = Vec::new();
    let pace_s = if file {
        // A Motion-JPEG file's frames raw, as a camera's MJPEG would come.
        crate::video::read_raw_if_jpeg(&mut capture);
        let fps = capture.get(videoio::CAP_PROP_FPS)?;
        Some(1.0 / if fps > 0.0 { fps } else { o.fps })
    } else if stream {
        // A stream's settings are the server's. Its Motion-JPEG frames are kept as the bytes
        // that came: no decoding and re-encoding on the grab thread (23.5 ms of CPU for a 720p
        // frame, which a busy computer cannot spare at 30 fps). Other codecs are decoded.
        if !crate::video::read_raw_if_jpeg(&mut capture) {
            refused.push(format!(
                "raw frames (codec {:?}, not Motion-JPEG: frames decoded, stored as PNG)",
                crate::video::codec(&capture)
            ));
        }
        None
    } else {
        let mjpg = f64::from(opencv::videoio::VideoWriter::fourcc('M', 'J', 'P', 'G')?);
        let settings = [
            ("MJPG", videoio::CAP_PROP_FOURCC, mjpg),
            ("width", videoio::CAP_PROP_FRAME_WIDTH, f64::from(o.width)),
            (
                "height",
                videoio::CAP_PROP_FRAME_HEIGHT,
                f64::from(o.height),
            ),
            ("frame rate", videoio::CAP_PROP_FPS, o.fps),
            // V4L2: 1 is manual exposure.
            ("fixed exposure", videoio::CAP_PROP_AUTO_EXPOSURE, 1.0),
            ("fixed white balance", videoio::CAP_PROP_AUTO_WB, 0.0),
            ("fixed focus", videoio::CAP_PROP_AUTOFOCUS, 0.0),
            // The MJPEG bytes as the camera sent them.
            ("raw frames", videoio::CAP_PROP_CONVERT_RGB, 0.0),
        ];
        for (name, prop, value) in settings {
            if !capture.set(prop, value).unwrap_or(false) {
                refused.push(name.to_string());
            }
        }
        None
    };
    Ok(Camera {
        capture,
        pace_s,
        refused,
    })
}

/// A frame as grabbed: its camera, number, time, and file bytes with their extension.
struct Grabbed {
    side: Side,
    index: usize,
    time_s: f64,
    bytes: Vec<u8>,
    extension: &'static str,
}

/// Why a camera's thread ended.
enum CameraEnd {
    Stopped,
    Failed { time_s: f64, frames: usize },
}

/// The frame a camera just grabbed, as file bytes: JPEG as it came, else PNG.
fn retrieve(capture: &mut VideoCapture, mat: &mut Mat) -> opencv::Result<(Vec<u8>, &'static str)> {
    capture.retrieve(mat, 0)?;
    let bytes = mat.data_bytes()?;
    if mat.rows() == 1 && bytes.starts_with(&[0xff, 0xd8]) {
        return Ok((bytes.to_vec(), "jpg"));
    }
    let mut png = Vector::<u8>::new();
    opencv::imgcodecs::imencode(".png", mat, &mut png, &Vector::new())?;
    Ok((png.to_vec(), "png"))
}

fn film(
    side: Side,
    mut camera: Camera,
    clock: &Clock,
    tx: &mpsc::Sender<Grabbed>,
    stop: &AtomicBool,
) -> CameraEnd {
    let mut mat = Mat::default();
    let mut index = 0;
    while !stop.load(Ordering::SeqCst) {
        if let Some(period) = camera.pace_s {
            let due = index as f64 * period;
            let wait = due - clock.now_s();
            if wait > 0.0 {
                std::thread::sleep(Duration::from_secs_f64(wait));
            }
        }
        let grabbed = camera.capture.grab().unwrap_or(false);
        let time_s = clock.now_s();
        let frame = grabbed
            .then(|| retrieve(&mut camera.capture, &mut mat).ok())
            .flatten();
        let Some((bytes, extension)) = frame else {
            return CameraEnd::Failed {
                time_s,
                frames: index,
            };
        };
        let sent = tx.send(Grabbed {
            side,
            index,
            time_s,
            bytes,
            extension,
        });
        if sent.is_err() {
            break;
        }
        index += 1;
    }
    CameraEnd::Stopped
}

/// Runs the protocol: each step's command, logged, then held. Returns how it ended.
fn drive(
    steps: &[protocol::Step],
    template: &str,
    clock: &Clock,
    log: &std::sync::Mutex<Vec<Commanded>>,
    stop: &AtomicBool,
) -> Option<Ending> {
    for step in steps {
        if stop.load(Ordering::SeqCst) {
            return None;
        }
        let command = protocol::command_for(template, step);
        let time_s = clock.now_s();
        let failed = match run_command(&command, stop, COMMAND_TIMEOUT_S) {
            Ok(CommandEnd::Done) => None,
            Ok(CommandEnd::Stopped) => return None,
            Ok(CommandEnd::Failed(why)) => Some(format!("`{command}` {why}")),
            Err(e) => Some(format!("`{command}` could not run: {e}")),
        };
        if let Some(message) = failed {
            return Some(Ending::CommandFailed {
                step: step.step,
                message,
            });
        }
        log.lock().expect("log").push(Commanded {
            time_s,
            end_s: clock.now_s(),
            step: step.clone(),
        });
        let wait = time_s + step.hold_s - clock.now_s();
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait));
        }
    }
    Some(Ending::ProtocolDone)
}

/// Longest a `--set-pressure` command may run (s): a regulator that does not answer ends the
/// session instead of holding it.
pub const COMMAND_TIMEOUT_S: f64 = 10.0;

/// How a pressure command ended.
enum CommandEnd {
    Done,
    /// The session is stopping (Ctrl-C, a signal, a camera lost): the command was killed.
    Stopped,
    /// Why it failed: its exit status and error output, or that it timed out.
    Failed(String),
}

/// Runs `command` with `sh -c`, waiting at most `timeout_s` and no longer than the session
/// runs.
fn run_command(command: &str, stop: &AtomicBool, timeout_s: f64) -> std::io::Result<CommandEnd> {
    let mut child = std::process::Command::new("sh")
        .arg("-c")
        .arg(command)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait()? {
            if status.success() {
                return Ok(CommandEnd::Done);
            }
            let mut error = String::new();
            if let Some(mut stderr) = child.stderr.take() {
                use std::io::Read;
                let _ = stderr.read_to_string(&mut error);
            }
            return Ok(CommandEnd::Failed(format!(
                "exited with {status}: {}",
                error.trim()
            )));
        }
        let stopping = stop.load(Ordering::SeqCst);
        if stopping || start.elapsed().as_secs_f64() > timeout_s {
            let _ = child.kill();
            let _ = child.wait();
            return Ok(if stopping {
                CommandEnd::Stopped
            } else {
                CommandEnd::Failed(format!(
                    "did not finish in {timeout_s} s (killed): check that the regulator answers"
                ))
            });
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A step the regulator was told: when its command started and when it returned.
#[derive(Clone, Debug)]
struct Commanded {
    time_s: f64,
    end_s: f64,
    step: protocol::Step,
}

fn pressures_csv(log: &[Commanded]) -> String {
    crate::session::pressures::pressures_csv(log.iter().map(|c| Logged {
        time_s: c.time_s,
        command_end_s: Some(c.end_s),
        pressures_kpa: c.step.pressures,
        step: c.step.step,
        phase: &c.step.phase,
    }))
}

/// Figures of one camera's times ([`crate::frame_times`]): frames per second, frames
/// dropped, frames stamped late and the latest (ms).
fn camera_figures(times: &[f64]) -> (f64, usize, usize, f64) {
    if times.len() < 2 {
        return (0.0, 0, 0, 0.0);
    }
    let fps = (times.len() - 1) as f64 / (times[times.len() - 1] - times[0]).max(1e-9);
    let period = crate::frame_times::period(times);
    let late: Vec<f64> = crate::frame_times::late(times)
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

fn stats(
    rows: &[(Side, usize, f64)],
    steps_done: usize,
    judge: Option<&calibration::Judge>,
) -> Stats {
    let times =
        |side: Side| -> Vec<f64> { rows.iter().filter(|r| r.0 == side).map(|r| r.2).collect() };
    let (l, r) = (times(Side::Left), times(Side::Right));
    let ((fl, dl, ll, ml), (fr, dr, lr, mr)) = (camera_figures(&l), camera_figures(&r));
    Stats {
        frames: [l.len(), r.len()],
        fps: [fl, fr],
        drops: [dl, dr],
        late: [ll, lr],
        late_max_ms: [ml, mr],
        skew_ms: 1e3 * crate::frame_times::skew(&l, &r),
        steps_done,
        board_pairs: judge.map_or(0, |j| j.taken),
        board_refused: judge.map_or_else(String::new, |j| j.refused.clone()),
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
        open_camera(Side::Left, &options.sources[0], options)?,
        open_camera(Side::Right, &options.sources[1], options)?,
    ];
    if options.calibration.is_none() {
        std::fs::create_dir_all(&frames_dir).map_err(|source| CaptureError::Write {
            path: frames_dir.clone(),
            source,
        })?;
    }
    let refused = [cameras[0].refused.clone(), cameras[1].refused.clone()];
    let session = SessionFiles { out, options };

    let start_unix_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64());
    let start_monotonic_s = monotonic_s();
    let clock = Clock {
        start: Instant::now(),
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
    let mut ending = None;
    let mut failure = None;
    std::thread::scope(|scope| {
        let mut filming = Vec::new();
        for (side, camera) in [Side::Left, Side::Right].into_iter().zip(cameras) {
            let tx = tx.clone();
            let (clock, stop) = (&clock, &stop);
            filming.push((
                side,
                scope.spawn(move || film(side, camera, clock, &tx, stop)),
            ));
        }
        drop(tx);
        let driving = options.protocol.as_ref().map(|(steps, template)| {
            let (clock, stop, log) = (&clock, &stop, &log);
            scope.spawn(move || drive(steps, template, clock, log, stop))
        });
        let mut last_shown = 0.0;
        // The first frame may take a while longer: a device warms up.
        let mut last_seen = [STALL_S; 2];
        let mut latest: [Option<Grabbed>; 2] = [None, None];
        let mut last_look = 0.0;
        let store = |frame: &Grabbed| -> Result<(), CaptureError> {
            let name = format!(
                "{}_{:05}.{}",
                frame.side.name(),
                frame.index,
                frame.extension
            );
            let path = frames_dir.join(name);
            fsio::write_bytes(&path, &frame.bytes)
                .map_err(|source| CaptureError::Write { path, source })
        };
        loop {
            // Every frame waiting, not just one: after a slow moment here (a board search on a
            // busy machine) the cameras' latest frames are what says whether they stalled.
            let mut arrived = Vec::new();
            match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(frame) => {
                    arrived.push(frame);
                    arrived.extend(rx.try_iter());
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    // Both cameras ended: the protocol stops too.
                    stop.store(true, Ordering::SeqCst);
                    break;
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
            }
            for frame in arrived {
                last_seen[frame.side as usize] = frame.time_s;
                if judge.is_some() {
                    // A calibration capture keeps only each camera's latest frame.
                    let side = frame.side as usize;
                    latest[side] = Some(frame);
                } else if let Err(e) = store(&frame) {
                    failure = Some(e);
                    stop.store(true, Ordering::SeqCst);
                } else {
                    rows.push((frame.side, frame.index, frame.time_s));
                }
            }
            let now = clock.now_s();
            if let (Some(judge), [Some(l), Some(r)]) = (judge.as_mut(), &latest) {
                if now - last_look >= calibration::BOARD_EVERY_S && !stop.load(Ordering::SeqCst) {
                    last_look = now;
                    if let Err(e) = judge.look(l, r) {
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
                let stalled = [Side::Left, Side::Right]
                    .into_iter()
                    .find(|s| now - last_seen[*s as usize] > STALL_S);
                ending = if interrupt.load(Ordering::SeqCst) {
                    Some(Ending::Interrupted)
                } else if options.duration_s.is_some_and(|d| now >= d) {
                    Some(Ending::Duration)
                } else if let Some(side) = stalled {
                    Some(Ending::CameraStopped {
                        side,
                        time_s: last_seen[side as usize],
                        frames: rows.iter().filter(|r| r.0 == side).count(),
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
                    stats: stats(&rows, log.len(), judge.as_ref()),
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
    });
    if let Some(e) = failure {
        return Err(e);
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
        stats: stats(&rows, log.len(), judge.as_ref()),
        refused,
        start_monotonic_s,
        start_unix_s,
    };
    session.write(&rows, &log, &summary)?;
    if let Ending::ThreadFailed { thread, message } = &summary.ending {
        return Err(CaptureError::ThreadFailed {
            thread: thread.clone(),
            message: message.clone(),
            out: out.to_path_buf(),
        });
    }
    Ok(summary)
}

/// The files that list a session: `frames/frames.csv` (not for a calibration capture),
/// `pressures.csv` (with a protocol) and `capture.json`; rewritten whole (temp file, then
/// rename) every second while filming and at the end, so that they always agree with the
/// images written.
struct SessionFiles<'a> {
    out: &'a Path,
    options: &'a CaptureOptions,
}

impl SessionFiles<'_> {
    fn write(
        &self,
        rows: &[(Side, usize, f64)],
        log: &[Commanded],
        summary: &CaptureSummary,
    ) -> Result<(), CaptureError> {
        let write = |path: &Path, text: &str| {
            fsio::write_bytes(path, text.as_bytes()).map_err(|source| CaptureError::Write {
                path: path.to_path_buf(),
                source,
            })
        };
        // capture.json first: it says how to read the others, so a kill between two writes
        // leaves it beside lists as of this pass or the one before, never lists without it.
        let options = self.options;
        let json = serde_json::json!({
            "sources": options.sources.each_ref().map(|s| redact(s)),
            "requested": {"width": options.width, "height": options.height, "fps": options.fps},
            "clock": "time_s = CLOCK_MONOTONIC seconds - start_monotonic_s (Python: time.monotonic() - start_monotonic_s)",
            "summary": summary,
        });
        write(
            &self.out.join("capture.json"),
            &(serde_json::to_string_pretty(&json).expect("serialisable") + "\n"),
        )?;
        if options.calibration.is_none() {
            write(
                &self.out.join("frames/frames.csv"),
                &frames_csv(rows.iter().copied()),
            )?;
        }
        if options.protocol.is_some() {
            write(&self.out.join("pressures.csv"), &pressures_csv(log))?;
        }
        Ok(())
    }
}

/// A calibration capture's judge: every `BOARD_EVERY_S` the latest frame of each camera is
/// searched for the board; a pair is taken when both show it, it stood still since the
/// previous search (no corner moved over [`crate::calib::video::STILL_PX`]) and it stands
/// somewhere new (`crate::calib::video::new_place`).
pub mod calibration {
    use super::*;
    use crate::calib::detect::{find_board, Detector, Seen};
    use crate::calib::video::{footprint, new_place, STILL_PX};

    /// How often the latest frames are searched for the board (s).
    pub const BOARD_EVERY_S: f64 = 0.2;

    /// The pairs taken so far and where their boards stood.
    pub struct Judge {
        pub spec: BoardPairs,
        dir: PathBuf,
        previous: Option<[Seen; 2]>,
        places: Vec<[f64; 6]>,
        pub taken: usize,
        pub refused: String,
    }

    fn corners(spec: &BoardPairs, bytes: &[u8]) -> Option<(Seen, [i32; 2])> {
        let gray = crate::cv::decode_image(
            &Vector::from_slice(bytes),
            opencv::imgcodecs::IMREAD_GRAYSCALE,
        )
        .ok()?;
        let found = find_board(&gray, &spec.board, Detector::first_for(&spec.board)).ok()??;
        Some((found, [gray.cols(), gray.rows()]))
    }

    impl Judge {
        /// # Errors
        /// The `calib` folder or its board file cannot be written.
        pub fn new(spec: BoardPairs, out: &Path) -> Result<Self, CaptureError> {
            let dir = out.join("calib");
            std::fs::create_dir_all(&dir).map_err(|source| CaptureError::Write {
                path: dir.clone(),
                source,
            })?;
            let board = dir.join(crate::calib::file::BOARD_FILE);
            fsio::write_bytes(
                &board,
                crate::calib::file::board_yaml(&spec.board).as_bytes(),
            )
            .map_err(|source| CaptureError::Write {
                path: board,
                source,
            })?;
            Ok(Judge {
                spec,
                dir,
                previous: None,
                places: Vec::new(),
                taken: 0,
                refused: String::new(),
            })
        }

        pub fn done(&self) -> bool {
            self.taken
                >= if self.spec.reference {
                    1
                } else {
                    self.spec.pairs
                }
        }

        /// Looks at the latest left and right frames; takes them when they qualify.
        ///
        /// # Errors
        /// A pair's file cannot be written.
        pub(super) fn look(&mut self, left: &Grabbed, right: &Grabbed) -> Result<(), CaptureError> {
            let (l, r) = (
                corners(&self.spec, &left.bytes),
                corners(&self.spec, &right.bytes),
            );
            let previous = self.previous.take();
            let (Some((l, size)), Some((r, _))) = (l, r) else {
                self.refused = "the board is not seen in both cameras".into();
                return Ok(());
            };
            // The rule `calibrate` will hold the pair to.
            if let Err(why) = crate::calib::pairs::match_corners(&self.spec.board, &l, &r) {
                self.refused = why;
                return Ok(());
            }
            let moved = match &previous {
                Some([pl, pr]) => l.moved_from(pl).max(r.moved_from(pr)),
                None => f64::INFINITY,
            };
            self.previous = Some([l.clone(), r]);
            if moved > STILL_PX {
                self.refused = "the board is moving: hold it still".into();
                return Ok(());
            }
            let place = footprint(&self.spec.board, &l, size);
            if !self.spec.reference && !new_place(&place, &self.places) {
                self.refused = "the board stands where a pair was taken: move or tilt it".into();
                return Ok(());
            }
            let name = if self.spec.reference {
                "ref".to_string()
            } else {
                format!("{:02}", self.taken)
            };
            for frame in [left, right] {
                let path =
                    self.dir
                        .join(format!("{}_{name}.{}", frame.side.name(), frame.extension));
                fsio::write_bytes(&path, &frame.bytes)
                    .map_err(|source| CaptureError::Write { path, source })?;
            }
            self.places.push(place);
            self.taken += 1;
            self.refused.clear();
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{run_command, AtomicBool, CommandEnd};

    #[test]
    fn a_pressure_command_is_timed_out_or_stopped_and_its_error_said() {
        let running = AtomicBool::new(false);
        let said = |end: CommandEnd| match end {
            CommandEnd::Failed(why) => why,
            CommandEnd::Done => "done".into(),
            CommandEnd::Stopped => "stopped".into(),
        };
        assert_eq!(said(run_command("true", &running, 5.0).unwrap()), "done");
        let why = said(run_command("echo no >&2; exit 3", &running, 5.0).unwrap());
        assert_eq!(why, "exited with exit status: 3: no");
        let why = said(run_command("sleep 5", &running, 0.2).unwrap());
        assert!(why.starts_with("did not finish in 0.2 s (killed)"), "{why}");
        let stopping = AtomicBool::new(true);
        assert_eq!(
            said(run_command("sleep 5", &stopping, 5.0).unwrap()),
            "stopped"
        );
    }
}
