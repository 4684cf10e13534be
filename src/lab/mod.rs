//! `handcap lab`: the virtual micro-hand in real time, a bench to run `capture` against before
//! the hardware arrives (and CI's live bench). The finger of `synth`'s seed follows a regulator
//! board on a pseudo-terminal ([`board`], handcap's line protocol) through the pneumatic line
//! of [`Dynamics::PNEUMATIC`]; two webcams ([`camera`]) film it at their own free-running 30 fps
//! and serve Motion-JPEG over HTTP on 127.0.0.1 ([`stream`]), each with its delay, jitter, lost
//! frames and stall; a lamp both cameras see is switched by the board's `LED`.
//!
//! # The truth (`DIR/truth/`, written every 10 s and when the lab stops)
//! - `rig.yml`: the rig, as `synth` writes it (the keys `calibrate` writes, and the hand frame);
//! - `received.csv`: `time_s,line,reply`, every line the board received and its answer;
//! - `frames.csv`: `camera,exposure_s,frame,sent_s,late_ms,x_mm,y_mm,z_mm,u_px,v_px,lamp`, every
//!   exposure: `frame` is its number in the camera's stream (empty when lost), `sent_s` when it
//!   went, the tip at the exposure's middle and its pixel, the lamp's lit share;
//! - `clients.csv`: `camera,connected_s,first_frame,frames_sent`: a client's frame k is the
//!   stream's `first_frame + k`;
//! - `lab.json`: the settings, the seed, the clock (`epoch_unix_s`: the wall-clock time of the
//!   lab's time 0, the clock every `_s` above is on), counts and provenance.

pub mod board;
pub mod camera;
pub mod stream;
mod truth;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::capture::line::Reply;
use crate::fsio;
use crate::provenance::Provenance;
use crate::stereo::Side;
use crate::synth::capture::CaptureConfig;
use crate::synth::capture::Knocked;
use crate::synth::dynamics::{Dynamics, Motion};
use crate::synth::faults::Timeline;
use crate::synth::plant::Pressures;
use crate::synth::render::View;
use crate::synth::SynthConfig;
use board::Received;
use camera::Exposed;
use stream::Stream;
use truth::TruthFiles;

/// Where the lamp stands (hand frame, mm): beside the finger's base, in both cameras' view.
pub const LAMP_MM: [f64; 3] = [-22.0, 4.0, 30.0];

/// How often the truth is written while the lab runs (s).
const TRUTH_EVERY_S: f64 = 10.0;

/// How the lab runs.
#[derive(Clone, Debug, Serialize)]
pub struct LabConfig {
    pub seed: u64,
    /// The finger (the plant's constants).
    pub synth: SynthConfig,
    /// The rig, the frames' realism and format, the frame rate, the pneumatic line.
    pub capture: CaptureConfig,
    /// Each camera's delay from exposure to sending (s).
    pub delay_s: [f64; 2],
    /// Each frame's sending varies by up to this much either way (s).
    pub jitter_s: f64,
    /// Share of frames lost.
    pub drop: f64,
    /// Both cameras stall at `[0]` s for `[1]` s: the frames exposed meanwhile go at once
    /// when it ends.
    pub stall: Option<[f64; 2]>,
    /// Stop after this long (s); else at SIGINT or SIGTERM.
    pub duration_s: Option<f64>,
    /// The first TCP port (left, then right); 0: any free ones.
    pub port: u16,
}

impl LabConfig {
    /// The lab of `seed`: `synth`'s rig and webcam frames, the pneumatic line.
    pub fn new(seed: u64) -> LabConfig {
        LabConfig {
            seed,
            synth: SynthConfig {
                seed,
                ..SynthConfig::default()
            },
            capture: CaptureConfig {
                dynamics: Dynamics::PNEUMATIC,
                ..CaptureConfig::default()
            },
            delay_s: [0.045, 0.080],
            jitter_s: 0.002,
            drop: 0.0,
            stall: None,
            duration_s: None,
            port: 0,
        }
    }

    /// Why these settings cannot run, if they cannot.
    pub fn check(&self) -> Result<(), String> {
        if let Err(e) = self.capture.check() {
            return Err(e.to_string());
        }
        if !self.delay_s.iter().all(|d| (0.0..=2.0).contains(d)) {
            return Err("each camera's delay must lie in 0-2000 ms".into());
        }
        if !(0.0..=0.05).contains(&self.jitter_s) {
            return Err("the jitter must lie in 0-50 ms".into());
        }
        if !(0.0..0.5).contains(&self.drop) {
            return Err("the share of lost frames must lie in [0, 0.5)".into());
        }
        if self
            .stall
            .is_some_and(|[at, length]| !(at >= 0.0 && (0.0..=10.0).contains(&length)))
        {
            return Err("a stall starts at a time ≥ 0 s and lasts 0-10 s".into());
        }
        if !(1.0..=60.0).contains(&self.capture.fps) {
            return Err("the frame rate must lie in 1-60 fps".into());
        }
        Ok(())
    }
}

/// Errors of running the lab.
#[derive(Debug, thiserror::Error)]
pub enum LabError {
    #[error("lab settings: {0}")]
    Settings(String),
    #[error("{0}")]
    Start(String),
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{0}")]
    Failed(String),
}

/// Where the lab is reached, once it runs.
#[derive(Clone, Debug)]
pub struct Ready {
    /// Each camera's name and stream URL.
    pub cameras: Vec<(String, String)>,
    /// The regulator board's serial device.
    pub regulator: PathBuf,
    /// Whether the cameras and the board run at a hardware's priority ([`HARDWARE_NICE`]).
    pub hardware_priority: bool,
}

/// What the lab did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LabSummary {
    pub seconds: f64,
    /// Per camera (left, right): frames exposed, sent, lost.
    pub exposed: [usize; 2],
    pub sent: [usize; 2],
    pub lost: [usize; 2],
    /// Frames rendered after they were due to be sent, and the latest of them (ms).
    pub late: usize,
    pub worst_late_ms: f64,
    pub lines_received: usize,
}

/// `left=45,right=80`, `45,80` or `45` (ms, as `--delay-ms` takes them) → each camera's
/// delay (s), or why not.
pub fn delays(text: &str) -> Result<[f64; 2], String> {
    let bad = || format!("{text:?}: give left=MS,right=MS, LEFT,RIGHT or one number (ms)");
    let mut named = [None, None];
    let mut plain = Vec::new();
    for part in text.split(',') {
        let (name, value) = match part.split_once('=') {
            Some((n, v)) => (Some(n.trim()), v),
            None => (None, part),
        };
        let ms = value
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(bad)?;
        match name {
            Some("left") => named[0] = Some(ms),
            Some("right") => named[1] = Some(ms),
            Some(_) => return Err(bad()),
            None => plain.push(ms),
        }
    }
    let ms = match (named, &plain[..]) {
        ([Some(l), Some(r)], []) => [l, r],
        ([None, None], [both]) => [*both; 2],
        ([None, None], [l, r]) => [*l, *r],
        _ => return Err(bad()),
    };
    Ok(ms.map(|ms| ms / 1e3))
}

impl std::fmt::Display for LabSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "lab stopped after {:.1} s: left {} frames sent ({} lost), right {} ({} lost), {} rendered late (worst {:.0} ms); {} lines from the regulator's host",
            self.seconds,
            self.sent[0],
            self.lost[0],
            self.sent[1],
            self.lost[1],
            self.late,
            self.worst_late_ms,
            self.lines_received,
        )
    }
}

/// The lamp's switches (lab clock, s), on first.
#[derive(Default)]
pub struct Lamps(Vec<f64>);

impl Lamps {
    /// The lamp on or off from `now`: a switch when that changes it.
    fn switch(&mut self, now: f64, on: bool) {
        if on != (self.0.len() % 2 == 1) {
            self.0.push(now);
        }
    }

    /// Share of the exposure centred on `t` (half-length `half`) the lamp was lit.
    pub fn lit(&self, t: f64, half: f64) -> f64 {
        crate::capture::sync_led::on_share(&self.0, t - half, t + half)
    }
}

/// The finger as the board drives it and the lamp.
struct Finger {
    motion: Motion,
    lamps: Lamps,
}

/// The priority of the lab's cameras and board (`nice` −10): hardware that does not slow down
/// when the machine is busy, so that a session beside CPU hogs tests `capture`, not the lab.
const HARDWARE_NICE: libc::c_int = -10;

/// Raises the calling thread to [`HARDWARE_NICE`] when allowed.
fn as_hardware() {
    crate::priority::set_thread_nice(HARDWARE_NICE);
}

/// What the lab's threads share: the clock, the finger, the truth.
pub struct Shared {
    start: Instant,
    /// The finger's constants, and what the faults change of it and the cameras, when.
    timeline: Timeline,
    finger: Mutex<Finger>,
    received: Mutex<Vec<Received>>,
    exposed: Mutex<Vec<Exposed>>,
    stop: AtomicBool,
    failure: Mutex<Option<String>>,
}

impl Shared {
    /// The lab's clock (s).
    pub fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    pub fn stopped(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }

    /// Sleeps until the lab's time `t` (s), or its stop.
    pub fn sleep_until(&self, t: f64) {
        loop {
            let left = t - self.now_s();
            if left <= 0.0 || self.stopped() {
                return;
            }
            std::thread::sleep(Duration::from_secs_f64(left.min(0.01)));
        }
    }

    /// Stops the lab, saying why.
    pub fn fail(&self, why: String) {
        self.failure.lock().expect("failure").get_or_insert(why);
        self.stop.store(true, Ordering::SeqCst);
    }

    /// Runs `f` on the finger's motion (simulated as far as `f` looks), the finger's timeline
    /// and the lamp.
    pub fn frame<T>(&self, f: impl FnOnce(&Motion, &Timeline, &Lamps) -> T) -> T {
        let mut finger = self.finger.lock().expect("finger");
        // Nothing commanded from now on moves the finger before now (the line's delay later).
        finger.motion.run_to(self.now_s() - Motion::AHEAD_S);
        f(&finger.motion, &self.timeline, &finger.lamps)
    }

    /// The pressures the line's gauges read now, and the board's clock (ms).
    fn measured(&self, finger: &mut Finger) -> Reply {
        let now = self.now_s();
        finger.motion.run_to(now - Motion::AHEAD_S);
        Reply::Measured {
            ms: now * 1e3,
            kpa: finger.motion.measured(),
        }
    }

    /// `SET`: the pressures commanded from now; answers what the gauges read.
    pub fn set(&self, p: Pressures) -> Reply {
        let mut finger = self.finger.lock().expect("finger");
        let reply = self.measured(&mut finger);
        let now = self.now_s();
        finger.motion.command(now, p);
        reply
    }

    pub fn read(&self) -> Reply {
        self.measured(&mut self.finger.lock().expect("finger"))
    }

    /// `VENT`: every muscle to 0 kPa; the board's time (ms).
    pub fn vent(&self) -> f64 {
        let mut finger = self.finger.lock().expect("finger");
        let now = self.now_s();
        finger.motion.command(now, [0.0; 3]);
        now * 1e3
    }

    /// `LED`: the lamp switched now; the board's time (ms).
    pub fn led(&self, on: bool) -> f64 {
        let mut finger = self.finger.lock().expect("finger");
        let now = self.now_s();
        finger.lamps.switch(now, on);
        now * 1e3
    }

    pub fn received(&self, r: Received) {
        self.received.lock().expect("received").push(r);
    }

    pub fn exposed(&self, e: Exposed) {
        self.exposed.lock().expect("exposed").push(e);
    }
}

/// Runs the lab into `out` until `interrupt` (SIGINT, SIGTERM) or its duration: `ready` is
/// called once the cameras serve and the board listens.
///
/// # Errors
/// [`LabError`]: bad settings, a port in use, a pseudo-terminal that cannot be made, a truth
/// file that cannot be written.
/// The two cameras' views of the scene, and the right one's once a fault knocked it; the
/// wall keeps clear of where the finger can be seen (its tips over the paper's grid).
fn cameras_views(
    config: &LabConfig,
    rig: &crate::synth::camera::Rig,
    timeline: &Timeline,
) -> Result<([View; 2], Option<Knocked>), LabError> {
    let grid = crate::session::protocol::paper_steps(50.0, 50.0, 1.0)
        .map_err(|e| LabError::Settings(e.to_string()))?;
    let tips = grid
        .iter()
        .map(|s| timeline.plant().tip(s.pressures))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| LabError::Settings(e.to_string()))?;
    let realism = &config.capture.realism;
    let views: [View; 2] =
        crate::synth::capture::views(rig, config.seed, realism, timeline.plant(), &tips)
            .try_into()
            .map_err(|_| LabError::Settings("the lab films with two cameras".into()))?;
    let knocked = crate::synth::capture::knocked_view(rig, config.seed, realism, timeline, &tips);
    Ok((views, knocked))
}

pub fn run(
    out: &Path,
    config: &LabConfig,
    provenance: &Provenance,
    ready: impl FnOnce(&Ready),
    interrupt: &AtomicBool,
) -> Result<LabSummary, LabError> {
    config.check().map_err(LabError::Settings)?;
    let rig = config.capture.rig.build(config.seed);
    let timeline = Timeline::new(&config.synth.plant, &rig, &config.capture.faults);
    let (views, knocked) = cameras_views(config, &rig, &timeline)?;
    let cost_s = camera::frame_cost(&views[0], config, &timeline)
        .map_err(|e| LabError::Settings(e.to_string()))?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    camera::renderable(cost_s, config, cores).map_err(LabError::Settings)?;
    let truth = out.join("truth");
    std::fs::create_dir_all(&truth).map_err(write_err(&truth))?;
    write(
        &truth.join("rig.yml"),
        &crate::synth::capture::rig_yaml(&rig, provenance),
    )?;

    let listeners = listen(config.port)?;
    let pty = board::Pty::open()
        .map_err(|e| LabError::Start(format!("the regulator's pseudo-terminal: {e}")))?;
    let epoch_unix_s = unix_now();
    let shared = Shared {
        start: Instant::now(),
        timeline,
        finger: Mutex::new(Finger {
            motion: Motion::at_rest(&config.capture.dynamics, config.synth.plant.hysteresis_kpa),
            lamps: Lamps::default(),
        }),
        received: Mutex::new(Vec::new()),
        exposed: Mutex::new(Vec::new()),
        stop: AtomicBool::new(false),
        failure: Mutex::new(None),
    };
    let streams: Vec<Arc<Stream>> = (0..2).map(|_| Arc::new(Stream::default())).collect();
    let cameras = serve(listeners, &streams, shared.start)?;
    let info = Ready {
        cameras,
        regulator: pty.path.clone(),
        // Allowed here if anywhere (the truth's writer goes back to 0).
        hardware_priority: crate::priority::set_thread_nice(HARDWARE_NICE)
            && crate::priority::set_thread_nice(0),
    };
    let files = TruthFiles {
        dir: &truth,
        config,
        provenance,
        epoch_unix_s,
        streams: &streams,
    };
    // The cameras, their rendering's parallel parts and the board at a hardware's priority.
    let render = rayon::ThreadPoolBuilder::new()
        .start_handler(|_| as_hardware())
        .build()
        .map_err(|e| LabError::Start(format!("the cameras' threads: {e}")))?;
    let summary = std::thread::scope(|scope| {
        scope.spawn(|| {
            as_hardware();
            board::run(pty, &shared)
        });
        for (k, side) in [Side::Left, Side::Right].into_iter().enumerate() {
            let (stream, shared, render) = (&streams[k], &shared, &render);
            let knocked = knocked.as_ref().filter(|_| side == Side::Right);
            let views = (&views[k], knocked);
            scope.spawn(move || {
                as_hardware();
                render.install(|| camera::film(side, views, config, shared, stream))
            });
        }
        ready(&info);
        let mut written_s = 0.0;
        let outcome = loop {
            std::thread::sleep(Duration::from_millis(20));
            let now = shared.now_s();
            if interrupt.load(Ordering::SeqCst)
                || shared.stopped()
                || config.duration_s.is_some_and(|d| now >= d)
            {
                break Ok(());
            }
            if now - written_s >= TRUTH_EVERY_S {
                written_s = now;
                if let Err(e) = files.write(&shared) {
                    break Err(e);
                }
            }
        };
        shared.stop.store(true, Ordering::SeqCst);
        for s in &streams {
            s.close();
        }
        outcome
    });
    summary?;
    let summary = files.write(&shared)?;
    match shared.failure.into_inner().expect("failure") {
        Some(why) => Err(LabError::Failed(why)),
        None => Ok(summary),
    }
}

/// Each camera's listener on 127.0.0.1: `port` and the next, or any free ones for 0.
fn listen(port: u16) -> Result<Vec<std::net::TcpListener>, LabError> {
    [Side::Left, Side::Right]
        .iter()
        .map(|side| {
            let port = match port {
                0 => 0,
                p => p + *side as u16,
            };
            std::net::TcpListener::bind(("127.0.0.1", port)).map_err(|e| {
                LabError::Start(format!(
                    "camera {}: port {port} on 127.0.0.1: {e} (give another --port, or 0 for any free)",
                    side.name()
                ))
            })
        })
        .collect()
}

/// Serves each camera's stream from its listener; their names and URLs.
fn serve(
    listeners: Vec<std::net::TcpListener>,
    streams: &[Arc<Stream>],
    start: Instant,
) -> Result<Vec<(String, String)>, LabError> {
    let mut cameras = Vec::new();
    for (side, (listener, stream)) in [Side::Left, Side::Right]
        .into_iter()
        .zip(listeners.into_iter().zip(streams))
    {
        let addr = listener
            .local_addr()
            .map_err(|e| LabError::Start(e.to_string()))?;
        cameras.push((
            side.name().to_string(),
            format!("http://{addr}/{}.mjpg", side.name()),
        ));
        stream::serve(
            listener,
            side.name().to_string(),
            stream.clone(),
            move || start.elapsed().as_secs_f64(),
        );
    }
    Ok(cameras)
}

fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

fn write_err(path: &Path) -> impl FnOnce(std::io::Error) -> LabError {
    let path = path.to_path_buf();
    move |source| LabError::Write { path, source }
}

fn write(path: &Path, text: &str) -> Result<(), LabError> {
    fsio::write_bytes(path, text.as_bytes()).map_err(write_err(path))
}

#[cfg(test)]
mod tests {
    #[test]
    fn delays_are_read_by_name_or_in_order() {
        assert_eq!(super::delays("left=45,right=80").unwrap(), [0.045, 0.08]);
        assert_eq!(super::delays("right=80,left=45").unwrap(), [0.045, 0.08]);
        assert_eq!(super::delays("30,60").unwrap(), [0.03, 0.06]);
        assert_eq!(super::delays("50").unwrap(), [0.05, 0.05]);
        for bad in [
            "left=45",
            "top=1,left=2",
            "a,b",
            "1,2,3",
            "left=1,40",
            "inf",
        ] {
            assert!(super::delays(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_lamp_is_lit_for_its_share_of_the_exposure() {
        let lamps = super::Lamps(vec![1.0, 1.004, 2.0]);
        assert_eq!(lamps.lit(0.5, 0.006), 0.0);
        // On for 4 ms of a 12 ms exposure.
        assert!((lamps.lit(1.002, 0.006) - 4.0 / 12.0).abs() < 1e-9);
        assert!((lamps.lit(2.0, 0.006) - 0.5).abs() < 1e-9);
        assert_eq!(lamps.lit(3.0, 0.006), 1.0);
        assert_eq!(lamps.lit(1.5, 0.0), 0.0);
    }
}
