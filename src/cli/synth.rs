//! `handcap synth`: the virtual micro-hand seen by a virtual stereo rig — calibration images,
//! finger frames, the regulator's log, datasets and ground truth (layout:
//! `crate::synth::capture`).

use std::path::PathBuf;

use anyhow::Context;

use crate::pipeline::synth;
use crate::session::protocol::{self, DynamicDesign};
use crate::synth::camera::RigConfig;
use crate::synth::capture::{CaptureConfig, DynamicSession, Realism};
use crate::synth::dynamics::Dynamics;
use crate::synth::faults::Fault;
use crate::synth::image_format::{Chroma, ImageFormat};
use crate::synth::quick;
use crate::synth::{plant::PlantParams, SynthConfig, DEFAULT_NOISE_MM};

#[derive(clap::Args)]
pub struct Args {
    /// Output directory (created if missing; files in it are replaced atomically)
    #[arg(long)]
    out: PathBuf,
    /// Write only the pressure → tip datasets, no camera images; with --dynamic or --protocol,
    /// the session's rows as `triangulate --per-frame` gives them, from each camera's view of
    /// the bead (no images: an hour's session in seconds), and the true tips
    #[arg(long)]
    no_images: bool,
    /// Seed of every random choice (noise, rig variation, board poses, clocks)
    #[arg(long, default_value_t = crate::DEFAULT_SEED)]
    seed: u64,
    /// Tip measurement noise of the datasets, standard deviation per coordinate (mm)
    #[arg(long, default_value_t = DEFAULT_NOISE_MM)]
    noise_mm: f64,
    /// Width of the muscles' pressure hysteresis (kPa); 0 turns it off (datasets only)
    #[arg(long, default_value_t = 0.0)]
    hysteresis_kpa: f64,
    /// Pressure step of the training grid (kPa)
    #[arg(long, default_value_t = 50.0)]
    grid_step_kpa: f64,
    /// Pressure step of the two test sweeps (kPa)
    #[arg(long, default_value_t = 10.0)]
    sweep_step_kpa: f64,
    /// Board pairs to render for calibration (of a ChArUco board, every other one partly out
    /// of view); with more cameras, the board views each camera gets
    #[arg(long, default_value_t = crate::synth::capture::VIEWS)]
    views: usize,
    #[command(flatten)]
    board: super::board::BoardArgs,
    /// How many cameras: 2, a stereo pair; 3 to 8 stand on an arc around the finger, 30° apart,
    /// named cam1 … camN, each seeing its share of the board views, the two ends none together
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(2..=8))]
    cameras: u8,
    /// Distance between the two cameras of a pair (mm)
    #[arg(long, default_value_t = RigConfig::default().baseline_mm)]
    baseline_mm: f64,
    /// Distance from the cameras to the finger's tip region (mm)
    #[arg(long, default_value_t = RigConfig::default().distance_mm)]
    distance_mm: f64,
    /// The cameras' image width and height (px)
    #[arg(long, default_value_t = RigConfig::default().width)]
    width: u32,
    #[arg(long, default_value_t = RigConfig::default().height)]
    height: u32,
    /// The cameras' diagonal field of view (degrees): with the size, their focal length
    #[arg(long, default_value_t = RigConfig::default().fov_diag_deg, value_parser = super::finite)]
    fov_deg: f64,
    /// Relative amplitude of a slow exposure drift (0: exposure locked)
    #[arg(long, default_value_t = 0.0)]
    exposure_drift: f64,
    /// How far the right camera's timestamps drift ahead of the left's over the session (ms)
    #[arg(long, default_value_t = 0.0, value_parser = super::finite)]
    clock_drift_ms: f64,
    /// Each camera's delay from exposure to the frame's timestamp (ms): LEFT,RIGHT, or one for
    /// both
    #[arg(long, value_delimiter = ',', num_args = 1..=2, value_parser = super::finite)]
    latency_ms: Vec<f64>,
    /// Frames are kept when stamped this long after their step's command (ms): START,END;
    /// 0,300 films the whole step, the finger's motion too
    #[arg(long, value_delimiter = ',', num_args = 1..=2, value_parser = super::finite)]
    window_ms: Vec<f64>,
    /// The finger's frames as two Motion-JPEG videos, frames/left.avi and frames/right.avi
    /// (frame numbers in frames.csv are positions in them), as a lab records with OBS or ffmpeg
    #[arg(long)]
    video: bool,
    #[command(flatten)]
    frames: FrameArgs,
    /// A dynamic session instead of the paper's steps: random excitation between rest holds
    /// (as `handcap protocol --dynamic` writes), the muscles lagging through a pneumatic line
    /// and creeping, every frame kept (truth/per_frame.csv is what triangulate --per-frame
    /// should give)
    #[arg(long, conflicts_with = "window_ms")]
    dynamic: bool,
    #[command(flatten)]
    design: super::protocol::DynamicArgs,
    /// A protocol file to play instead (as `handcap protocol` writes it, e.g. a trajectory's
    /// commands between rest holds), filmed as a dynamic session, without board pairs: the rig
    /// is the one a synth run of the same seed and rig flags calibrates
    #[arg(long, conflicts_with_all = ["dynamic", "window_ms"])]
    protocol: Option<PathBuf>,
    /// With --dynamic or --protocol: a fault at a time, KIND@T=AMOUNT (repeatable):
    /// camera@40=0.5 tilts the right camera 0.5° at 40 s (pan@40=0.5 turns it about its
    /// vertical axis instead), stiffness@40=-0.1 makes the finger
    /// 10 % softer, leak@40=0.05 loses up to 5 % of muscle 1's pressure over the next minute,
    /// payload@40=0.2 hangs 0.2 g on the tip
    #[arg(long = "fault", value_name = "KIND@T=AMOUNT")]
    faults: Vec<Fault>,
}

/// How the virtual webcams' frames look and are stored (synth and demo).
#[derive(clap::Args)]
pub struct FrameArgs {
    /// Ideal frames: plain backdrop, matte bead, steady light, no motion blur, nothing passing
    /// in front of the bead, stored as PNG (unless --format says otherwise). Without it the
    /// frames are a webcam's in a lab: MJPEG 4:2:0, a cluttered wall, red things in one
    /// camera, a highlight on the bead, flicker, motion blur, occlusions
    #[arg(long)]
    clean: bool,
    /// Image files: jpeg (as webcams stream MJPEG) or png (lossless); default jpeg, png with --clean
    #[arg(long, value_enum)]
    format: Option<FormatArg>,
    /// JPEG quality (webcams' MJPEG streams are about 85)
    #[arg(long, default_value_t = 85, value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: u8,
    /// JPEG colour resolution: 420 (half each way, as webcams and OpenCV write) or 444 (full)
    #[arg(long, value_enum, default_value = "420")]
    chroma: Chroma,
}

#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum FormatArg {
    Png,
    Jpeg,
}

impl FrameArgs {
    /// The image format and the scene's realism.
    pub fn look(&self) -> (ImageFormat, Realism) {
        let format = match self.format {
            Some(FormatArg::Png) => ImageFormat::Png,
            None if self.clean => ImageFormat::Png,
            _ => ImageFormat::Jpeg {
                quality: self.jpeg_quality,
                chroma: self.chroma,
            },
        };
        let realism = if self.clean {
            Realism::CLEAN
        } else {
            Realism::LAB
        };
        (format, realism)
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let config = SynthConfig {
        seed: a.seed,
        noise_mm: a.noise_mm,
        grid_step_kpa: a.grid_step_kpa,
        sweep_step_kpa: a.sweep_step_kpa,
        plant: PlantParams {
            hysteresis_kpa: a.hysteresis_kpa,
            ..PlantParams::default()
        },
    };
    let board = match a.board.flags().over(&CaptureConfig::default().board) {
        Ok(board) => board,
        Err(e) => super::usage!("{e}"),
    };
    board.check()?;
    let (format, realism) = a.frames.look();
    let window_s = match a.window_ms[..] {
        [] => CaptureConfig::default().window_s,
        [start, end] => [start / 1e3, end / 1e3],
        _ => super::usage!("--window-ms takes two numbers, START,END (e.g. 0,300)"),
    };
    let latency_s = super::left_right("--latency-ms", &a.latency_ms)?
        .map_or(CaptureConfig::default().latency_s, |ms| {
            ms.map(|ms| ms / 1e3)
        });
    let played = a.protocol.as_deref().map(protocol::read).transpose()?;
    if a.no_images && a.cameras != 2 {
        super::usage!("--cameras renders the cameras' images: drop --no-images");
    }
    if a.no_images && (a.dynamic || played.is_some()) {
        let steps = match played {
            Some(steps) => steps,
            None => protocol::dynamic(&a.design.with(a.seed, DynamicDesign::default().max_kpa))?,
        };
        let written = super::with_session(|s| {
            let provenance = s.provenance(Some(a.seed));
            quick::write(
                &a.out,
                &steps,
                a.seed,
                &config.plant,
                &a.faults,
                &provenance,
            )
        });
        print!(
            "{}",
            written.with_context(|| format!("synth into {}", a.out.display()))?
        );
        return Ok(());
    }
    if !a.faults.is_empty() && !a.dynamic && played.is_none() {
        super::usage!("--fault needs --dynamic or --protocol: faults happen in time");
    }
    let capture_config = (!a.no_images).then(|| CaptureConfig {
        rig: RigConfig {
            baseline_mm: a.baseline_mm,
            distance_mm: a.distance_mm,
            width: a.width,
            height: a.height,
            fov_diag_deg: a.fov_deg,
            cameras: a.cameras.into(),
            ..RigConfig::default()
        },
        views: a.views,
        board,
        exposure_drift: a.exposure_drift,
        format,
        video: a.video,
        clock_drift_s: a.clock_drift_ms / 1e3,
        latency_s,
        window_s,
        realism,
        faults: a.faults.clone(),
        calibration_images: a.protocol.is_none(),
        dynamic: match &played {
            Some(steps) => Some(DynamicSession::Played(steps.clone())),
            None => a.dynamic.then(|| {
                DynamicSession::Design(a.design.with(a.seed, DynamicDesign::default().max_kpa))
            }),
        },
        dynamics: if a.dynamic || a.protocol.is_some() {
            Dynamics::PNEUMATIC
        } else {
            Dynamics::STEPS
        },
        ..CaptureConfig::default()
    });
    let done = super::with_session(|s| synth::run(&a.out, &config, capture_config.as_ref(), s))
        .with_context(|| format!("synth into {}", a.out.display()))?;
    print!("{done}");
    if done.capture.as_ref().is_some_and(|c| c.interrupted) {
        return Err(crate::pipeline::PipelineError::Interrupted("interrupted: the images written so far are complete, the rest are missing; run again to finish".into()).into());
    }
    Ok(())
}
