//! One session, filmed: the cameras opened, a thread filming each and one driving the protocol
//! (after the flash), the frames stored as they come, the session's end decided, the files
//! written every second and at the end.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Mutex};
use std::thread::{Scope, ScopedJoinHandle};
use std::time::{Duration, Instant};

use super::files::SessionFiles;
use super::flash::{self, FlashLatency, FlashState};
use super::regulator::{self, drive, drive_streaming, run_command, CommandEnd};
use super::source::{self, film, CameraEnd, FrameSource, Grabbed};
use super::{
    calibration, monotonic_s, motion, stats, CaptureError, CaptureOptions, CaptureSummary, Clock,
    Ending, Regulator, Side, Stats, COMMAND_TIMEOUT_S,
};
use crate::fsio;

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
    // 1. Nothing filmed over an earlier session; both cameras open.
    refuse_existing(out, options)?;
    let cameras = open_cameras(out, options)?;
    // 2. The session's clock starts; the threads film, drive and flash while this one stores
    //    the frames, looks for the board, decides the end and writes the files each second.
    let shared = Shared::new();
    let mut recorder = Recorder::new(out, options, &cameras)?;
    std::thread::scope(|scope| {
        let threads = Threads::spawn(scope, cameras, &shared, options, recorder.judge.is_some());
        while recorder.step(&threads, &shared, live, interrupt) {}
        let names: Vec<&str> = options.sources.iter().map(|s| s.name.as_str()).collect();
        threads.join(&mut recorder.ending, &names);
    });
    // 3. The session's end: the regulator vented when aborted, the files written.
    recorder.finish(shared)
}

/// A capture into `out` refused when `out` holds one of the same kind.
fn refuse_existing(out: &Path, options: &CaptureOptions) -> Result<(), CaptureError> {
    let taken = |name: &str| {
        ["jpg", "png"]
            .iter()
            .any(|ext| out.join(format!("calib/left_{name}.{ext}")).exists())
    };
    let exists = match &options.calibration {
        None => out
            .join("frames/frames.csv")
            .exists()
            .then_some("a capture (frames/frames.csv)"),
        Some(c) if c.reference => taken("ref").then_some("a reference pair (calib/left_ref)"),
        Some(_) => taken("00").then_some("calibration pairs (calib/left_00)"),
    };
    match exists {
        Some(what) => Err(CaptureError::Exists(out.to_path_buf(), what)),
        None => Ok(()),
    }
}

/// Every camera opened, and the frames' folder made (not for a calibration capture).
fn open_cameras(
    out: &Path,
    options: &CaptureOptions,
) -> Result<Vec<Box<dyn FrameSource>>, CaptureError> {
    // The backends' own warnings (GStreamer trying a file name as a pipeline, …) would bury
    // handcap's one line; what failed is said there.
    let _ = opencv::core::set_log_level(opencv::core::LogLevel::LOG_LEVEL_SILENT);
    let cameras = options
        .sources
        .iter()
        .map(|s| source::open(&s.name, &s.source, options))
        .collect::<Result<Vec<_>, _>>()?;
    if options.calibration.is_none() {
        let frames_dir = out.join("frames");
        std::fs::create_dir_all(&frames_dir).map_err(|source| CaptureError::Write {
            path: frames_dir,
            source,
        })?;
    }
    Ok(cameras)
}

/// What the threads share: the session's clock, the stop, the regulator's log, the flash.
struct Shared {
    clock: Clock,
    start_unix_s: f64,
    stop: AtomicBool,
    log: Mutex<Vec<regulator::Commanded>>,
    flash: Mutex<FlashState>,
    /// The LED's switches (session clock, s), with --sync-led.
    led: Mutex<Vec<f64>>,
}

impl Shared {
    fn new() -> Self {
        let start_unix_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        Shared {
            clock: Clock {
                start: Instant::now(),
                start_monotonic_s: monotonic_s(),
            },
            start_unix_s,
            stop: AtomicBool::new(false),
            log: Mutex::new(Vec::new()),
            flash: Mutex::new(FlashState::Waiting),
            led: Mutex::new(Vec::new()),
        }
    }

    fn stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
    }

    fn stopped(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }
}

/// The threads of a session: one filming each camera (sending its frames), one driving the
/// protocol after the flash, or one for the flash alone.
struct Threads<'scope> {
    frames: mpsc::Receiver<Grabbed>,
    filming: Vec<ScopedJoinHandle<'scope, CameraEnd>>,
    driving: Option<ScopedJoinHandle<'scope, Option<Ending>>>,
    flashing: Option<ScopedJoinHandle<'scope, ()>>,
}

impl<'scope> Threads<'scope> {
    fn spawn<'env>(
        scope: &'scope Scope<'scope, 'env>,
        cameras: Vec<Box<dyn FrameSource>>,
        shared: &'env Shared,
        options: &'env CaptureOptions,
        measure_motion: bool,
    ) -> Self {
        let (tx, frames) = mpsc::channel::<Grabbed>();
        let mut filming = Vec::new();
        for (k, camera) in cameras.into_iter().enumerate() {
            let tx = tx.clone();
            // A calibration capture measures the motion its judge needs.
            let meter = measure_motion.then(motion::Meter::default);
            filming.push(
                scope.spawn(move || film(k, camera, &shared.clock, &tx, &shared.stop, meter)),
            );
        }
        let fire = move || {
            if let Some(command) = &options.flash {
                flash::fire(command, &shared.clock, &shared.stop, &shared.flash);
            }
        };
        let driving = options.protocol.as_ref().map(|(steps, regulator)| {
            scope.spawn(move || {
                fire();
                let failed = matches!(*shared.flash.lock().expect("flash"), FlashState::Failed(_));
                if failed {
                    return None;
                }
                let (clock, log, stop) = (&shared.clock, &shared.log, &shared.stop);
                match regulator {
                    Regulator::PerStep(template) => drive(steps, template, clock, log, stop),
                    Regulator::Streaming(command) => {
                        drive_streaming(steps, command, clock, log, stop)
                    }
                    Regulator::Serial(path, baud, dialect) => {
                        let led = options.sync_led.then_some(&shared.led);
                        let line = (path.as_str(), *baud, dialect.as_ref());
                        super::serial::drive_serial(steps, line, clock, log, stop, led)
                    }
                }
            })
        });
        let flashing = options.protocol.is_none().then(|| scope.spawn(fire));
        Threads {
            frames,
            filming,
            driving,
            flashing,
        }
    }

    /// Every frame waiting, not just one: after a slow moment here (a board search on a busy
    /// machine) the cameras' latest frames are what says whether they stalled. `None` when
    /// both cameras have ended.
    fn arrived(&self) -> Option<Vec<Grabbed>> {
        match self.frames.recv_timeout(Duration::from_millis(100)) {
            Ok(grabbed) => Some(
                std::iter::once(grabbed)
                    .chain(self.frames.try_iter())
                    .collect(),
            ),
            Err(mpsc::RecvTimeoutError::Disconnected) => None,
            Err(mpsc::RecvTimeoutError::Timeout) => Some(Vec::new()),
        }
    }

    /// Joins every thread: a camera that stopped, a failing command or a thread that panicked
    /// ends the session so (a camera's stop only when nothing ended it before); `names` are the
    /// cameras'.
    fn join(self, ending: &mut Option<Ending>, names: &[&str]) {
        let failed = |thread: String, payload: Box<dyn std::any::Any + Send>| {
            let message = payload
                .downcast_ref::<&str>()
                .map(|m| m.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic".into());
            Ending::ThreadFailed { thread, message }
        };
        for (name, thread) in names.iter().zip(self.filming) {
            match thread.join() {
                Ok(CameraEnd::Failed { time_s, frames }) => {
                    ending.get_or_insert(Ending::CameraStopped {
                        camera: name.to_string(),
                        time_s,
                        frames,
                    });
                }
                Ok(CameraEnd::Stopped) => {}
                Err(payload) => *ending = Some(failed(format!("{name} camera"), payload)),
            }
        }
        if let Some(driving) = self.driving {
            match driving.join() {
                Ok(Some(e @ Ending::CommandFailed { .. })) => *ending = Some(e),
                Ok(_) => {}
                Err(payload) => *ending = Some(failed("protocol".into(), payload)),
            }
        }
        if let Some(Err(payload)) = self.flashing.map(|f| f.join()) {
            *ending = Some(failed("flash".into(), payload));
        }
    }
}

/// What the session's own thread keeps as the frames come.
struct Recorder<'a> {
    out: &'a Path,
    options: &'a CaptureOptions,
    frames_dir: PathBuf,
    files: SessionFiles<'a>,
    judge: Option<calibration::Judge>,
    refused: Vec<Vec<String>>,
    /// Which cameras can stall (live ones; a video file only ends).
    can_stall: Vec<bool>,
    /// Each frame kept: its camera (its place in the session's), number and time.
    rows: Vec<(usize, usize, f64)>,
    by_driver: Vec<usize>,
    ending: Option<Ending>,
    /// A file that could not be written.
    failure: Option<CaptureError>,
    watch: Option<flash::Watch>,
    flash: Option<FlashLatency>,
    sync_led: Option<super::sync_led::SyncLed>,
    last_seen: Vec<f64>,
    received: Vec<usize>,
    /// Each camera's latest frame (a calibration capture keeps no other).
    latest: Vec<Option<Grabbed>>,
    last_look: f64,
    last_shown: f64,
    last_viewed: f64,
}

impl<'a> Recorder<'a> {
    fn new(
        out: &'a Path,
        options: &'a CaptureOptions,
        cameras: &[Box<dyn FrameSource>],
    ) -> Result<Self, CaptureError> {
        let n = cameras.len();
        Ok(Recorder {
            out,
            options,
            frames_dir: out.join("frames"),
            files: SessionFiles::new(out, options)?,
            judge: options
                .calibration
                .clone()
                .map(|spec| calibration::Judge::new(spec, out))
                .transpose()?,
            refused: cameras.iter().map(|c| c.refused()).collect(),
            can_stall: cameras.iter().map(|c| c.live()).collect(),
            rows: Vec::new(),
            by_driver: vec![0; n],
            ending: None,
            failure: None,
            watch: options.flash.as_ref().map(|_| flash::Watch::default()),
            flash: None,
            sync_led: None,
            // The first frame may take a while longer: a device warms up.
            last_seen: vec![options.stall_s; n],
            received: vec![0; n],
            latest: (0..n).map(|_| None).collect(),
            last_look: 0.0,
            last_shown: 0.0,
            last_viewed: f64::NEG_INFINITY,
        })
    }

    /// One pass of the session's loop: the frames arrived kept, the flash measured, the board
    /// looked for, the end decided, the files written each second. `false` once both cameras
    /// have ended.
    fn step(
        &mut self,
        threads: &Threads,
        shared: &Shared,
        live: &(dyn Fn(&Stats) + Sync),
        interrupt: &AtomicBool,
    ) -> bool {
        let Some(arrived) = threads.arrived() else {
            // Both cameras ended: the protocol stops too.
            shared.stop();
            return false;
        };
        let flash_now = shared.flash.lock().expect("flash").clone();
        let fired = match flash_now {
            FlashState::Fired(times) => Some(times),
            _ => None,
        };
        for grabbed in arrived {
            self.keep(grabbed, fired, shared);
        }
        let now = shared.clock.now_s();
        if let (Some(times), true) = (fired, self.watch.is_some()) {
            if now > times[1] + flash::WATCH_S {
                self.flash = self.watch.take().map(|w| w.measure(times));
            }
        }
        self.look_for_board(now, shared);
        if !shared.stopped() {
            let driven = threads.driving.as_ref().is_some_and(|d| d.is_finished());
            self.ending = self.end(now, &flash_now, driven, interrupt);
            // A camera whose stream ended says so when joined.
            if self.ending.is_some() || threads.filming.iter().any(|t| t.is_finished()) {
                shared.stop();
            }
        }
        if let Some(view) = &self.options.view {
            self.show(view, now, shared);
        }
        if now - self.last_shown >= 1.0 && self.failure.is_none() {
            self.last_shown = now;
            self.write_so_far(shared, live);
        }
        true
    }

    /// The page's figures, at most ten times a second: the session's clock, the steps, the
    /// command in force and what the regulator measured.
    fn show(&mut self, view: &super::view::View, now: f64, shared: &Shared) {
        if now - self.last_viewed < 0.1 {
            return;
        }
        self.last_viewed = now;
        let steps = self.options.protocol.as_ref().map_or(0, |(s, _)| s.len());
        let log = shared.log.lock().expect("log");
        let pressed = log
            .iter()
            .find(|c| c.step.pressures.iter().any(|&p| p > 0.0));
        view.session(now, [log.len(), steps], &log, pressed.map(|c| c.time_s));
    }

    /// A frame arrived: its time and count noted, the flash's watch fed, and the frame stored
    /// (a calibration capture keeps only each camera's latest frame, and its motion).
    fn keep(&mut self, grabbed: Grabbed, fired: Option<flash::Fired>, shared: &Shared) {
        let camera = grabbed.camera;
        self.last_seen[camera] = grabbed.frame.time_s;
        self.received[camera] += 1;
        if let Some(watch) = self.watch.as_mut() {
            let (time_s, bytes) = (grabbed.frame.time_s, &grabbed.frame.bytes);
            watch.add(grabbed.side(), time_s, bytes, fired);
        }
        if let Some(judge) = self.judge.as_mut() {
            if let Some(change) = grabbed.change {
                judge
                    .motion
                    .add(grabbed.side(), grabbed.frame.time_s, change);
            }
            self.latest[camera] = Some(grabbed);
            return;
        }
        if let Some(view) = &self.options.view {
            view.arrived(&grabbed);
        }
        let name = format!(
            "{}_{:05}.{}",
            self.options.sources[camera].name, grabbed.index, grabbed.frame.extension
        );
        let path = self.frames_dir.join(name);
        match fsio::write_bytes(&path, &grabbed.frame.bytes) {
            Err(source) => self.fail(CaptureError::Write { path, source }, shared),
            Ok(()) => {
                self.rows
                    .push((camera, grabbed.index, grabbed.frame.time_s));
                self.by_driver[camera] += usize::from(grabbed.frame.by_driver);
            }
        }
    }

    fn fail(&mut self, e: CaptureError, shared: &Shared) {
        self.failure = Some(e);
        shared.stop();
    }

    /// A calibration capture: the board looked for in both cameras' latest frames a few times
    /// a second, until the judge has its pairs.
    fn look_for_board(&mut self, now: f64, shared: &Shared) {
        let (Some(judge), [Some(l), Some(r)]) = (self.judge.as_mut(), &self.latest[..]) else {
            return;
        };
        if now - self.last_look < calibration::BOARD_EVERY_S || shared.stopped() {
            return;
        }
        self.last_look = now;
        let looked = judge.look(l, r, now);
        let done = judge.done();
        if let Err(e) = looked {
            self.fail(e, shared);
        }
        if done {
            self.ending = Some(Ending::PairsTaken);
            shared.stop();
        }
    }

    /// What ends the session now, if anything: Ctrl-C, the duration, a stalled camera, a
    /// failed flash, the protocol done.
    fn end(
        &self,
        now: f64,
        flash: &FlashState,
        driven: bool,
        interrupt: &AtomicBool,
    ) -> Option<Ending> {
        let stalled = (0..self.can_stall.len())
            .find(|&c| self.can_stall[c] && now - self.last_seen[c] > self.options.stall_s);
        if interrupt.load(Ordering::SeqCst) {
            Some(Ending::Interrupted)
        } else if self.options.duration_s.is_some_and(|d| now >= d) {
            Some(Ending::Duration)
        } else if let Some(c) = stalled {
            Some(Ending::CameraStopped {
                camera: self.options.sources[c].name.clone(),
                time_s: self.last_seen[c],
                frames: self.received[c],
            })
        } else if let FlashState::Failed(message) = flash {
            Some(Ending::FlashFailed {
                message: message.clone(),
            })
        } else if driven {
            Some(Ending::ProtocolDone)
        } else {
            None
        }
    }

    /// The session so far: its figures shown, its files written.
    fn write_so_far(&mut self, shared: &Shared, live: &(dyn Fn(&Stats) + Sync)) {
        let log = shared.log.lock().expect("log").clone();
        let so_far = self.summary(Ending::Filming, None, &log, shared);
        live(&so_far.stats);
        if let Some(view) = &self.options.view {
            view.stats(&so_far.stats);
        }
        if let Err(e) = self.files.write(&self.rows, &log, &so_far) {
            self.fail(e, shared);
        }
    }

    fn summary(
        &self,
        ending: Ending,
        on_abort: Option<String>,
        log: &[regulator::Commanded],
        shared: &Shared,
    ) -> CaptureSummary {
        CaptureSummary {
            ending,
            on_abort,
            stats: stats(&self.rows, &self.by_driver, log, self.judge.as_ref()),
            flash: self.flash.clone(),
            sync_led: self.sync_led.clone(),
            refused: self.refused.clone(),
            start_monotonic_s: shared.clock.start_monotonic_s,
            start_unix_s: shared.start_unix_s,
        }
    }

    /// The session's end: a write failure said as the ending (the regulator vented, the lists
    /// written in the space kept for them), the flash measured, the regulator vented when the
    /// session was aborted, the files written in their final order.
    fn finish(mut self, shared: Shared) -> Result<CaptureSummary, CaptureError> {
        if let Some(e) = self.failure.take() {
            self.ending = Some(Ending::WriteFailed {
                message: e.to_string(),
            });
        }
        if let (Some(watch), FlashState::Fired(times)) =
            (&self.watch, shared.flash.lock().expect("flash").clone())
        {
            self.flash = Some(watch.measure(times));
        }
        let switches = std::mem::take(&mut *shared.led.lock().expect("led"));
        if !switches.is_empty() {
            let paths: Vec<(Side, f64, PathBuf)> = self
                .rows
                .iter()
                .filter_map(|&(camera, index, t)| {
                    let side = Side::of_index(camera);
                    let path = ["jpg", "png"].iter().map(|ext| {
                        self.frames_dir
                            .join(format!("{}_{index:05}.{ext}", side.name()))
                    });
                    Some((side, t, path.into_iter().find(|p| p.is_file())?))
                })
                .collect();
            let frames: Vec<(Side, f64, &Path)> = paths
                .iter()
                .map(|(s, t, p)| (*s, *t, p.as_path()))
                .collect();
            let measured = super::sync_led::SyncLed::measure(switches, &frames);
            self.sync_led = Some(measured);
        }
        self.rows.sort_by_key(|r| (r.0, r.1));
        let log = std::mem::take(&mut *shared.log.lock().expect("log"));
        let ending = self.ending.take().unwrap_or(Ending::Interrupted);
        let on_abort = vent(self.options, &ending);
        let summary = self.summary(ending, on_abort, &log, &shared);
        if let Some(view) = &self.options.view {
            view.ended(&summary.ending);
        }
        // After a write failure the lists go in the space kept for them; a disk that does
        // not take them even then is said with the failure that stopped the session.
        if let Err(e) = self.files.finish(&self.rows, &log, &summary) {
            return Err(match &summary.ending {
                Ending::WriteFailed { message } => CaptureError::ListsLost {
                    first: message.clone(),
                    lists: Box::new(e),
                    vented: summary.on_abort.is_some(),
                },
                _ => e,
            });
        }
        if let Ending::ThreadFailed { thread, message } = &summary.ending {
            return Err(CaptureError::ThreadFailed {
                thread: thread.clone(),
                message: message.clone(),
                out: self.out.to_path_buf(),
            });
        }
        Ok(summary)
    }
}

/// The regulator left at the last step's pressures when a session is aborted: the user's
/// `--on-abort` command vents it; what it did.
fn vent(options: &CaptureOptions, ending: &Ending) -> Option<String> {
    let (Some(command), Some(_)) = (&options.on_abort, &options.protocol) else {
        return None;
    };
    ending.aborted().then(|| {
        match run_command(command, &AtomicBool::new(false), COMMAND_TIMEOUT_S) {
            Ok(CommandEnd::Done) => "done".to_string(),
            Ok(CommandEnd::Failed(why)) => format!("`{command}` {why}"),
            Ok(CommandEnd::Stopped) => unreachable!("nothing stops it"),
            Err(e) => format!("`{command}` could not run: {e}"),
        }
    })
}
