//! `handcap calibrate DIR`: stereo calibration from chessboard pairs → OpenCV YAML + quality
//! (the file's keys: `crate::calib::file`).

use std::path::PathBuf;

use anyhow::bail;

use crate::calib::uncertainty::{self, ParameterSd};
use crate::calib::{file, validate, CalibOptions};
use crate::pipeline::calibrate::{self, Calibrated};

#[derive(clap::Args)]
pub struct Args {
    /// Directory with left*/right* board images (PNG or JPEG), or two videos of the board
    dir: PathBuf,
    #[command(flatten)]
    board: super::board::BoardArgs,
    /// Calibration file to write (OpenCV YAML)
    #[arg(long, default_value = "calib.yml")]
    out: PathBuf,
    /// Fewest pairs to keep when rejecting outliers
    #[arg(long, default_value_t = CalibOptions::default().min_pairs)]
    min_pairs: usize,
    /// LEFT,RIGHT: each camera's intrinsics from an earlier single-camera calibration (OpenCV
    /// YAML: camera_matrix, distortion_coefficients, image_width, image_height), fixed instead of
    /// solved; `-` for a camera to solve (e.g. `--intrinsics left.yml,-`)
    #[arg(long, value_delimiter = ',', num_args = 1, allow_hyphen_values = true)]
    intrinsics: Vec<PathBuf>,
    /// Also find the standard deviations by recalibrating N times on the pairs drawn with
    /// replacement (a check of the covariance's, about N × 0.1 s)
    #[arg(long, default_value_t = 0)]
    bootstrap: usize,
    /// Seed of the bootstrap's draws
    #[arg(long, default_value_t = CalibOptions::default().seed)]
    seed: u64,
    /// For DIR holding left.<video> and right.<video> without frames.csv: when each video's
    /// first frame was taken, on one clock (s); LEFT,RIGHT or one time for both
    #[arg(long, value_delimiter = ',', num_args = 1..=2, value_parser = super::finite)]
    video_start_s: Vec<f64>,
    /// Most board pairs picked from videos
    #[arg(long, default_value_t = CalibOptions::default().max_video_pairs)]
    max_video_pairs: usize,
    /// Write the calibration even when it fails a plausibility gate (RMS, the boards
    /// triangulated back, the baseline, given intrinsics against the images); the file's
    /// `forced` key lists what failed
    #[arg(long)]
    force: bool,
    /// Check the stated standard deviations: calibrate two halves of the pairs (5 splits) and
    /// compare their disagreement at the finger's working volume with what their covariances
    /// predict (a ratio, about 1 when honest), and map the tip's deviation against the
    /// distance from the boards
    #[arg(long)]
    validate: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if !a.dir.is_dir() {
        bail!(
            "{} is not a directory of calibration images",
            a.dir.display()
        );
    }
    if !a.intrinsics.is_empty() && a.intrinsics.len() != 2 {
        super::usage!("--intrinsics takes LEFT,RIGHT (`-` for a camera to solve)");
    }
    let mut intrinsics = [None, None];
    for (slot, path) in intrinsics.iter_mut().zip(&a.intrinsics) {
        if path.as_os_str() != "-" {
            *slot = Some(file::read_intrinsics(path)?);
        }
    }
    let options = CalibOptions {
        min_pairs: a.min_pairs,
        intrinsics,
        bootstrap: a.bootstrap,
        seed: a.seed,
        video_start_s: super::left_right("--video-start-s", &a.video_start_s)?,
        max_video_pairs: a.max_video_pairs,
        force: a.force,
        validate: a.validate,
        ..CalibOptions::default()
    };
    let done = super::with_session(|s| {
        let board = calibrate::board(&a.dir, &a.board.flags(), s)?;
        calibrate::run(&a.dir, &board, &options, &a.out, s)
    })?;
    print_summary(&done);
    for (camera, known) in ["left", "right"].iter().zip(&options.intrinsics) {
        if let Some(k) = known {
            println!(
                "{camera} intrinsics fixed as {} gives them",
                k.path.display()
            );
        }
    }
    super::print_written(&done.written);
    Ok(())
}

pub fn print_summary(done: &Calibrated) {
    let c = &done.calibration;
    for f in &c.unpaired {
        println!("skipped {}: no partner image", f.display());
    }
    println!(
        "{} pairs used, {} rejected; detector: {}",
        c.used().count(),
        c.rejected().count(),
        c.detector.name()
    );
    for p in &c.pairs {
        match (&p.rms_px, &p.rejected) {
            (Some([l, r]), _) => println!(
                "  {:>6}  left {l:.3} px  right {r:.3} px{}",
                p.name,
                p.note
                    .as_ref()
                    .map(|n| format!("  ({n})"))
                    .unwrap_or_default()
            ),
            (_, Some(why)) => println!("  {:>6}  rejected: {why}", p.name),
            _ => {}
        }
    }
    let baseline = c.rig.right_from_left.translation.norm();
    println!(
        "RMS {:.3} px, epipolar {:.3} px, baseline {baseline:.2} mm, f {:.1}/{:.1} px",
        c.rms_px,
        c.epipolar_px,
        c.rig.left.fx(),
        c.rig.right.fx()
    );
    let parameters = |sd: &ParameterSd| {
        let camera = |sd: Option<[f64; 9]>| match sd {
            Some(sd) => format!(
                "fx ±{:.2} fy ±{:.2} cx ±{:.2} cy ±{:.2} px",
                sd[0], sd[1], sd[2], sd[3]
            ),
            None => "fixed".into(),
        };
        let [rx, ry, rz] = sd.rotation_deg;
        format!(
            "left {}; right {}; baseline ±{:.3} mm ({:.3} %), rotation ±{rx:.3}/{ry:.3}/{rz:.3}° about x/y/z",
            camera(sd.intrinsics[0]),
            camera(sd.intrinsics[1]),
            sd.baseline_mm,
            100.0 * sd.baseline_mm / baseline
        )
    };
    match &c.uncertainty {
        Some(u) => {
            println!(
                "1 sd (covariance of the fit, corners ±{:.3} px): {}",
                u.corner_sd_px,
                parameters(&u.parameters)
            );
            let t = &u.tip;
            let axes = |v: [f64; 3]| format!("±{:.3}/{:.3}/{:.3} mm", v[0], v[1], v[2]);
            println!(
                "tip at {} ({:.0} mm away), x/y/depth: position {} and a {} mm move {} from the calibration; {} per {} px of marker noise",
                u.at,
                nalgebra::Vector3::from(u.at_mm).norm(),
                axes(t.position),
                uncertainty::DISPLACEMENT_MM,
                axes(t.displacement),
                axes(t.marker),
                uncertainty::MARKER_NOISE_PX
            );
        }
        None => println!("{}", file::uncertainty_note(c)),
    }
    if let Some(b) = &c.bootstrap {
        println!(
            "1 sd (bootstrap, {} rounds, seed {}): {}",
            b.rounds,
            b.seed,
            parameters(&b.parameters)
        );
    }
    let g = &c.guidance;
    let coverage = g.coverage();
    println!(
        "coverage {:.0} % / {:.0} % of the image (left / right, # = corners seen); board tilt sd {:.0}° about x, {:.0}° about y",
        100.0 * coverage[0],
        100.0 * coverage[1],
        g.tilt_sd_deg[0],
        g.tilt_sd_deg[1]
    );
    for (l, r) in g.map(0).iter().zip(g.map(1)) {
        println!("  {l}  {r}");
    }
    println!(
        "boards triangulate to {:.4} ± {:.4} squares, {:.3} mm off-plane RMS",
        c.board_check.neighbour_mean_squares,
        c.board_check.neighbour_sd_squares,
        c.board_check.planarity_rms_mm
    );
    if let Some(v) = &c.validation {
        print_validation(v);
    }
    println!("hand axes: {}", c.hand_axes_note);
    for a in &g.advice {
        println!("advice: {a}");
    }
}

/// `--validate`'s check of the stated deviations against two halves of the pairs.
fn print_validation(v: &validate::Validation) {
    let axes = |v: [f64; 3]| format!("{:.4}/{:.4}/{:.4}", v[0], v[1], v[2]);
    println!(
        "validation ({} splits into halves of {}/{} pairs): the halves' tips disagree by {} mm RMS (x/y/depth) over ±{} mm around the finger, their covariances predict {} mm: ratio {:.2} (about 1 when the stated deviations are honest)",
        v.splits,
        v.half_pairs[0],
        v.half_pairs[1],
        axes(v.disagreement_mm),
        validate::VOLUME_MM,
        axes(v.predicted_mm),
        v.ratio
    );
    if let (Some(near), Some(far)) = (v.map.first(), v.map.last()) {
        println!(
            "  tip position sd {:.4} mm {:.0} mm from the nearest board corner seen, {:.4} mm at {:.0} mm; the finger's base is {:.0} mm from one",
            near.1, near.0, far.1, far.0, v.base_distance_mm
        );
    }
    for w in &v.warnings {
        println!("  warning: {w}");
    }
}
