//! `handcap calibrate DIR`: stereo calibration from chessboard pairs → OpenCV YAML + quality
//! (the file's keys: `handcap::calib::file`).

use std::path::PathBuf;

use anyhow::bail;

use handcap::calib::{file, CalibOptions};
use handcap::pipeline::calibrate::{self, Calibrated};

use super::synth::parse_board;

#[derive(clap::Args)]
pub struct Args {
    /// Directory with left*/right* chessboard images (PNG or JPEG)
    dir: PathBuf,
    /// Inner corners COLSxROWS (default: DIR/board.yml, as `synth` writes it, else calib/board.yml's 9x6)
    #[arg(long, value_parser = parse_board)]
    board: Option<(usize, usize)>,
    /// Printed square size in mm (default: DIR/board.yml, else calib/board.yml's 10 mm)
    #[arg(long)]
    square_mm: Option<f64>,
    /// Calibration file to write (OpenCV YAML)
    #[arg(long, default_value = "calib.yml")]
    out: PathBuf,
    /// Fewest pairs to keep when rejecting outliers
    #[arg(long, default_value_t = CalibOptions::default().min_pairs)]
    min_pairs: usize,
    /// LEFT,RIGHT: each camera's intrinsics from an earlier single-camera calibration (OpenCV
    /// YAML: camera_matrix, distortion_coefficients, image_width, image_height), fixed instead of
    /// solved; `-` for a camera to solve (e.g. `--intrinsics left.yml,-`)
    #[arg(long, value_delimiter = ',', num_args = 1)]
    intrinsics: Vec<PathBuf>,
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
        ..CalibOptions::default()
    };
    let done = super::with_session(|s| {
        let board = calibrate::board(&a.dir, a.board, a.square_mm, s)?;
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
    println!(
        "RMS {:.3} px, epipolar {:.3} px, baseline {:.2} mm, f {:.1}/{:.1} px",
        c.rms_px,
        c.epipolar_px,
        c.rig.right_from_left.translation.norm(),
        c.rig.left.fx(),
        c.rig.right.fx()
    );
    println!(
        "coverage {:.0} % / {:.0} % of the image; boards triangulate to {:.4} ± {:.4} squares, {:.3} mm off-plane RMS",
        100.0 * c.coverage[0],
        100.0 * c.coverage[1],
        c.board_check.neighbour_mean_squares,
        c.board_check.neighbour_sd_squares,
        c.board_check.planarity_rms_mm
    );
    println!("hand axes: {}", c.hand_axes_note);
}
