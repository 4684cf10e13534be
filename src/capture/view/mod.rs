//! `capture --view`: the session watched as it runs, on a page served on 127.0.0.1.
//!
//! The page (`page.html`, refreshing five times a second) shows each camera's latest frame
//! with the bead found in it (or why not), the commanded and measured pressures, the
//! session's progress and flags, and, given a calibration, the tip's track live: the frames
//! as they arrive, found and triangulated by the same code as `triangulate --per-frame`
//! ([`crate::triangulate::per_frame::tips_as_they_come`]), in the hand frame whose origin is
//! the tip at rest before the protocol's first pressure.
//!
//! # What it costs the session
//! The session's thread hands each frame over (its bytes shared, not copied again) and a
//! line of figures; nothing it does waits on the page. The frames are examined by one thread
//! of its own at a low priority (`nice` 10, its triangulation too): on a busy machine it
//! falls behind, and then skips frames in runs of a second (counted on the page) rather than
//! taking time from the cameras and the regulator.
//!
//! # Who may look
//! Only `127.0.0.1`, and only with the session's random token in the path
//! (`http://127.0.0.1:PORT/TOKEN/`); anything else is answered 404. Requests read; they
//! change nothing.

mod trust;
mod watch;

pub use trust::{Trust, Watching};

use std::collections::VecDeque;
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex};

use serde::Serialize;

use super::source::Grabbed;
use super::Stats;
use crate::calib::file::CalibrationFile;
use crate::stereo::Side;

/// Frames waiting to be examined at most; beyond, the examiner skips until half are done.
const QUEUE: usize = 60;

/// What `--view` was given.
#[derive(Clone, Debug, Default)]
pub struct ViewOptions {
    /// The port on 127.0.0.1 (0: any free one).
    pub port: u16,
    /// A calibration (as `triangulate --calib` takes it): the tip's track is shown.
    pub calib: Option<PathBuf>,
    /// With `calib`, a model to watch the track against ([`trust`]).
    pub model: Option<Watching>,
}

/// The page's figures: what `state.json` answers.
#[derive(Clone, Debug, Default, Serialize)]
struct Page {
    /// Seconds since the session began.
    elapsed_s: f64,
    /// `filming`, or how the session ended ([`super::Ending`]).
    status: serde_json::Value,
    /// Protocol steps sent, and of how many (0: no protocol).
    steps: [usize; 2],
    /// The pressures commanded now, and what the regulator measured last (kPa).
    commanded_kpa: Option<[f64; 3]>,
    measured_kpa: Option<[f64; 3]>,
    /// What a user should know: drops, late frames, unsettled steps, the examiner behind.
    flags: Vec<String>,
    cameras: [CameraPage; 2],
    track: Option<watch::TrackPage>,
    trust: Option<trust::TrustPage>,
}

/// One camera on the page.
#[derive(Clone, Debug, Default, Serialize)]
struct CameraPage {
    name: &'static str,
    /// Frames received, and per second over the session.
    frames: usize,
    fps: f64,
    /// The latest frame's number and time (s), its image at `camera/NAME`.
    frame: Option<usize>,
    time_s: Option<f64>,
    /// The newest frame examined: its number, size (px) and the bead in it, or why none.
    examined: Option<usize>,
    size: Option<[usize; 2]>,
    bead_px: Option<[f64; 2]>,
    why: Option<String>,
}

/// A frame handed to the page: its image, and to the examiner.
#[derive(Clone)]
struct Arrived {
    side: Side,
    index: usize,
    time_s: f64,
    bytes: Arc<Vec<u8>>,
    extension: &'static str,
}

/// What the server and the examiner share with the session.
#[derive(Default)]
struct Shared {
    page: Page,
    latest: [Option<Arrived>; 2],
    /// Frames not yet examined, and whether the examiner is skipping.
    queue: VecDeque<Arrived>,
    skipping: bool,
    skipped: [usize; 2],
    /// The first command with pressure (s): the rest before it sets the track's origin.
    rest_until_s: Option<f64>,
    /// The commands sent (time (s), and the pressures as `triangulate` gives them, kPa) the
    /// examiner has not taken yet, the newest sent again as it may have been measured since;
    /// and how many were sent in all.
    commands: Vec<(f64, [f64; 3])>,
    sent: usize,
    /// The monitor's alarms not yet said.
    said: Vec<String>,
    ended: bool,
}

/// A session's page: serving from [`View::start`], fed by the session.
pub struct View {
    url: String,
    shared: Mutex<Shared>,
    arrived: Condvar,
    /// The examiner, which returns the monitor when the session's frames are done.
    examiner: Mutex<Option<std::thread::JoinHandle<Option<trust::Trust>>>>,
}

impl std::fmt::Debug for View {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "View({})",
            self.url.split('/').take(3).collect::<Vec<_>>().join("/")
        )
    }
}

impl View {
    /// Serves the page on 127.0.0.1 and starts the examiner.
    ///
    /// # Errors
    /// One line: the calibration unreadable (naming it), the port taken.
    pub fn start(options: &ViewOptions) -> Result<Arc<View>, String> {
        let calibration = options.calib.as_deref().map(read_calibration).transpose()?;
        let listener = TcpListener::bind(("127.0.0.1", options.port)).map_err(|e| {
            format!(
                "cannot serve the view on 127.0.0.1:{}: {e}; choose another --view-port, or 0 for any free one",
                options.port
            )
        })?;
        let port = listener.local_addr().map_err(|e| e.to_string())?.port();
        let token = token().map_err(|e| format!("no random token for the view: {e}"))?;
        let mut page = Page {
            status: "filming".into(),
            ..Page::default()
        };
        for side in [Side::Left, Side::Right] {
            page.cameras[side as usize].name = side.name();
        }
        let view = Arc::new(View {
            url: format!("http://127.0.0.1:{port}/{token}/"),
            shared: Mutex::new(Shared {
                page,
                ..Shared::default()
            }),
            arrived: Condvar::new(),
            examiner: Mutex::new(None),
        });
        let server = view.clone();
        std::thread::spawn(move || {
            for client in listener.incoming().flatten() {
                let (view, token) = (server.clone(), token.clone());
                std::thread::spawn(move || view.answer(client, &token));
            }
        });
        let (examiner, model) = (view.clone(), options.model.clone());
        let handle = std::thread::spawn(move || watch::examine(&examiner, calibration, model));
        *view
            .examiner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(handle);
        Ok(view)
    }

    /// The page's address, its token in the path.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// A frame arrived: shown as its camera's latest and queued for the examiner (skipped,
    /// and counted, while the examiner is behind).
    pub(super) fn arrived(&self, grabbed: &Grabbed) {
        let side = grabbed.side();
        let arrived = Arrived {
            side,
            index: grabbed.index,
            time_s: grabbed.frame.time_s,
            bytes: Arc::new(grabbed.frame.bytes.clone()),
            extension: grabbed.frame.extension,
        };
        let mut s = self.lock();
        let camera = &mut s.page.cameras[side as usize];
        camera.frames += 1;
        camera.frame = Some(arrived.index);
        camera.time_s = Some(arrived.time_s);
        s.latest[side as usize] = Some(arrived.clone());
        s.skipping = match s.skipping {
            false => s.queue.len() >= QUEUE,
            true => s.queue.len() > QUEUE / 2,
        };
        if s.skipping {
            s.skipped[side as usize] += 1;
        } else {
            s.queue.push_back(arrived);
            self.arrived.notify_one();
        }
    }

    /// The session's state now (at most ten times a second): its clock, the protocol's
    /// steps, the commands sent so far and what the regulator measured last, and the time of
    /// the first command with pressure (the rest before it sets the track's origin).
    pub(super) fn session(
        &self,
        elapsed_s: f64,
        steps: [usize; 2],
        log: &[super::regulator::Commanded],
        rest_until_s: Option<f64>,
    ) {
        let mut s = self.lock();
        s.page.elapsed_s = elapsed_s;
        s.page.steps = steps;
        s.rest_until_s = rest_until_s;
        if let Some(last) = log.last() {
            s.page.commanded_kpa = Some(last.step.pressures);
            s.page.measured_kpa = last.measured.or(s.page.measured_kpa);
        }
        // The newest command again: the regulator may have measured it since.
        let from = s.sent.saturating_sub(1).min(log.len());
        let new = log[from..].iter().map(|c| (c.time_s, c.inputs()));
        s.commands.extend(new);
        s.sent = log.len();
    }

    /// The monitor's alarms raised since last asked, each a line to say.
    pub fn said(&self) -> Vec<String> {
        std::mem::take(&mut self.lock().said)
    }

    /// Once the session ended: waits for the examiner to finish its frames; the monitor
    /// (with `--model`), and the frames the examiner skipped per camera.
    pub fn finish(&self) -> Option<(Trust, [usize; 2])> {
        let handle = self
            .examiner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take()?;
        let trust = handle.join().ok().flatten()?;
        Some((trust, self.lock().skipped))
    }

    /// The session's figures of the last second, as flags a user acts on.
    pub(super) fn stats(&self, stats: &Stats) {
        let mut s = self.lock();
        let mut flags = Vec::new();
        for (k, side) in [Side::Left, Side::Right].into_iter().enumerate() {
            s.page.cameras[k].fps = stats.fps[k];
            if stats.drops[k] > 0 {
                flags.push(format!(
                    "{} camera dropped {} frames",
                    side.name(),
                    stats.drops[k]
                ));
            }
            if stats.late[k] > 0 {
                flags.push(format!(
                    "{} camera: {} frames stamped late (up to {:.0} ms): the machine or network fell behind",
                    side.name(),
                    stats.late[k],
                    stats.late_max_ms[k]
                ));
            }
            if s.skipped[k] > 0 {
                flags.push(format!(
                    "the page skipped {} {} frames: this machine is busy (the session keeps them all)",
                    s.skipped[k],
                    side.name()
                ));
            }
        }
        if stats.over_hold > 0 {
            flags.push(format!(
                "{} steps unsettled: the command took longer than the hold",
                stats.over_hold
            ));
        }
        s.page.flags = flags;
    }

    /// The session is over (`ending` as `capture.json` says it); the page stays up while the
    /// process does.
    pub(super) fn ended(&self, ending: &super::Ending) {
        let mut s = self.lock();
        s.page.status = serde_json::to_value(ending).unwrap_or_default();
        s.ended = true;
        self.arrived.notify_all();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Shared> {
        self.shared
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// One request: the page, its figures or a camera's latest frame, under the token.
    fn answer(&self, mut client: TcpStream, token: &str) {
        let Some(path) = crate::http::requested(&mut client) else {
            return;
        };
        let Some(rest) = path
            .strip_prefix('/')
            .and_then(|p| p.strip_prefix(token))
            .and_then(|p| p.strip_prefix('/'))
        else {
            return crate::http::not_found(&mut client);
        };
        let rest = rest.split('?').next().unwrap_or_default();
        match rest {
            "" => crate::http::ok(
                &mut client,
                "text/html; charset=utf-8",
                include_str!("page.html").as_bytes(),
            ),
            "state.json" => {
                let body = serde_json::to_vec(&self.lock().page).unwrap_or_default();
                crate::http::ok(&mut client, "application/json", &body);
            }
            _ => {
                let latest = [Side::Left, Side::Right]
                    .into_iter()
                    .find(|s| rest == format!("camera/{}", s.name()))
                    .and_then(|s| self.lock().latest[s as usize].clone());
                match latest {
                    Some(a) => {
                        let kind = if a.extension == "jpg" {
                            "image/jpeg"
                        } else {
                            "image/png"
                        };
                        crate::http::ok(&mut client, kind, &a.bytes);
                    }
                    None => crate::http::not_found(&mut client),
                }
            }
        }
    }
}

/// The calibration the track is triangulated with, as `triangulate` reads it.
fn read_calibration(path: &Path) -> Result<CalibrationFile, String> {
    crate::calib::file::read_calibration(path).map_err(|e| e.to_string())
}

/// 128 random bits from the system, in hex.
fn token() -> std::io::Result<String> {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}
