//! `handcap calibrate DIR`: stereo calibration from chessboard pairs → OpenCV YAML + quality
//! (the file's keys: `crate::calib::file`).

use std::path::PathBuf;

use anyhow::bail;

use crate::calib::CalibOptions;
use crate::pipeline::calibrate;

#[derive(clap::Args)]
pub struct Args {
    /// Directory with left*/right* board images (PNG or JPEG), or two videos of the board; or,
    /// for more cameras, `<camera>_NN` images (any word for a camera; one NN one instant) and
    /// `<camera>_ref`, written as Anipose's calibration.toml beside --out
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
    /// solved; `-` for a camera to solve (e.g. `--intrinsics left.yml,-`). With more cameras,
    /// NAME=FILE for every camera (cam1=cam1.yml,cam2=cam2.yml,…), all fixed in the joint
    /// refinement
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
    let (intrinsics, named_intrinsics) = calibrate::given_intrinsics(&a.intrinsics)?;
    let options = CalibOptions {
        min_pairs: a.min_pairs,
        intrinsics,
        named_intrinsics,
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
        calibrate::run_any(&a.dir, &board, &options, &a.out, s)
    })?;
    print!("{done}");
    for (camera, known) in ["left", "right"].iter().zip(&options.intrinsics) {
        if let Some(k) = known {
            println!(
                "{camera} intrinsics fixed as {} gives them",
                k.path.display()
            );
        }
    }
    super::print_written(done.written());
    Ok(())
}
