//! `handcap triangulate DIR/frames --calib calib.yml --pressures DIR/pressures.csv --out
//! dataset.csv`: the tip in every frame pair, in the hand frame, one row per pressure step.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use handcap::fsio;
use handcap::provenance::Provenance;
use handcap::stereo;
use handcap::triangulate::{self, pairing, TriangulateOptions, Triangulation};

#[derive(clap::Args)]
pub struct Args {
    /// Directory with frames.csv and left_NNNNN / right_NNNNN images (PNG or JPEG)
    frames: PathBuf,
    /// Stereo calibration with the hand axes (R_hand), as `handcap calibrate` writes it
    #[arg(long)]
    calib: PathBuf,
    /// Regulator log: time_s,P1_kpa,P2_kpa,P3_kpa, one row per commanded step (default: the
    /// frames directory's parent's pressures.csv)
    #[arg(long)]
    pressures: Option<PathBuf>,
    /// Dataset to write (CSV); the other files go beside it
    #[arg(long, default_value = "dataset.csv")]
    out: PathBuf,
    /// Largest left/right timestamp difference of a pair, ms
    #[arg(long, default_value_t = 1e3 * TriangulateOptions::default().max_dt_s)]
    max_dt_ms: f64,
    /// Frames earlier than this into their pressure step are skipped, s
    #[arg(long, default_value_t = TriangulateOptions::default().settle_s)]
    settle_s: f64,
    /// Largest reprojection error of a used pair, px
    #[arg(long, default_value_t = TriangulateOptions::default().max_reproj_px)]
    max_reproj_px: f64,
    /// Triangulate the raw matches, without the Hartley-Sturm correction
    #[arg(long)]
    no_correct_matches: bool,
    /// Rows with fewer frame pairs are flagged
    #[arg(long, default_value_t = TriangulateOptions::default().min_frames)]
    min_frames: usize,
    /// Rows whose frame pairs lie further apart are flagged, mm
    #[arg(long, default_value_t = TriangulateOptions::default().max_spread_mm)]
    max_spread_mm: f64,
    /// Marker area limits (pixels above half its peak redness): MIN,MAX
    #[arg(long, value_delimiter = ',', num_args = 2, default_values_t = [TriangulateOptions::default().marker.min_area_px, TriangulateOptions::default().marker.max_area_px])]
    marker_area_px: Vec<usize>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if !a.frames.is_dir() {
        bail!("{} is not a directory of frames", a.frames.display());
    }
    let pressures = match a.pressures {
        Some(p) => p,
        None => a
            .frames
            .parent()
            .map(|d| d.join("pressures.csv"))
            .filter(|p| p.is_file())
            .with_context(|| {
                format!(
                    "no --pressures given and no pressures.csv beside {}; pass --pressures LOG.csv",
                    a.frames.display()
                )
            })?,
    };
    let mut options = TriangulateOptions {
        max_dt_s: a.max_dt_ms / 1e3,
        settle_s: a.settle_s,
        max_reproj_px: a.max_reproj_px,
        correct_matches: !a.no_correct_matches,
        min_frames: a.min_frames,
        max_spread_mm: a.max_spread_mm,
        ..TriangulateOptions::default()
    };
    options.marker.min_area_px = a.marker_area_px[0];
    options.marker.max_area_px = a.marker_area_px[1];
    let inputs = [a.calib.as_path(), pressures.as_path()];
    if fsio::is_same_file_as_any(&a.out, &inputs) {
        bail!(
            "--out {} is one of the inputs; choose another file",
            a.out.display()
        );
    }
    triangulate_and_write(&a.frames, &a.calib, &pressures, &options, &a.out)?;
    Ok(())
}

/// Triangulates with a progress bar, prints the summary, writes the dataset and the files
/// beside it.
pub fn triangulate_and_write(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
) -> anyhow::Result<Triangulation> {
    let calibration = stereo::read_calibration(calib)?;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    let log = pairing::read_pressure_log(pressures)?;
    let bar = super::Counter::new("frames {bar:30} {pos}/{len} ({per_sec}, {eta})");
    let interrupt = super::interrupt_flag();
    let result = triangulate::triangulate(
        frames,
        &calibration,
        &log,
        options,
        &|done, total| bar.update(done, total),
        &interrupt,
    );
    bar.finish();
    let tri = result?;
    let provenance = Provenance::new(super::command_line(), None)
        .with_input(calib)
        .and_then(|p| p.with_input(pressures))
        .and_then(|p| p.with_input(&frames.join("frames.csv")))
        .context("hashing the inputs")?;
    // Files first, then the printing: a closed pipe on stdout must not cost the results.
    let written = tri.write(out, &provenance)?;
    print_summary(&tri);
    for f in written {
        println!("wrote {}", f.display());
    }
    if tri.summary.interrupted {
        bail!("interrupted: the dataset holds the frames examined before Ctrl-C; run again for all of them");
    }
    Ok(tri)
}

fn print_summary(t: &Triangulation) {
    let s = &t.summary;
    let f = &s.frames;
    println!(
        "frames: {} left, {} right; marker missing in {} / {}, several candidates in {} / {}, unreadable {} / {}, no file {} / {}",
        f.listed[0],
        f.listed[1],
        f.marker_missing[0],
        f.marker_missing[1],
        f.several_candidates[0],
        f.several_candidates[1],
        f.unreadable[0],
        f.unreadable[1],
        f.no_file[0],
        f.no_file[1],
    );
    let pairs: Vec<String> = s.pairs.iter().map(|(k, v)| format!("{v} {k}")).collect();
    println!(
        "pairs: {} formed ({} left, {} right frames unpaired): {}",
        s.pairs_formed,
        s.unpaired[0],
        s.unpaired[1],
        pairs.join(", ")
    );
    println!(
        "reprojection of used pairs: median {:.3} px, 95 % {:.3} px, max {:.3} px",
        s.reproj_px[0], s.reproj_px[1], s.reproj_px[2]
    );
    println!(
        "hand origin: {} pairs over {} zero-pressure steps, spread {:.4} mm",
        s.origin.pairs, s.origin.zero_steps, s.origin.spread_mm
    );
    println!(
        "steps: {} logged, {} rows ({} flagged), {} without a tip",
        s.steps_logged,
        s.rows,
        s.rows_flagged,
        s.steps_without_tip.len()
    );
    for r in t.rows.iter().filter(|r| !r.flags.is_empty()).take(10) {
        println!(
            "  flagged step {} ({}, {}, {} kPa): {} ({} pairs, spread {:.3} mm)",
            r.step,
            r.pressures_kpa[0],
            r.pressures_kpa[1],
            r.pressures_kpa[2],
            r.flags.join(", "),
            r.n_frames,
            r.spread_mm
        );
    }
}
