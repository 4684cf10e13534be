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
//!   commanded step (phase `train`, `sweep_a` or `sweep_b`).
//! - `truth/rig.yml` (OpenCV YAML, the keys `calibrate` writes: `image_size`, `K1`, `D1`, `K2`,
//!   `D2`, `R`, `T` (left → right, mm), `E`, `F`, and `R_hand`, `t_hand`: p_hand = R_hand ·
//!   p_left + t_hand); `truth/boards.csv`: each board pose in the left camera
//!   (`view,rx,ry,rz,tx_mm,ty_mm,tz_mm`, Rodrigues vector, board frame as OpenCV's object
//!   points); `truth/tips.csv`: per step `step,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm` (hand
//!   frame, settled) and `left_x_mm,left_y_mm,left_z_mm` (left camera frame);
//!   `truth/frames.csv`: per frame `frame,camera,exposure_s,step,x_mm,y_mm,z_mm,u_px,v_px,
//!   occluded`, the tip at the middle of the exposure (still settling early in a step), its
//!   projection, and 1 where something hides the bead.
//! - `manifest.json`: configuration, counts, provenance.
//!
//! # Timing
//!
//! The regulator commands step k at t_k = k · 0.3 s; each muscle's pressure follows
//! first-order, p(t) = p_k + (p_{k−1} − p_k) e^{−(t − t_k)/τ}, τ = 20 ms, and the finger follows
//! its pressures quasi-statically. Each camera exposes at its own 30 fps (±50 ppm) from its own
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

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use nalgebra::{Matrix3, Point3, Rotation3, Unit, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::camera::{Camera, Rig, RigConfig};
use super::clutter;
use super::plant::{Plant, Pressures};
use super::render::{ImageFormat, Lighting, Surroundings, View};
use super::scene::Markers;
use super::scene::{Board, Finger};
use super::{SynthConfig, SynthError};
use crate::calib::BoardSpec;
use crate::fsio;
use crate::geometry::WorldFromBoard;
use crate::opencv_yaml::FileStorage;
use crate::session::protocol::designed;
use crate::stereo::Side;

/// How the virtual capture session runs (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CaptureConfig {
    pub rig: RigConfig,
    /// Chessboard pairs for calibration (besides the reference pair).
    pub views: usize,
    /// The printed board.
    pub board: BoardSpec,
    pub step_s: f64,
    /// Frames are kept when stamped in [start, end) seconds after their step's command.
    pub window_s: [f64; 2],
    pub fps: f64,
    pub settle_tau_s: f64,
    /// Relative amplitude of a slow exposure drift (0 = locked exposure).
    pub exposure_drift: f64,
    pub format: ImageFormat,
    /// How far the right camera's timestamps run ahead of the left's by the session's end
    /// (s), growing evenly from 0: a USB latency that creeps up on one camera.
    pub clock_drift_s: f64,
    /// Each camera's delay (left, right) from exposure to the capture computer's stamp (s):
    /// what a USB or network camera's buffering adds.
    pub latency_s: [f64; 2],
    /// The finger's frames as one Motion-JPEG video per camera (`frames/left.avi`,
    /// `right.avi`; frame numbers are positions in them) instead of images.
    pub video: bool,
    /// What makes the frames as hard as a real webcam's.
    pub realism: Realism,
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

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            rig: RigConfig::default(),
            views: 20,
            board: crate::calib::file::default_board(),
            step_s: 0.3,
            window_s: [0.10, 0.20],
            fps: 30.0,
            settle_tau_s: 0.02,
            exposure_drift: 0.0,
            format: ImageFormat::WEBCAM,
            clock_drift_s: 0.0,
            latency_s: [0.0; 2],
            video: false,
            realism: Realism::LAB,
        }
    }
}

/// What a capture wrote.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CaptureSummary {
    pub board_pairs: usize,
    pub steps: usize,
    pub left_frames: usize,
    pub right_frames: usize,
    /// Whether Ctrl-C stopped the rendering before the end (files written so far are complete).
    pub interrupted: bool,
}

/// One image to render and write.
enum Shot {
    Board {
        camera: Side,
        name: String,
        board: usize,
    },
    Frame {
        camera: Side,
        index: usize,
        /// Middle of the exposure.
        exposure_s: f64,
    },
}

/// A shot rendered as the camera delivers it (8-bit RGB), and where its image file goes.
struct Rendered {
    path: PathBuf,
    size: [u32; 2],
    rgb: Vec<u8>,
}

/// Renders shot `id`.
type RenderShot<'a> = dyn Fn(usize, &Shot) -> Result<Rendered, SynthError> + Sync + 'a;

/// One camera frame kept by the capture computer.
struct Filmed {
    camera: Side,
    index: usize,
    exposure_s: f64,
    stamp_s: f64,
    step: usize,
}

/// A camera's free-running clock.
struct Clock {
    phase_s: f64,
    period_s: f64,
    offset_s: f64,
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
    let plant = Plant::new(synth.plant.clone());
    // Separate streams, so that the board count does not change the clocks.
    let mut rng = ChaCha8Rng::seed_from_u64(synth.seed ^ 0x4341_5054);
    let markers = Arc::new(
        Markers::of(&config.board)
            .map_err(|e| SynthError::BadCapture(format!("the board's markers: {e}")))?,
    );
    let boards = board_poses(config, &rig, &markers, &mut rng)?;
    let mut rng = ChaCha8Rng::seed_from_u64(synth.seed ^ 0x434c_4f43);
    let reference = reference_board(config, &markers);

    // The protocol as one session: steps in order, each commanded at k · step_s.
    let steps: Vec<(&'static str, Pressures)> =
        designed(synth.grid_step_kpa, synth.sweep_step_kpa)?
            .into_iter()
            .flat_map(|(phase, ps)| ps.into_iter().map(move |p| (phase, p)))
            .collect();
    let frames = camera_frames(config, steps.len(), &mut rng);

    for sub in ["calib", "frames", "truth"] {
        let path = dir.join(sub);
        std::fs::create_dir_all(&path).map_err(io_err(&path))?;
    }
    write_text(
        &dir.join("calib").join(crate::calib::file::BOARD_FILE),
        &crate::calib::file::board_yaml(&config.board),
    )?;
    write_text(&dir.join("truth/rig.yml"), &rig_yaml(&rig, provenance))?;
    write_text(
        &dir.join("truth/boards.csv"),
        &boards_csv(&rig, &boards, &reference),
    )?;
    write_text(&dir.join("pressures.csv"), &pressures_csv(config, &steps))?;
    let tips = steps
        .iter()
        .map(|(_, p)| plant.tip(*p))
        .collect::<Result<Vec<_>, _>>()?;
    write_text(&dir.join("truth/tips.csv"), &tips_csv(&rig, &steps, &tips))?;
    write_text(
        &dir.join("frames/frames.csv"),
        &crate::session::frames::frames_csv(frames.iter().map(|f| (f.camera, f.index, f.stamp_s))),
    )?;

    // Every image, in a fixed order; each is rendered, encoded and written on its own.
    let mut shots = Vec::new();
    for (k, _) in boards
        .iter()
        .enumerate()
        .chain(std::iter::once((boards.len(), &reference)))
    {
        let name = if k == boards.len() {
            "ref".to_string()
        } else {
            format!("{k:02}")
        };
        for camera in [Side::Left, Side::Right] {
            shots.push(Shot::Board {
                camera,
                name: name.clone(),
                board: k,
            });
        }
    }
    for f in &frames {
        shots.push(Shot::Frame {
            camera: f.camera,
            index: f.index,
            exposure_s: f.exposure_s,
        });
    }
    let all_boards: Vec<&Board> = boards.iter().chain(std::iter::once(&reference)).collect();
    let realism = &config.realism;
    let view = |camera: &Camera, side: Side| {
        let lighting = Lighting::from_seed(synth.seed ^ side as u64);
        let wall = realism.clutter.then(|| {
            let base = plant.centre_line([0.0; 3]).map(|line| line[0]);
            let keep = workspace_box(camera, tips.iter().chain(base.as_ref().ok()));
            let red = realism.red_distractors && side == Side::Right;
            clutter::wall(
                camera.width as usize,
                camera.height as usize,
                synth.seed ^ (side as u64 + 1) << 8,
                red,
                keep,
            )
        });
        let surroundings = Surroundings {
            wall,
            specular: realism.specular,
        };
        View::new(camera.clone(), lighting, surroundings)
    };
    let views = [view(&rig.left, Side::Left), view(&rig.right, Side::Right)];
    let truth_rows = truth_frames(&rig, &plant, synth.seed, config, &steps, &frames)?;
    write_text(&dir.join("truth/frames.csv"), &truth_rows)?;

    let ext = config.format.extension();
    let total = shots.len();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let render = |id: usize, shot: &Shot| -> Result<Rendered, SynthError> {
        let (side, path, canvas, time) = match shot {
            Shot::Board {
                camera,
                name,
                board,
            } => {
                let view = &views[*camera as usize];
                let path = dir.join(format!("calib/{}_{name}.{ext}", camera.name()));
                (*camera, path, view.board(all_boards[*board]), 0.0)
            }
            Shot::Frame {
                camera,
                index,
                exposure_s,
            } => {
                let view = &views[*camera as usize];
                let poses = finger_poses(config, &plant, &steps, &view.camera, *exposure_s)?;
                let mut canvas = view.finger(&poses);
                if let Some(angle) = occluder(synth.seed, config, *camera, *index) {
                    let tip = plant.tip(pressure_at(config, &steps, *exposure_s))?;
                    if let Some(through) = view.camera.project(&Point3::from(tip)) {
                        view.occlude(&mut canvas, through, angle);
                    }
                }
                let path = dir.join(format!("frames/{}_{index:05}.{ext}", camera.name()));
                (*camera, path, canvas, *exposure_s)
            }
        };
        // A slow drift of the auto-exposure and the lights' 100 Hz flicker.
        let phase = side as u8 as f64;
        let gain = (1.0
            + config.exposure_drift * (std::f64::consts::TAU * time / 20.0 + phase).sin())
            * (1.0 + realism.flicker * (std::f64::consts::TAU * 100.0 * time + phase).sin());
        let size = [canvas.width as u32, canvas.height as u32];
        let rgb = canvas.develop(gain, synth.seed, id as u64);
        Ok(Rendered { path, size, rgb })
    };
    let counted = || progress(done.fetch_add(1, Ordering::SeqCst) + 1, total);
    // Images: each shot rendered, encoded and written on its own; with `video`, the finger's
    // frames go to each camera's video instead, in order, rendered a chunk at a time.
    let boards_only = if config.video {
        2 * all_boards.len()
    } else {
        total
    };
    let written: Vec<Result<bool, SynthError>> = shots[..boards_only]
        .par_iter()
        .enumerate()
        .map(|(id, shot)| {
            if interrupt.load(Ordering::SeqCst) {
                return Ok(false);
            }
            let Rendered { path, size, rgb } = render(id, shot)?;
            let bytes = config.format.encode(size[0], size[1], &rgb);
            fsio::write_bytes(&path, &bytes).map_err(io_err(&path))?;
            counted();
            Ok(true)
        })
        .collect();
    let mut complete = true;
    for w in written {
        complete &= w?;
    }
    if config.video && complete {
        complete = write_videos(
            dir,
            config,
            &shots,
            boards_only,
            &render,
            &counted,
            interrupt,
        )?;
    }
    Ok(CaptureSummary {
        board_pairs: boards.len(),
        steps: steps.len(),
        left_frames: frames.iter().filter(|f| f.camera == Side::Left).count(),
        right_frames: frames.iter().filter(|f| f.camera == Side::Right).count(),
        interrupted: !complete,
    })
}

/// The finger's frames (`shots[first..]`) as `frames/left.avi` and `frames/right.avi`,
/// Motion-JPEG at the format's quality; `false` when interrupted (no video is then left).
fn write_videos(
    dir: &Path,
    config: &CaptureConfig,
    shots: &[Shot],
    first: usize,
    render: &RenderShot,
    counted: &(dyn Fn() + Sync),
    interrupt: &AtomicBool,
) -> Result<bool, SynthError> {
    let quality = match config.format {
        ImageFormat::Jpeg { quality, .. } => quality,
        ImageFormat::Png => 95,
    };
    let size = [config.rig.width, config.rig.height];
    for camera in [Side::Left, Side::Right] {
        let path = dir.join(format!("frames/{}.avi", camera.name()));
        let failed = |why: String| SynthError::Write {
            path: path.clone(),
            source: std::io::Error::other(why),
        };
        let mut writer =
            crate::video::MjpegWriter::create(&path, config.fps, size, quality).map_err(failed)?;
        let mine: Vec<(usize, &Shot)> = shots
            .iter()
            .enumerate()
            .skip(first)
            .filter(|(_, s)| matches!(s, Shot::Frame { camera: c, .. } if *c == camera))
            .collect();
        for chunk in mine.chunks(32) {
            if interrupt.load(Ordering::SeqCst) {
                return Ok(false);
            }
            let frames = chunk
                .par_iter()
                .map(|&(id, shot)| render(id, shot).map(|r| r.rgb))
                .collect::<Result<Vec<_>, _>>()?;
            for rgb in frames {
                writer.write(&rgb).map_err(|e| failed(e.message))?;
                counted();
            }
        }
        writer.finish().map_err(failed)?;
    }
    Ok(true)
}

impl CaptureConfig {
    /// # Errors
    /// [`SynthError::BadCapture`] saying which rule the settings break.
    pub fn check(&self) -> Result<(), SynthError> {
        let c = self;
        let bad = |what: &str| Err(SynthError::BadCapture(what.to_string()));
        if c.views < 3 {
            return bad("at least 3 board views are needed");
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

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError {
    let path = path.to_path_buf();
    move |source| SynthError::Write { path, source }
}

fn write_text(path: &Path, text: &str) -> Result<(), SynthError> {
    fsio::write_bytes(path, text.as_bytes()).map_err(io_err(path))
}

/// The board at the finger's base that fixes the hand frame's axes (module docs).
fn reference_board(c: &CaptureConfig, markers: &Arc<Markers>) -> Board {
    let s = c.board.square_mm;
    let (wide, tall) = ((c.board.cols - 1) as f64 * s, (c.board.rows - 1) as f64 * s);
    // Columns x, y, z of board → hand: x = hand x, y = hand −z, z = hand +y.
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::new(
        1.0, 0.0, 0.0, //
        0.0, 0.0, 1.0, //
        0.0, -1.0, 0.0,
    ));
    Board {
        spec: c.board,
        pose: WorldFromBoard::new(rotation, Vector3::new(-wide / 2.0, 5.0, 25.0 + tall / 2.0)),
        markers: markers.clone(),
    }
}

/// Random board poses: 110-230 mm from the rig, tilted up to 40°, turned in-plane up to 20°,
/// spread over the images. Both cameras see a chessboard whole; of a ChArUco board every other
/// view is partly out of an image (at least half its corners in both, some out of one),
/// pushed towards the images' edges where distortion is strongest.
fn board_poses(
    c: &CaptureConfig,
    rig: &Rig,
    markers: &Arc<Markers>,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Board>, SynthError> {
    let s = c.board.square_mm;
    let half = Vector3::new(
        (c.board.cols - 1) as f64 * s / 2.0,
        (c.board.rows - 1) as f64 * s / 2.0,
        0.0,
    );
    let eye = Point3::from((rig.left.pose.centre().coords + rig.right.pose.centre().coords) / 2.0);
    let aim = Point3::from(c.rig.aim_mm);
    let axis = (aim - eye).normalize();
    let mut boards = Vec::new();
    for _ in 0..20_000 {
        if boards.len() == c.views {
            break;
        }
        let partial = c.board.is_charuco() && boards.len() % 2 == 1;
        let distance = rng.random_range(110.0..230.0);
        let spread = distance * if partial { 0.6 } else { 0.35 };
        let side = Vector3::x();
        let up = axis.cross(&side).normalize();
        let centre = eye
            + axis * distance
            + side * rng.random_range(-spread..spread)
            + up * rng.random_range(-spread * 0.6..spread * 0.6);
        // Facing the rig: board z away from the cameras, board x along hand x.
        let z = (centre - eye).normalize();
        let x = (side - z * side.dot(&z)).normalize();
        let y = z.cross(&x);
        let facing = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        let tilt_axis =
            Unit::new_normalize(x * rng.random_range(-1.0..1.0) + y * rng.random_range(-1.0..1.0));
        let tilt =
            Rotation3::from_axis_angle(&tilt_axis, rng.random_range(0.0..40f64.to_radians()));
        let spin = Rotation3::from_axis_angle(
            &Unit::new_normalize(z),
            rng.random_range(-20f64..20.0).to_radians(),
        );
        let rotation = tilt * spin * facing;
        let board = Board {
            spec: c.board,
            pose: WorldFromBoard::new(rotation, (centre - rotation * half).coords),
            markers: markers.clone(),
        };
        let wanted = if partial {
            partly_visible(&board, rig)
        } else {
            facing_both(&board, rig)
                && [&rig.left, &rig.right]
                    .iter()
                    .all(|cam| board.paper_corners().iter().all(|p| inside(cam, p, 15.0)))
        };
        if wanted {
            boards.push(board);
        }
    }
    if boards.len() < c.views {
        return Err(SynthError::BadCapture(format!(
            "could place only {} of {} board views inside both images; use a smaller --square-mm",
            boards.len(),
            c.views
        )));
    }
    Ok(boards)
}

/// Both cameras see the board's front at under 70°.
fn facing_both(board: &Board, rig: &Rig) -> bool {
    let normal = board.pose.rotation * Vector3::z();
    [&rig.left, &rig.right].iter().all(|cam| {
        let view = (Point3::from(board.pose.translation) - cam.pose.centre()).normalize();
        view.dot(&normal) >= 70f64.to_radians().cos()
    })
}

/// At least half the inner corners inside both images (15 px margin), and one outside an
/// image.
fn partly_visible(board: &Board, rig: &Rig) -> bool {
    let corners = board.corners();
    let cams = [&rig.left, &rig.right];
    let seen = corners
        .iter()
        .filter(|p| cams.iter().all(|cam| inside(cam, p, 15.0)))
        .count();
    facing_both(board, rig)
        && 2 * seen >= corners.len()
        && cams
            .iter()
            .any(|cam| corners.iter().any(|p| !inside(cam, p, 0.0)))
}

fn inside(cam: &Camera, p: &Point3<f64>, margin: f64) -> bool {
    cam.project(p).is_some_and(|[u, v]| {
        u >= margin
            && v >= margin
            && u <= f64::from(cam.width) - 1.0 - margin
            && v <= f64::from(cam.height) - 1.0 - margin
    })
}

/// The frames each camera keeps: those stamped inside a step's window.
fn camera_frames(c: &CaptureConfig, steps: usize, rng: &mut ChaCha8Rng) -> Vec<Filmed> {
    let clocks: Vec<Clock> = (0..2)
        .map(|_| Clock {
            phase_s: rng.random_range(0.0..1.0 / c.fps),
            period_s: 1.0 / (c.fps * (1.0 + rng.random_range(-50e-6..50e-6))),
            offset_s: rng.random_range(-0.005..0.005),
        })
        .collect();
    let end = steps as f64 * c.step_s;
    let mut out = Vec::new();
    for (side, clock) in [Side::Left, Side::Right].into_iter().zip(&clocks) {
        let mut index = 0;
        let mut n = 0u64;
        loop {
            let exposure_s = clock.phase_s + n as f64 * clock.period_s;
            n += 1;
            if exposure_s >= end {
                break;
            }
            let drift = if side == Side::Right {
                c.clock_drift_s * exposure_s / end
            } else {
                0.0
            };
            let stamp_s = exposure_s
                + c.latency_s[side as usize]
                + clock.offset_s
                + rng.random_range(-0.002..0.002)
                + drift;
            let step = (stamp_s / c.step_s).floor();
            if step < 0.0 || step as usize >= steps {
                continue;
            }
            let into = stamp_s - step * c.step_s;
            if into >= c.window_s[0] && into < c.window_s[1] {
                out.push(Filmed {
                    camera: side,
                    index,
                    exposure_s,
                    stamp_s,
                    step: step as usize,
                });
                index += 1;
            }
        }
    }
    out
}

/// The finger during the exposure centred on `t`: one pose when it moves less than 0.02 px
/// in the image meanwhile, else four, evenly spread over the exposure (motion blur).
fn finger_poses(
    c: &CaptureConfig,
    plant: &Plant,
    steps: &[(&str, Pressures)],
    camera: &Camera,
    t: f64,
) -> Result<Vec<Finger>, SynthError> {
    let pose = |t: f64| -> Result<Finger, SynthError> {
        let line = plant.centre_line(pressure_at(c, steps, t))?;
        Ok(Finger::from_centre_line(&line, 4))
    };
    let half = c.realism.exposure_s / 2.0;
    let (start, end) = (pose(t - half)?, pose(t + half)?);
    let moved = match (camera.project(&start.tip), camera.project(&end.tip)) {
        (Some(a), Some(b)) => (a[0] - b[0]).hypot(a[1] - b[1]),
        _ => 0.0,
    };
    if moved < 0.02 {
        return Ok(vec![pose(t)?]);
    }
    (0..4)
        .map(|k| pose(t - half + c.realism.exposure_s * (k as f64 + 0.5) / 4.0))
        .collect()
}

/// The angle of the rod hiding the bead in this frame, for a share `realism.occluded` of the
/// frames (drawn from the seed, the camera and the frame).
fn occluder(seed: u64, c: &CaptureConfig, camera: Side, index: usize) -> Option<f64> {
    let key = seed ^ 0x4f43_434c ^ (camera as u64) << 40 ^ index as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(key);
    (rng.random::<f64>() < c.realism.occluded).then(|| rng.random_range(0.0..std::f64::consts::TAU))
}

/// The pixel box [u0, v0, u1, v1] of the points' images.
fn workspace_box<'a>(camera: &Camera, points: impl Iterator<Item = &'a [f64; 3]>) -> [f64; 4] {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for [u, v] in points.filter_map(|p| camera.project(&Point3::from(*p))) {
        b = [b[0].min(u), b[1].min(v), b[2].max(u), b[3].max(v)];
    }
    b
}

/// The muscles' pressures at time `t` (first-order response to each command).
fn pressure_at(c: &CaptureConfig, steps: &[(&str, Pressures)], t: f64) -> Pressures {
    let k = ((t / c.step_s).floor().max(0.0) as usize).min(steps.len() - 1);
    let target = steps[k].1;
    let before = if k == 0 { [0.0; 3] } else { steps[k - 1].1 };
    let decay = (-(t - k as f64 * c.step_s).max(0.0) / c.settle_tau_s).exp();
    std::array::from_fn(|i| target[i] + (before[i] - target[i]) * decay)
}

fn mat3(m: &Matrix3<f64>) -> Vec<f64> {
    (0..3)
        .flat_map(|r| (0..3).map(move |c| m[(r, c)]))
        .collect()
}

fn rig_yaml(rig: &Rig, provenance: &crate::provenance::Provenance) -> String {
    let cams = rig.stereo();
    // The virtual world is the hand frame: the left camera's pose inverted.
    let hand_from_left = rig.left.pose.inverse();
    let mut fs = FileStorage::new();
    crate::calib::file::write_rig(&mut fs, &cams)
        .matrix("E", 3, 3, &mat3(&cams.essential()))
        .matrix("F", 3, 3, &mat3(&cams.fundamental()))
        .matrix("R_hand", 3, 3, &hand_from_left.rotation_rows())
        .matrix("t_hand", 3, 1, &hand_from_left.translation_array())
        .string("handcap_version", &provenance.handcap_version)
        .string("command", &provenance.command.join(" "));
    if let Some(seed) = provenance.seed {
        fs.int("seed", seed as i64);
    }
    fs.text().to_string()
}

fn boards_csv(rig: &Rig, boards: &[Board], reference: &Board) -> String {
    let mut out = String::from("view,rx,ry,rz,tx_mm,ty_mm,tz_mm\n");
    let named = boards
        .iter()
        .enumerate()
        .map(|(k, b)| (format!("{k:02}"), b))
        .chain(std::iter::once(("ref".to_string(), reference)));
    for (name, b) in named {
        let left_from_board = b.pose.then(&rig.left.pose);
        let (r, t) = (
            left_from_board.rotation.scaled_axis(),
            left_from_board.translation,
        );
        out += &format!("{name},{},{},{},{},{},{}\n", r.x, r.y, r.z, t.x, t.y, t.z);
    }
    out
}

fn pressures_csv(c: &CaptureConfig, steps: &[(&str, Pressures)]) -> String {
    crate::session::pressures::pressures_csv(steps.iter().enumerate().map(|(k, (phase, p))| {
        crate::session::pressures::Logged {
            time_s: k as f64 * c.step_s,
            command_end_s: None,
            pressures_kpa: *p,
            step: k,
            phase,
        }
    }))
}

fn tips_csv(rig: &Rig, steps: &[(&str, Pressures)], tips: &[[f64; 3]]) -> String {
    let mut out = String::from(
        "step,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,left_x_mm,left_y_mm,left_z_mm\n",
    );
    for (k, ((phase, p), tip)) in steps.iter().zip(tips).enumerate() {
        let left = rig.left.pose.apply(&Point3::from(*tip));
        out += &format!(
            "{k},{phase},{},{},{},{},{},{},{},{},{}\n",
            p[0], p[1], p[2], tip[0], tip[1], tip[2], left.x, left.y, left.z
        );
    }
    out
}

fn truth_frames(
    rig: &Rig,
    plant: &Plant,
    seed: u64,
    c: &CaptureConfig,
    steps: &[(&str, Pressures)],
    frames: &[Filmed],
) -> Result<String, SynthError> {
    let mut out = String::from("frame,camera,exposure_s,step,x_mm,y_mm,z_mm,u_px,v_px,occluded\n");
    for f in frames {
        let tip = plant.tip(pressure_at(c, steps, f.exposure_s))?;
        let cam = match f.camera {
            Side::Left => &rig.left,
            Side::Right => &rig.right,
        };
        let [u, v] = cam
            .project(&Point3::from(tip))
            .unwrap_or([f64::NAN, f64::NAN]);
        let occluded = occluder(seed, c, f.camera, f.index).is_some();
        out += &format!(
            "{},{},{:.6},{},{},{},{},{},{},{}\n",
            f.index,
            f.camera.name(),
            f.exposure_s,
            f.step,
            tip[0],
            tip[1],
            tip[2],
            u,
            v,
            u8::from(occluded)
        );
    }
    Ok(out)
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
