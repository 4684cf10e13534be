//! `handcap calibrate DIR`: stereo calibration from chessboard pairs → OpenCV YAML + quality.
//!
//! The YAML (`cv2.FileStorage` reads it) holds `image_size`, `K1`, `D1`, `K2`, `D2`, `R`, `T`
//! (left → right, mm), `E`, `F`, `R1`, `R2`, `P1`, `P2`, `Q`, `rms_px`, `epipolar_px`,
//! `per_view_rms_px` (one row per used pair: left, right), `views_used`, `views_rejected`, the
//! board, the detector, `coverage`, the triangulated-board check, `R_hand` (left camera → hand
//! axes) when a reference pair was given, and provenance.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use handcap::calib::{self, BoardSpec, CalibOptions, StereoCalibration};
use handcap::fsio;
use handcap::provenance::Provenance;

use super::synth::parse_board;

#[derive(clap::Args)]
pub struct Args {
    /// Directory with left*/right* chessboard images (PNG or JPEG)
    dir: PathBuf,
    /// Inner corners COLSxROWS (default: DIR/board.yml, as `synth` writes it)
    #[arg(long, value_parser = parse_board)]
    board: Option<(usize, usize)>,
    /// Printed square size in mm (default: DIR/board.yml)
    #[arg(long)]
    square_mm: Option<f64>,
    /// Calibration file to write (OpenCV YAML)
    #[arg(long, default_value = "calib.yml")]
    out: PathBuf,
    /// Fewest pairs to keep when rejecting outliers
    #[arg(long, default_value_t = CalibOptions::default().min_pairs)]
    min_pairs: usize,
}

/// Board size and square as given, else from `dir/board.yml`.
pub fn board_spec(
    dir: &Path,
    board: Option<(usize, usize)>,
    square_mm: Option<f64>,
) -> anyhow::Result<BoardSpec> {
    let from_file = || -> anyhow::Result<BoardSpec> {
        let path = dir.join("board.yml");
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "no --board/--square-mm given and {} cannot be read; pass --board COLSxROWS --square-mm MM",
                path.display()
            )
        })?;
        let value = |key: &str| -> anyhow::Result<f64> {
            text.lines()
                .find_map(|l| l.strip_prefix(&format!("{key}:")))
                .and_then(|v| v.trim().parse().ok())
                .with_context(|| format!("{}: no number for {key}", path.display()))
        };
        Ok(BoardSpec {
            cols: value("inner_corners_cols")? as usize,
            rows: value("inner_corners_rows")? as usize,
            square_mm: value("square_mm")?,
        })
    };
    let file = if board.is_none() || square_mm.is_none() {
        Some(from_file()?)
    } else {
        None
    };
    let (cols, rows) = board.unwrap_or_else(|| file.map(|f| (f.cols, f.rows)).expect("read above"));
    Ok(BoardSpec {
        cols,
        rows,
        square_mm: square_mm.unwrap_or_else(|| file.map(|f| f.square_mm).expect("read above")),
    })
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if !a.dir.is_dir() {
        bail!(
            "{} is not a directory of calibration images",
            a.dir.display()
        );
    }
    let board = board_spec(&a.dir, a.board, a.square_mm)?;
    let options = CalibOptions {
        min_pairs: a.min_pairs,
        ..CalibOptions::default()
    };
    calibrate_and_write(&a.dir, &board, &options, &a.out)?;
    Ok(())
}

/// Calibrates with a progress bar, prints the summary, writes the YAML and the figures.
pub fn calibrate_and_write(
    dir: &Path,
    board: &BoardSpec,
    options: &CalibOptions,
    out: &Path,
) -> anyhow::Result<StereoCalibration> {
    let bar = super::Counter::new("detect {bar:30} {pos}/{len} images");
    let result = calib::calibrate(dir, board, options, &|done, total| bar.update(done, total));
    bar.finish();
    let cal = result?;
    let provenance = Provenance::new(super::command_line(), None);
    // Files first, then the printing: a closed pipe on stdout must not cost the results.
    fsio::write_bytes(out, cal.to_yaml(&provenance).as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    let figures = cal.write_figures(out)?;
    print_summary(&cal);
    println!("wrote {}", out.display());
    for f in figures {
        println!("wrote {}", f.display());
    }
    Ok(cal)
}

fn print_summary(c: &StereoCalibration) {
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
    let t = c.rig.t;
    println!(
        "RMS {:.3} px, epipolar {:.3} px, baseline {:.2} mm, f {:.1}/{:.1} px",
        c.rms_px,
        c.epipolar_px,
        (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt(),
        c.rig.left.k[0],
        c.rig.right.k[0]
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
