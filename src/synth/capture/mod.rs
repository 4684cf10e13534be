//! The synthetic capture session: chessboard pairs for calibration, then the finger driven
//! through the protocol and filmed by two free-running webcams, with the regulator's log and the
//! ground truth of everything.
//!
//! # Layout of `handcap synth --out DIR`
//!
//! - `calib/left_NN.png`, `calib/right_NN.png`: the chessboard pairs (NN from 00), and
//!   `calib/left_ref.png`, `calib/right_ref.png`: the reference pair (`.jpg` instead of `.png`
//!   everywhere with the JPEG format), the board fixed at the
//!   finger's base (see below). `calib/board.yml`: `inner_corners_cols`, `inner_corners_rows`,
//!   `square_mm`.
//! - `frames/left_NNNNN.png`, `frames/right_NNNNN.png` (each camera numbers its own frames) and
//!   `frames/frames.csv`: `frame,camera,time_s`, the capture computer's timestamp of each frame.
//! - `pressures.csv`: the regulator log, `time_s,P1_kpa,P2_kpa,P3_kpa,step,phase` — one row per
//!   commanded step (phase `train`, `sweep_a` or `sweep_b`; `rest`, `dyn_1` … in a dynamic
//!   session).
//! - `truth/rig.yml` (OpenCV YAML, the keys `calibrate` writes: `image_size`, `K1`, `D1`, `K2`,
//!   `D2`, `R`, `T` (left → right, mm), `E`, `F`, and `R_hand`, `t_hand`: p_hand = R_hand ·
//!   p_left + t_hand); `truth/boards.csv`: each board pose in the left camera
//!   (`view,rx,ry,rz,tx_mm,ty_mm,tz_mm`, Rodrigues vector, board frame as OpenCV's object
//!   points); `truth/tips.csv`: per step `step,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm` (hand
//!   frame, settled) and `left_x_mm,left_y_mm,left_z_mm` (left camera frame);
//!   `truth/frames.csv`: per frame `frame,camera,exposure_s,step,x_mm,y_mm,z_mm,u_px,v_px,
//!   occluded`, the tip at the middle of the exposure (still settling early in a step), its
//!   projection, and 1 where something hides the bead.
//!   `truth/per_frame.csv` (dynamic sessions): per left frame
//!   `time_s,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,frame,exposure_s`, the row
//!   `triangulate --per-frame` should give: the frame's stamp, the command in force then, the
//!   true tip at its exposure.
//! - `manifest.json`: configuration, counts, provenance.
//!
//! # More cameras
//!
//! With `cameras` of three or more ([`crate::synth::camera`]'s arc, named `cam1` … `camN`),
//! the same layout with every camera's name in place of `left`/`right`, except that a board
//! view is photographed only by the cameras that see it whole (`calib/<camera>_NN` exists
//! for those; the arc's two ends never share one, so they are tied only through the cameras
//! between; every camera gets `views` of them), the reference board by the cameras that see it,
//! and the true rig is `truth/cameras.toml` (as `calibrate` writes more cameras: Anipose's
//! TOML, the first camera's frame the world, `hand_rotation`) instead of `truth/rig.yml`;
//! `truth/tips.csv`'s camera columns are the first camera's (`cam1_x_mm` …). The red cable
//! and push-pin stand in cam2's view, as in a pair's right one.
//!
//! # Timing
//!
//! The regulator commands step k at t_k = k · 0.3 s; each muscle's pressure follows
//! first-order with τ = 20 ms ([`Dynamics::STEPS`]), and the finger follows its pressures
//! quasi-statically. A dynamic session (`dynamic`) commands its protocol's rows at their times
//! through the pneumatic line of [`Dynamics::PNEUMATIC`] (delay, lags, creep; see
//! [`crate::synth::dynamics`]) and keeps every frame. Each camera exposes at its own 30 fps (±50 ppm) from its own
//! phase; the capture computer stamps a frame at exposure + the camera's latency (`latency_s`,
//! 0 unless asked) + its offset (±5 ms) + jitter (±2 ms), and keeps the frames stamped 100-200
//! ms into a step (`window_s`): three per camera and step, the first of them possibly not settled
//! (e^{−5} of the step remains at 100 ms). A window of the whole step films the finger moving
//! too, as a live capture does.
//!
//! # The reference pair and the hand frame
//!
//! The reference board stands in the hand's x-z plane just behind the finger's axis (y = 5 mm),
//! its corner rows along hand +x and its columns running from the base down (board y = hand −z,
//! board z = hand +y, away from the cameras). From it, `calibrate` recovers the hand frame's
//! axes in the left camera; the origin (the tip at zero pressure) comes from the frames.

mod boards;
mod shots;
mod timing;
mod truth;

use std::path::Path;
use std::sync::atomic::AtomicBool;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::camera::RigConfig;
use super::dynamics::{Dynamics, Motion};
use super::faults::{Fault, Timeline};
use super::image_format::ImageFormat;
use super::plant::Pressures;
use super::{SynthConfig, SynthError};
use crate::calib::BoardSpec;
use crate::fsio;
use crate::session::protocol::{self, DynamicDesign, Step};
use boards::calibration_boards;
use shots::Studio;
pub(crate) use shots::{exposure_gain, finger_frame, knocked_view, views, Knocked};
use timing::camera_frames;
pub(crate) use timing::finger_poses;
pub(crate) use truth::rig_yaml;
use truth::{boards_csv, cameras_toml, per_frame_csv, pressures_csv, tips_csv, truth_frames};

/// How the virtual capture session runs (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CaptureConfig {
    pub rig: RigConfig,
    /// Chessboard pairs for calibration (besides the reference pair); with more than two
    /// cameras, the board views each camera gets at least.
    pub views: usize,
    /// Whether to render the board pairs (`calib/`, `truth/boards.csv`); a session filmed
    /// with a rig calibrated before (the same seed's) needs none.
    pub calibration_images: bool,
    /// The printed board.
    pub board: BoardSpec,
    /// How long the paper's protocol holds each step (s).
    pub step_s: f64,
    /// Frames are kept when stamped in [start, end) seconds after their step's command (the
    /// paper's protocol; a dynamic session keeps every frame).
    pub window_s: [f64; 2],
    pub fps: f64,
    /// A dynamic protocol instead of the paper's steps (the session films it all).
    pub dynamic: Option<DynamicSession>,
    /// How the muscles follow the regulator.
    pub dynamics: Dynamics,
    /// Relative amplitude of a slow exposure drift (0 = locked exposure).
    pub exposure_drift: f64,
    pub format: ImageFormat,
    /// How far the right camera's timestamps run ahead of the left's by the session's end
    /// (s), growing evenly from 0: a USB latency that creeps up on one camera.
    pub clock_drift_s: f64,
    /// The first two cameras' delay (left, right) from exposure to the capture computer's
    /// stamp (s): what a USB or network camera's buffering adds. Further cameras have none.
    pub latency_s: [f64; 2],
    /// The finger's frames as one Motion-JPEG video per camera (`frames/left.avi`,
    /// `right.avi`; frame numbers are positions in them) instead of images.
    pub video: bool,
    /// What makes the frames as hard as a real webcam's.
    pub realism: Realism,
    /// What goes wrong during the session, and when ([`crate::synth::faults`]).
    pub faults: Vec<Fault>,
}

/// What a real lab adds to the ideal frames; [`Realism::CLEAN`] turns all of it off.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Realism {
    /// A cluttered wall behind the finger (posters, print, shelves, cables) instead of a plain
    /// grey backdrop.
    pub clutter: bool,
    /// A red cable and a red push-pin in the right camera's view (never near the finger).
    pub red_distractors: bool,
    /// Strength of a room lamp's highlight on the bead (0: matte).
    pub specular: f64,
    /// Relative amplitude of the lights' 100 Hz flicker (each frame catches another phase).
    pub flicker: f64,
    /// Exposure time (s): the finger moves during it while a step settles (motion blur).
    pub exposure_s: f64,
    /// Share of frames in which something passes between a camera and the bead.
    pub occluded: f64,
}

impl Realism {
    /// A webcam in a lab.
    pub const LAB: Realism = Realism {
        clutter: true,
        red_distractors: true,
        specular: 0.8,
        flicker: 0.03,
        exposure_s: 0.012,
        occluded: 0.01,
    };
    /// Ideal frames: plain backdrop, matte bead, steady light, instant exposure.
    pub const CLEAN: Realism = Realism {
        clutter: false,
        red_distractors: false,
        specular: 0.0,
        flicker: 0.0,
        exposure_s: 0.0,
        occluded: 0.0,
    };
}

/// Board pairs a capture renders for calibration by default ([`CaptureConfig::views`]): a
/// constant of its own, so that building the command line (every run of `handcap-cameras`) reads
/// no board through OpenCV for `synth --views`'s default.
pub const VIEWS: usize = 20;

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            rig: RigConfig::default(),
            views: VIEWS,
            calibration_images: true,
            board: crate::calib::file::default_board(),
            step_s: 0.3,
            window_s: [0.10, 0.20],
            fps: 30.0,
            dynamic: None,
            dynamics: Dynamics::STEPS,
            exposure_drift: 0.0,
            format: ImageFormat::WEBCAM,
            clock_drift_s: 0.0,
            latency_s: [0.0; 2],
            video: false,
            realism: Realism::LAB,
            faults: Vec::new(),
        }
    }
}

/// What a capture wrote.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CaptureSummary {
    /// The board poses photographed for calibration (a pair's board pairs), the reference
    /// besides.
    pub boards: usize,
    pub steps: usize,
    /// The cameras' names, and the frames each kept.
    pub cameras: Vec<String>,
    pub frames: Vec<usize>,
    /// Whether Ctrl-C stopped the rendering before the end (files written so far are complete).
    pub interrupted: bool,
}

/// Writes the whole capture into `dir`; `progress(done, total)` is called as images are
/// written, and `interrupt` stops the rendering between images.
///
/// # Errors
/// [`SynthError`] for bad settings, a plant error, or a file that cannot be written.
pub fn write_capture(
    dir: &Path,
    synth: &SynthConfig,
    config: &CaptureConfig,
    provenance: &crate::provenance::Provenance,
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &AtomicBool,
) -> Result<CaptureSummary, SynthError> {
    config.check()?;
    let rig = config.rig.build(synth.seed);
    let names = rig.names();
    let timeline = Timeline::new(&synth.plant, &rig, &config.faults);
    let boards = calibration_boards(config, &rig, synth.seed)?;
    // A stream of its own, so that the board count does not change the clocks.
    let mut rng = ChaCha8Rng::seed_from_u64(synth.seed ^ 0x434c_4f43);

    // The protocol as one session, each step commanded when the one before it ends; the
    // muscles following through the line.
    let steps = config.steps(synth)?;
    let (starts, end_s) = protocol::start_times(&steps);
    let commands: Vec<(f64, Pressures)> = starts
        .iter()
        .zip(&steps)
        .map(|(&t, s)| (t, s.pressures))
        .collect();
    let motion = Motion::simulate(
        &commands,
        &config.dynamics,
        synth.plant.hysteresis_kpa,
        end_s,
    );
    let frames = camera_frames(config, &starts, end_s, &mut rng);

    let subs: &[&str] = if config.calibration_images {
        &["calib", "frames", "truth"]
    } else {
        &["frames", "truth"]
    };
    for sub in subs {
        let path = dir.join(sub);
        std::fs::create_dir_all(&path).map_err(io_err(&path))?;
    }
    if rig.cameras.len() == 2 {
        write_text(&dir.join("truth/rig.yml"), &rig_yaml(&rig, provenance))?;
    } else {
        write_text(&dir.join("truth/cameras.toml"), &cameras_toml(&rig))?;
    }
    if config.calibration_images {
        write_text(
            &dir.join("calib").join(crate::calib::file::BOARD_FILE),
            &crate::calib::file::board_yaml(&config.board),
        )?;
        write_text(&dir.join("truth/boards.csv"), &boards_csv(&rig, &boards))?;
    }
    write_text(&dir.join("pressures.csv"), &pressures_csv(&steps, &starts))?;
    let tips = steps
        .iter()
        .zip(&starts)
        .map(|(s, &t)| timeline.settled_tip(t, s.pressures))
        .collect::<Result<Vec<_>, _>>()?;
    write_text(&dir.join("truth/tips.csv"), &tips_csv(&rig, &steps, &tips))?;
    write_text(
        &dir.join("frames/frames.csv"),
        &crate::session::frames::frames_csv(
            frames
                .iter()
                .map(|f| (&names[f.camera], f.index, f.stamp_s)),
        ),
    )?;

    let truth_rows = truth_frames(&rig, &timeline, &motion, synth.seed, config, &frames)?;
    write_text(&dir.join("truth/frames.csv"), &truth_rows)?;
    if config.dynamic.is_some() {
        let rows = per_frame_csv(&timeline, &motion, &steps, &frames)?;
        write_text(&dir.join("truth/per_frame.csv"), &rows)?;
    }

    let studio = Studio {
        dir,
        seed: synth.seed,
        config,
        timeline: &timeline,
        motion: &motion,
        boards: if config.calibration_images {
            boards.iter().collect()
        } else {
            Vec::new()
        },
        names: names.clone(),
        views: shots::views(&rig, synth.seed, &config.realism, timeline.plant(), &tips),
        knocked: knocked_view(&rig, synth.seed, &config.realism, &timeline, &tips),
    };
    let complete = shots::write_all(&studio, &frames, progress, interrupt)?;
    Ok(CaptureSummary {
        boards: if config.calibration_images {
            boards.len() - 1
        } else {
            0
        },
        steps: steps.len(),
        cameras: names,
        frames: (0..rig.cameras.len())
            .map(|i| frames.iter().filter(|f| f.camera == i).count())
            .collect(),
        interrupted: !complete,
    })
}

/// Where a dynamic session's commands come from.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DynamicSession {
    /// Random excitation between rest holds (`handcap protocol --dynamic`).
    Design(DynamicDesign),
    /// A protocol file's rows, played as they are (e.g. a trajectory's commands).
    Played(Vec<Step>),
}

impl CaptureConfig {
    /// Camera `camera`'s delay from exposure to its stamp (s).
    pub fn latency(&self, camera: usize) -> f64 {
        self.latency_s.get(camera).copied().unwrap_or(0.0)
    }

    /// The protocol the session drives: the dynamic design, or the paper's steps at `synth`'s
    /// grid and sweep steps, each held `step_s`.
    ///
    /// # Errors
    /// [`SynthError::Protocol`] for a design the protocol refuses.
    pub fn steps(&self, synth: &SynthConfig) -> Result<Vec<Step>, SynthError> {
        Ok(match &self.dynamic {
            Some(DynamicSession::Design(design)) => protocol::dynamic(design)?,
            Some(DynamicSession::Played(steps)) => steps.clone(),
            None => protocol::paper_steps(synth.grid_step_kpa, synth.sweep_step_kpa, self.step_s)?,
        })
    }

    /// # Errors
    /// [`SynthError::BadCapture`] saying which rule the settings break.
    pub fn check(&self) -> Result<(), SynthError> {
        let c = self;
        let bad = |what: &str| Err(SynthError::BadCapture(what.to_string()));
        if c.views < 3 {
            return bad("at least 3 board views are needed");
        }
        if !(2..=8).contains(&c.rig.cameras) {
            return bad("a rig has 2 to 8 cameras");
        }
        if let Err(e) = c.board.check() {
            return bad(&e.to_string());
        }
        if !(c.board.square_mm > 1.0 && c.board.square_mm < 40.0) {
            return bad("square size must lie between 1 and 40 mm");
        }
        if !(c.fps > 1.0 && c.step_s > 0.0 && c.window_s[0] >= 0.0 && c.window_s[1] > c.window_s[0])
            || c.window_s[1] > c.step_s
        {
            return bad("the capture window must lie inside a step and the frame rate be positive");
        }
        if let Err(why) = c.dynamics.check() {
            return bad(&format!("the muscles' dynamics: {why}"));
        }
        if c.clock_drift_s.is_nan() || c.clock_drift_s.abs() >= 1.0 {
            return bad("the clock drift must lie within ±1 s");
        }
        if !c.latency_s.iter().all(|l| (0.0..2.0).contains(l)) {
            return bad("each camera's latency must lie in [0, 2) s");
        }
        if !(c.exposure_drift >= 0.0 && c.exposure_drift < 0.5) {
            return bad("exposure drift must lie in [0, 0.5)");
        }
        Ok(())
    }
}

pub(super) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError {
    let path = path.to_path_buf();
    move |source| SynthError::Write { path, source }
}

fn write_text(path: &Path, text: &str) -> Result<(), SynthError> {
    fsio::write_bytes(path, text.as_bytes()).map_err(io_err(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_capture_rule_is_checked() {
        let ok = CaptureConfig::default();
        assert!(ok.check().is_ok());
        let board = BoardSpec::chessboard;
        let cases = [
            (
                CaptureConfig {
                    views: 2,
                    ..ok.clone()
                },
                "board views",
            ),
            (
                CaptureConfig {
                    board: board(2, 6, 10.0),
                    ..ok.clone()
                },
                "at least 3",
            ),
            (
                CaptureConfig {
                    board: board(7, 7, 10.0),
                    ..ok.clone()
                },
                "no orientation",
            ),
            (
                CaptureConfig {
                    board: board(9, 6, 45.0),
                    ..ok.clone()
                },
                "between 1 and 40",
            ),
            (
                CaptureConfig {
                    fps: 0.5,
                    ..ok.clone()
                },
                "frame rate",
            ),
            (
                CaptureConfig {
                    window_s: [0.2, 0.1],
                    ..ok.clone()
                },
                "window",
            ),
            (
                CaptureConfig {
                    window_s: [0.1, 0.4],
                    ..ok.clone()
                },
                "window",
            ),
            (
                CaptureConfig {
                    exposure_drift: 0.5,
                    ..ok.clone()
                },
                "exposure drift",
            ),
        ];
        for (config, says) in cases {
            let err = config.check().unwrap_err().to_string();
            assert!(err.contains(says), "{err}");
        }
    }
}
